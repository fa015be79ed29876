"""What a channel becomes after EDM: the material-removal simulation.

In EDM the material within the discharge gap g of the electrode is eroded,
so the channel after machining is the union, over every electrode and every
pose t, of the electrode E_t grown by g (its Minkowski sum with a ball of
radius g). At a point p of a final channel surface the stock left is

    stock(p) = min over electrodes, poses t of  sd(p, E_t) - g

with sd the signed distance to the closed electrode mesh (positive
outside). This is exact for the Minkowski sum: the distance from an outside
point to E + B(g) is d(p, E) - g. stock > 0 is material left, stock < 0 an
overcut of depth -stock.

:func:`stock_at_points` evaluates that minimum exactly (to float precision,
with respect to the electrode meshes and the given poses) by libigl's exact
point-triangle distance, signed by the angle-weighted pseudonormal test
(Baerentzen & Aanaes; the same test as ``igl.signed_distance`` with
``SIGNED_DISTANCE_TYPE_PSEUDONORMAL``, done here in numpy because libigl's own
signed path is ~20x slower per query than its unsigned one). It prunes
(point, pose) pairs by branch and bound over the pose sequence: sd is
1-Lipschitz in the point, and between two poses a and s a point p, seen in
the electrode frame, moves by |q_s - q_a| <= ||R_s^T - R_a^T|| |p - c| +
|(R_s^T - R_a^T) c - (R_s^T o_s - R_a^T o_a)| (c the centroid of the
points). The poses of a sweep form a binary tree of intervals (each node
evaluated at its middle pose); a pair is refined into the node's halves only
while ``sd(middle) - travel`` could still beat the point's best, and a child
is skipped without a distance query where the point's distance to the
electrode's bounding box (in its frame) less the child's travel already
cannot. Every sweep's last pose (a feed's machining pose) is evaluated first
to seed the bounds. The result is the brute-force minimum over all poses
(``test/test_removal.py`` checks it).

Measured on this 2-core machine (shared with other jobs), default blisk,
84 463 wall samples at 0.2 mm: one pose of the primitive electrode (58 856
triangles) 0.35 s (2.4e5 points x poses per second, every pair queried);
a real certified feed (the rear electrode of the front/rear split design,
18 112 triangles, 943 poses 0.05 mm apart) 13 s, 6.1e6 points x poses per
second with 5.7 % of the pairs queried; the same feed densified to 1 885
poses 17 s, 9.2e6 per second, 3.8 % queried; a synthetic 2 000-pose sweep
4.5 um apart that cuts through the walls 33 s, 5.1e6 per second. The
unsigned query costs ~3-4 us plus ~40 ms per call (libigl builds its AABB
tree per call, so queries are batched). What pruning cannot remove are
near-ties: a pose within its travel bound of a point's minimum must be
evaluated, so a sweep that keeps a wall at nearly the same distance over
many poses (sliding along it) costs one query per such pair.

:func:`simulate_removal` applies it to four channel surfaces sampled by
:func:`wall_samples` and reports the stock per surface
(:class:`RemovalReport`); :func:`plot_stock_maps` draws the stock maps and
:func:`stock_vertex_colours` colours a channel surface mesh the same way.

Plain numpy/scipy/trimesh/libigl; no rclpy. Units: mm, rad, s.
"""

import time
from dataclasses import dataclass, field

import igl
import numba
import numpy as np

from ..geometry.blisk import CHANNEL_SURFACES
from ..geometry.frames import cylindrical_to_cartesian


#: depths [mm] of the extra sample rows inside every surface edge (see wall_samples)
REMOVAL_EDGE_DEPTHS = (0.005, 0.01, 0.02, 0.03, 0.045, 0.07, 0.1)


@dataclass(frozen=True)
class RemovalTolerances:
    """Settings and numerical tolerances of the removal simulation [mm]."""

    #: stock above this is "not done" [mm]
    stock: float = 0.02
    #: wall sample spacing, the largest distance between neighbouring samples [mm]
    spacing: float = 0.2
    #: samples on a hub/shroud radius are evaluated this far inside the channel for the
    #: wall angles, whose spline footprint may report "outside" exactly on its edge [mm]
    wall_inset: float = 1e-6
    #: barycentric coordinate below which a closest point is on an edge or vertex
    #: (selects the pseudonormal; looser than igl's 1e-12, safe for any dihedral < 180 deg)
    barycentric: float = 1e-9
    #: added to every travel bound so that rounding never prunes a pair that ties [mm]
    travel_safety: float = 1e-9
    #: (point, pose) pairs per distance query batch (memory ~50 bytes each)
    batch: int = 250_000
    #: coarse grid per sample direction used to size the wall grids
    pilot: int = 161
    #: most sample rows or columns of one surface (the grid stops refining there; its spacing is reported)
    max_grid: int = 3000


REMOVAL = RemovalTolerances()


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


# -- exact signed distance ------------------------------------------------------
@numba.njit(cache=True)
def _inside(q, closest, face, V, F, face_normals, edge_normals, vertex_normals, tol):
    """Per query: is it inside the mesh? The pseudonormal of the closest feature (face, edge or vertex).

    A barycentric coordinate of the closest point at or below ``tol`` puts it
    on the opposite edge (one small) or on a vertex (two small, the largest
    one's corner); the query is inside where ``(q - closest) . normal < 0``.
    """
    n = q.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    bary = np.empty(3)
    for i in range(n):
        f = face[i]
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        e0x, e0y, e0z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
        e1x, e1y, e1z = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
        px, py, pz = closest[i, 0] - V[a, 0], closest[i, 1] - V[a, 1], closest[i, 2] - V[a, 2]
        d00 = e0x * e0x + e0y * e0y + e0z * e0z
        d01 = e0x * e1x + e0y * e1y + e0z * e1z
        d11 = e1x * e1x + e1y * e1y + e1z * e1z
        d20 = px * e0x + py * e0y + pz * e0z
        d21 = px * e1x + py * e1y + pz * e1z
        den = d00 * d11 - d01 * d01
        if not abs(den) > 0:
            den = 1.0
        b1 = (d11 * d20 - d01 * d21) / den
        b2 = (d00 * d21 - d01 * d20) / den
        bary[0], bary[1], bary[2] = 1.0 - b1 - b2, b1, b2
        small, low, high = 0, 0, 0
        for j in range(3):
            if bary[j] <= tol:
                small += 1
            if bary[j] < bary[low]:
                low = j
            if bary[j] > bary[high]:
                high = j
        dx, dy, dz = q[i, 0] - closest[i, 0], q[i, 1] - closest[i, 1], q[i, 2] - closest[i, 2]
        if small == 1:
            dot = dx * edge_normals[f, low, 0] + dy * edge_normals[f, low, 1] + dz * edge_normals[f, low, 2]
        elif small >= 2:
            v = F[f, high]
            dot = dx * vertex_normals[v, 0] + dy * vertex_normals[v, 1] + dz * vertex_normals[v, 2]
        else:
            dot = dx * face_normals[f, 0] + dy * face_normals[f, 1] + dz * face_normals[f, 2]
        out[i] = dot < 0
    return out


@numba.njit(cache=True)
def _scatter_min(idx, vals, pose, best, which, j):
    """best[idx] = min(best[idx], vals) pair by pair, ``which`` the (sweep, pose) of each new minimum."""
    for i in range(len(idx)):
        p = idx[i]
        if vals[i] < best[p]:
            best[p] = vals[i]
            which[p, 0] = j
            which[p, 1] = pose[i]


class MeshDistance:
    """Exact signed distance to one closed triangle mesh (libigl + pseudonormal sign).

    Parameters
    ----------
    vertices : (m, 3) float
    faces : (f, 3) int
        Closed, consistently outward-oriented triangles.
    """

    def __init__(self, vertices, faces):
        self.V = np.ascontiguousarray(vertices, dtype=np.float64)
        self.F = np.ascontiguousarray(faces, dtype=np.int64)
        tri = self.V[self.F]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        # degenerate triangles are never the closest face of libigl's query; zero normal
        self.face_normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        # angle-weighted vertex pseudonormals
        vn = np.zeros_like(self.V)
        for j in range(3):
            a = tri[:, (j + 1) % 3] - tri[:, j]
            b = tri[:, (j + 2) % 3] - tri[:, j]
            cos = np.einsum("ij,ij->i", a, b) / np.maximum(
                np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
            np.add.at(vn, self.F[:, j], np.arccos(np.clip(cos, -1.0, 1.0))[:, None] * self.face_normals)
        self.vertex_normals = vn
        # edge pseudonormals: sum of the two faces' normals, per (face, edge opposite corner j)
        edges = np.stack([self.F[:, [1, 2]], self.F[:, [2, 0]], self.F[:, [0, 1]]], axis=1).reshape(-1, 2)
        _, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
        en = np.zeros((inverse.max() + 1, 3))
        np.add.at(en, inverse, np.repeat(self.face_normals, 3, axis=0))
        self.edge_normals = en[inverse].reshape(-1, 3, 3)
        self.box = self.V.min(axis=0), self.V.max(axis=0)

    def __call__(self, points):
        """Signed distances (n,) [mm] of ``points`` (n, 3) in the mesh frame; positive outside."""
        q = np.ascontiguousarray(points, dtype=np.float64)
        if not len(q):
            return np.zeros(0)
        dist, face, closest = igl.signed_distance(q, self.V, self.F, sign_type=igl.SIGNED_DISTANCE_TYPE_UNSIGNED)
        dist = np.asarray(dist, dtype=np.float64).ravel()
        face = np.ascontiguousarray(np.asarray(face, dtype=np.int64).ravel())
        closest = np.ascontiguousarray(closest, dtype=np.float64).reshape(-1, 3)
        inside = _inside(q, closest, face, self.V, self.F, self.face_normals, self.edge_normals,
                         self.vertex_normals, REMOVAL.barycentric)
        return np.where(inside, -dist, dist)

    def box_distance(self, points):
        """Distance (n,) from ``points`` (n, 3) to the mesh's bounding box; 0 inside it."""
        lo, hi = self.box
        return np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)


# -- the pose tree ---------------------------------------------------------------
class _PoseTree:
    """Binary tree of pose intervals with travel bounds; node = (lo, hi), evaluated at its middle pose.

    ``travel(node, d)`` bounds, for a point at distance d from ``centre``, how far
    it moves in the electrode frame between the node's middle pose and any pose
    of the node's interval; ``travel_from_parent`` the same from the parent's
    middle pose.
    """

    def __init__(self, inv_r, inv_t, centre, first, last):
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
        self.alpha, self.beta = self._bounds(anchor_self, centre)
        self.alpha_par, self.beta_par = self._bounds(anchor_parent, centre)

    def _bounds(self, anchor, centre):
        """Per node: max over its poses s of ||R_s^T - R_a^T|| and |(R_s^T - R_a^T) c + t_s - t_a|."""
        alpha = np.zeros(len(self.lo))
        beta = np.zeros(len(self.lo))
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
            shift = np.linalg.norm(dr @ centre + self.inv_t[s] - self.inv_t[a], axis=1)
            start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            alpha[nodes] = np.maximum.reduceat(norm, start)
            beta[nodes] = np.maximum.reduceat(shift, start)
        return alpha, beta


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
        'calls' (libigl calls) and 'elapsed' [s].

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
    centre = P.mean(axis=0)
    d_centre = np.linalg.norm(P - centre, axis=1)
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
        tree = _PoseTree(inv_r, inv_t, centre, 0, k - 2)
        g = gaps[j]

        def children_of(idx, node, val):
            """Pairs (point, child node) that may still beat the best, with their query points."""
            out_i, out_c, out_q = [], [], []
            for side in (tree.left, tree.right):
                ch = side[node]
                m = ch >= 0
                i, c = idx[m], ch[m]
                ok = val[m] - (tree.alpha_par[c] * d_centre[i] + tree.beta_par[c] + safety) < best[i]
                i, c = i[ok], c[ok]
                q = np.einsum("nij,nj->ni", inv_r[tree.mid[c]], P[i]) + inv_t[tree.mid[c]]
                bd = dist.box_distance(q)
                # outside its box a point is at least the box distance from the mesh
                lb = np.where(bd > 0, bd - g, -np.inf) - (tree.alpha[c] * d_centre[i] + tree.beta[c] + safety)
                ok = lb < best[i]
                out_i.append(i[ok]), out_c.append(c[ok]), out_q.append(q[ok])
            return np.concatenate(out_i), np.concatenate(out_c), np.concatenate(out_q)

        # root: the whole interval, pruned by the box only
        root = np.zeros(n, dtype=np.int64)
        q = np.einsum("ij,nj->ni", inv_r[tree.mid[0]], P) + inv_t[tree.mid[0]]
        bd = dist.box_distance(q)
        lb = np.where(bd > 0, bd - g, -np.inf) - (tree.alpha[0] * d_centre + tree.beta[0] + safety)
        ok = lb < best
        stack = [(everyone[ok], root[ok], q[ok])]
        while stack:
            idx, node, q = stack.pop()
            if not len(idx):
                continue
            val = evaluate(j, idx, tree.mid[node], q)
            # a node's other poses can beat the best only if sd(middle) - travel can
            keep = val - (tree.alpha[node] * d_centre[idx] + tree.beta[node] + safety) < best[idx]
            ci, cc, cq = children_of(idx[keep], node[keep], val[keep])
            for s in range(0, len(ci), REMOVAL.batch):
                stack.append((ci[s:s + REMOVAL.batch], cc[s:s + REMOVAL.batch], cq[s:s + REMOVAL.batch]))
    if stats is not None:
        stats.update(counts, elapsed=time.perf_counter() - t0)
    return best, which


# -- wall samples ------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class WallSamples:
    """Samples of one channel surface on a structured grid.

    Attributes
    ----------
    surface : str
        'suction', 'pressure', 'hub' or 'shroud'.
    points : (n, 3) float
        Sample points in W [mm], n = rows * cols, row-major in ``shape``.
    u, v : (rows, cols) float
        Unrolled map coordinates [mm]: blade walls x and r; hub/shroud x and
        arc length r * theta.
    weights : (n,) float
        Area weights [mm^2] (Jacobian of the parametrisation x trapezoid rule); 0 where invalid.
    valid : (n,) bool
        The walls exist at the sample (always true on a blisk whose full-span range is sound).
    spacing : float
        Largest distance between neighbouring samples in W [mm].
    """

    surface: str
    points: np.ndarray
    u: np.ndarray
    v: np.ndarray
    weights: np.ndarray
    valid: np.ndarray
    spacing: float

    @property
    def shape(self):
        """(rows, cols) of the grid."""
        return self.u.shape

    @property
    def area(self):
        """Area of the sampled surface [mm^2]."""
        return float(self.weights.sum())


def _trapezoid(t):
    w = np.zeros_like(t)
    d = np.diff(t)
    w[:-1] += d / 2
    w[1:] += d / 2
    return w


def _steps(pts, inside, shape):
    """Largest distance in W between neighbouring samples along x and across, where both lie on the wall.

    Samples outside the walls' footprint carry no meaningful position and are left out.
    """
    grid, ok = pts.reshape(*shape, 3), np.asarray(inside).reshape(shape)
    dx = np.linalg.norm(np.diff(grid, axis=1), axis=2)[ok[:, 1:] & ok[:, :-1]]
    dt = np.linalg.norm(np.diff(grid, axis=0), axis=2)[ok[1:] & ok[:-1]]
    return float(dx.max(initial=0.0)), float(dt.max(initial=0.0))


def _graded(params, stretch, depths=REMOVAL_EDGE_DEPTHS):
    """``params`` (increasing) with extra values at physical ``depths`` [mm] inside both ends.

    ``stretch``: mm per unit of the parameter (its largest rate over the surface).
    """
    lo, hi = params[0], params[-1]
    first = params[1] - lo
    extra = [d / stretch for d in depths if d / stretch < 0.5 * first]
    return np.unique(np.concatenate([params, lo + np.asarray(extra), hi - np.asarray(extra)]))


def _grid_count(length, stretch, spacing):
    return max(2, int(np.ceil(length * stretch / spacing)) + 1)


def wall_samples(blisk, spacing=REMOVAL.spacing):
    """Sample the four surfaces of channel 0 over its closed axial range.

    Over ``blisk.full_span_axial_range`` (where both blade faces span hub to
    shroud): the blade walls on an (x, normalised span) grid at theta =
    wall_angles (suction: theta_suction, pressure: theta_pressure, both in
    channel-0 position), hub and shroud on an (x, normalised angle between
    the two walls) grid at the hub/shroud radius. The grid counts are chosen
    so that neighbouring samples are at most ``spacing`` apart in W (sized on
    a pilot grid). Wall angles at the hub/shroud radius are evaluated
    ``REMOVAL.wall_inset`` (1e-6 mm) inside the channel, since the spline
    footprint may report "outside" exactly on its edge; the blade-wall rows
    at the ends of the span lie that far inside too.

    Parameters
    ----------
    blisk : Blisk
    spacing : float
        Largest sample spacing [mm].

    Returns
    -------
    dict
        surface name -> :class:`WallSamples`, in ``CHANNEL_SURFACES`` order.
    """
    x0, x1 = blisk.full_span_axial_range
    eps = REMOVAL.wall_inset

    def span(x):
        lo = blisk.hub.radius_at(x) + eps
        return lo, blisk.shroud.radius_at(x) - eps - lo

    def blade(xx, ss, which):
        r_lo, h = span(xx)
        r = r_lo + ss * h
        th_s, th_p, inside, (g_s, g_p) = blisk.wall_angles(xx.ravel(), r.ravel(), with_gradient=True)
        th, grad = (th_s, g_s) if which == "suction" else (th_p, g_p)
        r = r.ravel()
        # |dP/dx x dP/dr| for theta = f(x, r); times dr/ds = h
        jac = np.sqrt(1.0 + r**2 * (grad[:, 0] ** 2 + grad[:, 1] ** 2)) * np.broadcast_to(h, xx.shape).ravel()
        return cylindrical_to_cartesian(xx.ravel(), r, th), r, inside, jac

    def ring(xx, tt, profile, sign):
        R = profile.radius_at(xx)
        th_s, th_p, inside = blisk.wall_angles(xx.ravel(), (R + sign * eps).ravel())
        th = th_s + tt.ravel() * (th_p - th_s)
        jac = R.ravel() * np.sqrt(1.0 + profile.slope_at(xx).ravel() ** 2) * (th_p - th_s)
        return cylindrical_to_cartesian(xx.ravel(), R.ravel(), th), R.ravel() * th, inside, jac

    def build(surface, make):
        # pilot grid: how far samples move in W per unit of each grid parameter
        a = np.linspace(0.0, 1.0, REMOVAL.pilot)
        xx, tt = np.meshgrid(x0 + a * (x1 - x0), a)
        pts, _, inside, _ = make(xx, tt)
        along_x, across = (s * (REMOVAL.pilot - 1) for s in _steps(pts, inside, xx.shape))
        nx, nt = _grid_count(1.0, along_x, spacing), _grid_count(1.0, across, spacing)
        cap = REMOVAL.max_grid
        for _ in range(4):
            xs, ts = np.linspace(x0, x1, nx), np.linspace(0.0, 1.0, nt)
            xx, tt = np.meshgrid(xs, ts)
            pts, v, inside, jac = make(xx, tt)
            step_x, step_t = _steps(pts, inside, xx.shape)
            if max(step_x, step_t) <= spacing or max(nx, nt) >= cap:
                break
            # the pilot grid missed a tighter bend: refine by the excess (never beyond the cap: a
            # degenerate corner of the surface must not take the memory)
            nx = min(int(np.ceil((nx - 1) * max(step_x / spacing, 1.0))) + 1, cap)
            nt = min(int(np.ceil((nt - 1) * max(step_t / spacing, 1.0))) + 1, cap)
        reach = max(step_x, step_t)
        # rows graded towards every edge: the corner fillets (about gap (sqrt 2 - 1) deep, a few
        # hundredths wide) and the end strips are narrower than the spacing, and a boundary row's
        # half-cell weight would count them several times too wide
        xs = _graded(xs, along_x / (x1 - x0))
        ts = _graded(ts, across)
        xx, tt = np.meshgrid(xs, ts)
        pts, v, inside, jac = make(xx, tt)
        nt, nx = len(ts), len(xs)
        weights = jac * np.outer(_trapezoid(ts), _trapezoid(xs)).ravel() * inside
        return WallSamples(surface, pts, xx, v.reshape(nt, nx), weights, inside, float(reach))

    return {
        "suction": build("suction", lambda xx, ss: blade(xx, ss, "suction")),
        "pressure": build("pressure", lambda xx, ss: blade(xx, ss, "pressure")),
        "hub": build("hub", lambda xx, tt: ring(xx, tt, blisk.hub, +1.0)),
        "shroud": build("shroud", lambda xx, tt: ring(xx, tt, blisk.shroud, -1.0)),
    }


#: wall of each concave channel corner and the ring it meets; the surfaces that meet at each
CORNERS = (("suction", "hub"), ("suction", "shroud"), ("pressure", "hub"), ("pressure", "shroud"))


def corner_rounding_stock(blisk, samples, gap, resolution=0.005):
    """The stock an ideal electrode leaves at the wall samples: the EDM corner rounding, from the walls alone.

    The ideal electrode is the channel shrunk by the gap g; what it erodes,
    E + B(g), is the channel with every concave corner rounded by a ball of
    radius g. This computes that stock directly from the blisk's wall
    geometry (the blade faces' angles and their gradients, the hub and shroud
    profiles), independent of the electrode design code: along each of the
    four corners where a blade wall meets the hub or shroud, the interior
    angle phi between the two surfaces (from their normals) puts the ball's
    contact at t = g / tan(phi / 2) from the corner line on either surface;
    a sample at distance s < t from the corner keeps sqrt((t - s)^2 + g^2) - g
    (g (1 / sin(phi / 2) - 1) on the corner line), elsewhere nothing. Exact for
    planar faces meeting in a straight corner; the walls' curvature over the
    strip (t <= 0.3 mm on the default blisk, wall radii tens of mm) changes it
    by microns. The distance to the corner is the distance to the corner line
    sampled every ``resolution`` mm (projected on its segments).

    Parameters
    ----------
    blisk : Blisk
    samples : dict
        :func:`wall_samples` output (channel 0).
    gap : float
        Discharge gap [mm].
    resolution : float
        Corner line sample spacing along x [mm].

    Returns
    -------
    dict
        surface name -> (n,) inherent stock [mm] per sample of ``samples[name]`` (0 where invalid).
    """
    from scipy.spatial import cKDTree

    g = float(gap)
    x0, x1 = blisk.full_span_axial_range
    xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / resolution)) + 1))
    lines = {}
    for ring, profile, sign in (("hub", blisk.hub, 1.0), ("shroud", blisk.shroud, -1.0)):
        R = profile.radius_at(xs)
        th_s, th_p, _, (g_s, g_p) = blisk.wall_angles(xs, R + sign * REMOVAL.wall_inset, with_gradient=True)
        for wall, th, grad, side in (("suction", th_s, g_s, 1.0), ("pressure", th_p, g_p, -1.0)):
            e_r = np.stack([np.zeros_like(th), np.cos(th), np.sin(th)], axis=1)
            e_t = np.stack([np.zeros_like(th), -np.sin(th), np.cos(th)], axis=1)
            e_x = np.broadcast_to([1.0, 0.0, 0.0], e_r.shape)
            # blade wall theta = f(x, r): tangents along x and r; normal towards the channel (theta inside)
            n_w = np.cross(e_x + (R * grad[:, 0])[:, None] * e_t, e_r + (R * grad[:, 1])[:, None] * e_t)
            n_w *= (side * np.sign(np.einsum("ij,ij->i", n_w, e_t)))[:, None]
            # hub / shroud r = R(x): tangents along x and theta; normal towards the channel (r inside)
            n_r = np.cross(e_x + profile.slope_at(xs)[:, None] * e_r, e_t)
            n_r *= (sign * np.sign(np.einsum("ij,ij->i", n_r, e_r)))[:, None]
            cos = np.einsum("ij,ij->i", n_w, n_r) / (np.linalg.norm(n_w, axis=1) * np.linalg.norm(n_r, axis=1))
            phi = np.pi - np.arccos(np.clip(cos, -1.0, 1.0))          # interior angle of the corner
            reach = np.where(phi < np.pi, g / np.tan(np.minimum(phi, np.pi - 1e-12) / 2), 0.0)
            lines[wall, ring] = (cylindrical_to_cartesian(xs, R, th), reach, phi)
    out = {}
    for name, smp in samples.items():
        stock = np.zeros(len(smp.points))
        for key in CORNERS:
            if name not in key:
                continue
            pts, reach, _ = lines[key]
            _, i = cKDTree(pts).query(smp.points)
            s = np.full(len(smp.points), np.inf)
            for a, b in ((np.maximum(i - 1, 0), i), (i, np.minimum(i + 1, len(pts) - 1))):
                seg = pts[b] - pts[a]
                length2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-300)
                u = np.clip(np.einsum("ij,ij->i", smp.points - pts[a], seg) / length2, 0.0, 1.0)
                s = np.minimum(s, np.linalg.norm(smp.points - (pts[a] + u[:, None] * seg), axis=1))
            t = reach[i]
            stock = np.maximum(stock, np.where(s < t, np.sqrt((t - s) ** 2 + g * g) - g, 0.0))
        out[name] = np.where(smp.valid, stock, 0.0)
    return out


# -- the report --------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SurfaceStock:
    """Stock left on one channel surface.

    Attributes
    ----------
    surface : str
    stock : (rows, cols) float
        [mm] at the samples; NaN where the surface was not sampled (``valid`` false).
    u, v : (rows, cols) float
        Map coordinates [mm] (see :class:`WallSamples`).
    which : (rows, cols, 2) int
        (sweep, pose) attaining the stock.
    area : float
        Sampled area [mm^2].
    stock_max, stock_mean : float
        Largest and area-weighted mean stock [mm].
    area_fraction_above_tolerance : float
        Area fraction with stock > tolerance.
    inherent_max, area_fraction_beyond_inherent : float
        With an ``inherent`` stock or a ``reference`` in :func:`simulate_removal`
        (what an ideal electrode, the channel shrunk by the gap, leaves: the EDM
        corner rounding, radius = gap, which no electrode can avoid in a
        concave corner): its largest value, and the area fraction whose stock
        exceeds it by more than the tolerance (the electrode set's acceptance
        figure); NaN without.
    overcut_max : float
        max(0, -min stock) [mm].
    inherent : (rows, cols) float or None
        The inherent stock at the samples [mm] (NaN where not sampled).
    """

    surface: str
    stock: np.ndarray
    u: np.ndarray
    v: np.ndarray
    which: np.ndarray
    area: float
    stock_max: float
    stock_mean: float
    area_fraction_above_tolerance: float
    overcut_max: float
    inherent_max: float = float("nan")
    area_fraction_beyond_inherent: float = float("nan")
    inherent: np.ndarray = field(default=None, repr=False)

    def to_dict(self):
        return {
            "area_mm2": round(self.area, 2),
            "stock_max_mm": _mm(self.stock_max),
            "stock_mean_mm": _mm(self.stock_mean),
            "area_fraction_above_tolerance": round(self.area_fraction_above_tolerance, 5),
            "inherent_stock_max_mm": None if np.isnan(self.inherent_max) else _mm(self.inherent_max),
            "area_fraction_beyond_inherent": (None if np.isnan(self.area_fraction_beyond_inherent)
                                              else round(self.area_fraction_beyond_inherent, 5)),
            "overcut_max_mm": _mm(self.overcut_max),
        }


def _mm(value):
    # 0.1 um: far below every tolerance, above float noise
    return round(float(value), 4)


@dataclass(frozen=True, eq=False)
class RemovalReport:
    """The channel after EDM: stock on its four surfaces and how far to trust it.

    Attributes
    ----------
    surfaces : dict
        'suction', 'pressure', 'hub', 'shroud' -> :class:`SurfaceStock`.
    gap : tuple of float
        Discharge gap per sweep [mm].
    tolerance : float
        Stock (and overcut) accepted as finished [mm].
    every_sample_within_tolerance : bool
        Every sample within [-tolerance, tolerance] of the sharp-cornered
        channel (the strict figure; the corner rounding alone fails it). Not
        the electrode set's acceptance, which allows the corner rounding
        (``area_fraction_beyond_inherent``, :func:`..electrode_set.acceptance`).
    spacing : float
        Largest distance between neighbouring wall samples [mm].
    pose_count : int
        Poses over all sweeps.
    continuous_bound : float
        Half the largest travel of a sample point (in the electrode frame)
        between consecutive poses [mm]: the continuous motion between two
        poses can remove at most this much more than the poses themselves
        (if a point's path between them is no longer than its chord).
    exact : str
        What the values are.
    elapsed : float
        [s].
    inherent_reference : str
        What the inherent stock is ("" without one).
    queries : int
        Distance queries made (of sample count x pose count pairs).
    """

    surfaces: dict
    gap: tuple
    tolerance: float
    every_sample_within_tolerance: bool
    spacing: float
    pose_count: int
    continuous_bound: float
    exact: str
    elapsed: float
    queries: int = 0
    samples: dict = field(default=None, repr=False)
    inherent_reference: str = ""

    @property
    def stock_max(self):
        """Largest stock on any surface [mm]."""
        return max(s.stock_max for s in self.surfaces.values())

    @property
    def overcut_max(self):
        """Deepest overcut on any surface [mm]."""
        return max(s.overcut_max for s in self.surfaces.values())

    def to_dict(self):
        """JSON-safe summary (no arrays) for plan.json."""
        return {
            "every_sample_within_tolerance": bool(self.every_sample_within_tolerance),
            "tolerance_mm": _mm(self.tolerance),
            "discharge_gap_mm": [_mm(g) for g in self.gap],
            "stock_max_mm": _mm(self.stock_max),
            "overcut_max_mm": _mm(self.overcut_max),
            "surfaces": {name: s.to_dict() for name, s in self.surfaces.items()},
            "accuracy": {
                "sample_spacing_mm": _mm(self.spacing),
                "exact": self.exact,
                "continuous_bound_mm": _mm(self.continuous_bound),
                "inherent_reference": self.inherent_reference,
            },
            "pose_count": int(self.pose_count),
            "distance_queries": int(self.queries),
            "elapsed_s": round(self.elapsed, 2),
        }


def _stock_in_parts(points, sweeps, gap, executor, parts, stats):
    """``stock_at_points`` over interleaved parts of the points in an executor's processes, joined.

    Every point's minimum is its own (the pruning is exact per point), so the
    parts give the same stock as one call; interleaving keeps their work even.
    """
    if executor is None or parts < 2 or len(points) < 1000 * parts:
        return stock_at_points(points, sweeps, gap, stats=stats)
    sweeps = [(sw.vertices, sw.faces, sw.poses) for sw in sweeps]
    owner = np.arange(len(points)) % parts
    futures = [executor.submit(_stock_part, points[owner == i], sweeps, gap) for i in range(parts)]
    stock, which = np.empty(len(points)), np.empty((len(points), 2), dtype=np.int64)
    for i, future in enumerate(futures):
        part_stock, part_which, part_stats = future.result()
        stock[owner == i], which[owner == i] = part_stock, part_which
        for key, value in part_stats.items():
            stats[key] = stats.get(key, 0) + value
    return stock, which


def _stock_part(points, sweeps, gap):
    stats = {}
    stock, which = stock_at_points(points, sweeps, gap, stats=stats)
    return stock, which, stats


def _as_sweep(sweep):
    """A :class:`Sweep` of float64 arrays from a Sweep or a plain (vertices, faces, poses) tuple."""
    v, f, p = sweep
    return Sweep(np.asarray(v, dtype=np.float64), np.asarray(f), _poses(p), getattr(sweep, "breaks", None))


def simulate_removal(blisk, sweeps, gap, tolerance=REMOVAL.stock, spacing=REMOVAL.spacing, samples=None,
                     reference=None, executor=None, parts=1, inherent=None):
    """Stock left on the four surfaces of channel 0 after the given electrode sweeps.

    Parameters
    ----------
    blisk : Blisk
    sweeps : sequence of Sweep or (vertices, faces, poses)
        As for :func:`stock_at_points`; poses in channel-0 position.
    gap : float or sequence of float
        Discharge gap [mm], one or one per sweep.
    tolerance : float
        Stock accepted as finished [mm].
    spacing : float
        Wall sample spacing [mm] (ignored with ``samples``).
    samples : dict, optional
        :func:`wall_samples` output to reuse.
    reference : sequence of sweeps, optional
        An ideal electrode (the whole channel shrunk by the gap at its machining
        pose): its stock is the inherent one (concave corners keep a fillet of
        radius ``gap`` whatever the electrodes), reported beside the stock.
    inherent : dict or True, optional
        The inherent stock itself, surface -> (n,) per sample of ``samples``
        (:func:`corner_rounding_stock`, computed from the walls, independent of
        any electrode design; ``True`` computes it); instead of ``reference``.
    executor : concurrent.futures.Executor, optional
        With ``parts`` > 1, the points are shared out among its processes in
        that many interleaved parts (the same stock as one process).
    parts : int

    Returns
    -------
    RemovalReport
    """
    t0 = time.perf_counter()
    samples = samples or wall_samples(blisk, spacing)
    sweeps = [_as_sweep(sw) for sw in sweeps]
    names = list(samples)
    valid = [samples[s].valid for s in names]
    points = np.vstack([samples[s].points[m] for s, m in zip(names, valid)])
    stats = {}
    stock, which = _stock_in_parts(points, sweeps, gap, executor, parts, stats)
    first_gap = float(gap if np.ndim(gap) == 0 else gap[0])
    described = ""
    if inherent is True:
        inherent = corner_rounding_stock(blisk, samples, first_gap)
    if inherent is not None:
        if reference is not None:
            raise ValueError("give the inherent stock or a reference electrode, not both")
        inherent = np.concatenate([np.asarray(inherent[s], dtype=np.float64)[m] for s, m in zip(names, valid)])
        described = (f"the EDM corner rounding of the walls' own geometry (radius = gap {first_gap:g} mm, from the "
                     f"corner angles; independent of the electrode design)")
    elif reference is not None:
        ref = [Sweep(np.asarray(v, dtype=np.float64), np.asarray(f), _poses(p)) for v, f, p in reference]
        inherent = np.maximum(stock_at_points(points, ref, first_gap)[0], 0.0)
        described = "the stock of the given reference electrode"
    centre = points.mean(axis=0)
    radius = float(np.linalg.norm(points - centre, axis=1).max())
    step = max((float(np.delete(_step_travel(*_inverse(sw.poses), centre, radius),
                                np.asarray([] if sw.breaks is None else sw.breaks, dtype=np.int64)).max(initial=0.0))
                for sw in sweeps), default=0.0)
    surfaces = {}
    offset = 0
    ok = True
    for name, m in zip(names, valid):
        smp = samples[name]
        k = int(m.sum())
        full = np.full(len(m), np.nan)
        full[m] = stock[offset:offset + k]
        w_full = np.full((len(m), 2), -1, dtype=np.int64)
        w_full[m] = which[offset:offset + k]
        inh = None if inherent is None else inherent[offset:offset + k]
        inh_full = None
        if inh is not None:
            inh_full = np.full(len(m), np.nan)
            inh_full[m] = inh
            inh_full = inh_full.reshape(smp.shape)
        offset += k
        s, w = full[m], smp.weights[m]
        area = float(w.sum())
        surfaces[name] = SurfaceStock(
            surface=name, stock=full.reshape(smp.shape), u=smp.u, v=smp.v,
            which=w_full.reshape(*smp.shape, 2), area=area,
            stock_max=float(s.max()), stock_mean=float((s * w).sum() / area),
            area_fraction_above_tolerance=float(w[s > tolerance].sum() / area),
            overcut_max=float(max(0.0, -s.min())),
            inherent_max=float("nan") if inh is None else float(inh.max()),
            area_fraction_beyond_inherent=(float("nan") if inh is None
                                           else float(w[s - inh > tolerance].sum() / area)),
            inherent=inh_full)
        ok &= bool(s.max() <= tolerance and -s.min() <= tolerance)
    reach = max(smp.spacing for smp in samples.values())
    pose_count = sum(len(sw.poses) for sw in sweeps)
    return RemovalReport(
        surfaces=surfaces,
        gap=tuple(float(g) for g in np.broadcast_to(np.asarray(gap, dtype=float), (len(sweeps),))),
        tolerance=float(tolerance), every_sample_within_tolerance=ok, spacing=reach, pose_count=pose_count,
        continuous_bound=0.5 * step,
        exact=(f"exact at the wall samples (<= {reach:.3g} mm apart) to float precision for the "
               f"{pose_count} given poses, with respect to the electrode meshes"),
        elapsed=time.perf_counter() - t0, queries=int(stats.get("queries", 0)), samples=samples,
        inherent_reference=described)


# -- pictures and colours -------------------------------------------------------------
_TITLES = {"suction": "suction wall", "pressure": "pressure wall", "hub": "hub (unrolled)",
           "shroud": "shroud (unrolled)"}


def stock_colour_scale(tolerance, stock_max, overcut_max):
    """Colour map and norm of the stock maps (no pyplot needed).

    Within +-tolerance ("done") near-white to pale green (a faint cyan tint
    below 0), overcut beyond the tolerance blue (deeper is darker), stock
    above the tolerance yellow -> orange -> red -> dark red. The bands keep
    fixed fractions of the colour bar whatever the range.

    Parameters
    ----------
    tolerance, stock_max, overcut_max : float
        [mm].

    Returns
    -------
    cmap : matplotlib Colormap
    norm : matplotlib Normalize
        Maps stock [mm] to 0..1.
    """
    from matplotlib.colors import FuncNorm, LinearSegmentedColormap

    vmin = -max(overcut_max, 2.0 * tolerance)
    vmax = max(stock_max, 4.0 * tolerance)
    # colour-bar fractions where -tolerance, 0 and +tolerance fall
    a, z, b = 0.18, 0.30, 0.42
    xs, ys = np.array([vmin, -tolerance, 0.0, tolerance, vmax]), np.array([0.0, a, z, b, 1.0])
    norm = FuncNorm((lambda v: np.interp(v, xs, ys), lambda y: np.interp(y, ys, xs)), vmin=vmin, vmax=vmax)
    cmap = LinearSegmentedColormap.from_list("stock", [
        (0.0, "#08306b"), (a - 0.001, "#6baed6"),                 # overcut beyond tolerance: blue
        (a, "#d5eef3"), (z, "#f4fbf1"), (b, "#a1d99b"),           # within +-tolerance: done
        (b + 0.001, "#ffeda0"), (b + 0.25 * (1 - b), "#feb24c"),
        (b + 0.6 * (1 - b), "#f03b20"), (1.0, "#67000d")])        # stock above: yellow -> dark red
    return cmap.with_extremes(bad="#bdbdbd"), norm


def plot_stock_maps(report, path, tolerance=None):
    """Four stock maps in one PNG: blade walls in (x, r), hub and shroud unrolled in (x, r theta).

    Parameters
    ----------
    report : RemovalReport
    path : str or Path
        PNG to write.
    tolerance : float, optional
        [mm]; default the report's.

    Returns
    -------
    path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tol = report.tolerance if tolerance is None else float(tolerance)
    cmap, norm = stock_colour_scale(tol, report.stock_max, report.overcut_max)
    fig, axes = plt.subplots(2, 2, figsize=(13, 10), constrained_layout=True)
    for ax, name in zip(axes.ravel(), CHANNEL_SURFACES):
        s = report.surfaces[name]
        mesh = ax.pcolormesh(s.u, s.v, np.ma.masked_invalid(s.stock), cmap=cmap, norm=norm,
                             shading="nearest", rasterized=True)
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("r [mm]" if name in ("suction", "pressure") else "r·θ [mm]")
        above = 100.0 * s.area_fraction_above_tolerance
        beyond = ("" if np.isnan(s.area_fraction_beyond_inherent)
                  else f" ({100.0 * s.area_fraction_beyond_inherent:.2f} % beyond the corner rounding)")
        ax.set_title(f"{_TITLES[name]}: stock max {s.stock_max:.3f}, mean {s.stock_mean:.4f} mm\n"
                     f"{above:.2f} % of area above {tol:g} mm{beyond}, overcut max {s.overcut_max:.3f} mm",
                     fontsize=10)
    ticks = sorted({norm.vmin, -tol, 0.0, tol, *np.linspace(tol, norm.vmax, 5)[1:]})
    bar = fig.colorbar(mesh, ax=axes, shrink=0.85, ticks=ticks)
    bar.set_label(f"stock left [mm]   (blue: overcut, green: done within ±{tol:g} mm, warm: stock above)")
    bar.ax.set_yticklabels([f"{t:.3f}" for t in ticks])
    verdict = ("every sample within" if report.every_sample_within_tolerance
               else "not every sample within")
    fig.suptitle(
        f"Stock after EDM ({verdict} ±{tol:g} mm of the sharp-cornered channel) = min over {report.pose_count} pose(s) of distance to the "
        f"electrode less the gap {', '.join(f'{g:g}' for g in sorted(set(report.gap)))} mm\n"
        f"exact at wall samples ≤ {report.spacing:.2f} mm apart; continuous motion between poses "
        f"removes at most {report.continuous_bound:.4f} mm more", fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def stock_vertex_colours(mesh, report, surface, transform=None, tolerance=None):
    """RGBA vertex colours of a channel surface mesh by its nearest wall sample's stock.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        E.g. ``blisk.channel_meshes(k)[surface]``.
    report : RemovalReport
    surface : str
        'suction', 'pressure', 'hub' or 'shroud'.
    transform : (4, 4) float, optional
        Channel 0 -> the mesh's position (``blisk.channel_transform(k)``).
    tolerance : float, optional
        [mm]; default the report's.

    Returns
    -------
    (v, 4) uint8
        Same colour scale as :func:`plot_stock_maps`; grey where the mesh lies
        farther than two sample spacings from any sample (outside the sampled range).
    """
    from scipy.spatial import cKDTree

    tol = report.tolerance if tolerance is None else float(tolerance)
    cmap, norm = stock_colour_scale(tol, report.stock_max, report.overcut_max)
    smp = report.samples[surface]
    stock = report.surfaces[surface].stock.ravel()
    pts, stock = smp.points[smp.valid], stock[smp.valid]
    if transform is not None:
        t = np.asarray(transform, dtype=float)
        pts = pts @ t[:3, :3].T + t[:3, 3]
    d, i = cKDTree(pts).query(np.asarray(mesh.vertices))
    values = np.where(d <= 2.0 * report.spacing, stock[i], np.nan)
    return (np.asarray(cmap(norm(np.ma.masked_invalid(values)))) * 255).round().astype(np.uint8)
