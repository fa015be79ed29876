"""A whole blisk as scanned: every blade's sections read from one closed triangle mesh of the part (no rclpy).

An inspection system (a structured-light or CT scan, aligned to the part's datums) gives the whole blisk as one
closed mesh: hub, shroud and every blade. :func:`read_blisk_scan` cuts each blade's sections out of it, in its
own place on the part, for the ``as_measured`` section of a geometry file (:mod:`~.as_measured`): the nominal
blisk (from the same file) names the blades and gives the walls the blades are extended into.

1. **Rays on the mesh** (:class:`MeshRays`): the questions :mod:`~.solid_sections` asks of a solid (the
   stretches of material along a meridional ray and along a coaxial circle), answered exactly on the mesh's
   flat triangles. A plane ``x = x0`` cuts the triangles that straddle it (found through axial bins) into
   segments; a ray or a circle in that plane crosses the segments where a line or a quadratic says, and the
   triangle's outward normal tells entering from leaving.
2. **The part frame**: the scan's hub and shroud (meridional rays half way between the nominal blades) must lie
   within :data:`WALL_MISMATCH` of the nominal ones, and it must have the nominal blade count at mid span, each
   blade within a quarter pitch of its nominal place. Otherwise the scan is another part, not aligned to the
   part frame (X the blisk axis, blade 0 where the nominal blade 0 is) or not in millimetres, and is refused.
3. **The blades**: each blade's sections by :func:`~.solid_sections.blade_sections`, on cylinders clear of the
   nominal walls (and of the root and tip fillets, whose depth the file gives: a mesh has no faces to tell a
   fillet by), with two check sections between them for the fit.

Written by hand (no library reads a blade from a mesh): the axial bins, the plane cut, the ray and circle
crossings. Units: millimetres and radians. Frame W: X is the blisk axis, ``theta = atan2(z, y)``.
"""

import json
import logging
import os
import pathlib
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from ..errors import GeometryError
from .sections import BladeSections
from .solid_sections import blade_sections, merge_wrap, mid_span_blades, stretches, walls, wrap_angle

_log = logging.getLogger(__name__)

#: what the reader gives for a scan: part of the scan cache's key (raise it when the blades read would change)
READER_VERSION = 1
#: the scan's hub and shroud may lie this far [mm] from the nominal ones (beyond: not the part, or not aligned)
WALL_MISMATCH = 0.5
#: a scanned blade may lie this fraction of the pitch from its nominal place at mid span
POSITION_TOL = 0.25
#: crossings of a ray or circle closer than this (parameter: mm along a ray, rad along a circle) are one
MERGE_TOL = 1e-9
#: cells of the triangle grid round the turn
THETA_CELLS = 720
#: a triangle spanning more than this angle [rad] is listed in every angular cell
WIDE_TRIANGLE = np.pi / 8


class MeshRays:
    """The stretches of material along meridional rays and coaxial circles of a closed triangle mesh.

    The triangles are listed in the cells of a grid over (x, r, theta) that their ranges touch (the radial
    range conservatively: distance from the axis is 1-Lipschitz and every point of a triangle lies within its
    longest edge of each vertex; the angular range from the vertices, or the whole turn for a triangle that may
    reach the axis or spans more than :data:`WIDE_TRIANGLE`), so a circle looks only at the triangles of the
    cells along its arc and a ray at those of its angle.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        One closed, outward-wound body in W [mm].
    r_max : float
        Rays run from the axis to this radius [mm].
    """

    def __init__(self, mesh, r_max):
        tri = np.asarray(mesh.triangles, dtype=np.float64)
        self.r_max = float(r_max)
        self._tri = tri
        self._normal = np.asarray(mesh.face_normals, dtype=np.float64)
        self._xmin = tri[:, :, 0].min(axis=1)
        self._xmax = tri[:, :, 0].max(axis=1)
        r_v = np.hypot(tri[:, :, 1], tri[:, :, 2])
        longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
        rmin = r_v.min(axis=1) - longest
        rmax = r_v.max(axis=1)
        th_v = np.arctan2(tri[:, :, 2], tri[:, :, 1])
        rel = wrap_angle(th_v - th_v[:, :1])
        tmin, tmax = th_v[:, 0] + rel.min(axis=1), th_v[:, 0] + rel.max(axis=1)
        whole = (rmin <= 0.0) | (tmax - tmin > WIDE_TRIANGLE)
        # cells about twice a typical triangle in x and r, and a fine angle
        size = 2.0 * max(float(np.median(longest)), 1e-6)
        self._lo = np.array([self._xmin.min(), max(rmin.min(), 0.0)])
        span = np.array([self._xmax.max(), rmax.max()]) - self._lo
        self._n = np.clip(np.ceil(span / size).astype(np.int64), 1, 256)
        self._h = np.maximum(span / self._n, 1e-12)
        self._nt = THETA_CELLS
        cx0, cx1 = self._cell(0, self._xmin), self._cell(0, self._xmax)
        cr0, cr1 = self._cell(1, np.maximum(rmin, 0.0)), self._cell(1, rmax)
        # widened a little: a crossing's angle, computed from another point, may round across a cell's edge
        ct0 = np.where(whole, 0, np.floor((tmin - 1e-9 + np.pi) / (2 * np.pi) * self._nt).astype(np.int64))
        ct1 = np.where(whole, self._nt - 1, np.floor((tmax + 1e-9 + np.pi) / (2 * np.pi) * self._nt).astype(np.int64))
        nx, nr, nt = cx1 - cx0 + 1, cr1 - cr0 + 1, ct1 - ct0 + 1
        count = nx * nr * nt
        ids = np.repeat(np.arange(len(tri)), count)
        k = np.arange(len(ids)) - np.repeat(np.cumsum(count) - count, count)
        per_x = (nr * nt)[ids]
        cell = ((cx0[ids] + k // per_x) * self._n[1] + cr0[ids] + (k % per_x) // nt[ids]) * self._nt \
            + (ct0[ids] + (k % per_x) % nt[ids]) % self._nt
        order = np.argsort(cell, kind="stable")
        self._ids = ids[order]
        self._start = np.searchsorted(cell[order], np.arange(int(self._n[0] * self._n[1]) * self._nt + 1))

    def _cell(self, axis, v):
        return np.clip(((v - self._lo[axis]) / self._h[axis]).astype(np.int64), 0, self._n[axis] - 1)

    def _grid(self):
        return (self._tri, self._normal, self._xmin, self._xmax, self._ids, self._start, self._lo, self._h, self._n,
                self._nt)

    def intervals(self, x, theta):
        """[(r_in, r_out), ...] of material on the ray from the axis at (x, theta), or None where its crossings
        do not alternate in, out."""
        s, entering = _ray_crossings(float(x), float(theta), self.r_max, *self._grid())
        return stretches(list(zip(s.tolist(), entering.tolist())), 0.0, self.r_max, MERGE_TOL)

    def circle(self, x, r, start, length=2 * np.pi):
        """[(theta_in, theta_out), ...] of material on the arc of the circle (x, r) from ``start`` over
        ``length`` (unwrapped; a stretch through the start of a whole turn joined), or None where the
        crossings do not alternate in, out."""
        th, entering = _circle_crossings(float(x), float(r), float(start), float(length), *self._grid())
        found = stretches(list(zip(th.tolist(), entering.tolist())), start, start + length, MERGE_TOL)
        return None if found is None else merge_wrap(found, start, length)


@numba.njit(cache=True)
def _plane_segment(tri, x):
    """The segment (ay, az, by, bz) where the plane ``x`` cuts a triangle that straddles it."""
    d0, d1, d2 = tri[0, 0] - x, tri[1, 0] - x, tri[2, 0] - x
    above = (d0 >= 0) + (d1 >= 0) + (d2 >= 0)
    # the lone vertex on its side of the plane, and the other two (as MeshSlicer.slice)
    lone = 0
    for k, d in enumerate((d0, d1, d2)):
        if (above == 1 and d >= 0) or (above == 2 and d < 0):
            lone = k
            break
    k1, k2 = (lone + 1) % 3, (lone + 2) % 3
    dl, e1, e2 = tri[lone, 0] - x, tri[k1, 0] - x, tri[k2, 0] - x
    f1, f2 = dl / (dl - e1), dl / (dl - e2)
    return (tri[lone, 1] + f1 * (tri[k1, 1] - tri[lone, 1]), tri[lone, 2] + f1 * (tri[k1, 2] - tri[lone, 2]),
            tri[lone, 1] + f2 * (tri[k2, 1] - tri[lone, 1]), tri[lone, 2] + f2 * (tri[k2, 2] - tri[lone, 2]))


@numba.njit(cache=True)
def _cell_of(v, lo, h, n):
    c = int((v - lo) / h) if v > lo else 0
    return min(max(c, 0), n - 1)


@numba.njit(cache=True)
def _cell_segments(cell, x, tri, xmin, xmax, ids, cstart):
    """The segments (ay, az, by, bz) where the plane ``x`` cuts the triangles of a grid cell that straddle it,
    and those triangles."""
    lo, hi = cstart[cell], cstart[cell + 1]
    segments = np.empty((hi - lo, 4))
    faces = np.empty(hi - lo, dtype=np.int64)
    m = 0
    for q in range(lo, hi):
        f = ids[q]
        if xmin[f] < x and xmax[f] >= x:
            segments[m] = _plane_segment(tri[f], x)
            faces[m] = f
            m += 1
    return segments[:m], faces[:m]


@numba.njit(cache=True)
def _append(values, flags, m, value, flag):
    """``values[m], flags[m] = value, flag``, the arrays doubled when full; returns them."""
    if m == len(values):
        values = np.concatenate((values, np.empty(m)))
        flags = np.concatenate((flags, np.empty(m, dtype=np.bool_)))
    values[m] = value
    flags[m] = flag
    return values, flags


@numba.njit(cache=True)
def _circle_crossings(x, r, start, length, tri, normal, xmin, xmax, ids, cstart, lo, h, n, nt):
    """Where the circle (x, r) crosses the mesh on the arc from ``start`` over ``length``: unwrapped angles [rad]
    and whether the circle enters material there. A triangle is listed in every angular cell it touches, so a
    crossing counts only in the cell its angle falls in (each once)."""
    ix = _cell_of(x, lo[0], h[0], n[0])
    ir = _cell_of(r, lo[1], h[1], n[1])
    two_pi = 2.0 * np.pi
    if length >= two_pi:
        c0, c1 = 0, nt - 1
    else:
        w = (start + np.pi) % two_pi - np.pi
        c0 = int(np.floor((w + np.pi) / two_pi * nt))
        c1 = c0 + int(np.ceil(length / two_pi * nt)) + 1
    th_out = np.empty(64)
    in_out = np.empty(64, dtype=np.bool_)
    m = 0
    for cc in range(c0, c1 + 1):
        it = cc % nt
        segments, faces = _cell_segments((ix * n[1] + ir) * nt + it, x, tri, xmin, xmax, ids, cstart)
        for i in range(len(faces)):
            f = faces[i]
            ay, az, by, bz = segments[i]
            dy, dz = by - ay, bz - az
            A = dy * dy + dz * dz
            if A <= 0.0:
                continue
            B = 2.0 * (ay * dy + az * dz)
            C = ay * ay + az * az - r * r
            disc = B * B - 4.0 * A * C
            if disc < 0.0:
                continue
            root = np.sqrt(disc)
            for sign in (-1.0, 1.0):
                if sign > 0 and root == 0.0:
                    continue
                t = (-B + sign * root) / (2.0 * A)
                if t < 0.0 or t > 1.0:
                    continue
                py, pz = ay + t * dy, az + t * dz
                th = np.arctan2(pz, py)
                if int(np.floor((th + np.pi) / two_pi * nt)) % nt != it:
                    continue
                th = start + (th - start) % two_pi
                if th > start + length:
                    continue
                # entering when the face's outward normal is against the circle's direction (d/d theta)
                th_out, in_out = _append(th_out, in_out, m, th,
                                         -normal[f, 1] * np.sin(th) + normal[f, 2] * np.cos(th) < 0.0)
                m += 1
    return th_out[:m], in_out[:m]


@numba.njit(cache=True)
def _ray_crossings(x, theta, r_max, tri, normal, xmin, xmax, ids, cstart, lo, h, n, nt):
    """Where the ray from the axis at (x, theta) crosses the mesh: radii [mm] and whether it enters material
    there. A crossing counts only in the radial cell its radius falls in (each once)."""
    two_pi = 2.0 * np.pi
    w = (theta + np.pi) % two_pi - np.pi
    it = int(np.floor((w + np.pi) / two_pi * nt)) % nt
    ix = _cell_of(x, lo[0], h[0], n[0])
    ey, ez = np.cos(theta), np.sin(theta)
    s_out = np.empty(64)
    in_out = np.empty(64, dtype=np.bool_)
    m = 0
    for ir in range(n[1]):
        segments, faces = _cell_segments((ix * n[1] + ir) * nt + it, x, tri, xmin, xmax, ids, cstart)
        for i in range(len(faces)):
            f = faces[i]
            ay, az, by, bz = segments[i]
            dy, dz = by - ay, bz - az
            den = dy * ez - dz * ey
            if den == 0.0:
                continue
            u = -(ay * ez - az * ey) / den          # a + u d = s e
            if u < 0.0 or u > 1.0:
                continue
            s = (ay + u * dy) * ey + (az + u * dz) * ez
            if s <= 0.0 or s > r_max or _cell_of(s, lo[1], h[1], n[1]) != ir:
                continue
            s_out, in_out = _append(s_out, in_out, m, s, normal[f, 1] * ey + normal[f, 2] * ez < 0.0)
            m += 1
    return s_out[:m], in_out[:m]


@dataclass
class ScanBlades:
    """What :func:`read_blisk_scan` found.

    Attributes
    ----------
    blades : dict
        Blade index -> :class:`~.sections.BladeSections` in its own place on the part [mm, rad].
    checks : dict
        Blade index -> check sections half way between section radii (as :class:`~.step_import.StepBlisk`'s).
    report : dict
        What was found, for :meth:`~.loader.LoadedGeometry.info` (keys without the ``scan_`` prefix).
    """

    blades: dict
    checks: dict = field(default_factory=dict, repr=False)
    report: dict = field(default_factory=dict)


def read_blisk_scan(mesh, nominal, section_count=25, station_count=81, root_fillet_depth=0.0,
                    tip_fillet_depth=0.0, where="as_measured.scan", progress=None):
    """Every blade's sections from a closed mesh of the whole blisk, in the part frame.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        One closed, outward-wound body: the whole blisk as scanned [mm], X its axis, blade 0 where the nominal
        blade 0 is.
    nominal : Blisk
        The nominal blisk: the blade count, the walls the sections keep clear of, each blade's place.
    section_count, station_count : int
        Sections per blade from hub to shroud, stations per section.
    root_fillet_depth, tip_fillet_depth : float
        How far [mm] root and tip fillets reach from hub and shroud (the sections keep clear of them).
    progress : callable, optional
        ``progress(done, total)`` after each blade.

    Raises
    ------
    GeometryError
        A scan that is not this blisk in the part frame (walls, blade count or blade places off), or a blade
        that cannot be cut.
    """
    t0 = time.perf_counter()
    n = nominal.blade_count
    pitch = nominal.pitch
    lo, hi = mesh.bounds
    r_max = 1.05 * float(np.max(np.abs(np.r_[lo[1:], hi[1:]]))) * np.sqrt(2.0)
    x_lo, x_hi = float(lo[0]), float(hi[0])
    rays = MeshRays(mesh, r_max)
    hub, shroud = nominal.hub, nominal.shroud
    b0, b1 = nominal.axial_range
    mid_x = 0.5 * (b0 + b1)
    r_mid = 0.5 * float(hub.radius_at(mid_x) + shroud.radius_at(mid_x))
    # nominal blade 0's mid-span angle
    th_m, _ = nominal.pressure_face.theta_at([mid_x], [r_mid])
    th_p, _ = nominal.suction_face.theta_at([mid_x], [r_mid])
    centre0 = 0.5 * float(th_m[0] + th_p[0])
    # 24 rays spread round the part and over a pitch: at every x some pass between the (twisted) blades
    j = np.arange(24)
    between = centre0 + pitch * ((j * max(1, n // 24)) % n + (j + 0.5) / 24)
    scan_hub, scan_shroud, _ = walls(rays, max(x_lo, b0), min(x_hi, b1), wrap_angle(between), n_x=25)
    xs = np.linspace(*scan_hub.x_range, 49)
    off_hub = float(np.max(np.abs(scan_hub.radius_at(xs) - hub.radius_at(xs))))
    off_shroud = float(np.max(np.abs(scan_shroud.radius_at(xs) - shroud.radius_at(xs))))
    if max(off_hub, off_shroud) > WALL_MISMATCH:
        raise GeometryError(
            f"{where}: the scan's hub lies up to {off_hub:.3f} mm and its shroud up to {off_shroud:.3f} mm from the "
            f"nominal ones over the blades' axial range (at most {WALL_MISMATCH} mm): another part, or not in the "
            f"part frame (X the blisk axis, millimetres)")
    loops = mid_span_blades(rays, r_mid, x_lo, x_hi)
    if len(loops) != n:
        raise GeometryError(f"{where}: {len(loops)} blades meet the mid-span cylinder (r = {r_mid:.3f} mm) of the "
                            f"scan, the nominal blisk has {n}")
    x_loop = loops[0]["x"]
    th_m, _ = nominal.pressure_face.theta_at([x_loop], [r_mid])
    th_p, _ = nominal.suction_face.theta_at([x_loop], [r_mid])
    ref = 0.5 * float(th_m[0] + th_p[0])
    by_blade, worst = {}, 0.0
    for loop in loops:
        k = int(np.round((loop["theta"] - ref) / pitch)) % n
        off = float(wrap_angle(loop["theta"] - ref - k * pitch))
        if abs(off) > POSITION_TOL * pitch or k in by_blade:
            raise GeometryError(
                f"{where}: the scan's blade at {np.degrees(loop['theta']):.3f} deg (mid span, x = {x_loop:.3f} mm) "
                f"is {np.degrees(off):+.3f} deg from nominal blade {k}'s place"
                + (" (which another scanned blade takes)" if k in by_blade else "")
                + f": the scan is not aligned to the part frame (blade 0 at {np.degrees(ref):.3f} deg)")
        by_blade[k] = loop
        worst = max(worst, abs(off) * r_mid)
    zones = {"root_fillet_depth": float(root_fillet_depth), "tip_fillet_depth": float(tip_fillet_depth)}
    blades, checks, radii = {}, {}, None
    for i, k in enumerate(sorted(by_blade)):
        sections, check, radii = blade_sections(rays, hub, shroud, by_blade[k], pitch, zones, section_count,
                                                station_count, 2, x_lo, x_hi, where, name=f"blade {k}")
        # in its own place, k pitches from blade 0 (the mid-span loop's angle is wrapped to -pi .. pi)
        turns = 2.0 * np.pi * np.round((np.mean(sections.theta_minus) - (centre0 + k * pitch)) / (2.0 * np.pi))
        blades[k] = sections.rotated(-turns)
        checks[k] = {key: [v - turns for v in val] if key.startswith("theta") else val for key, val in check.items()}
        if progress is not None:
            progress(i + 1, n)
    report = {"triangles": int(len(mesh.faces)), "blades": n, "mid_span_radius": r_mid,
              "blade_place_offset_max_mm": worst, "hub_offset_max_mm": off_hub, "shroud_offset_max_mm": off_shroud,
              "section_count": int(section_count), "station_count": int(station_count),
              "section_radii": [float(radii[0]), float(radii[-1])], **zones,
              "read_time_s": time.perf_counter() - t0}
    return ScanBlades(blades, checks, report)


def face_fit(view, suction_check, pressure_check, channel):
    """How far channel ``channel``'s reconstructed faces lie from the scan's check sections of its two blades
    (half way between section radii): the largest distance along the circle [mm], and the points compared.

    Parameters
    ----------
    view : Blisk
        The channel's own blisk (:func:`~.as_measured.channel_blisk`): blade k's suction face, blade k+1's
        pressure face, both turned back into blade 0's position.
    suction_check, pressure_check : dict or None
        The check sections of blade k and of blade k+1 (:class:`ScanBlades`), in place; None: not scanned.
    """
    worst, count = 0.0, 0
    for check, face, key, turn in ((suction_check, view.suction_face, "theta_plus", channel),
                                   (pressure_check, view.pressure_face, "theta_minus", (channel + 1) % view.blade_count)):
        if not check or not check.get("x"):
            continue
        x, r = np.concatenate(check["x"]), np.concatenate(check["r"])
        theta, inside = face.theta_at(x, r)
        if inside.any():
            own = np.concatenate(check[key]) - turn * view.pitch
            worst = max(worst, float(np.max(np.abs(theta - own)[inside] * r[inside])))
            count += int(inside.sum())
    return worst, count


def save_scan(found, path):
    """Keep what :func:`read_blisk_scan` found in an ``.npz`` (arrays and the report as JSON; no pickles),
    written to a temporary name and moved into place (a reader never sees half a file)."""
    arrays = {"report": np.array(json.dumps(found.report))}
    for k, b in found.blades.items():
        for name in ("x", "r", "theta_minus", "theta_plus"):
            arrays[f"blade{k}_{name}"] = getattr(b, name)
    for k, check in found.checks.items():
        for name, rows in check.items():
            arrays[f"check{k}_{name}"] = np.asarray(rows)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def load_scan(path):
    """A :class:`ScanBlades` kept by :func:`save_scan`, or None where there is none (or it cannot be read)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            report = json.loads(str(data["report"]))
            blades, checks = {}, {}
            for key in data.files:
                kind, _, name = key.partition("_")
                if kind.startswith("blade"):
                    blades.setdefault(int(kind[5:]), {})[name] = data[key]
                elif kind.startswith("check"):
                    checks.setdefault(int(kind[5:]), {})[name] = list(data[key])
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        if os.path.exists(path):
            _log.warning("scan cache %s not read (%s): reading the scan again", path, exc)
        return None
    return ScanBlades({k: BladeSections(v["x"], v["r"], v["theta_minus"], v["theta_plus"])
                       for k, v in blades.items()}, checks, report)
