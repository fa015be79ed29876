"""Reading a blisk solid through its rays and circles: the part of the STEP import (and of the whole-blisk
scan) that needs only "where is material" along lines (no rclpy, no OpenCascade).

A *rays* object answers two questions about a solid in frame W (X the blisk axis):

- ``rays.intervals(x, theta)``: [(r_in, r_out), ...], the stretches of material along the meridional half-line
  from the axis at (x, theta), or None where its crossings do not pair up;
- ``rays.circle(x, r, start, length)``: [(theta_in, theta_out), ...], the stretches of material on the arc of the
  circle (x, r) about X from ``start`` over ``length`` (unwrapped, a stretch through the arc's start of a whole
  turn joined by :func:`merge_wrap`), or None where its crossings do not pair up.

:class:`~.step_import` answers them on an OpenCascade solid, :mod:`~.blisk_scan` on a triangle mesh. From them
:func:`angular_extent` tells a whole blisk from a sector, :func:`walls` takes the hub and shroud profiles,
:func:`mid_span_blades` finds the blades on the mid-span cylinder, :func:`whole_count` checks their spacing,
:func:`blade_sections` cuts one blade's sections on cylinders clear of the walls and fillets, and
:func:`fit_deviation` compares them with a reconstructed blade. All written by hand (no library reads a blade
from a solid); the steps are in :mod:`~.step_import`'s notes.

Units: millimetres and radians. Frame W: X is the blisk axis, ``theta = atan2(z, y)``.
"""

import numpy as np

from ..errors import GeometryError
from .profiles import RevolutionProfile
from .sections import BladeSections

#: the blades' angular positions at mid span may differ from equal spacing by this fraction of the pitch
SPACING_TOL = 0.01
#: the blade sections keep this fraction of the smallest channel height clear of the walls (and of fillets)
WALL_CLEARANCE = 0.01


def stretches(crossings, lo, hi, merge_tol):
    """[(in, out), ...] of material on a line's stretch ``lo .. hi`` from its crossings of the solid's boundary,
    or None where they do not alternate in, out (a broken or self-intersecting boundary).

    ``crossings``: [(parameter, entering)], ``entering`` from the boundary's orientation (its outward normal
    against the line's direction), so no point needs classifying; a crossing found twice (on an edge shared by
    two faces, or at the end of one of the pieces a line was cut into) within ``merge_tol`` counts once. A line
    that starts or ends inside material gets ``lo``/``hi`` as its first entry or last exit.
    """
    merged = []
    for v, entering in sorted(crossings):
        if not merged or v - merged[-1][0] > merge_tol:
            merged.append((float(v), bool(entering)))
    if not merged:
        return []
    if not merged[0][1]:
        merged.insert(0, (float(lo), True))
    if merged[-1][1]:
        merged.append((float(hi), False))
    if any(merged[i][1] == merged[i + 1][1] for i in range(len(merged) - 1)):
        return None
    return [(merged[i][0], merged[i + 1][0]) for i in range(0, len(merged), 2)]


def merge_wrap(stretches, start, length):
    """Stretches of a whole turn with the one running through its start joined: (a, start + 2 pi) and
    (start, b) become (a, b + 2 pi)."""
    if (len(stretches) > 1 and length >= 2 * np.pi - 1e-12 and stretches[0][0] <= start + 1e-12
            and stretches[-1][1] >= start + length - 1e-12):
        return stretches[1:-1] + [(stretches[-1][0], stretches[0][1] + 2 * np.pi)]
    return stretches


def wrap_angle(theta):
    return (theta + np.pi) % (2 * np.pi) - np.pi


def angular_extent(rays, x_lo, x_hi, n=360):
    """'whole' or 'sector', the sector angle [rad], and angles at which to sample meridional rays.

    Written by hand: rays at ``n`` angles at the axial middle; the sector's two ends refined by bisection.
    """
    x = 0.5 * (x_lo + x_hi)
    th = np.linspace(-np.pi, np.pi, n, endpoint=False)
    hit = np.array([bool(rays.intervals(x, t)) for t in th])
    if hit.all():
        return "whole", 2 * np.pi, th
    if not hit.any():
        raise GeometryError("STEP import: no material on rays from the axis at the part's axial middle")
    # the sector: one run of hits around the circle
    starts = np.nonzero(hit & ~np.roll(hit, 1))[0]
    if len(starts) != 1:
        raise GeometryError(f"STEP import: the part covers {len(starts)} separate angular ranges around its axis; "
                            f"expected a whole blisk or one sector")
    i0 = int(starts[0])
    i1 = int(np.nonzero(hit & ~np.roll(hit, -1))[0][0])

    def edge(inside, outside):
        for _ in range(40):
            mid = 0.5 * (inside + outside)
            if rays.intervals(x, mid):
                inside = mid
            else:
                outside = mid
        return inside

    step = 2 * np.pi / n
    a = edge(th[i0], th[i0] - step)
    b_in = th[i1] if th[i1] >= th[i0] else th[i1] + 2 * np.pi
    b = edge(b_in, b_in + step)
    sector = b - a
    return "sector", float(sector), np.linspace(a, b, 40)[1:-1]


def walls(rays, x_lo, x_hi, angles, n_x=49):
    """Hub and shroud profiles from meridional rays (hand-written, see the module's notes)."""
    take = angles if len(angles) <= 24 else angles[np.linspace(0, len(angles) - 1, 24).astype(int)]
    span = x_hi - x_lo
    xs = np.linspace(x_lo + 1e-4 * span, x_hi - 1e-4 * span, n_x)
    hub_pts, shroud_pts = [], []
    for x in xs:
        tops, bottoms = [], []
        for t in take:
            iv = rays.intervals(x, t)
            if iv and len(iv) >= 2:
                tops.append(iv[0][1])
                bottoms.append(iv[-1][0])
        if tops:
            hub_pts.append((x, min(tops)))
            shroud_pts.append((x, max(bottoms)))
    if len(hub_pts) < 2:
        raise GeometryError("STEP import: no meridional section with a hub and a shroud (the rays from the axis "
                            "do not cross two separate walls): not a shrouded blisk")
    hub = RevolutionProfile(np.array(hub_pts), "hub_profile (from STEP)")
    shroud = RevolutionProfile(np.array(shroud_pts), "shroud_profile (from STEP)")
    return hub, shroud, {
        "hub_x_range": [float(hub_pts[0][0]), float(hub_pts[-1][0])],
        "hub_r_range": [float(min(p[1] for p in hub_pts)), float(max(p[1] for p in hub_pts))],
        "shroud_r_range": [float(min(p[1] for p in shroud_pts)), float(max(p[1] for p in shroud_pts))],
        "profile_points": len(hub_pts)}


def whole_count(loops, path, r_mid):
    """The blade count of a whole blisk from its mid-span loops, which must be equally spaced."""
    n = len(loops)
    if n < 2:
        raise GeometryError(f"{path}: a whole turn with {n} blade at mid span: no blade pitch")
    th = np.sort(np.array([lp["theta"] for lp in loops]) % (2 * np.pi))
    gaps = np.diff(np.r_[th, th[0] + 2 * np.pi])
    pitch = 2 * np.pi / n
    worst = float(np.max(np.abs(gaps - pitch)))
    widths = np.array([lp["theta_span"] for lp in loops])
    if worst > SPACING_TOL * pitch or np.ptp(widths) > SPACING_TOL * pitch:
        raise GeometryError(
            f"{path}: no rotational symmetry: the {n} blades met at mid span (r = {r_mid:.3f} mm) are not copies "
            f"equally spaced by 360/{n} deg (spacing off by up to {np.degrees(worst):.4g} deg, angular widths "
            f"differ by {np.degrees(np.ptp(widths)):.4g} deg; tolerance {SPACING_TOL:.0%} of the pitch)")
    return n

def mid_span_blades(rays, r_mid, x_lo, x_hi, n_x=41):
    """The blades met by the mid-span cylinder: [{theta, x_min, x_max, theta_span}], one per blade.

    Written by hand: the cylinder's section sampled by circles at ``n_x`` axial stations; the blades are the
    stretches of material on the circle at the station where the most are met (the middle such station), and
    each blade's axial extent is where circles meet it near its angle.
    """
    xs = np.linspace(x_lo, x_hi, n_x + 2)[1:-1]
    found = [rays.circle(x, r_mid, -np.pi) or [] for x in xs]
    counts = np.array([len(f) for f in found])
    if counts.max() == 0:
        return []
    best = np.nonzero(counts == counts.max())[0]
    i = int(best[len(best) // 2])
    half_pitch = np.pi / counts.max()
    blades = []
    for a, b in found[i]:
        centre = 0.5 * (a + b)
        ends = []
        for step in (-1, 1):                   # follow the blade station by station (it sweeps round the axis)
            ref, j, last = centre, i, i
            while 0 <= j + step < len(xs):
                near = [0.5 * (c + d) for c, d in found[j + step] if abs(wrap_angle(0.5 * (c + d) - ref)) < half_pitch]
                if not near:
                    break
                j += step
                ref = ref + wrap_angle(min(near, key=lambda m: abs(wrap_angle(m - ref))) - ref)
                last = j
            ends.append(last)
        blades.append({"theta": float(wrap_angle(centre)), "theta_span": float(b - a), "x": float(xs[i]),
                       "x_min": float(xs[ends[0]]), "x_max": float(xs[ends[1]])})
    return blades


def blade_sections(rays, hub, shroud, blade0, pitch, zones, n_sec, n_st, n_check, x_lo, x_hi, path, name="blade 0"):
    """BladeSections of one blade (``blade0``: its mid-span loop from :func:`mid_span_blades`, called ``name`` in
    errors) on cylinders clear of the walls and the fillets, and the check sections.

    Written by hand: on each cylinder the leading and trailing edge are found by bisection on "the circle at
    (x, r) meets blade 0", the stations cosine-clustered between them, and each station's two angles are where
    its circle enters and leaves blade 0.
    """
    if isinstance(n_sec, bool) or not isinstance(n_sec, int) or n_sec < 4 or n_sec > 1000:
        raise GeometryError(f"section_count: must be an integer in 4 .. 1000, got {n_sec!r}")
    if isinstance(n_st, bool) or not isinstance(n_st, int) or n_st < 8 or n_st > 1000:
        raise GeometryError(f"station_count: must be an integer in 8 .. 1000, got {n_st!r}")
    lo_x = max(hub.x_range[0], shroud.x_range[0])
    hi_x = min(hub.x_range[1], shroud.x_range[1])
    xs = np.linspace(lo_x, hi_x, 400)
    height_min = float(np.min(shroud.radius_at(xs) - hub.radius_at(xs)))
    clear = WALL_CLEARANCE * height_min
    chord = blade0["x_max"] - blade0["x_min"]
    theta0 = blade0["theta"]

    def wall_limits(a, b):
        sel = (xs >= a) & (xs <= b)
        if not sel.any():
            sel = np.ones_like(xs, dtype=bool)
        return (float(hub.radius_at(xs[sel]).max()) + zones["root_fillet_depth"] + clear,
                float(shroud.radius_at(xs[sel]).min()) - zones["tip_fillet_depth"] - clear)

    reach = min(np.pi, 0.75 * pitch)
    x_ref = blade0["x"]

    def blade_at(x, r, ref):
        """(theta_minus, theta_plus) of blade 0 on the circle (x, r), or None where it is not met: the stretch
        of material nearest ``ref`` (blade 0's angle at a neighbouring station) on the arc of +-3/4 pitch
        about it (a stretch cut by the arc's ends is a neighbour's or a wall's)."""
        lo = ref - reach
        found = rays.circle(x, r, lo, 2 * reach)
        if not found:
            return None
        found = [ab for ab in found if ab[0] > lo + 1e-12 and ab[1] < lo + 2 * reach - 1e-12]
        if not found:
            return None
        return min(found, key=lambda ab: abs(0.5 * (ab[0] + ab[1]) - ref))

    def scan(r):
        """Blade 0's angle at the stations of an axial grid where the circle meets it: followed station by
        station from ``x_ref`` both ways (a blade sweeps round the axis along its chord by about a pitch)."""
        grid = np.linspace(x_lo, x_hi, 81)
        j0 = int(np.argmin(np.abs(grid - x_ref)))
        ab = blade_at(grid[j0], r, theta0)
        if ab is None:
            raise GeometryError(f"{path}: {name} does not meet the cylinder r = {r:.4f} mm at x = {grid[j0]:.3f} mm")
        centres = {j0: 0.5 * (ab[0] + ab[1])}
        for step in (1, -1):
            j, ref = j0 + step, centres[j0]
            while 0 <= j < len(grid):
                ab = blade_at(grid[j], r, ref)
                if ab is None:
                    break
                ref = centres[j] = 0.5 * (ab[0] + ab[1])
                j += step
        return grid, centres

    def edges(r):
        """Leading and trailing edge x of blade 0 on the cylinder r (bisection), and its angle along x."""
        grid, centres = scan(r)
        i0, i1 = min(centres), max(centres)

        def bisect(inside, outside, ref):
            for _ in range(30):
                mid = 0.5 * (inside + outside)
                if blade_at(mid, r, ref) is not None:
                    inside = mid
                else:
                    outside = mid
            return inside

        le = bisect(grid[i0], grid[i0 - 1], centres[i0]) if i0 > 0 else grid[0]
        te = bisect(grid[i1], grid[i1 + 1], centres[i1]) if i1 < len(grid) - 1 else grid[-1]
        keys = sorted(centres)
        return le, te, grid[keys], np.array([centres[k] for k in keys])

    def section(r, edge_margin=1e-4):
        le, te, along_x, along_theta = edges(r)
        u = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n_st))
        x = le + (te - le) * (edge_margin + (1 - 2 * edge_margin) * u)
        tm, tp = np.empty(n_st), np.empty(n_st)
        mid = 0.5 * (le + te)
        for c, xc in enumerate(x):
            ab = blade_at(xc, r, np.interp(xc, along_x, along_theta))
            for k in range(1, 30):              # a knife edge's two crossings can merge: step in a little
                if ab is not None:
                    break
                x[c] = xc = xc + (mid - xc) * 2e-4 * k
                ab = blade_at(xc, r, np.interp(xc, along_x, along_theta))
            if ab is None:
                raise GeometryError(f"{path}: the circle at x = {xc:.4f} mm, r = {r:.4f} mm misses {name} "
                                    f"between its edges")
            tm[c], tp[c] = ab
        return x, tm, tp

    r_lo, r_hi = wall_limits(blade0["x_min"] - 0.2 * chord, blade0["x_max"] + 0.2 * chord)
    if r_hi <= r_lo:
        raise GeometryError(f"{path}: no span clear of the walls and fillets to cut blade sections in "
                            f"(r {r_lo:.3f} .. {r_hi:.3f} mm)")
    # the limits again from the blade's edges at the two outermost cylinders, a little beyond them
    e_lo, e_hi = edges(r_lo)[:2], edges(r_hi)[:2]
    span = max(e_lo[1], e_hi[1]) - min(e_lo[0], e_hi[0])
    r_lo, r_hi = wall_limits(min(e_lo[0], e_hi[0]) - 0.02 * span, max(e_lo[1], e_hi[1]) + 0.02 * span)
    radii = np.linspace(r_lo, r_hi, n_sec)
    X, TM, TP = [], [], []
    for radius in radii:
        x, tm, tp = section(radius)
        X.append(x)
        TM.append(tm)
        TP.append(tp)
    sections = BladeSections(np.array(X), np.repeat(radii[:, None], n_st, axis=1), np.array(TM), np.array(TP))
    check = {"x": [], "r": [], "theta_minus": [], "theta_plus": []}
    picks = np.unique(np.linspace(0, n_sec - 2, n_check).round().astype(int)) if n_check else []
    for j in picks:
        radius = 0.5 * (radii[j] + radii[j + 1])
        x, tm, tp = section(radius)
        for key, val in (("x", x), ("r", np.full(n_st, radius)), ("theta_minus", tm), ("theta_plus", tp)):
            check[key].append(val)
    return sections, check, radii


def fit_deviation(blisk, step_blisk):
    """Largest distance [mm] along the circle between the STEP's blade and the reconstructed blade faces, at
    the check sections (half way between the section radii), and the number of points compared.

    Returns
    -------
    (float, int) or (None, 0) without check sections
    """
    c = step_blisk.check
    if not c or not c.get("x"):
        return None, 0
    x = np.concatenate(c["x"])
    r = np.concatenate(c["r"])
    th_s, ok_s = blisk.suction_face.theta_at(x, r)
    th_p, ok_p = blisk.pressure_face.theta_at(x, r)
    ok = ok_s & ok_p
    if not ok.any():
        return None, 0
    dev = np.maximum(np.abs(th_s - np.concatenate(c["theta_plus"])),
                     np.abs(th_p - np.concatenate(c["theta_minus"]))) * r
    return float(dev[ok].max()), int(ok.sum())
