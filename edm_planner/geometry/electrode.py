"""Electrode design (Huang section II; Liu 2024 sections 1 and 4.1).

The primitive electrode is the channel volume over an axial range. It is
shrunk by the discharge gap (every face offset from its channel wall by
exactly the gap: hub and shroud by exact normal offsets of their profiles,
the blade faces by a per-vertex solve on the exact distance to the
reconstructed face), reduced circumferentially (side faces rotated about X
by h, Huang's H_h) and radially (the shroud side contracted), and optionally
split into two sub-electrodes with an overlap.

The electrode is a structured volume lattice (x along the axis, rho from hub
to shroud, tau from the suction to the pressure wall) whose boundary is a
closed, watertight triangle mesh. Its frame has its origin at the electrode's
centre of volume at the final pose, X along the blisk axis and Z radial
(outwards through the centre), so that the C axis yaws it about the radial
direction; the final pose in channel k is ``rotation_about_x(k * pitch) @ final_pose``.
"""

from dataclasses import dataclass, field, fields

import numpy as np
import trimesh

from ..constants import TOL
from ..errors import GeometryError
from .frames import cylindrical_to_cartesian, rotation_about_x

SIDES = ("left", "right", "upper", "lower")
REDUCTION_SIDES = ("left", "right", "both")
SPLITS = ("none", "left_right", "front_rear")


@dataclass(frozen=True)
class ElectrodeDesign:
    """Electrode design parameters (YAML key ``electrode:``; all optional).

    Attributes
    ----------
    discharge_gap : float
        Offset of every electrode face from the channel [mm], 0.01 .. 0.5.
    circumferential_reduction : float
        h [rad] >= 0: the side faces rotate about X towards the channel middle.
    reduction_side : str
        'left' (the suction side), 'right' (the pressure side) or 'both' (h/2 each).
    radial_reduction : float
        Contraction of the shroud-side face [mm] >= 0.
    axial_range : tuple of float or None
        (x_start, x_end) [mm]; default: where both blade faces span the whole channel.
    split : str
        'none', 'left_right' or 'front_rear'.
    split_fraction : float
        Where the split falls, 0..1 of the angle (left/right) or of the axial range (front/rear).
    split_overlap : float
        Overlap of the two sub-electrodes [mm].
    split_inset : float
        A roughing twin's left/right split: each split face lies this far [mm] inside, along its
        normal, the split face of the same design with the discharge gap less this (its finishing
        electrode's); 0: the split faces follow this design's own walls.
    resolution : float
        Largest edge length of the electrode lattice [mm].
    chord_tolerance : float
        Largest deviation of the lattice's flat triangles from the exact offset
        faces [mm]; the lattice is refined where the walls curve tightly.
    """

    discharge_gap: float = 0.1
    circumferential_reduction: float = 0.0
    reduction_side: str = "both"
    radial_reduction: float = 0.0
    axial_range: tuple = None
    split: str = "none"
    split_fraction: float = 0.5
    split_overlap: float = 0.5
    resolution: float = 0.5
    chord_tolerance: float = 0.005
    split_inset: float = 0.0

    def __post_init__(self):
        w = "electrode"
        for name in ("discharge_gap", "circumferential_reduction", "radial_reduction",
                     "split_fraction", "split_overlap", "resolution", "chord_tolerance", "split_inset"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise GeometryError(f"{w}.{name}: must be a number, got {value!r}")
            if not np.isfinite(value):
                raise GeometryError(f"{w}.{name}: must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))
        if not 0.01 <= self.discharge_gap <= 0.5:
            raise GeometryError(f"{w}.discharge_gap: must lie in 0.01 .. 0.5 mm, got {self.discharge_gap:g}")
        if self.circumferential_reduction < 0 or self.circumferential_reduction > 0.5:
            raise GeometryError(
                f"{w}.circumferential_reduction: must lie in 0 .. 0.5 rad, got {self.circumferential_reduction:g}")
        if self.radial_reduction < 0:
            raise GeometryError(f"{w}.radial_reduction: must be >= 0 mm, got {self.radial_reduction:g}")
        if self.reduction_side not in REDUCTION_SIDES:
            raise GeometryError(f"{w}.reduction_side: must be one of {REDUCTION_SIDES}, got {self.reduction_side!r}")
        if self.split not in SPLITS:
            raise GeometryError(f"{w}.split: must be one of {SPLITS}, got {self.split!r}")
        if not 0.05 <= self.split_fraction <= 0.95:
            raise GeometryError(f"{w}.split_fraction: must lie in 0.05 .. 0.95, got {self.split_fraction:g}")
        if self.split_overlap < 0:
            raise GeometryError(f"{w}.split_overlap: must be >= 0 mm, got {self.split_overlap:g}")
        if not 0.0 <= self.split_inset <= self.discharge_gap - 0.01:
            raise GeometryError(f"{w}.split_inset: must lie in 0 .. discharge_gap - 0.01 = "
                                f"{self.discharge_gap - 0.01:g} mm, got {self.split_inset:g}")
        if not 1e-4 <= self.chord_tolerance <= 0.1:
            raise GeometryError(f"{w}.chord_tolerance: must lie in 0.0001 .. 0.1 mm, got {self.chord_tolerance:g}")
        if not 0.05 <= self.resolution <= 5:
            raise GeometryError(f"{w}.resolution: must lie in 0.05 .. 5 mm, got {self.resolution:g}")
        if self.axial_range is not None:
            ar = self.axial_range
            if (not isinstance(ar, (list, tuple)) or len(ar) != 2
                    or not all(isinstance(v, (int, float)) and np.isfinite(v) for v in ar) or ar[0] >= ar[1]):
                raise GeometryError(f"{w}.axial_range: must be [x_start, x_end] in mm with x_start < x_end, got {ar!r}")
            object.__setattr__(self, "axial_range", (float(ar[0]), float(ar[1])))

    @classmethod
    def from_dict(cls, data, where="electrode"):
        """Design from a YAML mapping; unknown keys are errors."""
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise GeometryError(f"{where}: must be a mapping of design keys")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise GeometryError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
        return cls(**data)

    def to_dict(self):
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["axial_range"] = list(self.axial_range) if self.axial_range else None
        if not self.split_inset:                       # a finishing design's record (and id) as before
            del d["split_inset"]
        return d


@dataclass(frozen=True, eq=False)
class Electrode:
    """A designed electrode.

    Attributes
    ----------
    electrode_id : str
        'main', or 'left'/'right'/'front'/'rear' for split electrodes.
    mesh : trimesh.Trimesh
        Closed, watertight mesh in the electrode frame [mm].
    final_pose : (4, 4) float
        Electrode frame -> W at the machining pose in channel 0.
    samples : dict
        'left', 'right', 'upper', 'lower' -> (n, 3) surface points in the electrode frame [mm]
        (left faces the suction wall, right the pressure wall, upper the shroud, lower the hub).
    """

    electrode_id: str
    mesh: trimesh.Trimesh
    final_pose: np.ndarray
    samples: dict = field(default_factory=dict)

    def pose_in_channel(self, channel, pitch):
        """Final pose (4x4) in channel k."""
        return rotation_about_x(channel * pitch) @ self.final_pose


def _offset_wall(face, x, r, theta, grad, gap, sign, iterations=12):
    """Angles at (x, r) whose exact distance to a blade face is ``gap``.

    Starts from the first-order offset of the surface theta = f(x, r):
    d(theta) = gap * |grad F|, |grad F| = sqrt(f_x^2 + f_r^2 + 1/r^2), then
    solves distance(delta) = gap per vertex by the secant method on the exact
    distance to the reconstructed face (where the closest point is on the
    face's edge the relation is far from linear, hence the iterations); only
    the vertices not yet within 1e-10 mm are iterated.
    """
    def distance(delta, k):
        return face.closest_points(cylindrical_to_cartesian(x[k], r[k], theta[k] + sign * delta))[1]

    every = np.arange(len(x))
    d0 = gap * np.sqrt(grad[:, 0] ** 2 + grad[:, 1] ** 2 + 1.0 / r**2)
    f0 = distance(d0, every) - gap
    d1 = d0 * gap / np.maximum(f0 + gap, 1e-12)
    f1 = distance(d1, every) - gap
    for _ in range(iterations):
        k = np.where(np.abs(f1) > 1e-10)[0]
        if not len(k):
            break
        step = d1[k] - d0[k]
        slope = (f1[k] - f0[k]) / np.where(np.abs(step) > 1e-15, step, 1e-15)
        slope = np.where(slope > 1e-6, slope, (f1[k] + gap) / np.maximum(d1[k], 1e-15))  # fall back to the ratio
        d0[k], f0[k] = d1[k], f1[k]
        d1[k] = np.maximum(d1[k] - f1[k] / slope, 0.0)
        f1[k] = distance(d1[k], k) - gap
    return theta + sign * d1


def _box_mesh(lattice):
    """Closed triangle mesh of the boundary of a structured (nx, nr, nt, 3) lattice, normals outwards.

    The winding follows from the lattice's orientation (the sign of its
    Jacobian, the same in every cell of an unfolded lattice): on the side
    i = 0 the triangles (a, b, c) of a (j, k) grid turn about +d/di, so they
    face inwards when the Jacobian is positive; likewise for the other five
    sides. Setting it directly replaces trimesh's graph traversal
    (``fix_normals``, seconds on a refined electrode); the result is checked.
    """
    nx, nr, nt, _ = lattice.shape
    idx = np.arange(nx * nr * nt).reshape(nx, nr, nt)
    e = lattice[1, 0, 0] - lattice[0, 0, 0], lattice[0, 1, 0] - lattice[0, 0, 0], lattice[0, 0, 1] - lattice[0, 0, 0]
    positive = np.dot(e[0], np.cross(e[1], e[2])) > 0
    faces = []
    # (side grid, flip when the Jacobian is positive)
    for grid, flip in ((idx[0], True), (idx[-1], False), (idx[:, 0], False), (idx[:, -1], True),
                       (idx[:, :, 0], True), (idx[:, :, -1], False)):
        a, b = grid[:-1, :-1].ravel(), grid[1:, :-1].ravel()
        c, d = grid[1:, 1:].ravel(), grid[:-1, 1:].ravel()
        tri = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
        faces.append(tri[:, ::-1] if flip == positive else tri)
    mesh = trimesh.Trimesh(lattice.reshape(-1, 3), np.vstack(faces), process=True)
    mesh.remove_unreferenced_vertices()
    if not (mesh.is_winding_consistent and mesh.volume > 0):
        trimesh.repair.fix_normals(mesh)              # a folded lattice: let trimesh sort it out
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise GeometryError("electrode: the electrode mesh is not closed (internal error in the lattice)")
    return mesh


def design_electrodes(blisk, design=None, only=None, walls_cache=None):
    """Design the electrode(s) of channel 0.

    Parameters
    ----------
    blisk : Blisk
    design : ElectrodeDesign, optional
    only : str, optional
        Design just the electrode of this id (the other part of a split is skipped).
    walls_cache : dict, optional
        Offset walls kept across designs of the same blisk (the caller's, one per
        blisk): designs that differ only in the circumferential reduction, the
        reduction side or the split reuse them (h only turns the side faces).

    Returns
    -------
    list of Electrode
        One, or two for a split design.
    """
    design = design or ElectrodeDesign()
    fx0, fx1 = blisk.full_span_axial_range
    # default: the full-span range, inset 0.5 % of it so that the spline faces'
    # footprint corners (curved between sections) still cover every station
    inset = 0.005 * (fx1 - fx0)
    x0, x1 = design.axial_range or (fx0 + inset, fx1 - inset)
    if x0 < fx0 - 1e-9 or x1 > fx1 + 1e-9:
        raise GeometryError(
            f"electrode.axial_range: [{x0:g}, {x1:g}] mm reaches beyond [{fx0:.3f}, {fx1:.3f}] mm, "
            "where both blade faces span the whole channel")
    if design.split == "front_rear":
        xs = x0 + design.split_fraction * (x1 - x0)
        lo, hi = xs - 0.5 * design.split_overlap, xs + 0.5 * design.split_overlap
        if lo <= x0 + design.resolution or hi >= x1 - design.resolution:
            raise GeometryError("electrode.split_overlap: the overlap is longer than a sub-electrode")
        ranges = {"front": (x0, hi), "rear": (lo, x1)}
        parts = {k: _walls(blisk, design, *r, cache=walls_cache) for k, r in ranges.items() if only in (None, k)}
    else:
        parts = _split_sides(design, *_walls(blisk, design, x0, x1, cache=walls_cache), blisk=blisk)
    electrodes = []
    for name, (X, R, tl, tr) in parts.items():
        if only is not None and name != only:
            continue
        nt = max(4, int(np.ceil(np.max((tr - tl) * R) / design.resolution)) + 1)
        tau = np.linspace(0, 1, nt)
        T = tl[..., None] + tau * (tr - tl)[..., None]
        lattice = cylindrical_to_cartesian(X[..., None], R[..., None], T)    # (nx, nr, nt, 3)
        mesh = _box_mesh(lattice)
        centre = mesh.center_mass
        # electrode frame: origin at the centre of volume, X along the blisk axis, Z radial
        # outwards through the centre (the machine's C axis turns the electrode about it, as
        # with the channel under the vertical C axis in Huang's machine), Y = Z x X
        pose = rotation_about_x(np.arctan2(centre[2], centre[1]) - np.pi / 2)
        pose[:3, 3] = centre
        inverse = np.linalg.inv(pose)
        mesh.apply_transform(inverse)
        local = lattice @ inverse[:3, :3].T + inverse[:3, 3]
        samples = {"left": local[:, :, 0].reshape(-1, 3), "right": local[:, :, -1].reshape(-1, 3),
                   "lower": local[:, 0, :].reshape(-1, 3), "upper": local[:, -1, :].reshape(-1, 3)}
        electrodes.append(Electrode(name, mesh, pose, samples))
    return electrodes


def _walls(blisk, design, x0, x1, cache=None):
    """Lattice stations and side angles over [x0, x1]: (X, R, theta_left, theta_right), each (nx, nr).

    The discharge-gap offsets (``_offset_walls``) come from ``cache`` when it
    holds them; the circumferential reduction is applied here.
    """
    key = (design.discharge_gap, design.resolution, design.chord_tolerance, design.radial_reduction, x0, x1)
    walls = None if cache is None else cache.get(key)
    if walls is None:
        walls = _offset_walls(blisk, design, x0, x1)
        if cache is not None:
            cache[key] = walls
    x, R, th_l, th_r = walls
    h = design.circumferential_reduction
    th_l, th_r = _reduced(design, th_l, th_r)
    width = (th_r - th_l) * R
    if width.min() < TOL.min_feature:
        raise GeometryError(
            f"electrode.circumferential_reduction: h = {h:g} rad leaves no electrode "
            f"(narrowest channel after the gap: {np.min(width + h * R):.3f} mm)")
    X = np.repeat(x[:, None], R.shape[1], axis=1)
    return X, R, th_l, th_r


def _reduced(design, th_l, th_r):
    """Side angles with the circumferential reduction h applied (rotated towards the channel middle)."""
    h = design.circumferential_reduction
    if design.reduction_side == "left":
        return th_l + h, th_r
    if design.reduction_side == "right":
        return th_l, th_r - h
    return th_l + h / 2, th_r - h / 2


def _side_angles(blisk, x, r, gap):
    """Suction and pressure wall angles offset by ``gap`` at the points (x, r) [mm]: (theta_l, theta_r)."""
    th_s, th_p, inside, (g_s, g_p) = blisk.wall_angles(x, r, with_gradient=True)
    if not inside.all():
        raise GeometryError("electrode: the channel walls do not cover the electrode's axial range")
    # discharge-gap offset on the exact distance to the reconstructed faces
    return _offset_wall(blisk.suction_face, x, r, th_s, g_s, gap, +1.0), _offset_pressure(blisk, x, r, th_p, g_p, gap)


def _offset_walls(blisk, design, x0, x1):
    """Axial stations, radii and the side angles at the discharge gap over [x0, x1]: (x, R, theta_l, theta_r).

    The axial stations start at the design resolution and are refined where a
    flat lattice triangle would leave the exact offset surface by more than
    the design's chord tolerance (the walls curve tightly near the blade edges, where a
    0.5 mm chord across the trailing-edge rounding misses by 0.1 mm).
    """
    gap, res, tol = design.discharge_gap, design.resolution, design.chord_tolerance
    hub = blisk.hub.offset(gap, x0 - 1, x1 + 1, step=min(res, 0.1))
    shroud = blisk.shroud.offset(-gap, x0 - 1, x1 + 1, step=min(res, 0.1))
    r_lo_all = hub.radius_at(np.linspace(x0, x1, 50))
    r_hi_all = shroud.radius_at(np.linspace(x0, x1, 50)) - design.radial_reduction
    if np.min(r_hi_all - r_lo_all) < TOL.min_feature:
        raise GeometryError(
            f"electrode.radial_reduction: {design.radial_reduction:g} mm leaves no electrode "
            f"(channel height after the gap is {np.min(r_hi_all + design.radial_reduction - r_lo_all):.3f} mm)")
    nr = max(4, int(np.ceil(np.max(r_hi_all - r_lo_all) / res)) + 1)
    rho = np.linspace(0, 1, nr)

    # (x, R) -> (theta_l, theta_r): each refinement round checks every interval's midpoint, and the
    # intervals a round left alone ask for the same points again (30 % of the points of a design); an
    # offset is a point's own (its secant solve and closest points), so a point's angles are taken once
    solved = {}

    def stations(x, rho=rho):
        nr = len(rho)
        r_lo = hub.radius_at(x)
        r_hi = shroud.radius_at(x) - design.radial_reduction
        R = r_lo[:, None] + rho[None, :] * (r_hi - r_lo)[:, None]
        xs, rs = np.repeat(x, nr), R.ravel()
        keys = list(zip(xs.tolist(), rs.tolist()))
        new = [i for i, key in enumerate(keys) if key not in solved]
        if new:
            th_l, th_r = _side_angles(blisk, xs[new], rs[new], gap)
            solved.update(zip((keys[i] for i in new), zip(th_l.tolist(), th_r.tolist())))
        angles = np.array([solved[key] for key in keys]).reshape(len(x), nr, 2)
        return R, angles[..., 0], angles[..., 1]

    x = np.linspace(x0, x1, max(8, int(np.ceil((x1 - x0) / res)) + 1))
    R, th_l, th_r = stations(x)
    for _ in range(10):
        xm = 0.5 * (x[:-1] + x[1:])
        Rm, lm, rm = stations(xm)
        dev = np.maximum.reduce([
            np.abs(Rm - 0.5 * (R[:-1] + R[1:])),
            np.abs(lm - 0.5 * (th_l[:-1] + th_l[1:])) * Rm,
            np.abs(rm - 0.5 * (th_r[:-1] + th_r[1:])) * Rm]).max(axis=1)
        bad = dev > tol
        if not bad.any():
            break
        order = np.argsort(np.concatenate([x, xm[bad]]))
        x = np.concatenate([x, xm[bad]])[order]
        R = np.concatenate([R, Rm[bad]])[order]
        th_l = np.concatenate([th_l, lm[bad]])[order]
        th_r = np.concatenate([th_r, rm[bad]])[order]
    # the quads' diagonals: the lattice triangles run from (i, j) to (i+1, j+1)
    for _ in range(6):
        xm = 0.5 * (x[:-1] + x[1:])
        rm_ = 0.5 * (rho[:-1] + rho[1:])
        Rm, lm, rm = stations(xm, rm_)
        dev = np.maximum.reduce([
            np.abs(lm - 0.5 * (th_l[:-1, :-1] + th_l[1:, 1:])) * Rm,
            np.abs(rm - 0.5 * (th_r[:-1, :-1] + th_r[1:, 1:])) * Rm])
        bad_x, bad_r = (dev > tol).any(axis=1), (dev > tol).any(axis=0)
        if not bad_x.any():
            break
        # solve the offsets only where the lattice is new: old rows x new columns, new rows x all columns
        x_add, r_add = xm[bad_x], rm_[bad_r]
        rho_all = np.concatenate([rho, r_add])
        cols, rows = stations(x, r_add), stations(x_add, rho_all)
        ox, orr = np.argsort(np.concatenate([x, x_add])), np.argsort(rho_all)
        R, th_l, th_r = (np.vstack([np.hstack([old, c]), r])[ox][:, orr]
                         for old, c, r in zip((R, th_l, th_r), cols, rows))
        x, rho = np.concatenate([x, x_add])[ox], rho_all[orr]
    # the same along the span, at every axial station
    for _ in range(6):
        rm_ = 0.5 * (rho[:-1] + rho[1:])
        Rm, lm, rm = stations(x, rm_)
        dev = np.maximum.reduce([
            np.abs(lm - 0.5 * (th_l[:, :-1] + th_l[:, 1:])) * Rm,
            np.abs(rm - 0.5 * (th_r[:, :-1] + th_r[:, 1:])) * Rm]).max(axis=0)
        bad = dev > tol
        if not bad.any():
            break
        order = np.argsort(np.concatenate([rho, rm_[bad]]))
        rho = np.concatenate([rho, rm_[bad]])[order]
        R = np.concatenate([R, Rm[:, bad]], axis=1)[:, order]
        th_l = np.concatenate([th_l, lm[:, bad]], axis=1)[:, order]
        th_r = np.concatenate([th_r, rm[:, bad]], axis=1)[:, order]
    return x, R, th_l, th_r


def _offset_pressure(blisk, x, r, theta, grad, gap):
    """Pressure wall (blade 1's minus face): offset in blade 0's position, rotated back."""
    th = _offset_wall(blisk.pressure_face, x, r, theta - blisk.pitch, grad, gap, -1.0)
    return th + blisk.pitch


def _split_sides(design, X, R, th_l, th_r, blisk=None):
    """{name: (X, R, theta_left, theta_right)} for 'none' and 'left_right' designs.

    The split surface lies at ``split_fraction`` of the angle between the (reduced) walls, and each
    part reaches ``split_overlap / 2`` across it along the arc. With ``split_inset`` (a roughing twin)
    the split faces are those of the finishing design, whose walls lie ``split_inset`` closer, taken at
    the same lattice points, each moved ``split_inset`` into its part along its own normal: on a
    twisted channel the split face is inclined to the arc, so an arc offset alone would come in less.
    """
    if design.split == "none":
        return {"main": (X, R, th_l, th_r)}
    half = 0.5 * design.split_overlap / R
    if design.split_inset > 0:
        ref_l, ref_r = _side_angles(blisk, X.ravel(), R.ravel(), design.discharge_gap - design.split_inset)
        ref_l, ref_r = _reduced(design, ref_l.reshape(X.shape), ref_r.reshape(X.shape))
        mid = ref_l + design.split_fraction * (ref_r - ref_l)
        left_face = mid + half - _arc_for_normal(X, R, mid + half, design.split_inset)
        right_face = mid - half + _arc_for_normal(X, R, mid - half, design.split_inset)
    else:
        mid = th_l + design.split_fraction * (th_r - th_l)
        left_face, right_face = mid + half, mid - half
    if np.any(left_face >= th_r) or np.any(right_face <= th_l):
        raise GeometryError("electrode.split_overlap: the overlap is wider than a sub-electrode")
    if np.any(left_face <= th_l) or np.any(right_face >= th_r):
        raise GeometryError("electrode.split_inset: the split faces drawn in leave no sub-electrode")
    return {"left": (X, R, th_l, left_face), "right": (X, R, right_face, th_r)}


def _arc_for_normal(X, R, theta, distance):
    """The angle [rad] by which to turn the lattice surface theta(X, R) about X so that it moves ``distance``
    [mm] along its normal: distance / (R |n . e_theta|), with n from the lattice's tangents."""
    P = cylindrical_to_cartesian(X, R, theta)
    n = np.cross(np.gradient(P, axis=0), np.gradient(P, axis=1))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    e_theta = np.stack([np.zeros_like(theta), -np.sin(theta), np.cos(theta)], axis=-1)
    return distance / (R * np.abs(np.sum(n * e_theta, axis=-1)))
