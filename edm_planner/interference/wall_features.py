"""The walls' sharp features against the electrode's faces: what a vertex check cannot see.

The certificate of a path (:mod:`..planning.certify`) and the exact re-check
(:mod:`.plan_check`) measure every electrode *vertex* against the walls. A
wall feature that is sharper than the electrode's triangles can pass between
vertices: on blisk72 (``../shared/cases/blisk72``) the blade's trailing-edge
corner, the boundary edge of the pressure face, came 0.0177 mm from an
electrode edge whose two vertices were 0.0985 and 0.1212 mm from the wall,
so the feed was "certified at 0.08 mm" while the removal proof found a
0.082 mm overcut there (``docs/certificate.md``).

The features are the blade faces' boundary edges at the leading and trailing
edges (u = 0 and u = 1 of each bicubic face), and the end cap between the
suction and the pressure face of a blade where its ends are blunt: the ruled
strip between the two faces' edges, which no face covers. They are sampled
densely (:class:`WallFeatures`), and the clearance of an electrode pose is
the smallest distance from a feature sample to the electrode's *triangles*
(exact point-to-triangle distances) less the samples' covering radius: a
certified lower bound on the distance from every point of the features to
every point of the electrode mesh, by the 1-Lipschitz distance.

Sign: the value is the unsigned distance to the electrode's surface, capped
at ``reach``. A feature inside the electrode is found on a continuous path,
which must cross the electrode's surface to get there (the certificate
bounds the distance between samples); a single pose that already swallows a
feature deeper than ``reach`` is not. Plain numpy + numba; no rclpy. Units: mm.

Written by hand: libigl's point-to-mesh query (the independent check in the
tests) builds its tree on every call, about 40 ms for one pose's electrode,
and the certificate asks for thousands of poses of the same mesh; here the
triangles are binned once per electrode, the samples of each small cube are
measured against the triangles near it, and a pose costs 0.02 to 0.3 ms
(Emerald Rapids, one core).
"""

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numba
import numpy as np
from scipy.ndimage import distance_transform_cdt

from ..geometry.disk_cache import arrays_digest
from ..geometry.frames import rotation_about_x

#: surface index of each feature sample (the order of interference.SURFACES)
SUCTION, PRESSURE = 0, 1


@dataclass(frozen=True, eq=False)
class WallFeatures:
    """Dense samples of the sharp features of channel 0's blade walls (mm).

    Attributes
    ----------
    points : (n, 3) float
        In W, channel 0, grouped by cluster.
    surface : (n,) int
        0 suction (blade 0), 1 pressure (blade 1).
    cover : float
        Every point of a feature lies within this distance of a sample [mm].
    groups : tuple
        The two-level clustering the kernel prunes with: coarse clusters (cubes of
        ``cluster_size``, one surface each) of fine ones (cubes a tenth of that):
        (coarse_start, fine_start, coarse_centre, coarse_radius, fine_centre, fine_radius, fine_surface).
    """

    points: np.ndarray
    surface: np.ndarray
    cover: float
    groups: tuple

    @classmethod
    def from_blisk(cls, blisk, spacing=0.01, cluster_size=1.0):
        """Sample the leading- and trailing-edge features of channel 0's two blades.

        Each feature is the ruled strip between a blade's suction and pressure
        face edges at u = 0 or u = 1 (a single curve where the faces meet),
        sampled on a grid no coarser than ``spacing`` in W along and across.
        The covering radius is the largest distance from a point of a grid
        triangle to its nearest corner (:func:`vertex_reach`), plus how far the
        edge curves leave their chords between samples (measured at the
        midpoints).
        """
        pts, lab, cover = [], [], 0.0
        for u_edge in (0.0, 1.0):
            # along the span: fine enough in v for spacing in W
            probe = np.linspace(0.0, 1.0, 401)
            edges = [f.surface.evaluate(np.full_like(probe, u_edge), probe)
                     for f in (blisk.suction_face, blisk.pressure_face)]
            step = max(float(np.linalg.norm(np.diff(e, axis=0), axis=1).max()) for e in edges) * 400
            nv = max(2, int(np.ceil(step / spacing)) + 1)
            v = np.linspace(0.0, 1.0, nv)
            s_edge = blisk.suction_face.surface.evaluate(np.full_like(v, u_edge), v)
            p_edge = blisk.pressure_face.surface.evaluate(np.full_like(v, u_edge), v)
            width = float(np.linalg.norm(s_edge - p_edge, axis=1).max())
            nw = max(2, int(np.ceil(width / spacing)) + 1)
            w = np.linspace(0.0, 1.0, nw)[:, None, None]
            cap = (1.0 - w) * s_edge[None] + w * p_edge[None]              # (nw, nv, 3), blade 0
            a, b, c, d = cap[:-1, :-1], cap[:-1, 1:], cap[1:, :-1], cap[1:, 1:]
            cells = np.concatenate([np.stack([a, b, d], axis=-2), np.stack([a, d, c], axis=-2),
                                    np.stack([a, b, c], axis=-2), np.stack([b, d, c], axis=-2)]).reshape(-1, 3, 3)
            vm = 0.5 * (v[:-1] + v[1:])
            sag = max(float(np.linalg.norm(f.surface.evaluate(np.full_like(vm, u_edge), vm)
                                           - 0.5 * (e[:-1] + e[1:]), axis=1).max())
                      for f, e in ((blisk.suction_face, s_edge), (blisk.pressure_face, p_edge)))
            cover = max(cover, vertex_reach(cells) + sag)
            blade0 = cap.reshape(-1, 3)
            blade1 = blade0 @ rotation_about_x(blisk.pitch)[:3, :3].T
            pts += [blade0, blade1]
            lab += [np.full(len(blade0), SUCTION), np.full(len(blade1), PRESSURE)]
        points, surface = np.concatenate(pts), np.concatenate(lab)
        points, surface, groups = _grouped(points, surface, cluster_size)
        return cls(points, surface, float(cover), groups)

    def clearances(self, poses, mesh_grid, upper=None, reach=0.5):
        """(n, 2) lower bounds of the suction- and pressure-feature clearance of the electrode at ``poses`` [mm].

        Parameters
        ----------
        poses : (n, 4, 4) float
            Electrode frame -> W, channel 0.
        mesh_grid : TriangleGrid
            The electrode's triangles in its own frame.
        upper : (n, 2) float, optional
            Values the caller takes the minimum with anyway (the vertex bounds): features are
            searched only as far as they could go below them, and reported as ``min(upper, ...)``.
        reach : float
            Distances beyond it are reported as ``reach`` less the cover [mm].
        """
        P = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4))
        start = np.full((len(P), 2), float(reach))
        if upper is not None:
            start = np.minimum(start, np.asarray(upper, dtype=np.float64).reshape(-1, 2) + self.cover)
        g = mesh_grid
        out = _feature_kernel(P, np.ascontiguousarray(start), self.points, self.surface, *self.groups,
                              g.vertices, g.faces, g.lo, g.hi, g.origin, float(g.cell), g.dims, g.cell_start, g.items,
                              g.steps, max(1, min(numba.get_num_threads(), len(P))))
        return out - self.cover


def _grouped(points, surface, size):
    """Points sorted into fine cubes (a tenth of ``size``) within coarse cubes, one surface per cube."""
    coarse = np.column_stack([surface, np.floor(points / size).astype(np.int64)])
    fine = np.column_stack([coarse, np.floor(points / (0.1 * size)).astype(np.int64)])
    _, fid = np.unique(fine, axis=0, return_inverse=True)
    fid = fid.ravel()
    order = np.lexsort((fid,))
    points, surface, fid = points[order], surface[order], fid[order]
    fine_start = np.concatenate([[0], np.flatnonzero(np.diff(fid)) + 1, [len(fid)]]).astype(np.int64)
    counts = np.diff(fine_start)
    fine_centre = np.add.reduceat(points, fine_start[:-1]) / counts[:, None]
    fine_radius = np.maximum.reduceat(np.linalg.norm(points - np.repeat(fine_centre, counts, axis=0), axis=1),
                                      fine_start[:-1])
    fine_surface = surface[fine_start[:-1]]
    # the fine cubes are sorted by their coarse cube first (np.unique sorts rows lexicographically)
    ckey = np.column_stack([surface[fine_start[:-1]], np.floor(points[fine_start[:-1]] / size).astype(np.int64)])
    change = np.flatnonzero((np.diff(ckey, axis=0) != 0).any(axis=1)) + 1
    coarse_start = np.concatenate([[0], change, [len(ckey)]]).astype(np.int64)
    ccount = np.diff(coarse_start)
    coarse_centre = np.add.reduceat(fine_centre * counts[:, None], coarse_start[:-1]) / np.add.reduceat(
        counts, coarse_start[:-1])[:, None]
    coarse_radius = np.maximum.reduceat(
        np.linalg.norm(fine_centre - np.repeat(coarse_centre, ccount, axis=0), axis=1) + fine_radius,
        coarse_start[:-1])
    groups = (coarse_start, fine_start, np.ascontiguousarray(coarse_centre), coarse_radius,
              np.ascontiguousarray(fine_centre), fine_radius, fine_surface.astype(np.int64))
    return np.ascontiguousarray(points), surface.astype(np.int64), groups


@dataclass(frozen=True, eq=False)
class TriangleGrid:
    """An electrode mesh's triangles binned in a uniform grid of its own frame (for :class:`WallFeatures`)."""

    vertices: np.ndarray
    faces: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    origin: np.ndarray
    cell: float
    dims: np.ndarray
    cell_start: np.ndarray
    items: np.ndarray
    steps: np.ndarray

    @classmethod
    def from_mesh(cls, vertices, faces, cell=0.25):
        V = np.ascontiguousarray(vertices, dtype=np.float64)
        F = np.ascontiguousarray(faces, dtype=np.int64)
        lo, hi = V.min(axis=0), V.max(axis=0)
        origin = lo - 1e-6
        dims = np.maximum(1, np.ceil((hi - origin) / cell).astype(np.int64) + 1)
        tri = V[F]
        a = np.clip(np.floor((tri.min(axis=1) - origin) / cell).astype(np.int64), 0, dims - 1)
        b = np.clip(np.floor((tri.max(axis=1) - origin) / cell).astype(np.int64), 0, dims - 1)
        cell_start, items = _bin_triangles(a, b, dims)
        # chessboard steps from each cell to the nearest cell holding a triangle
        empty = (np.diff(cell_start) == 0).reshape(tuple(dims))
        steps = distance_transform_cdt(empty, metric="chessboard").astype(np.int64).ravel()
        return cls(V, F, lo, hi, origin, float(cell), dims, cell_start, items, steps)

    @property
    def max_vertex_reach(self):
        """Largest distance from a point of a triangle to the nearest of its vertices [mm]."""
        return vertex_reach(self.vertices[self.faces])


#: the last few grids made, by content: a plan's search and its certification bin the same electrode
_GRIDS = OrderedDict()
_GRIDS_KEPT = 2
_GRIDS_LOCK = threading.Lock()


def triangle_grid(vertices, faces, cell=0.25):
    """:meth:`TriangleGrid.from_mesh`, made once for the same mesh (by content) while it is among the last two.

    The search and the certification of a plan both need the electrode's grid; on Rotor 37 each costs about
    1 s (its distance transform and binning), 2 s of a 5 s plan.
    """
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int64)
    key = (arrays_digest(V, F), float(cell))
    with _GRIDS_LOCK:
        grid = _GRIDS.get(key)
        if grid is not None:
            _GRIDS.move_to_end(key)
            return grid
    grid = TriangleGrid.from_mesh(V, F, cell)
    with _GRIDS_LOCK:
        _GRIDS[key] = grid
        while len(_GRIDS) > _GRIDS_KEPT:
            _GRIDS.popitem(last=False)
    return grid


def vertex_reach(triangles):
    """Largest distance from a point of any of ``triangles`` (k, 3, 3) to the nearest of its corners.

    Half the longest edge for a right or obtuse triangle (the midpoint of that
    edge), else the circumradius (the circumcentre lies inside). Two triangles
    of a grid cell split either way both count, so either split is covered.
    """
    t = np.asarray(triangles, dtype=np.float64)
    if not len(t):
        return 0.0
    e = np.linalg.norm(t[:, [1, 2, 0]] - t[:, [2, 0, 1]], axis=2)          # opposite each corner
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    sq = np.sort(e, axis=1) ** 2
    # a flat triangle (the cap where the faces meet) is a segment: as an obtuse one, half its longest edge
    obtuse = (sq[:, 2] >= sq[:, 0] + sq[:, 1]) | (area <= 1e-9 * sq[:, 2])
    circum = np.divide(e.prod(axis=1), 4 * area, out=np.full(len(area), np.inf), where=area > 0)
    return float(np.where(obtuse, 0.5 * e.max(axis=1), circum).max())


@numba.njit(cache=True)
def _bin_triangles(a, b, dims):
    ny, nz = dims[1], dims[2]
    count = np.zeros(dims[0] * ny * nz + 1, dtype=np.int64)
    for t in range(a.shape[0]):
        for i in range(a[t, 0], b[t, 0] + 1):
            for j in range(a[t, 1], b[t, 1] + 1):
                for k in range(a[t, 2], b[t, 2] + 1):
                    count[(i * ny + j) * nz + k + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int64)
    for t in range(a.shape[0]):
        for i in range(a[t, 0], b[t, 0] + 1):
            for j in range(a[t, 1], b[t, 1] + 1):
                for k in range(a[t, 2], b[t, 2] + 1):
                    c = (i * ny + j) * nz + k
                    items[fill[c]] = t
                    fill[c] += 1
    return start, items


@numba.njit(cache=True, inline="always")
def closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """The point of triangle (a, b, c) closest to p (Ericson, Real-Time Collision Detection 5.1.5)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@numba.njit(cache=True, inline="always")
def point_triangle_sq(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from p to triangle (a, b, c): |closest - p|^2 (``closest_on_triangle``)."""
    x, y, z = closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
    dx, dy, dz = x - px, y - py, z - pz
    return dx * dx + dy * dy + dz * dz


@numba.njit(cache=True, inline="always")
def _point_triangle_sq(px, py, pz, V, f):
    """Squared distance from p to triangle f of the mesh V."""
    return point_triangle_sq(px, py, pz, V[f[0], 0], V[f[0], 1], V[f[0], 2], V[f[1], 0], V[f[1], 1], V[f[1], 2],
                             V[f[2], 0], V[f[2], 1], V[f[2], 2])


@numba.njit(cache=True, inline="always")
def _box_distance(qx, qy, qz, lo, hi):
    dx = max(lo[0] - qx, 0.0, qx - hi[0])
    dy = max(lo[1] - qy, 0.0, qy - hi[1])
    dz = max(lo[2] - qz, 0.0, qz - hi[2])
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@numba.njit(cache=True)
def _lower_bound(qx, qy, qz, lo, hi, origin, cell, dims, steps):
    """A lower bound of q's distance to the mesh: its box distance, or (steps to a filled cell - 1) cells."""
    bd = _box_distance(qx, qy, qz, lo, hi)
    ci = int(math.floor((qx - origin[0]) / cell))
    cj = int(math.floor((qy - origin[1]) / cell))
    ck = int(math.floor((qz - origin[2]) / cell))
    if 0 <= ci < dims[0] and 0 <= cj < dims[1] and 0 <= ck < dims[2]:
        return max(bd, max(steps[(ci * dims[1] + cj) * dims[2] + ck] - 1, 0) * cell)
    return bd


@numba.njit(cache=True, inline="always")
def _cell_box(qx, qy, qz, r, origin, cell, dims):
    """The grid's cell index ranges (i0, i1, j0, j1, k0, k1), inclusive, that the box [q - r, q + r] meets."""
    i0 = max(int(math.floor((qx - r - origin[0]) / cell)), 0)
    i1 = min(int(math.floor((qx + r - origin[0]) / cell)), dims[0] - 1)
    j0 = max(int(math.floor((qy - r - origin[1]) / cell)), 0)
    j1 = min(int(math.floor((qy + r - origin[1]) / cell)), dims[1] - 1)
    k0 = max(int(math.floor((qz - r - origin[2]) / cell)), 0)
    k1 = min(int(math.floor((qz + r - origin[2]) / cell)), dims[2] - 1)
    return i0, i1, j0, j1, k0, k1


@numba.njit(cache=True, inline="always")
def _to_frame(R, ox, oy, oz, p):
    """p (W) in the electrode frame: R^T (p - o)."""
    px, py, pz = p[0] - ox, p[1] - oy, p[2] - oz
    return (R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz, R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz,
            R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz)


@numba.njit(cache=True)
def _gather(qx, qy, qz, r, origin, cell, dims, cell_start, items, stamp, mark, out):
    """The triangles in the cells of the box [q - r, q + r], each once, into ``out``; returns their count.

    ``mark[t] == stamp`` once triangle t is taken (a triangle is binned in every
    cell it overlaps); ``out`` has room for every triangle of the mesh.
    """
    ny, nz = dims[1], dims[2]
    i0, i1, j0, j1, k0, k1 = _cell_box(qx, qy, qz, r, origin, cell, dims)
    n = 0
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                c = (i * ny + j) * nz + k
                for m in range(cell_start[c], cell_start[c + 1]):
                    t = items[m]
                    if mark[t] != stamp:
                        mark[t] = stamp
                        out[n] = t
                        n += 1
    return n


@numba.njit(cache=True, parallel=True)
def _feature_kernel(P, start, pts, surf, coarse_start, fine_start, coarse_centre, coarse_radius, fine_centre,
                    fine_radius, fine_surface, V, F, lo, hi, origin, cell, dims, cell_start, items, steps, workers):
    """Per pose, per surface: min(start, the smallest distance from a feature sample to the mesh) [mm].

    Coarse cubes nearest first (by a lower bound of their distance, so that the
    bound drops early), fine cubes skipped where the triangle grid's bound of
    their distance less their radius cannot beat the bound. The triangles near
    a fine cube that remains are gathered once, each with its exact distance d
    from the cube's centre; where none has d - radius below the bound the cube
    is done (an exact nearest-triangle search of the centre first cost more
    than it saved: the default plan's search, certificate and re-check calls
    took 0.21-0.24 s with it, 0.13 s without, one thread, AMD Zen 4). The
    samples are measured against the triangles kept, sorted by d: a sample
    stops at the first triangle with d - radius above its nearest so far (less
    1e-9 mm, so that rounding cannot let a skipped triangle be nearer), so the
    result is the exact minimum over all pairs, bit for bit what a search of
    every triangle gives. Poses run in parallel on ``workers`` threads, each
    with scratch arrays of its own (one entry per triangle), made once rather
    than per pose.
    """
    n = P.shape[0]
    out = np.empty((n, 2))
    nc = coarse_start.shape[0] - 1
    for w in numba.prange(workers):
        low = np.empty(nc)
        mark = np.zeros(F.shape[0], dtype=np.int64)
        tris = np.empty(F.shape[0], dtype=np.int64)
        dc = np.empty(F.shape[0])
        stamp = 0                                      # counts on over this thread's poses: mark needs no reset
        for t in range(w, n, workers):
            R = P[t, :3, :3]
            ox, oy, oz = P[t, 0, 3], P[t, 1, 3], P[t, 2, 3]
            best = start[t].copy()
            for c in range(nc):
                qx, qy, qz = _to_frame(R, ox, oy, oz, coarse_centre[c])
                low[c] = _lower_bound(qx, qy, qz, lo, hi, origin, cell, dims, steps) - coarse_radius[c]
            for c in np.argsort(low):
                s = fine_surface[coarse_start[c]]
                if low[c] >= best[s]:
                    continue
                for f in range(coarse_start[c], coarse_start[c + 1]):
                    rf = fine_radius[f]
                    qx, qy, qz = _to_frame(R, ox, oy, oz, fine_centre[f])
                    if _lower_bound(qx, qy, qz, lo, hi, origin, cell, dims, steps) - rf >= best[s]:
                        continue
                    # the triangles a sample of the cube can be nearer to than best: within best + 2 rf
                    stamp += 1
                    nt = _gather(qx, qy, qz, best[s] + 2.0 * rf, origin, cell, dims, cell_start, items, stamp, mark,
                                 tris)
                    kept = 0
                    for m in range(nt):
                        lower = math.sqrt(_point_triangle_sq(qx, qy, qz, V, F[tris[m]])) - rf - 1e-9
                        if lower < best[s]:
                            tris[kept], dc[kept] = tris[m], lower
                            kept += 1
                    if kept == 0:
                        continue                                # no sample of the cube can beat best
                    order = np.argsort(dc[:kept])
                    for k in range(fine_start[f], fine_start[f + 1]):
                        px, py, pz = _to_frame(R, ox, oy, oz, pts[k])
                        b = best[s]
                        d2 = np.inf
                        for m in order:
                            if dc[m] >= b or (dc[m] >= 0.0 and dc[m] * dc[m] >= d2):
                                break                           # this triangle and every later one are farther
                            e2 = _point_triangle_sq(px, py, pz, V, F[tris[m]])
                            if e2 < d2:
                                d2 = e2
                        if d2 < b * b:
                            best[s] = math.sqrt(d2)
            out[t, 0], out[t, 1] = best[0], best[1]
    return out
