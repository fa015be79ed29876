"""Volume of blisk material each machining leg removes, on a voxel field with a certified bracket.

A leg (cut) of an electrode E, posed by P_t along a continuous move, removes
``blank ∩ ∪_t (P_t E ⊕ B(g))`` less what earlier cuts removed (EDM erodes the
material within the discharge gap g of the electrode). The blank is voxelised
(cells of size ``resolution``); per cut and voxel the kernel keeps

    f = min over the cut's sampled poses of  sd(P_k^-1 c) - g

(c the voxel centre, sd the electrode's signed distance, positive outside,
interpolated trilinearly from an exact grid in the electrode frame). A voxel
counts for the estimate when its centre is in the blank and f < 0 for the
first time.

The bracket. With rho = resolution*sqrt(3)/2 (voxel half diagonal), e =
sqrt(3)/2*sdf_spacing (the trilinear error of a 1-Lipschitz function sampled
exactly) and d = travel/2 (how far a point of the continuous move can be from
the same electrode point at the nearest sampled pose):

* f < -(rho + e): the whole voxel lies within the grown electrode at a
  sampled pose, hence in the cut's removal region ("surely in");
* f > rho + e + d: no point of the voxel is within g of the electrode at any
  pose of the continuous move ("surely out");
* else uncertain.

The blank's own boundary is voxelised too: a voxel is "surely blank" when its
centre is inside and farther than rho from the blank's boundary (annulus: a
conservative distance bound, see ``_annulus_state``; mesh: exact signed
distance); "possibly blank" adds the voxels whose centre is within rho of
the boundary, inside or out.

Per cut k: ``lower`` counts voxels surely blank, surely in cut k and surely
out of every earlier cut; ``upper`` voxels possibly blank, not surely out of
cut k and not surely in an earlier cut. Both hold for cut k's own removal
(blank ∩ S_k minus S_1..S_k-1, S the continuous swept region) whatever the
attribution of the uncertain voxels between cuts; the estimate attributes a
voxel to the first cut whose f < 0 at its centre. The totals are bracketed
directly (surely blank and surely in some cut / possibly blank and not surely
out of every cut), so they are tighter than the sums of the per-cut bounds.

What the bracket does not cover: the electrode and blank meshes are taken as
the true shapes (closed, outward oriented), float rounding, and the motion
between two poses: d assumes each electrode point moves on a straight line or
on a circular arc / helix about a fixed axis between them (the computed
travel is the chord times 1/cos(phi/4) for a rotation phi: exact for the arc's
mid-point, shown for the helix's mid-point only); a caller-given
``pose_travel`` is trusted as is. Voxel cubes are bounded by their
circumscribed ball (rho), which is what makes the bracket conservative.
"""

import hashlib
import logging
import math
import pathlib
import time
from dataclasses import dataclass

import numba
import numpy as np
import trimesh

from ..errors import EdmError, ErrorCode
from ..geometry.frames import hull_points
from ..machining.mesh_distance import MeshDistance  # exact: nearest triangle + pseudonormal sign

_log = logging.getLogger(__name__)

SQRT3_2 = math.sqrt(3.0) / 2.0


def _bad(message):
    return EdmError(ErrorCode.INVALID_REQUEST, message)


def _finite(name, a, shape_tail=None, dtype=np.float64):
    a = np.asarray(a, dtype=dtype)
    if shape_tail is not None and (a.ndim != len(shape_tail) + 1 or a.shape[1:] != shape_tail or not len(a)):
        raise _bad(f"{name}: expected a non-empty array of shape (n, {', '.join(map(str, shape_tail))})")
    if dtype == np.float64 and not np.all(np.isfinite(a)):
        raise _bad(f"{name}: contains NaN or infinite values")
    return a


@dataclass(frozen=True)
class AnnulusBlank:
    """The solid ring a channel is cut from: x0 <= x <= x1, hub(x) <= r <= shroud(x), r = hypot(y, z) [mm].

    Profiles are piecewise linear in x (``np.interp``, constant beyond their ends).
    """

    hub_x: np.ndarray
    hub_r: np.ndarray
    shroud_x: np.ndarray
    shroud_r: np.ndarray
    x0: float
    x1: float

    @classmethod
    def from_blisk(cls, blisk, step=0.25, whole_profiles=False):
        """Ring between ``blisk.hub`` and ``blisk.shroud`` over the blades' axial range, sampled every ``step`` mm.

        Ahead of and behind the blades the flow path between hub and shroud is a surface of revolution,
        turned on a lathe before EDM, so the solid a channel's electrodes cut is the ring over the blades'
        own axial range (``whole_profiles``: over the profiles' whole common range instead). The dense
        sampling makes the piecewise-linear blank follow the profiles' PCHIP to O(step^2 * r'') (well
        below 1e-3 mm for real profiles at 0.25 mm).
        """
        x0 = max(blisk.hub.x_range[0], blisk.shroud.x_range[0])
        x1 = min(blisk.hub.x_range[1], blisk.shroud.x_range[1])
        if not whole_profiles:
            x0, x1 = max(x0, blisk.axial_range[0]), min(x1, blisk.axial_range[1])
        xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / step)) + 1))
        return cls(xs, blisk.hub.radius_at(xs), xs.copy(), blisk.shroud.radius_at(xs), float(x0), float(x1))

    def bounds(self):
        rmax = float(max(np.max(self.shroud_r), np.max(self.hub_r)))
        return np.array([self.x0, -rmax, -rmax]), np.array([self.x1, rmax, rmax])


@dataclass(frozen=True)
class MeshBlank:
    """A pre-machined stock mesh (closed, watertight, outward normals) [mm]; material = inside it."""

    vertices: np.ndarray
    faces: np.ndarray

    def bounds(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        return v.min(axis=0), v.max(axis=0)


@dataclass(frozen=True)
class Cut:
    """One leg of one electrode: its mesh (electrode frame, mm), poses (n, 4, 4) to the workpiece, gap [mm]."""

    label: str
    vertices: np.ndarray
    faces: np.ndarray
    poses: np.ndarray
    gap: float


@dataclass(frozen=True)
class CutVolume:
    """Removed volume of one cut [mm^3]: estimate and certified bracket."""

    label: str
    volume: float
    lower: float
    upper: float


@dataclass(frozen=True)
class VolumeResult:
    """Per-cut volumes (input order) and totals [mm^3]; ``resolution`` [mm], ``seconds`` wall time."""

    cuts: list
    resolution: float
    total: float
    total_lower: float
    total_upper: float
    blank_volume_in_grid: float
    voxels: int
    seconds: float

    def to_dict(self):
        return {
            "cuts": [{"label": c.label, "volume_mm3": c.volume, "lower_mm3": c.lower, "upper_mm3": c.upper}
                     for c in self.cuts],
            "resolution_mm": self.resolution,
            "total_mm3": self.total, "total_lower_mm3": self.total_lower, "total_upper_mm3": self.total_upper,
            "blank_volume_in_grid_mm3": self.blank_volume_in_grid,
            "voxels": self.voxels, "seconds": self.seconds,
            "accuracy": ("voxel estimate; [lower, upper] bounds each cut's removal (blank within the gap of the "
                         "continuous sweep, less earlier cuts) for the given meshes, exact signed distances, "
                         "voxelisation and pose sampling; assumes straight or helical motion between poses"),
        }


# -- kernels ---------------------------------------------------------------------
@numba.njit(cache=True)
def _sdf_at(sdf, origin, h, lo, hi, gap, q0, q1, q2):
    """sd - gap at q (electrode frame): trilinear inside the grid, else the distance to the mesh box (a lower bound)."""
    n0, n1, n2 = sdf.shape
    u0 = (q0 - origin[0]) / h
    u1 = (q1 - origin[1]) / h
    u2 = (q2 - origin[2]) / h
    if u0 < 0.0 or u1 < 0.0 or u2 < 0.0 or u0 > n0 - 1 or u1 > n1 - 1 or u2 > n2 - 1:
        a = max(lo[0] - q0, q0 - hi[0], 0.0)
        b = max(lo[1] - q1, q1 - hi[1], 0.0)
        c = max(lo[2] - q2, q2 - hi[2], 0.0)
        return math.sqrt(a * a + b * b + c * c) - gap
    i = min(int(u0), n0 - 2)
    j = min(int(u1), n1 - 2)
    k = min(int(u2), n2 - 2)
    t0, t1, t2 = u0 - i, u1 - j, u2 - k
    c00 = sdf[i, j, k] * (1 - t0) + sdf[i + 1, j, k] * t0
    c10 = sdf[i, j + 1, k] * (1 - t0) + sdf[i + 1, j + 1, k] * t0
    c01 = sdf[i, j, k + 1] * (1 - t0) + sdf[i + 1, j, k + 1] * t0
    c11 = sdf[i, j + 1, k + 1] * (1 - t0) + sdf[i + 1, j + 1, k + 1] * t0
    c0 = c00 * (1 - t1) + c10 * t1
    c1 = c01 * (1 - t1) + c11 * t1
    return c0 * (1 - t2) + c1 * t2 - gap


@numba.njit(cache=True, parallel=True)
def _pose_min(inv, sdf, origin, h, lo, hi, gap, g0, res, active, rng, off, fmin, decided):
    """fmin[v - off] = min(fmin, sd - gap) at the centres of the active voxels v in the index box rng (3, 2).

    A voxel whose fmin is already below ``decided`` is surely in: no pose can change its counts."""
    for i in numba.prange(rng[0, 0], rng[0, 1]):
        x = g0[0] + (i + 0.5) * res
        for j in range(rng[1, 0], rng[1, 1]):
            y = g0[1] + (j + 0.5) * res
            for k in range(rng[2, 0], rng[2, 1]):
                a, b, c = i - off[0], j - off[1], k - off[2]
                if not active[i, j, k] or fmin[a, b, c] < decided:
                    continue
                z = g0[2] + (k + 0.5) * res
                q0 = inv[0, 0] * x + inv[0, 1] * y + inv[0, 2] * z + inv[0, 3]
                q1 = inv[1, 0] * x + inv[1, 1] * y + inv[1, 2] * z + inv[1, 3]
                q2 = inv[2, 0] * x + inv[2, 1] * y + inv[2, 2] * z + inv[2, 3]
                f = _sdf_at(sdf, origin, h, lo, hi, gap, q0, q1, q2)
                if f < fmin[a, b, c]:
                    fmin[a, b, c] = f


@numba.njit(cache=True)
def _classify(fmin, off, blank, first, sure, maybe, cut, t_in, t_out):
    """Attribute and count one cut's voxels; returns (estimate, lower, upper) counts. See the module docstring."""
    est = low = up = 0
    n0, n1, n2 = fmin.shape
    for a in range(n0):
        for b in range(n1):
            for c in range(n2):
                f = fmin[a, b, c]
                i, j, k = a + off[0], b + off[1], c + off[2]
                s = blank[i, j, k]  # 0 out, 1 surely in, 2 near boundary centre in, 3 near boundary centre out
                if s == 0 or f > t_out:
                    continue
                if f < 0.0 and s != 3 and first[i, j, k] < 0:
                    first[i, j, k] = cut
                    est += 1
                if f < -t_in and s == 1 and not maybe[i, j, k]:
                    low += 1
                if not sure[i, j, k]:
                    up += 1
    for a in range(n0):  # update the earlier-cut flags only after counting
        for b in range(n1):
            for c in range(n2):
                f = fmin[a, b, c]
                i, j, k = a + off[0], b + off[1], c + off[2]
                if f <= t_out:
                    maybe[i, j, k] = True
                if f < -t_in:
                    sure[i, j, k] = True
    return est, low, up


@numba.njit(cache=True, parallel=True)
def _annulus_state(g0, res, shape, hub, shroud, xmargin, kh, ks, rho, out):
    """Blank state per voxel. The distance of (x, r) to the curve r = p(x) is >= |r - p(x)| / sqrt(1 + L^2)
    (L the profile's largest slope) and (x, y, z) -> (x, r) is 1-Lipschitz, so margins > rho are certain."""
    for i in numba.prange(shape[0]):
        for j in range(shape[1]):
            y = g0[1] + (j + 0.5) * res
            for k in range(shape[2]):
                z = g0[2] + (k + 0.5) * res
                r = math.sqrt(y * y + z * z)
                mh = (r - hub[i]) * kh
                ms = (shroud[i] - r) * ks
                m = min(xmargin[i], mh, ms)  # > 0 inside
                if abs(mh) <= rho or abs(ms) <= rho or abs(xmargin[i]) <= rho:
                    out[i, j, k] = 2 if m >= 0.0 else 3
                elif m > 0.0:
                    out[i, j, k] = 1
                else:
                    out[i, j, k] = 0


# -- helpers ---------------------------------------------------------------------
def _check_pose(label, poses):
    poses = _finite(f"cut {label!r} poses", poses, (4, 4))
    R = poses[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = (err > 1e-6) | (np.abs(np.linalg.det(R) - 1.0) > 1e-6) | \
        (np.abs(poses[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-9)
    if bad.any():
        raise _bad(f"cut {label!r}: pose {int(np.argmax(bad))} is not a rigid transform (rotation + translation)")
    return poses


def _pair_moves(vertices, poses, on_hull=False):
    """Per consecutive pose pair: the largest move [mm] of an electrode point, helix-corrected (module doc).

    Over the vertices of the points' convex hull (:func:`hull_points`); ``on_hull``: ``vertices`` are those
    already (a hull costs 2 ms even of hull points, and a set's volumes asked for it about 90 times).
    """
    v = vertices if on_hull else hull_points(vertices)
    D = poses[1:] - poses[:-1]
    moves = np.concatenate([  # in blocks of poses: (poses, vertices, 3) stays small
        np.linalg.norm(np.einsum("nij,mj->nmi", D[s:s + 256, :3, :3], v) + D[s:s + 256, None, :3, 3],
                       axis=2).max(axis=1) for s in range(0, len(D), 256)])
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    phi = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    return moves / np.cos(phi / 4.0)


def pose_travel_of(vertices, poses, on_hull=False):
    """Largest move [mm] of an electrode point between consecutive poses, helix-corrected (see module doc).

    ``on_hull``: ``vertices`` are already their convex hull's (:func:`hull_points`).
    """
    if len(poses) < 2:
        return 0.0
    return float(_pair_moves(vertices, poses, on_hull).max())


def thin_poses(vertices, poses, max_travel, on_hull=False):
    """Indices of a subsequence of ``poses`` (first and last kept) whose consecutive moves stay about within
    ``max_travel`` [mm] (the sum of the skipped pairs' moves bounds it; the bracket measures the result).

    A cut's poses are sampled for the certificate (every 0.05 mm of travel); the volume field needs far
    fewer: the grown electrodes at poses t apart leave scallops g - sqrt(g^2 - t^2 / 4) deep (8 um for the
    rough gap at a quarter of a 0.5 mm voxel), which the voxels cannot see. ``on_hull``: ``vertices`` are
    already their convex hull's (:func:`hull_points`).
    """
    if len(poses) < 3:
        return np.arange(len(poses))
    moves = _pair_moves(vertices, poses, on_hull)
    keep, run = [0], 0.0
    for k, m in enumerate(moves):
        if run + m > max_travel and run > 0.0:
            keep.append(k)
            run = 0.0
        run += m
    if keep[-1] != len(poses) - 1:
        keep.append(len(poses) - 1)
    return np.asarray(keep, dtype=np.int64)


def _grid_sd(dist, axes):
    """Signed distances of ``dist`` at the points of the grid ``axes`` (3 coordinate arrays), in 1e6-point chunks."""
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    sd = np.concatenate([dist(pts[s:s + 1_000_000]) for s in range(0, len(pts), 1_000_000)])
    return sd.reshape([len(a) for a in axes])


def _electrode_sdf(vertices, faces, margin, h):
    """Exact signed distances (positive outside) on a grid over the mesh box grown by ``margin``, spacing h."""
    dist = MeshDistance(vertices, faces)
    lo, hi = dist.box
    n = np.maximum(np.ceil((hi - lo + 2 * margin) / h).astype(int) + 1, 2)
    origin = (lo + hi) / 2 - (n - 1) * h / 2
    return _grid_sd(dist, [origin[a] + h * np.arange(n[a]) for a in range(3)]), origin, lo, hi


def _mesh_state(blank, g0, res, shape, rho):
    dist = MeshDistance(blank.vertices, blank.faces)
    sd = _grid_sd(dist, [g0[a] + res * (np.arange(shape[a]) + 0.5) for a in range(3)])
    return np.where(np.abs(sd) <= rho, np.where(sd <= 0, 2, 3), np.where(sd < 0, 1, 0)).astype(np.uint8)


def _check_mesh(name, vertices, faces):
    V = _finite(f"{name} vertices", vertices, (3,))
    F = np.asarray(faces)
    if (F.ndim != 2 or F.shape[1] != 3 or not len(F) or not np.issubdtype(F.dtype, np.integer)
            or F.min() < 0 or F.max() >= len(V)):
        raise _bad(f"{name}: faces must be (f, 3) indices into the vertices")
    return V, F.astype(np.int64)


def _positive(name, value, zero_ok=False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and (v > 0 or (zero_ok and v == 0))):
        raise _bad(f"{name} must be {'>= 0' if zero_ok else 'positive'} and finite, got {value!r}")
    return v


#: largest stock mesh file read [bytes]
MAX_STOCK_BYTES = 200_000_000


def load_stock_mesh(path):
    """A pre-machined stock (STL, OBJ, PLY, ... in the workpiece frame, mm) as a MeshBlank, and its SHA-256.

    FILE_ERROR: unreadable, too large or not a mesh; INVALID_GEOMETRY: not one closed, outward-oriented
    solid (the material is what lies inside it), or non-finite coordinates.
    """
    path = pathlib.Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"stock mesh {path}: {exc.strerror or exc}") from None
    if len(data) > MAX_STOCK_BYTES:
        raise EdmError(ErrorCode.FILE_ERROR, f"stock mesh {path}: larger than {MAX_STOCK_BYTES} bytes")
    try:
        mesh = trimesh.load(trimesh.util.wrap_as_stream(data), file_type=path.suffix.lstrip(".").lower() or "stl",
                            force="mesh", process=True)
    except Exception as exc:                 # trimesh raises many kinds on a broken file
        raise EdmError(ErrorCode.FILE_ERROR, f"stock mesh {path}: not a readable mesh: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
        raise EdmError(ErrorCode.FILE_ERROR, f"stock mesh {path}: no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise EdmError(ErrorCode.INVALID_GEOMETRY, f"stock mesh {path}: NaN or infinite coordinates")
    if not mesh.is_watertight or not mesh.is_winding_consistent or mesh.volume <= 0:
        raise EdmError(ErrorCode.INVALID_GEOMETRY,
                       f"stock mesh {path}: must be one closed solid with outward normals (watertight "
                       f"{mesh.is_watertight}, consistent winding {mesh.is_winding_consistent}, volume "
                       f"{mesh.volume:.6g} mm^3)")
    return MeshBlank(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)), \
        hashlib.sha256(data).hexdigest()


def _check_blank(blank):
    if isinstance(blank, MeshBlank):
        _check_mesh("blank", blank.vertices, blank.faces)
        return
    if not isinstance(blank, AnnulusBlank):
        raise _bad(f"blank: expected AnnulusBlank or MeshBlank, got {type(blank).__name__}")
    if not (math.isfinite(blank.x0) and math.isfinite(blank.x1) and blank.x0 < blank.x1):
        raise _bad(f"blank: need finite x0 < x1, got {blank.x0!r}, {blank.x1!r}")
    for name in ("hub", "shroud"):
        px = _finite(f"blank {name}_x", getattr(blank, f"{name}_x"))
        pr = _finite(f"blank {name}_r", getattr(blank, f"{name}_r"))
        if px.ndim != 1 or px.shape != pr.shape or len(px) < 2 or np.any(np.diff(px) <= 0) or np.any(pr < 0):
            raise _bad(f"blank {name}: x and r must be equal-length 1-D arrays, x strictly increasing, r >= 0")


def _blank_state(blank, g0, res, shape, rho):
    if isinstance(blank, MeshBlank):
        return _mesh_state(blank, g0, res, shape, rho)
    xs = g0[0] + res * (np.arange(shape[0]) + 0.5)

    def prof(px, pr):
        px, pr = np.asarray(px, dtype=np.float64), np.asarray(pr, dtype=np.float64)
        slope = np.abs(np.diff(pr) / np.diff(px)).max()
        return np.interp(xs, px, pr), 1.0 / math.hypot(1.0, slope)

    hub, kh = prof(blank.hub_x, blank.hub_r)
    shroud, ks = prof(blank.shroud_x, blank.shroud_r)
    xmargin = np.minimum(xs - blank.x0, blank.x1 - xs)
    out = np.empty(shape, dtype=np.uint8)
    _annulus_state(g0, res, np.array(shape), hub, shroud, xmargin, kh, ks, rho, out)
    return out


def _index_range(lo, hi, g0, res, shape):
    a = np.clip(np.floor((lo - g0) / res - 0.5).astype(np.int64), 0, shape)
    b = np.clip(np.ceil((hi - g0) / res - 0.5).astype(np.int64) + 1, 0, shape)
    return np.stack([a, b], axis=1)


# -- the computation -------------------------------------------------------------
def removed_volumes(blank, cuts, resolution=0.5, sdf_spacing=None, pose_travel=None, max_travel=None):
    """Volume each cut removes from ``blank`` [mm^3], in order, with a certified bracket (module docstring).

    Parameters
    ----------
    blank : AnnulusBlank or MeshBlank
    cuts : list of Cut
    resolution : float
        Voxel size [mm].
    sdf_spacing : float, optional
        Spacing of the electrode distance grids [mm]. Default: the resolution (measured on the default
        blisk's set at 0.5 mm voxels: grids of 0.5, 0.25 and 0.125 mm change the estimate by 0.5 % and cost
        1x, 2x and 7x the time; the voxel size is what sets the estimate's accuracy).
    pose_travel : float, optional
        Largest move of an electrode point between consecutive poses [mm], for every cut;
        default: computed per cut (:func:`pose_travel_of`).
    max_travel : float, optional
        Thin each cut's poses to about this travel between poses first (:func:`thin_poses`); the bracket
        then covers the motion between the poses kept. Default: every pose.

    Returns
    -------
    VolumeResult
    """
    t_start = time.perf_counter()
    res = _positive("resolution", resolution)
    h = res if sdf_spacing is None else _positive("sdf_spacing", sdf_spacing)
    if pose_travel is not None:
        pose_travel = _positive("pose_travel", pose_travel, zero_ok=True)
    if not cuts:
        raise _bad("cuts: at least one cut is needed")
    _check_blank(blank)
    rho, e = SQRT3_2 * res, SQRT3_2 * h
    prepared, hulls = [], {}
    for c in cuts:
        V, F = _check_mesh(f"cut {c.label!r}", c.vertices, c.faces)
        gap = _positive(f"cut {c.label!r}: gap", c.gap)
        P = _check_pose(c.label, c.poses)
        key = hashlib.sha1(V.tobytes() + F.tobytes()).hexdigest()  # one distance grid per distinct mesh
        if pose_travel is None and key not in hulls:
            hulls[key] = hull_points(V)        # once per mesh: 20 ms for an electrode of 29 430 vertices
        if max_travel is not None and pose_travel is None:
            P = P[thin_poses(hulls[key], P, _positive("max_travel", max_travel), on_hull=True)]
        d = pose_travel / 2 if pose_travel is not None else pose_travel_of(hulls[key], P, on_hull=True) / 2
        prepared.append((c, V, F, P, gap, d, key))

    # distance grids: one per mesh, wide enough that outside it every voxel is surely out
    sdfs = {}
    for c, V, F, P, g, d, key in prepared:
        margin = g + rho + e + d + h
        if key not in sdfs or sdfs[key][0] < margin:
            sdfs[key] = (margin, V, F)
    for key, (margin, V, F) in sdfs.items():
        sdfs[key] = _electrode_sdf(V, F, margin, h)
        _log.info("electrode distance grid %s: %d points", key[:8], sdfs[key][0].size)

    # per cut and pose: the box of voxel centres that may be within reach
    boxes = []
    for c, V, F, P, g, d, key in prepared:
        _, _, lo, hi = sdfs[key]
        grow = g + rho + e + d
        corners = np.array(np.meshgrid(*zip(lo - grow, hi + grow), indexing="ij")).reshape(3, 8).T
        w = np.einsum("nij,mj->nmi", P[:, :3, :3], corners) + P[:, None, :3, 3]
        boxes.append((w.min(axis=1), w.max(axis=1)))
    blo, bhi = blank.bounds()
    # the voxel lattice is anchored at the workpiece origin: results do not depend on which cuts are given
    g_lo = np.floor(np.maximum(np.min([b[0].min(axis=0) for b in boxes], axis=0), blo) / res) * res
    g_hi = np.ceil(np.minimum(np.max([b[1].max(axis=0) for b in boxes], axis=0), bhi) / res) * res
    shape = tuple(int(s) for s in np.maximum(np.ceil((g_hi - g_lo) / res), 0).astype(int))
    voxels = int(np.prod(shape))
    _log.info("volume grid %s = %d voxels at %g mm", shape, voxels, res)

    blank_state = _blank_state(blank, g_lo, res, shape, rho) if voxels else np.zeros(shape, np.uint8)
    first = np.full(shape, -1, dtype=np.int32)
    sure = np.zeros(shape, dtype=np.bool_)
    maybe = np.zeros(shape, dtype=np.bool_)
    active = blank_state != 0
    vox = res ** 3
    results = []
    for n, ((c, V, F, P, g, d, key), (plo, phi_)) in enumerate(zip(prepared, boxes)):
        sdf, origin, mlo, mhi = sdfs[key]
        rngs = np.array([_index_range(a, b, g_lo, res, np.array(shape)) for a, b in zip(plo, phi_)])
        off = rngs[:, :, 0].min(axis=0)
        top = np.maximum(rngs[:, :, 1].max(axis=0), off)
        fmin = np.full(tuple(top - off), np.inf)
        live = active & ~sure  # voxels surely removed earlier cannot change any count
        inv = np.linalg.inv(P)
        tick = time.perf_counter()
        if fmin.size:
            for p in range(len(P)):
                if np.all(rngs[p, :, 1] > rngs[p, :, 0]):
                    _pose_min(inv[p], sdf, origin, h, mlo, mhi, g, g_lo, res, live, rngs[p], off, fmin, -(rho + e))
                if time.perf_counter() - tick > 10:
                    _log.info("cut %s: pose %d / %d", c.label, p + 1, len(P))
                    tick = time.perf_counter()
        est, low, up = _classify(fmin, off, blank_state, first, sure, maybe, n, rho + e, rho + e + d)
        results.append(CutVolume(c.label, est * vox, low * vox, up * vox))
        _log.info("cut %s: %.1f mm^3 in [%.1f, %.1f]", c.label, est * vox, low * vox, up * vox)
    return VolumeResult(
        cuts=results, resolution=res, total=float(sum(r.volume for r in results)),
        total_lower=float(np.count_nonzero(sure & (blank_state == 1)) * vox),
        total_upper=float(np.count_nonzero(maybe & active) * vox),
        blank_volume_in_grid=float(np.count_nonzero((blank_state == 1) | (blank_state == 2)) * vox),
        voxels=voxels, seconds=time.perf_counter() - t_start)


def channel_cavity_volume(blisk, step=0.25):
    """Volume [mm^3] of channel 0's cavity: ∫∫ (theta_p - theta_s) r dr dx where both walls exist.

    Midpoint rule on an (x, r) grid of cells at most ``step`` mm over the blade's axial range
    between hub and shroud; points where a wall does not exist (beyond the leading/trailing edges)
    contribute nothing, so the open annulus before and after the blades is not counted.
    The rule is second order inside and first order at the edges where the walls end.
    """
    step = _positive("step", step)
    x0, x1 = blisk.axial_range
    nx = max(1, int(np.ceil((x1 - x0) / step)))
    xs = x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx
    hub, shroud = blisk.hub.radius_at(xs), blisk.shroud.radius_at(xs)
    nr = max(1, int(np.ceil((shroud - hub).max() / step)))
    t = (np.arange(nr) + 0.5) / nr
    dr = (shroud - hub) / nr
    X = np.repeat(xs, nr)
    R = (hub[:, None] + t[None, :] * (shroud - hub)[:, None]).ravel()
    th_s, th_p, inside = blisk.wall_angles(X, R)
    w = np.where(inside, (th_p - th_s) * R, 0.0) * np.repeat(dr, nr) * (x1 - x0) / nx
    return float(w.sum())
