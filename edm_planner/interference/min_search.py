"""The exact minimum clearance over a pose sequence (numba): the kernels of plan verification.

Branch and bound over (sample interval x vertex cluster) on the 1-Lipschitz
signed distance, with the side-of-wall test for vertices behind a wall; used
by :func:`.pose_check.verify_poses` through
:meth:`.fast.FastChannelField`. Units: mm, rad.
"""

import heapq
import math

import numba
import numpy as np
from numba import types
from numba.typed import Dict

from ..geometry.spline_kernels import new_work
from .exact_solvers import _behind_at, _exact_at
from .field_params import named_args, named_exact
from .field_query import _fast_point


#: relative slack on a node's reach (rounding; rotations orthonormal to 1e-9)
_REACH_SLACK = 1e-8


#: bound on |R_t - R_mid| less |R_t - R_mid|_F / sqrt 2 for rotations orthonormal to 1e-9
_ROTATION_SLACK = 1e-8


#: the side test trusts the field's sign beyond this clearance [mm] (its error bound is ~0.004 mm; cells
#: across a change of sign, where values of neighbouring nodes differ by more than their distance, are
#: marked for the exact solver)
_SIDE_SCREEN = 1.0


#: margin on the faces' (x, r) box (from 201 x 101 samples of each face, plus 0.01 mm) [mm]
_BOX_MARGIN = 0.1


@numba.njit(cache=True)
def _vertex_tree(V):
    """Binary tree of vertex clusters: median splits along the longest side of the cluster's box.

    Returns
    -------
    rep : (n,) int
        Per node the vertex (index into V) nearest the middle of its box.
    radius : (n,) float
        Largest distance of a vertex of the cluster from ``rep`` [mm].
    left, right : (n,) int
        Children; -1 for a leaf (one vertex).
    """
    m = V.shape[0]
    n = 2 * m - 1
    perm = np.arange(m)
    lo = np.zeros(n, dtype=np.int64)
    hi = np.zeros(n, dtype=np.int64)
    rep = np.zeros(n, dtype=np.int64)
    radius = np.zeros(n)
    left = np.full(n, -1, dtype=np.int64)
    right = np.full(n, -1, dtype=np.int64)
    hi[0] = m
    count, node = 1, 0
    while node < count:
        a, b = lo[node], hi[node]
        box_lo = np.full(3, np.inf)
        box_hi = np.full(3, -np.inf)
        for i in range(a, b):
            for j in range(3):
                box_lo[j] = min(box_lo[j], V[perm[i], j])
                box_hi[j] = max(box_hi[j], V[perm[i], j])
        centre = 0.5 * (box_lo + box_hi)
        near, r = np.inf, perm[a]
        for i in range(a, b):
            d = (V[perm[i], 0] - centre[0]) ** 2 + (V[perm[i], 1] - centre[1]) ** 2 + (V[perm[i], 2] - centre[2]) ** 2
            if d < near:
                near, r = d, perm[i]
        far = 0.0
        for i in range(a, b):
            far = max(far, (V[perm[i], 0] - V[r, 0]) ** 2 + (V[perm[i], 1] - V[r, 1]) ** 2
                      + (V[perm[i], 2] - V[r, 2]) ** 2)
        rep[node], radius[node] = r, math.sqrt(far)
        if b - a > 1:
            axis = int(np.argmax(box_hi - box_lo))
            part = perm[a:b].copy()
            perm[a:b] = part[np.argsort(V[part, axis], kind="mergesort")]
            half = (a + b) // 2
            left[node], right[node] = count, count + 1
            lo[count], hi[count], lo[count + 1], hi[count + 1] = a, half, half, b
            count += 2
        node += 1
    return rep, radius, left, right


@numba.njit(cache=True)
def _sample_tree(poses, origin):
    """Binary tree of sample intervals [lo, hi], split after their middle sample.

    Returns
    -------
    mid : (n,) int
    rho : (n,) float
        Largest |R_t - R_mid| (spectral norm: a difference of rotations has two equal singular values,
        so the Frobenius norm over sqrt 2) over the interval.
    tau : (n,) float
        Largest |(R_t - R_mid) origin + T_t - T_mid| over the interval [mm].
    left, right : (n,) int
        Children; -1 for a leaf (one sample).
    """
    N = poses.shape[0]
    n = 2 * N - 1
    lo = np.zeros(n, dtype=np.int64)
    hi = np.zeros(n, dtype=np.int64)
    mid = np.zeros(n, dtype=np.int64)
    rho = np.zeros(n)
    tau = np.zeros(n)
    left = np.full(n, -1, dtype=np.int64)
    right = np.full(n, -1, dtype=np.int64)
    hi[0] = N - 1
    move = np.zeros(3)
    count, node = 1, 0
    while node < count:
        a, b = lo[node], hi[node]
        md = (a + b) // 2
        mid[node] = md
        r2, t2 = 0.0, 0.0
        for t in range(a, b + 1):
            f = 0.0
            for i in range(3):
                move[i] = poses[t, i, 3] - poses[md, i, 3]
                for j in range(3):
                    e = poses[t, i, j] - poses[md, i, j]
                    f += e * e
                    move[i] += e * origin[j]
            r2 = max(r2, 0.5 * f)
            t2 = max(t2, move[0] * move[0] + move[1] * move[1] + move[2] * move[2])
        rho[node], tau[node] = math.sqrt(r2) + _ROTATION_SLACK, math.sqrt(t2)
        if b > a:
            left[node], right[node] = count, count + 1
            lo[count], hi[count], lo[count + 1], hi[count + 1] = a, md, md + 1, b
            count += 2
        node += 1
    return mid, rho, tau, left, right


@numba.njit(cache=True, inline="always")
def _place(poses, V, t, k):
    """Vertex k under pose t, in W."""
    ex, ey, ez = V[k, 0], V[k, 1], V[k, 2]
    return (poses[t, 0, 0] * ex + poses[t, 0, 1] * ey + poses[t, 0, 2] * ez + poses[t, 0, 3],
            poses[t, 1, 0] * ex + poses[t, 1, 1] * ey + poses[t, 1, 2] * ez + poses[t, 1, 3],
            poses[t, 2, 0] * ex + poses[t, 2, 1] * ey + poses[t, 2, 2] * ez + poses[t, 2, 3])


@numba.njit(cache=True, inline="always")
def _reach(radius, rho, offset, tau):
    return (radius + rho * offset + tau) * (1.0 + _REACH_SLACK) + _REACH_SLACK


@numba.njit(cache=True, nogil=True)
def _min_search(surface, poses, V, c_rep, c_rad, c_off, c_left, c_right, s_mid, s_rho, s_tau, s_left, s_right,
                seed_t, seed_k, seed_v, tol, channel_angle, params, shape, tables, c_root, shared):
    """Exact minimum of one surface's signed distance over every sample and the vertices of cluster ``c_root``.

    Best-first branch and bound. ``seed_*``: pairs evaluated already (behind a wall). ``shared`` (1,): the
    smallest value found so far by any search of the same surface (other clusters, other threads): it
    prunes here as well, and this search lowers it. Only a value actually found is ever written, so it
    never lies below the surface's minimum, and a pair attaining that minimum is never pruned (its bound
    is not above it): the minimum and its pair (the lowest key among ties) are those of one search over
    all vertices. Which other pairs get evaluated depends on the threads' timing. Returns the minimum
    over the cluster (inf when everything was pruned by ``shared``), its sample and vertex, the number of
    exact evaluations and the keys ``t * m + k`` of every pair evaluated.
    """
    params, shape, tables = named_exact(params, shape, tables)
    m = V.shape[0]
    work = new_work()
    done = Dict.empty(key_type=types.int64, value_type=types.float64)
    best, best_key = np.inf, -1
    for i in range(seed_t.shape[0]):
        key = seed_t[i] * m + seed_k[i]
        done[key] = seed_v[i]
        if seed_v[i] < best or (seed_v[i] == best and key < best_key):
            best, best_key = seed_v[i], key
    evaluations = 0
    heap = [(-np.inf, np.int64(0), np.int64(c_root))]
    while len(heap) > 0:
        prior, sn, cn = heapq.heappop(heap)
        if best < shared[0]:
            shared[0] = best            # a value found (a racing thread may raise it again: only less pruning)
        low = min(best, shared[0])
        if prior >= low + tol:
            break
        t, k = s_mid[sn], c_rep[cn]
        key = t * m + k
        px, py, pz = _place(poses, V, t, k)
        if key in done:
            v = done[key]
        else:
            v = _exact_at(surface, px, py, pz, channel_angle, params, shape, tables, work)
            done[key] = v
            evaluations += 1
            if v < best or (v == best and key < best_key):
                best, best_key = v, key
        limit = min(best, low) + tol
        bound = max(prior, v - _reach(c_rad[cn], s_rho[sn], c_off[cn], s_tau[sn]))
        if bound >= limit or (s_left[sn] < 0 and c_left[cn] < 0):
            continue
        split_samples = c_left[cn] < 0 or (s_left[sn] >= 0 and s_rho[sn] * c_off[cn] + s_tau[sn] >= c_rad[cn])
        for side in range(2):
            if split_samples:
                sc, cc = (s_left[sn] if side == 0 else s_right[sn]), cn
            else:
                sc, cc = sn, (c_left[cn] if side == 0 else c_right[cn])
            qx, qy, qz = _place(poses, V, s_mid[sc], c_rep[cc])
            gap = math.sqrt((qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2)
            child = max(bound, v - gap * (1.0 + _REACH_SLACK) - _reach(c_rad[cc], s_rho[sc], c_off[cc], s_tau[sc]))
            if child < limit:
                heapq.heappush(heap, (child, sc, cc))
    keys = np.empty(len(done), dtype=np.int64)
    i = 0
    for key in done.keys():
        keys[i] = key
        i += 1
    return best, best_key // m, best_key % m, evaluations, keys


@numba.njit(cache=True, inline="always")
def _sides(x, y, z, channel_angle, flat, hs, fast, fast_shape, params, shape, tables, work):
    """Is the point behind the suction / pressure wall: the sign rule alone, screened by the field.

    Beyond the faces' (x, r) box the point lies outside both footprints: in front. Where the field's
    tables answer and put the point more than ``_SIDE_SCREEN`` in front of a wall (cells across a change of
    sign are marked for the exact solver), it is in front of that wall; elsewhere the exact sign rule
    decides (``_behind_at``).
    """
    rho = math.sqrt(y * y + z * z)
    if (x < params.fx0 - _BOX_MARGIN or x > params.fx1 + _BOX_MARGIN
            or rho < params.fr0 - _BOX_MARGIN or rho > params.fr1 + _BOX_MARGIN):
        return False, False                    # beyond the faces' (x, r) box: outside both footprints
    s, p, _, _, ok = _fast_point(x, y, z, flat, hs, fast, fast_shape)
    behind_s = False if ok and s > _SIDE_SCREEN else _behind_at(0, x, y, z, channel_angle, params, shape, tables, work)
    behind_p = False if ok and p > _SIDE_SCREEN else _behind_at(1, x, y, z, channel_angle, params, shape, tables, work)
    return behind_s, behind_p


@numba.njit(cache=True)
def _anchor_sides(poses, V, anchors, channel_angle, flat, hs, fast, fast_shape, params, shape, tables):
    """``_anchor_sides_named`` on the arguments named (``named_args``): the entry point (plain or named tuples)."""
    return _anchor_sides_named(poses, V, anchors, channel_angle, flat, hs,
                               *named_args(fast, fast_shape, params, shape, tables))


@numba.njit(cache=True, parallel=True)
def _anchor_sides_named(poses, V, anchors, channel_angle, flat, hs, fast, fast_shape, params, shape, tables):
    """(anchors, m, 2) bool: every vertex behind the suction / pressure wall at the anchor samples."""
    m = V.shape[0]
    out = np.zeros((anchors.shape[0], m, 2), dtype=np.bool_)
    for i in numba.prange(anchors.shape[0]):
        work = new_work()
        for k in range(m):
            x, y, z = _place(poses, V, anchors[i], k)
            out[i, k, 0], out[i, k, 1] = _sides(x, y, z, channel_angle, flat, hs, fast, fast_shape, params, shape,
                                                tables, work)
    return out


@numba.njit(cache=True)
def _sweep_sides(poses, V, face, vertex, first, last, channel_angle, flat, hs, fast, fast_shape, params, shape,
                 tables):
    """``_sweep_sides_named`` on the arguments named (``named_args``): the entry point (plain or named tuples)."""
    return _sweep_sides_named(poses, V, face, vertex, first, last, channel_angle, flat, hs,
                              *named_args(fast, fast_shape, params, shape, tables))


@numba.njit(cache=True, parallel=True)
def _sweep_sides_named(poses, V, face, vertex, first, last, channel_angle, flat, hs, fast, fast_shape, params, shape,
                       tables):
    """Vertex ``vertex[i]`` behind wall ``face[i]`` at samples first[i] .. last[i] - 1.

    Returns the flags of all runs concatenated and their starts in it ((runs + 1,) int).
    """
    start = np.zeros(face.shape[0] + 1, dtype=np.int64)
    for i in range(face.shape[0]):
        start[i + 1] = start[i] + max(last[i] - first[i], 0)
    out = np.zeros(start[-1], dtype=np.bool_)
    for i in numba.prange(face.shape[0]):
        work = new_work()
        for t in range(first[i], last[i]):
            x, y, z = _place(poses, V, t, vertex[i])
            out[start[i] + t - first[i]] = _sides(x, y, z, channel_angle, flat, hs, fast, fast_shape, params, shape,
                                                  tables, work)[face[i]]
    return out, start


@numba.njit(cache=True)
def _exact_pairs(poses, V, t, k, surface, channel_angle, params, shape, tables):
    """``_exact_pairs_named`` on the arguments named (``named_exact``): the entry point (plain or named tuples)."""
    return _exact_pairs_named(poses, V, t, k, surface, channel_angle, *named_exact(params, shape, tables))


@numba.njit(cache=True, parallel=True)
def _exact_pairs_named(poses, V, t, k, surface, channel_angle, params, shape, tables):
    """Exact signed distances of the given (sample, vertex, surface) triples."""
    out = np.empty(t.shape[0])
    for i in numba.prange(t.shape[0]):
        work = new_work()
        x, y, z = _place(poses, V, t[i], k[i])
        out[i] = _exact_at(surface[i], x, y, z, channel_angle, params, shape, tables, work)
    return out


@numba.njit(cache=True, parallel=True)
def _vertex_steps(poses, V):
    """(N - 1,) the largest move of any vertex between consecutive samples [mm]."""
    N, m = poses.shape[0], V.shape[0]
    out = np.zeros(max(N - 1, 0))
    for t in numba.prange(N - 1):
        big = 0.0
        for k in range(m):
            ax, ay, az = _place(poses, V, t, k)
            bx, by, bz = _place(poses, V, t + 1, k)
            big = max(big, (bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
        out[t] = math.sqrt(big)
    return out
