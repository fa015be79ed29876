"""The stock electrode sweeps leave at points: the exact minimum over every pose, pruned by branch and bound.

In EDM the material within the discharge gap g of the electrode is eroded,
so at a point p the stock left is

    stock(p) = min over electrodes, poses t of  sd(p, E_t) - g

with sd the signed distance to the closed electrode mesh (positive outside;
:class:`~.mesh_distance.MeshDistance`). This is exact for the Minkowski sum
E_t + B(g): the distance from an outside point to it is d(p, E_t) - g.

:func:`stock_at_points` evaluates that minimum exactly (to float precision,
with respect to the electrode meshes and the given poses). It prunes
(point, pose) pairs by branch and bound over the pose sequence: sd is
1-Lipschitz in the point, and between two poses a and s a point p, seen in
the electrode frame, moves by |q_s - q_a| <= ||R_s^T - R_a^T|| |p - c| +
|(R_s^T - R_a^T) c - (R_s^T o_s - R_a^T o_a)| (c the centroid of the
point's part: the points are split into ``CLUSTERS`` parts, :func:`_clusters`). The poses of a sweep form a binary tree of intervals (each node
evaluated at its middle pose; :class:`_PoseTree`); a pair is refined into the
node's halves only while ``sd(middle) - travel`` could still beat the point's
best, and a child is skipped without a distance query where the point's
distance to the electrode's bounding box (in its frame) less the child's
travel already cannot. Every sweep's last pose (a feed's machining pose) is
evaluated first to seed the bounds. The result is the brute-force minimum
over all poses (``test/test_removal.py`` checks it).

Measured on this 2-core machine (shared with other jobs), default blisk,
84 463 wall samples at 0.2 mm: one pose of the primitive electrode (58 856
triangles) 0.35 s (2.4e5 points x poses per second, every pair queried);
a real certified feed (the rear electrode of the front/rear split design,
18 112 triangles, 943 poses 0.05 mm apart) 13 s, 6.1e6 points x poses per
second with 5.7 % of the pairs queried; the same feed densified to 1 885
poses 17 s, 9.2e6 per second, 3.8 % queried; a synthetic 2 000-pose sweep
4.5 um apart that cuts through the walls 33 s, 5.1e6 per second. What
pruning cannot remove are near-ties: a pose within its travel bound of a
point's minimum must be evaluated, so a sweep that keeps a wall at nearly
the same distance over many poses (sliding along it) costs one query per
such pair.

Plain numpy/numba; no rclpy. Units: mm, rad, s.
"""

import time
from dataclasses import dataclass

import numba
import numpy as np

from .mesh_distance import MeshDistance
from .removal_tolerances import REMOVAL


#: parts of the points with a travel centre of their own (the rotation term of a travel bound grows with the
#: distance from the centre)
CLUSTERS = 64


@dataclass(frozen=True)
class Sweep:
    """One electrode moved through a sequence of poses.

    Attributes
    ----------
    vertices : (m, 3) float
        Electrode mesh vertices in the electrode frame [mm].
    faces : (f, 3) int
        Triangles of the closed, outward-oriented electrode mesh.
    poses : (k, 4, 4) float
        Electrode frame -> W, in motion order.
    breaks : (b,) int, optional
        Indices i where pose i + 1 does not follow pose i by a motion (the sweep joins moves that do
        not meet: the moves that retrace another are left out of a proof); the continuous bound skips them.
    """

    vertices: np.ndarray
    faces: np.ndarray
    poses: np.ndarray
    breaks: np.ndarray = None

    def __iter__(self):
        # unpacks like the plain (vertices, faces, poses) tuple
        return iter((self.vertices, self.faces, self.poses))

    @classmethod
    def from_electrode(cls, electrode, poses):
        """Sweep of an :class:`~edm_planner.geometry.electrode.Electrode` through ``poses`` (k, 4, 4) or (4, 4)."""
        return cls(np.asarray(electrode.mesh.vertices), np.asarray(electrode.mesh.faces), _poses(poses))


def _poses(poses):
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 2:
        p = p[None]
    if p.ndim != 3 or p.shape[1:] != (4, 4) or not len(p):
        raise ValueError(f"poses: expected (k, 4, 4) electrode->W transforms, got shape {p.shape}")
    return p


@numba.njit(cache=True)
def _scatter_min(idx, vals, pose, best, which, j):
    """best[idx] = min(best[idx], vals) pair by pair, ``which`` the (sweep, pose) of each new minimum."""
    for i in range(len(idx)):
        p = idx[i]
        if vals[i] < best[p]:
            best[p] = vals[i]
            which[p, 0] = j
            which[p, 1] = pose[i]


# -- the pose tree ---------------------------------------------------------------
class _PoseTree:
    """Binary tree of pose intervals with travel bounds; node = (lo, hi), evaluated at its middle pose.

    ``alpha[node] * d + beta[node, k]`` bounds, for a point of part k at distance d
    from that part's centre (row k of ``centres``), how far it moves in the
    electrode frame between the node's middle pose and any pose of the node's
    interval; ``alpha_par``, ``beta_par`` the same from the parent's middle pose.
    """

    def __init__(self, inv_r, inv_t, centres, first, last):
        self.inv_r, self.inv_t = inv_r, inv_t
        lo, hi, parent = [first], [last], [-1]
        level = [0]
        while level:
            nxt = []
            for i in level:
                m = (lo[i] + hi[i]) // 2
                for a, b in ((lo[i], m - 1), (m + 1, hi[i])):
                    if a <= b:
                        lo.append(a), hi.append(b), parent.append(i)
                        nxt.append(len(lo) - 1)
            level = nxt
        self.lo, self.hi, self.parent = np.array(lo), np.array(hi), np.array(parent)
        self.mid = (self.lo + self.hi) // 2
        self.left = np.full(len(lo), -1)
        self.right = np.full(len(lo), -1)
        for i in range(1, len(lo)):
            p = self.parent[i]
            if self.lo[i] == self.lo[p]:
                self.left[p] = i
            else:
                self.right[p] = i
        anchor_self = self.mid
        anchor_parent = np.where(self.parent >= 0, self.mid[np.maximum(self.parent, 0)], self.mid)
        self.alpha, self.beta = self._bounds(anchor_self, centres)
        self.alpha_par, self.beta_par = self._bounds(anchor_parent, centres)

    def _bounds(self, anchor, centres):
        """Per node: max over its poses s of ||R_s^T - R_a^T|| and, per centre c (rows of ``centres``, (K, 3)),
        |(R_s^T - R_a^T) c + t_s - t_a|: (alpha (nodes,), beta (nodes, K))."""
        centres = np.atleast_2d(centres)
        alpha = np.zeros(len(self.lo))
        beta = np.zeros((len(self.lo), len(centres)))
        # nodes of one depth have disjoint intervals: one vectorised pass per depth
        depth = np.zeros(len(self.lo), dtype=int)
        for i in range(1, len(self.lo)):
            depth[i] = depth[self.parent[i]] + 1
        for d in range(depth.max() + 1):
            nodes = np.where(depth == d)[0]
            sizes = self.hi[nodes] - self.lo[nodes] + 1
            owner = np.repeat(nodes, sizes)
            s = np.concatenate([np.arange(a, b + 1) for a, b in zip(self.lo[nodes], self.hi[nodes])])
            a = anchor[owner]
            dr = self.inv_r[s] - self.inv_r[a]
            norm = np.linalg.norm(dr, ord=2, axis=(1, 2))
            shift = np.linalg.norm(dr @ centres.T + (self.inv_t[s] - self.inv_t[a])[:, :, None], axis=1)
            start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            alpha[nodes] = np.maximum.reduceat(norm, start)
            beta[nodes] = np.maximum.reduceat(shift, start)
        return alpha, beta


def _clusters(points, count=CLUSTERS):
    """Split the points at the median of their longest extent until ``count`` parts: (centres (K, 3), part (n,))."""
    part = np.zeros(len(points), dtype=np.int64)
    groups = [np.arange(len(points))]
    while len(groups) < count and max(len(g) for g in groups) > 1:
        nxt = []
        for g in groups:
            if len(g) < 2:
                nxt.append(g)
                continue
            q = points[g]
            axis = int(np.argmax(q.max(axis=0) - q.min(axis=0)))
            order = np.argsort(q[:, axis], kind="stable")
            half = len(g) // 2
            nxt += [g[order[:half]], g[order[half:]]]
        groups = nxt
    centres = np.empty((len(groups), 3))
    for i, g in enumerate(groups):
        part[g] = i
        centres[i] = points[g].mean(axis=0)
    return centres, part


def _step_travel(inv_r, inv_t, centre, radius):
    """Bound (k-1,) on how far any point within ``radius`` of ``centre`` moves between consecutive poses."""
    if len(inv_r) < 2:
        return np.zeros(0)
    dr = inv_r[1:] - inv_r[:-1]
    return (np.linalg.norm(dr, ord=2, axis=(1, 2)) * radius
            + np.linalg.norm(dr @ centre + inv_t[1:] - inv_t[:-1], axis=1))


def _inverse(poses):
    inv_r = np.swapaxes(poses[:, :3, :3], 1, 2)
    inv_t = -np.einsum("kij,kj->ki", inv_r, poses[:, :3, 3])
    return np.ascontiguousarray(inv_r), np.ascontiguousarray(inv_t)


def stock_at_points(points, sweeps, gap, stats=None):
    """Exact stock left at points after EDM by the given electrode sweeps.

    ``stock(p) = min over sweeps j, poses t of sd(p, E_jt) - gap_j`` with sd the
    exact signed distance to the electrode mesh, pruned by branch and bound over
    the poses (see the module docstring); equal to the brute-force minimum.

    Parameters
    ----------
    points : (n, 3) float
        Query points in W [mm].
    sweeps : sequence of Sweep or (vertices (m, 3), faces (f, 3), poses (k, 4, 4))
        Electrode meshes in their own frame [mm] and their poses electrode -> W.
    gap : float or sequence of float
        Discharge gap [mm], one for all sweeps or one per sweep.
    stats : dict, optional
        Filled with 'pairs' (n x total poses), 'queries' (distance queries made),
        'calls' (distance calls) and 'elapsed' [s].

    Returns
    -------
    stock : (n,) float
        [mm]; > 0 material left, < 0 overcut.
    which : (n, 2) int
        (sweep index, pose index) attaining each point's minimum.
    """
    t0 = time.perf_counter()
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(P)
    sweeps = [Sweep(np.asarray(v, dtype=np.float64), np.asarray(f), _poses(p)) for v, f, p in sweeps]
    gaps = np.broadcast_to(np.asarray(gap, dtype=np.float64), (len(sweeps),))
    best = np.full(n, np.inf)
    which = np.full((n, 2), -1, dtype=np.int64)
    counts = {"pairs": n * sum(len(s.poses) for s in sweeps), "queries": 0, "calls": 0}
    if not n or not sweeps:
        return best, which
    # each part of the points measures its travel from a centre of its own: the rotation term of the bound
    # grows with the distance from the centre (about 20 % fewer queries than one centre for all)
    centres, cluster = _clusters(P)
    d_centre = np.linalg.norm(P - centres[cluster], axis=1)
    cache = {}
    prepared = []
    for sw in sweeps:
        key = (id(sw.vertices), id(sw.faces))
        if key not in cache:
            cache[key] = MeshDistance(sw.vertices, sw.faces)
        inv_r, inv_t = _inverse(sw.poses)
        prepared.append((cache[key], inv_r, inv_t))

    def evaluate(j, idx, pose, q=None):
        """Stock of points idx at poses pose (arrays) of sweep j; updates best/which."""
        dist, inv_r, inv_t = prepared[j]
        if q is None:
            q = np.einsum("nij,nj->ni", inv_r[pose], P[idx]) + inv_t[pose]
        vals = np.empty(len(idx))
        for s in range(0, len(idx), REMOVAL.batch):
            vals[s:s + REMOVAL.batch] = dist(q[s:s + REMOVAL.batch]) - gaps[j]
            counts["calls"] += 1
        counts["queries"] += len(idx)
        _scatter_min(np.ascontiguousarray(idx, dtype=np.int64), vals,
                     np.ascontiguousarray(np.broadcast_to(pose, idx.shape), dtype=np.int64), best, which, j)
        return vals

    # seed: every sweep's last pose (a feed's machining pose) for every point
    everyone = np.arange(n)
    for j, sw in enumerate(sweeps):
        evaluate(j, everyone, np.full(n, len(sw.poses) - 1))

    safety = REMOVAL.travel_safety
    for j, sw in enumerate(sweeps):
        k = len(sw.poses)
        if k < 2:
            continue
        dist, inv_r, inv_t = prepared[j]
        tree = _PoseTree(inv_r, inv_t, centres, 0, k - 2)
        g = gaps[j]

        def children_of(idx, node, val):
            """Pairs (point, child node) that may still beat the best, with their query points."""
            out_i, out_c, out_q = [], [], []
            for side in (tree.left, tree.right):
                ch = side[node]
                m = ch >= 0
                i, c = idx[m], ch[m]
                ok = val[m] - (tree.alpha_par[c] * d_centre[i] + tree.beta_par[c, cluster[i]] + safety) < best[i]
                i, c = i[ok], c[ok]
                q = np.einsum("nij,nj->ni", inv_r[tree.mid[c]], P[i]) + inv_t[tree.mid[c]]
                bd = dist.box_distance(q)
                # outside its box a point is at least the box distance from the mesh
                lb = np.where(bd > 0, bd - g, -np.inf) - (tree.alpha[c] * d_centre[i] + tree.beta[c, cluster[i]] + safety)
                ok = lb < best[i]
                out_i.append(i[ok]), out_c.append(c[ok]), out_q.append(q[ok])
            return np.concatenate(out_i), np.concatenate(out_c), np.concatenate(out_q)

        # root: the whole interval, pruned by the box only
        root = np.zeros(n, dtype=np.int64)
        q = np.einsum("ij,nj->ni", inv_r[tree.mid[0]], P) + inv_t[tree.mid[0]]
        bd = dist.box_distance(q)
        lb = np.where(bd > 0, bd - g, -np.inf) - (tree.alpha[0] * d_centre + tree.beta[0, cluster] + safety)
        ok = lb < best
        stack = [(everyone[ok], root[ok], q[ok])]
        while stack:
            idx, node, q = stack.pop()
            if not len(idx):
                continue
            val = evaluate(j, idx, tree.mid[node], q)
            # a node's other poses can beat the best only if sd(middle) - travel can
            keep = val - (tree.alpha[node] * d_centre[idx] + tree.beta[node, cluster[idx]] + safety) < best[idx]
            ci, cc, cq = children_of(idx[keep], node[keep], val[keep])
            for s in range(0, len(ci), REMOVAL.batch):
                stack.append((ci[s:s + REMOVAL.batch], cc[s:s + REMOVAL.batch], cq[s:s + REMOVAL.batch]))
    if stats is not None:
        stats.update(counts, elapsed=time.perf_counter() - t0)
    return best, which
