"""Converting a closed blade mesh into :class:`~.sections.BladeSections` by exact slicing.

:func:`mesh_to_sections` slices the mesh: every station (x0, r0) is the
circle ``{(x0, r0 cos t, r0 sin t)}``, cut with the mesh's cross-section in
the plane ``x = x0`` (:class:`~.mesh_slicer.MeshSlicer`). Given the hub and
shroud, it slices only the span the channel needs (their wall overlap
included), so a CAD blade may run past the walls, closed by caps of any shape
there. :func:`mesh_to_sections_with_report` also says what was sliced.

The conversion runs in named steps: ``_check_arguments``, ``_footprint``
(the blade's meridional footprint and the hub-side and tip-side bounds inside
it), ``_SectionLines`` (the section lines between those bounds),
``_edge_parameters`` (leading and trailing edge of every section line),
``_station_circles`` and ``_crossing_angles`` (where every station's circle
enters and leaves the blade); ``_slicing_report`` says what was sliced.

Units: millimetres and radians. Frame W: X is the blisk axis,
``theta = atan2(z, y)``.
"""

import logging
import warnings
from dataclasses import dataclass

import numpy as np
import trimesh

from ..errors import GeometryError
from .blisk import mesh_slice_overlap
from .mesh_build import MERGE_REL
from .mesh_slicer import MeshSlicer
from .mesh_validate import count_open_edges
from .sections import BladeSections

_log = logging.getLogger(__name__)

#: deepest end zone of a cross-section taken for an end cap dipping into the blade and
#: left out of the slicing, as a fraction of the blade's span
MAX_CAP_DEPTH = 0.05

#: a face whose unit normal has a radial component of at least this is part of an end cap
CAP_NORMAL = 0.9

#: a circle crossing into the blade through a face whose unit normal has a +theta
#: component above this (or out of it through one below minus this) crosses faces
#: the wrong way: the mesh intersects itself
CROSSED_FACES = 0.1


def mesh_to_sections(mesh, n_sections=25, n_stations=81, *, hub=None, shroud=None, overlap=None,
                     span_margin=1e-3, edge_margin=1e-4, n_footprint=256, n_scan=81, with_report=None):
    """Convert a closed blade mesh into :class:`BladeSections` by exact slicing.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        One closed blade of a blisk in W [mm] (X the rotation axis, the blade
        spanning radially, covering a small range of theta).
    n_sections : int
        S, number of sections from the hub-side to the tip-side bound (>= 2).
    n_stations : int
        C, number of chord stations per section, leading to trailing edge
        (>= 4), cosine-clustered towards both edges.
    hub, shroud : RevolutionProfile, optional
        The walls the blade stands between (both or neither). With them the
        blade is sliced only over the span the channel needs: the hub-side
        bound is never below ``hub(x) - overlap`` and the tip-side bound
        never above ``shroud(x) + overlap``, so a mesh that runs past the
        walls (CAD blades often do, closed by caps of any shape) is sliced
        inside them. A mesh that stops short is sliced to its own ends, as
        without profiles (:class:`~.blisk.Blisk` then extends it).
    overlap : float, optional
        How far beyond the walls to slice [mm]; default
        :func:`~.blisk.mesh_slice_overlap` (3 % of the smallest channel
        height, more than the :func:`~.blisk.wall_overlap` :class:`~.blisk.Blisk`
        extends its blade by).
    span_margin : float
        Inset of the first and last section from the footprint's inner and
        outer radial bounds, as a fraction of the span (on top of the
        depth of chords across the caps).
    edge_margin : float
        Inset of the first and last station from the leading and trailing
        edge, as a fraction of the section's chord.
    n_footprint : int
        Number of planes used to find the meridional footprint.
    n_scan : int
        Samples along each section line used to bracket the edges (then
        refined by bisection).
    with_report : bool, optional
        Deprecated: call :func:`mesh_to_sections_with_report` for the report.
        ``True`` returns ``(sections, report)`` as that function does,
        ``False`` the sections; either warns (DeprecationWarning).

    Returns
    -------
    sections : BladeSections
        (S, C) stations; ``theta_minus``/``theta_plus`` are the smallest and
        largest angle at which the station's circle meets the mesh, unwrapped
        around the blade's mean angle.

    Raises
    ------
    GeometryError
        Not a closed mesh, not a single blade (a circle meets the mesh in two
        separate intervals, or leaves it where it should enter it: faces
        crossing), or no usable footprint; every such circle is named by its
        x and r.

    Notes
    -----
    The footprint (the blade's projection on the (x, r) half-plane) is found
    from the exact radial extent ``[r_lo(x), r_hi(x)]`` of cross-sections at
    ``n_footprint`` planes. Its four corners (leading/trailing edge at
    hub/tip) split the lower bound into the hub-side curve and the upper
    bound into the tip-side curve. Both are moved into the blade by 1.5 times
    the depth of chords across the caps plus ``span_margin``, and past each
    end zone -- the radial range of the end caps (faces whose normal is within
    about 25 deg of -r at the hub end, +r at the tip end) and the range where
    circles meet the cross-section other than twice (a flat cap dipping into
    the blade between two points of its section), counted exactly from the
    segments -- by ``span_margin``, if that zone is at most 5 % of the span
    deep (a deeper one is no cap: the circles report it where they meet it).
    With profiles the curves are then clipped to ``hub - overlap`` and
    ``shroud + overlap``. Section j is the curve ``(1 - f_j) H(u) + f_j T(u)``
    between them (u the chord fraction along each curve, H and T continued
    linearly beyond u in [0, 1]); its leading and trailing edge are found by
    bisection on "does the circle meet the mesh". Every station's circle must
    meet the mesh exactly twice, entering it at the first crossing and leaving
    it at the last.
    """
    if with_report is not None:
        warnings.warn("mesh_to_sections(with_report=...) is deprecated: mesh_to_sections returns the sections, "
                      "mesh_to_sections_with_report (sections, report)", DeprecationWarning, stacklevel=2)
        if with_report:
            return mesh_to_sections_with_report(
                mesh, n_sections, n_stations, hub=hub, shroud=shroud, overlap=overlap, span_margin=span_margin,
                edge_margin=edge_margin, n_footprint=n_footprint, n_scan=n_scan)
    return _slice(mesh, n_sections, n_stations, hub, shroud, overlap, span_margin, edge_margin, n_footprint,
                  n_scan).sections


def mesh_to_sections_with_report(mesh, n_sections=25, n_stations=81, *, hub=None, shroud=None, overlap=None,
                                 span_margin=1e-3, edge_margin=1e-4, n_footprint=256, n_scan=81):
    """:func:`mesh_to_sections`, and what was sliced.

    Parameters
    ----------
    mesh, n_sections, n_stations, hub, shroud, overlap, span_margin, edge_margin, n_footprint, n_scan
        As :func:`mesh_to_sections`.

    Returns
    -------
    sections : BladeSections
        As :func:`mesh_to_sections`.
    report : dict
        Plain data, lengths in mm: ``axial_extent_mm`` and
        ``radial_extent_mm`` (the mesh's own extent, [min, max]),
        ``sliced_axial_extent_mm``, ``sliced_hub_side_radius_mm`` and
        ``sliced_tip_side_radius_mm`` ([min, max] of the stations, of section
        0 and S-1), and with profiles ``wall_overlap_mm``,
        ``beyond_hub_mm`` / ``beyond_shroud_mm`` ([min, max] over
        the hub-/tip-side stations of how far the mesh's own end reaches
        beyond the wall; negative where it stops short) and
        ``clipped_to_hub`` / ``clipped_to_shroud`` ('all', 'none' or
        'k of n stations' sliced at the wall's bound instead of the mesh's
        own end).

    Raises
    ------
    GeometryError
        As :func:`mesh_to_sections`.
    """
    result = _slice(mesh, n_sections, n_stations, hub, shroud, overlap, span_margin, edge_margin, n_footprint,
                    n_scan)
    return result.sections, _slicing_report(result, hub, shroud)


# --------------------------------------------------------------------------
# the steps
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class _Footprint:
    """The blade's meridional footprint and the bounds the sections are taken between.

    Attributes
    ----------
    xmin, xmax, rmin, rmax : float
        The mesh's own axial and radial extent [mm].
    span : float
        Median radial extent of its cross-sections [mm].
    hub_x, hub_r : (H,) float
        The hub-side bound (the lower bound of the footprint between its
        leading and trailing edge corners, moved into the blade past the
        caps) [mm].
    own_hub_r : (H,) float
        The mesh's own lower bound at ``hub_x`` (not moved) [mm].
    tip_x, tip_r, own_tip_r : (T,) float
        The same on the tip side (upper bound) [mm].
    """

    xmin: float
    xmax: float
    rmin: float
    rmax: float
    span: float
    hub_x: np.ndarray
    hub_r: np.ndarray
    own_hub_r: np.ndarray
    tip_x: np.ndarray
    tip_r: np.ndarray
    own_tip_r: np.ndarray


class _SectionLines:
    """The hub-side and tip-side bound curves and the S section lines between them.

    Parameters
    ----------
    footprint : _Footprint
    n_sections : int
        S; section j is ``(1 - f_j) H(u) + f_j T(u)``, ``f_j = j / (S - 1)``.
    n_footprint : int
        Planes the footprint was found from (the step of the end slopes).
    hub, shroud : RevolutionProfile or None
        The walls the bounds are clipped to (both or neither).
    overlap : float or None
        How far beyond the walls to slice [mm] (None without walls).
    """

    def __init__(self, footprint, n_sections, n_footprint, hub, shroud, overlap):
        self.hub_x, self.hub_r = footprint.hub_x, footprint.hub_r
        self.tip_x, self.tip_r = footprint.tip_x, footprint.tip_r
        self.du = 1.0 / (n_footprint - 1)
        self.hub, self.shroud, self.overlap = hub, shroud, overlap
        self.walls = hub is not None
        self.n_sections = n_sections
        self.f = np.linspace(0.0, 1.0, n_sections)[:, None]

    def curve(self, side, uu):
        """(x, r) of the hub-side (0) or tip-side (1) bound at chord parameters uu.

        Linear in x along uu; r interpolated in [0, 1] and continued beyond with
        the end slopes, then clipped to the walls.
        """
        cx, cr = (self.hub_x, self.hub_r) if side == 0 else (self.tip_x, self.tip_r)
        uu = np.asarray(uu, dtype=np.float64)
        du = self.du

        def x_at(w):
            return cx[0] + w * (cx[-1] - cx[0])

        xx = x_at(uu)
        rr = np.interp(x_at(np.clip(uu, 0.0, 1.0)), cx, cr)
        for end, sign in ((0.0, 1.0), (1.0, -1.0)):
            outside = (uu < 0) if end == 0.0 else (uu > 1)
            if np.any(outside):
                r0 = np.interp(x_at(end), cx, cr)
                slope = (np.interp(x_at(end + sign * du), cx, cr) - r0) / (sign * du)
                rr = np.where(outside, r0 + (uu - end) * slope, rr)
        if self.walls:
            rr = (np.maximum(rr, self.hub.radius_at(xx) - self.overlap) if side == 0
                  else np.minimum(rr, self.shroud.radius_at(xx) + self.overlap))
        return xx, rr

    def points(self, u):
        """(x, r) of the section lines at chord parameters u, (S, U) each."""
        u = np.asarray(u, dtype=np.float64)
        if u.ndim == 1:
            u = np.broadcast_to(u, (self.n_sections, len(u)))
        hx, hr = self.curve(0, u)
        tx, tr = self.curve(1, u)
        f = self.f
        return (1 - f) * hx + f * tx, (1 - f) * hr + f * tr

    def check_span(self):
        """GeometryError when the tip-side bound does not lie above the hub-side one everywhere."""
        u_check = np.linspace(0, 1, 33)
        if np.any(self.curve(1, u_check)[1] <= self.curve(0, u_check)[1]):
            where = " between the hub and shroud profiles" if self.walls else ""
            raise GeometryError(f"mesh_to_sections: the blade's footprint{where} is too thin in span")


@dataclass(frozen=True)
class _Slicing:
    """What :func:`_slice` found: the sections and what the report is made of."""

    sections: BladeSections
    x: np.ndarray
    r: np.ndarray
    footprint: _Footprint
    overlap: float


def _slice(mesh, n_sections, n_stations, hub, shroud, overlap, span_margin, edge_margin, n_footprint, n_scan):
    """All steps of :func:`mesh_to_sections`; returns a :class:`_Slicing`."""
    overlap = _check_arguments(mesh, n_sections, n_stations, hub, shroud, overlap)
    theta0 = _mean_angle(mesh)
    slicer = MeshSlicer(mesh, theta0)
    _check_one_blade(slicer)
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(mesh.vertices), axis=0)))
    merge_tol = MERGE_REL * 10 * diagonal
    footprint = _footprint(mesh, slicer, n_footprint, span_margin, merge_tol)
    lines = _SectionLines(footprint, n_sections, n_footprint, hub, shroud, overlap)
    lines.check_span()
    u_le, u_te = _edge_parameters(slicer, lines, n_scan)
    x, r = _station_circles(lines, u_le, u_te, n_stations, edge_margin)
    t_min, t_max = _crossing_angles(slicer, mesh, x, r, merge_tol)
    theta_minus = theta0 + t_min
    theta_plus = theta0 + t_max
    _log.debug("mesh_to_sections: %d x %d stations, x %.4g..%.4g mm, r %.4g..%.4g mm",
               n_sections, n_stations, x.min(), x.max(), r.min(), r.max())
    sections = BladeSections(x=x, r=r, theta_minus=theta_minus, theta_plus=theta_plus)
    return _Slicing(sections, x, r, footprint, overlap)


def _check_arguments(mesh, n_sections, n_stations, hub, shroud, overlap):
    """Validate the arguments of :func:`mesh_to_sections`.

    Returns
    -------
    overlap : float or None
        How far beyond the walls to slice [mm] (the default filled in), None
        without walls.
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise GeometryError("mesh_to_sections: expected a non-empty trimesh.Trimesh")
    if n_sections < 2 or n_stations < 4:
        raise GeometryError(
            f"mesh_to_sections: need at least 2 sections of 4 stations, got {n_sections} x {n_stations}")
    if not np.all(np.isfinite(mesh.vertices)):
        raise GeometryError("mesh_to_sections: mesh vertices contain NaN or infinite values")
    if not mesh.is_watertight:
        raise GeometryError(
            f"mesh_to_sections: blade mesh is not closed ({count_open_edges(mesh)} open edges)")
    if (hub is None) != (shroud is None):
        raise GeometryError("mesh_to_sections: give both the hub and the shroud profile, or neither")
    if hub is None:
        return None
    if overlap is None:
        overlap = mesh_slice_overlap(hub, shroud)
    overlap = float(overlap)
    if not (np.isfinite(overlap) and overlap >= 0):
        raise GeometryError(f"mesh_to_sections: overlap must be a finite length >= 0 mm, got {overlap!r}")
    return overlap


def _mean_angle(mesh):
    """Circular mean of the vertex angles about X [rad]."""
    v = np.asarray(mesh.vertices)
    theta = np.arctan2(v[:, 2], v[:, 1])
    return float(np.arctan2(np.sin(theta).sum(), np.cos(theta).sum()))


def _check_one_blade(slicer):
    """GeometryError when the mesh spans more than +-90 deg about its mean angle (a whole blisk)."""
    t_rel = np.arctan2(slicer.tri[..., 2], slicer.tri[..., 1])
    if np.max(np.abs(t_rel)) > 0.5 * np.pi:
        raise GeometryError(
            "mesh_to_sections: the mesh spans more than +-90 deg about its mean angle; "
            "expected one blade, not a whole blisk")


def _footprint(mesh, slicer, n_footprint, span_margin, merge_tol):
    """The blade's meridional footprint from ``n_footprint`` planes; see the Notes of :func:`mesh_to_sections`.

    Returns
    -------
    _Footprint
    """
    v = np.asarray(mesh.vertices)
    xmin, xmax = float(v[:, 0].min()), float(v[:, 0].max())
    if not xmax > xmin:
        raise GeometryError("mesh_to_sections: the mesh has no axial extent")
    xf = xmin + (xmax - xmin) * (np.arange(n_footprint) + 0.5) / n_footprint
    r_lo, r_hi, dip = slicer.radial_range(xf)
    in_lo, in_hi = slicer.single_interval_range(xf, merge_tol)
    cap_lo, cap_hi = slicer.end_caps(xf, CAP_NORMAL)
    good = np.isfinite(r_lo) & np.isfinite(r_hi)
    if np.count_nonzero(good) < 4:
        raise GeometryError("mesh_to_sections: no usable cross-sections of the mesh")
    xf, r_lo, r_hi, dip, in_lo, in_hi, cap_lo, cap_hi = (
        a[good] for a in (xf, r_lo, r_hi, dip, in_lo, in_hi, cap_lo, cap_hi))
    rmin, rmax = float(r_lo.min()), float(r_hi.max())
    xn = (xf - xmin) / (xmax - xmin)
    rln = (r_lo - rmin) / (rmax - rmin)
    rhn = (r_hi - rmin) / (rmax - rmin)
    i_a = int(np.argmin(xn + rln))  # leading edge, hub
    i_b = int(np.argmax(xn - rln))  # trailing edge, hub
    i_d = int(np.argmin(xn - rhn))  # leading edge, tip
    i_c = int(np.argmax(xn + rhn))  # trailing edge, tip
    if i_b <= i_a or i_c <= i_d:
        raise GeometryError("mesh_to_sections: cannot identify the blade's hub and tip bounds in its footprint")
    span = float(np.median(r_hi - r_lo))
    inset = 1.5 * float(dip.max()) + span_margin * span
    # end zones -- the radial range of faces looking along -r / +r (the caps) and where
    # circles meet the cross-section other than twice (a cap dipping into the blade) --
    # are left out if shallow; a deeper one is no cap (the circles report it if sliced)
    zone_lo = np.fmax(cap_lo, in_lo)        # NaN in_lo (no single interval at mid-span): the cap alone
    zone_hi = np.fmin(cap_hi, in_hi)
    deep = MAX_CAP_DEPTH * span
    lo_own = np.maximum(r_lo + inset, np.where(zone_lo - r_lo <= deep, zone_lo + span_margin * span, -np.inf))
    hi_own = np.minimum(r_hi - inset, np.where(r_hi - zone_hi <= deep, zone_hi - span_margin * span, np.inf))
    return _Footprint(xmin=xmin, xmax=xmax, rmin=rmin, rmax=rmax, span=span,
                      hub_x=xf[i_a:i_b + 1], hub_r=lo_own[i_a:i_b + 1], own_hub_r=r_lo[i_a:i_b + 1],
                      tip_x=xf[i_d:i_c + 1], tip_r=hi_own[i_d:i_c + 1], own_tip_r=r_hi[i_d:i_c + 1])


def _edge_parameters(slicer, lines, n_scan):
    """Chord parameters of the leading and trailing edge of every section line.

    Brackets the edges on ``n_scan`` samples (widening the scanned range
    until both ends miss the blade), then bisects on "does the circle meet
    the mesh".

    Returns
    -------
    u_le, u_te : (S,) float
    """
    n_sections = lines.n_sections
    reach = 0.25
    for _ in range(5):
        us = np.linspace(-reach, 1 + reach, n_scan)
        sx, sr = lines.points(us)
        hit = slicer.hits(sx.ravel(), sr.ravel()).reshape(sx.shape)
        if not np.all(hit.any(axis=1)):
            s = int(np.argmin(hit.any(axis=1)))
            raise GeometryError(f"mesh_to_sections: section {s} does not meet the blade")
        if not np.any(hit[:, 0] | hit[:, -1]):
            break
        reach *= 2
    else:
        raise GeometryError("mesh_to_sections: cannot bracket the blade's leading and trailing edges")
    k_first = np.argmax(hit, axis=1)
    k_last = n_scan - 1 - np.argmax(hit[:, ::-1], axis=1)
    # brackets (miss, hit) for the leading edge and (hit, miss) for the trailing edge
    lo = np.concatenate([us[k_first - 1], us[k_last + 1]])
    hi = np.concatenate([us[k_first], us[k_last]])
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        mx, mr = lines.points(np.stack([mid[:n_sections], mid[n_sections:]], axis=1))
        h = slicer.hits(mx.T.ravel(), mr.T.ravel())
        lo = np.where(h, lo, mid)
        hi = np.where(h, mid, hi)
        if np.max(np.abs(hi - lo)) < 1e-13:
            break
    u_le, u_te = hi[:n_sections], hi[n_sections:]
    if np.any(u_te <= u_le):
        raise GeometryError("mesh_to_sections: a section has no chord inside the blade")
    return u_le, u_te


def _station_circles(lines, u_le, u_te, n_stations, edge_margin):
    """(x, r) of the stations, (S, C) each: cosine-clustered between the edges, ``edge_margin`` inside them."""
    k = np.arange(n_stations)
    w = edge_margin + (1 - 2 * edge_margin) * 0.5 * (1 - np.cos(np.pi * k / (n_stations - 1)))
    u = u_le[:, None] + (u_te - u_le)[:, None] * w[None, :]
    return lines.points(u)


def _crossing_angles(slicer, mesh, x, r, merge_tol):
    """Angles (rotated frame) where every station's circle enters and leaves the blade, (S, C) each [rad].

    Raises
    ------
    GeometryError
        A circle that meets the mesh other than twice, or leaves it where it
        should enter it (faces crossing).
    """
    count, t_min, t_max, n_min, n_max = slicer.circle_angles(x.ravel(), r.ravel(), merge_tol)
    count = count.reshape(x.shape)
    bad = count != 2
    if np.any(bad):
        s, c = (int(i) for i in np.argwhere(bad)[np.argmax(count[bad])])
        n = int(count[s, c])
        if n > 2:
            raise GeometryError(
                f"mesh_to_sections: the circle x={x[s, c]:.4f} mm, r={r[s, c]:.4f} mm (section {s}, "
                f"station {c}) meets the mesh {n} times, i.e. in separate intervals: not a single blade")
        raise GeometryError(
            f"mesh_to_sections: the circle x={x[s, c]:.4f} mm, r={r[s, c]:.4f} mm (section {s}, "
            f"station {c}) meets the mesh {n} time(s) instead of twice")
    # an outward-wound solid is entered at the first crossing and left at the last
    sign = 1.0 if mesh.volume >= 0 else -1.0
    crossed = ((sign * n_min > CROSSED_FACES) | (sign * n_max < -CROSSED_FACES)).reshape(x.shape)
    if np.any(crossed):
        s, c = (int(i) for i in np.argwhere(crossed)[0])
        raise GeometryError(
            f"mesh_to_sections: the circle x={x[s, c]:.4f} mm, r={r[s, c]:.4f} mm (section {s}, "
            f"station {c}) leaves the mesh where it should enter it: its faces cross (a self-intersecting "
            "mesh), not a single blade")
    return t_min.reshape(x.shape), t_max.reshape(x.shape)


def _station_count(flags):
    """'all', 'none' or 'k of n' stations where ``flags`` holds."""
    k, n = int(np.count_nonzero(flags)), len(flags)
    return "all" if k == n else "none" if k == 0 else f"{k} of {n} stations"


def _slicing_report(result, hub, shroud):
    """The report of :func:`mesh_to_sections_with_report` from a :class:`_Slicing`."""
    fp, x, r, overlap = result.footprint, result.x, result.r, result.overlap

    def extent(a):
        return [float(np.min(a)), float(np.max(a))]

    report = {
        "axial_extent_mm": [fp.xmin, fp.xmax],
        "radial_extent_mm": [fp.rmin, fp.rmax],
        "sliced_axial_extent_mm": extent(x),
        "sliced_hub_side_radius_mm": extent(r[0]),
        "sliced_tip_side_radius_mm": extent(r[-1]),
    }
    if hub is not None:
        # the mesh's own ends (no inset) at the hub-side and tip-side stations
        own_hub = np.interp(x[0], fp.hub_x, fp.own_hub_r)
        own_tip = np.interp(x[-1], fp.tip_x, fp.own_tip_r)
        hub_r0, shroud_r1 = hub.radius_at(x[0]), shroud.radius_at(x[-1])
        report.update({
            "wall_overlap_mm": overlap,
            "beyond_hub_mm": extent(hub_r0 - own_hub),
            "beyond_shroud_mm": extent(own_tip - shroud_r1),
            "clipped_to_hub": _station_count(r[0] <= hub_r0 - overlap + 1e-9 * fp.span),
            "clipped_to_shroud": _station_count(r[-1] >= shroud_r1 + overlap - 1e-9 * fp.span),
        })
    return report
