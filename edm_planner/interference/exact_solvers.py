"""The exact solvers behind the fast field (numba): the channel's walls without the tables.

* hub and shroud: the exact signed distance to a profile (x, r) of cubic
  pieces (1-D Newton on each piece), and the (x, r) table filled from it;
* blade faces: the closest point on a bicubic B-spline face by a Newton
  projection with backtracking (``_solve_node``), started from the nearest
  sample of the face, with the sign rule of the exact method (negative behind
  a wall within its face's meridional footprint, ``_behind``/``_wall_angle``);
* per point: the exact signed distance to any of the four surfaces of
  channel k (``_exact_at``) and the side-of-wall test (``_behind_at``).

They fill the grid (:mod:`.field_build`), answer the cells the tables do not
trust (:mod:`.field_query`) and make the exact minimum exact
(:mod:`.min_search`). Units: mm, rad.
"""

import math

import numba
import numpy as np

from ..geometry.spline_kernels import new_work, project, project_edge, uv_at
from .field_params import _FAR_START, _NEWTON_TOL, _TWO_PI, named_exact


@numba.njit(cache=True)
def _pchip(xb, c, t):
    """r, r', r'' of a piecewise cubic at t; constant continuation outside [xb[0], xb[-1]]."""
    n = xb.shape[0]
    if t <= xb[0]:
        return c[3, 0], 0.0, 0.0
    if t >= xb[n - 1]:
        h = xb[n - 1] - xb[n - 2]
        return ((c[0, n - 2] * h + c[1, n - 2]) * h + c[2, n - 2]) * h + c[3, n - 2], 0.0, 0.0
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if t < xb[mid]:
            hi = mid
        else:
            lo = mid
    s = t - xb[lo]
    c0, c1, c2, c3 = c[0, lo], c[1, lo], c[2, lo], c[3, lo]
    return ((c0 * s + c1) * s + c2) * s + c3, (3.0 * c0 * s + 2.0 * c1) * s + c2, 6.0 * c0 * s + 2.0 * c1


@numba.njit(cache=True)
def _profile_signed(xb, c, bounds, sign, x, rho):
    """Signed distance of (x, rho) to the profile r(x), as ``ProfileDistance.signed`` (numba).

    The foot t lies within ``dv = |rho - r(x)|`` of x. Where
    ``(1 + max|r'|) dv max|r''| < 0.9`` (``bounds`` = (max|r'|, max|r''|))
    and the interval holds neither end of the profile (where the slope drops
    to the cylinder's 0), the squared distance is convex in t on that
    interval and Newton from x finds the global minimum; otherwise the start
    is the best of 65 samples of [x - dv, x + dv]. Newton on ``(t - x)^2 + (r(t) - rho)^2`` then runs to
    a step below 1e-13 mm; the profile's ends, where the slope jumps, are
    candidates of their own (Newton cannot settle on a kink). Positive on the channel side (``sign`` +1: hub,
    material below; -1: shroud).
    """
    rx, _, _ = _pchip(xb, c, x)
    dv = abs(rho - rx)
    t = x
    ends = (x - dv <= xb[0] <= x + dv) or (x - dv <= xb[xb.shape[0] - 1] <= x + dv)
    if ends or (1.0 + bounds[0]) * dv * bounds[1] >= 0.9:
        best_f = dv * dv
        for k in range(65):
            tt = x - dv + 2.0 * dv * (k / 64.0)
            r, _, _ = _pchip(xb, c, tt)
            f = (tt - x) ** 2 + (r - rho) ** 2
            if f < best_f:
                best_f, t = f, tt
    for _ in range(40):
        r, r1, r2 = _pchip(xb, c, t)
        g1 = (t - x) + (r - rho) * r1
        g2 = 1.0 + r1 * r1 + (r - rho) * r2
        if g2 <= 1e-3:
            g2 = 1.0 + r1 * r1
        step = g1 / g2
        t -= step
        if abs(step) < 1e-13:
            break
    r, _, _ = _pchip(xb, c, t)
    dist = math.hypot(t - x, r - rho)
    for end in (xb[0], xb[xb.shape[0] - 1]):
        if abs(end - x) < dist:
            r, _, _ = _pchip(xb, c, end)
            dist = min(dist, math.hypot(end - x, r - rho))
    return dist if sign * (rho - rx) >= 0.0 else -dist


@numba.njit(cache=True)
def _fill_profile_table(xb, c, bounds, sign, x0, hx, nx, r0, hr, nr):
    """(nx, nr) float32 table of ``_profile_signed`` on a regular (x, r) grid."""
    out = np.empty((nx, nr), dtype=np.float32)
    for i in range(nx):
        for j in range(nr):
            out[i, j] = _profile_signed(xb, c, bounds, sign, x0 + i * hx, r0 + j * hr)
    return out


@numba.njit(cache=True)
def _behind(face, th_w, th_face, in_face, pitch):
    """The sign rule of ``ExactChannelDistance``: is the point behind the wall?

    ``th_w`` is the point's angle in blade 0's position of the wall (the
    channel-0 angle for the suction wall, minus one pitch for the pressure
    wall), ``th_face`` and ``in_face`` the face's angle and footprint test at
    the point's (x, r). Behind the suction wall: up to one pitch below it;
    behind the pressure wall: up to one pitch above it.
    """
    if not in_face:
        return False
    rel = th_w - th_face
    rel -= _TWO_PI * math.floor((rel + math.pi) / _TWO_PI)
    if face == 0:
        return -pitch < rel < 0.0
    return 0.0 < rel < pitch


@numba.njit(cache=True)
def _on_edge(u, v):
    """Which edge of the parameter square (u, v) lies on: 0 none, 1..4 u=0, u=1, v=0, v=1."""
    if u <= 0.0:
        return 1
    if u >= 1.0:
        return 2
    if v <= 0.0:
        return 3
    if v >= 1.0:
        return 4
    return 0


@numba.njit(cache=True)
def _solve_node(cp, tu, tv, px, py, pz, su, sv, coarse_uv, face, cx, cr, ct, kx, kr, kt, amb, scale_u, scale_v,
                jump, work):
    """Closest point of a fine node: continuation start, checked against the coarse nodes' closest points.

    Starts from (su, sv) (the extrapolated continuation; NaN: the nearest
    coarse node's closest point). A coarse node's closest point is tried as
    well where it lies more than ``jump`` mm (in the metric ``scale_u``,
    ``scale_v`` mm per unit parameter) from the result, or on another edge of
    the face (or on an edge while the result is inside, or vice versa): the
    continuation may have stayed on a local minimum after the global one
    moved elsewhere. In an ambiguous coarse cell all 8 corners are checked
    (a corner alike an earlier one is skipped), elsewhere the nearest coarse
    node.

    Returns
    -------
    u, v, f : float
    extra : int
        Number of additional starts tried.
    """
    if su != su:
        su, sv = coarse_uv[kx, kr, kt, face, 0], coarse_uv[kx, kr, kt, face, 1]
    u, v, f = project(cp, tu, tv, px, py, pz, su, sv, work, _NEWTON_TOL, 80)
    extra = 0
    edge = _on_edge(u, v)
    for a in range(8 if amb else 1):
        if amb:
            ia, ja, ka = cx + (a & 1), cr + ((a >> 1) & 1), ct + ((a >> 2) & 1)
        else:
            ia, ja, ka = kx, kr, kt
        au, av = coarse_uv[ia, ja, ka, face, 0], coarse_uv[ia, ja, ka, face, 1]
        a_edge = _on_edge(au, av)
        if a_edge == edge and ((au - u) * scale_u) ** 2 + ((av - v) * scale_v) ** 2 < jump * jump:
            continue
        seen = False
        for b in range(a):      # an earlier corner alike: tried already, or alike the result
            ib, jb, kb = cx + (b & 1), cr + ((b >> 1) & 1), ct + ((b >> 2) & 1)
            bu, bv = coarse_uv[ib, jb, kb, face, 0], coarse_uv[ib, jb, kb, face, 1]
            if (((au - bu) * scale_u) ** 2 + ((av - bv) * scale_v) ** 2 < 0.25 * jump * jump
                    and _on_edge(bu, bv) == a_edge):
                seen = True
                break
        if seen:
            continue
        u2, v2, f2 = project(cp, tu, tv, px, py, pz, au, av, work, _NEWTON_TOL, 80)
        extra += 1
        if f2 < f:
            u, v, f = u2, v2, f2
            edge = _on_edge(u, v)
    return u, v, f, extra


@numba.njit(cache=True)
def _nearest_start(face, x, rho, samples, scale, box, start, items):
    """Index of the sample nearest to (x, rho) in scaled (x, r): ``BladeFace.uv_at``'s start.

    The samples are binned in an (nb, nb) grid over their box (``box`` (2, 4):
    lower corner and bin size per face; ``start`` (2, nb*nb+1) and ``items``
    (2, n) list each bin's samples); rings of bins are searched outwards until
    the ring lies farther than the best sample found.
    """
    sx, sr = x / scale[face, 0], rho / scale[face, 1]
    nb = int(math.sqrt(start.shape[1] - 1) + 0.5)
    x0, r0, bx, br = box[face, 0], box[face, 1], box[face, 2], box[face, 3]
    fx, fr = (sx - x0) / bx, (sr - r0) / br
    cx = min(max(int(fx), 0), nb - 1)
    cr = min(max(int(fr), 0), nb - 1)
    best, j_best = np.inf, 0
    for ring in range(nb):
        for i in range(cx - ring, cx + ring + 1):
            if i < 0 or i >= nb:
                continue
            for j in range(cr - ring, cr + ring + 1):
                if j < 0 or j >= nb or (abs(i - cx) != ring and abs(j - cr) != ring):
                    continue
                b = i * nb + j
                for q in range(start[face, b], start[face, b + 1]):
                    k = items[face, q]
                    dd = (samples[face, k, 0] - sx) ** 2 + (samples[face, k, 1] - sr) ** 2
                    if dd < best or (dd == best and k < j_best):
                        best, j_best = dd, k
        # the bins not searched yet lie beyond the square searched so far
        bound = np.inf
        if cx - ring > 0:
            bound = min(bound, max(0.0, fx - (cx - ring)) * bx)
        if cx + ring < nb - 1:
            bound = min(bound, max(0.0, (cx + ring + 1) - fx) * bx)
        if cr - ring > 0:
            bound = min(bound, max(0.0, fr - (cr - ring)) * br)
        if cr + ring < nb - 1:
            bound = min(bound, max(0.0, (cr + ring + 1) - fr) * br)
        if best <= bound * bound:
            break
    return j_best


#: The small entry points below are inlined (``inline="always"``): a call of a compiled function that takes
#: ``tables`` costs about 0.2 to 0.5 us before its first instruction of work (measured on AMD Zen 3: the side
#: test decided by the lines' angles took 0.52 us through two such calls and 0.04 us inlined), which the
#: field's off-common-case points pay once or twice each.


@numba.njit(cache=True, inline="always")
def _exact_blade(face, x, rho, th, params, shape, tables, work):
    """Exact signed distance of (x, rho, th) (channel-0 angle) to a wall: the slow path."""
    d, _, _ = _exact_blade_uv(face, x, rho, th, params, shape, tables, work)
    return d


@numba.njit(cache=True, inline="always")
def _table_angle(face, x, rho, th_w, params, nx, nr, line_theta, line_inside):
    """``_wall_angle`` from the (x, r) lines' angles alone: (decided, in_face, th_face).

    Where the 4 x 4 surrounding (x, r) lines lie in the footprint and the
    point is off the face's angle by more than 4 times the bilinear error
    estimate (from the lines' second differences), the bilinear angle
    decides; else (decided False) Newton does (``_newton_angle``).
    """
    lx = (x - params.x0) / params.hx
    lr = (rho - params.r0) / params.hr
    if 0.0 <= lx <= nx - 1 and 0.0 <= lr <= nr - 1:
        ix, ir = min(int(lx), nx - 2), min(int(lr), nr - 2)
        ax, ar = lx - ix, lr - ir
        inside4 = 0 < ix < nx - 2 and 0 < ir < nr - 2
        if inside4:
            for jx in range(ix - 1, ix + 3):
                for jr in range(ir - 1, ir + 3):
                    inside4 = inside4 and line_inside[jx, jr, face]
        if inside4:
            t00, t10 = line_theta[ix, ir, face], line_theta[ix + 1, ir, face]
            t01, t11 = line_theta[ix, ir + 1, face], line_theta[ix + 1, ir + 1, face]
            est = (1 - ax) * ((1 - ar) * t00 + ar * t01) + ax * ((1 - ar) * t10 + ar * t11)
            bend = 0.0
            for jx in range(ix, ix + 2):
                for jr in range(ir, ir + 2):
                    bend = max(bend, abs(line_theta[jx - 1, jr, face] - 2 * line_theta[jx, jr, face]
                                         + line_theta[jx + 1, jr, face])
                               + abs(line_theta[jx, jr - 1, face] - 2 * line_theta[jx, jr, face]
                                     + line_theta[jx, jr + 1, face]))
            margin = 0.5 * bend + 1e-9
            rel = th_w - est
            rel -= _TWO_PI * math.floor((rel + math.pi) / _TWO_PI)
            if abs(rel) > margin and abs(abs(rel) - params.pitch) > margin:
                return True, True, est
    return False, False, 0.0


@numba.njit(cache=True)
def _newton_angle(face, x, rho, tables, work):
    """``_wall_angle`` by Newton: (in_face, th_face).

    Newton from the start ``BladeFace.uv_at`` takes (the nearest of its 64 x 64
    samples in scaled (x, r)): near the leading and trailing edges the map
    (u, v) -> (x, r) can fold, and then the footprint test depends on the start.
    """
    if face == 0:
        cp, tu, tv = tables.cp_s, tables.tu_s, tables.tv_s
    else:
        cp, tu, tv = tables.cp_p, tables.tu_p, tables.tv_p
    xr_uv = tables.start_uv
    j_best = _nearest_start(face, x, rho, tables.start_samples, tables.start_scale, tables.start_box,
                            tables.start_first, tables.start_items)
    _, _, in_face, th_face = uv_at(cp, tu, tv, x, rho, xr_uv[face, j_best, 0], xr_uv[face, j_best, 1], work)
    return in_face, th_face


@numba.njit(cache=True, inline="always")
def _wall_angle(face, x, rho, th, params, shape, tables, work):
    """The face's footprint test and angle at (x, rho), for the sign rule (``_behind``) of ``_exact_blade_uv``.

    From the lines' angles where they decide (``_table_angle``), else by
    Newton (``_newton_angle``).

    Returns
    -------
    in_face : bool
        (x, rho) lies in the face's meridional footprint.
    th_face : float
        The face's angle there [rad] (0 outside the footprint).
    """
    th_w = th - params.pitch if face == 1 else th
    decided, in_face, th_face = _table_angle(face, x, rho, th_w, params, shape.nx, shape.nr, tables.line_theta,
                                             tables.line_inside)
    if decided:
        return in_face, th_face
    return _newton_angle(face, x, rho, tables, work)


@numba.njit(cache=True, inline="always")
def _blade_behind(face, x, rho, th, params, shape, tables, work):
    """The sign of ``_exact_blade`` alone (no closest point): is (x, rho, th) (channel-0 angle) behind the wall?"""
    in_face, th_face = _wall_angle(face, x, rho, th, params, shape, tables, work)
    pitch = params.pitch
    return _behind(face, th - pitch if face == 1 else th, th_face, in_face, pitch)


@numba.njit(cache=True)
def _exact_blade_uv(face, x, rho, th, params, shape, tables, work):
    """Exact signed distance of (x, rho, th) (channel-0 angle) to a wall and its foot's (u, v).

    The sign rule as in the fill; the closest point from the nearest coarse
    node's, checked against the other corners' where the coarse cell is
    ambiguous (``_solve_node``) and restarted from inside when it ends on an
    edge of the face.
    """
    if face == 0:
        cp, tu, tv = tables.cp_s, tables.tu_s, tables.tv_s
    else:
        cp, tu, tv = tables.cp_p, tables.tu_p, tables.tv_p
    coarse_uv, kind = tables.coarse_uv, tables.kind
    C = shape.coarse
    pitch = params.pitch
    th_w = th - pitch if face == 1 else th
    in_face, th_face = _wall_angle(face, x, rho, th, params, shape, tables, work)
    gx = min(max((x - params.x0) / (C * params.hx), 0.0), shape.ncx - 1.0)
    gr = min(max((rho - params.r0) / (C * params.hr), 0.0), shape.ncr - 1.0)
    gt = min(max((th - params.t0) / (C * params.ht), 0.0), shape.nct - 1.0)
    cx, cr, ct = min(int(gx), shape.ncx - 2), min(int(gr), shape.ncr - 2), min(int(gt), shape.nct - 2)
    kx, kr, kt = int(round(gx)), int(round(gr)), int(round(gt))
    px, py, pz = x, rho * math.cos(th_w), rho * math.sin(th_w)
    amb = kind[cx, cr, ct, face] == 2
    scale_u, scale_v = (params.scale_su, params.scale_sv) if face == 0 else (params.scale_pu, params.scale_pv)
    u, v, f, _ = _solve_node(cp, tu, tv, px, py, pz, np.nan, np.nan, coarse_uv, face, cx, cr, ct, kx, kr, kt, amb,
                             scale_u, scale_v, params.jump, work)
    if _on_edge(u, v) != 0:
        u2, v2, f2 = project(cp, tu, tv, px, py, pz, min(max(u, 0.03), 0.97), min(max(v, 0.03), 0.97), work,
                              _NEWTON_TOL, 80)
        if f2 < f:
            u, v, f = u2, v2, f2
    if f > _FAR_START * _FAR_START:
        # beyond the band the coarse nodes' closest points can lie on another local minimum: a grid of starts
        for i in range(5):
            for j in range(5):
                u2, v2, f2 = project_edge(cp, tu, tv, px, py, pz, 0.1 + 0.2 * i, 0.1 + 0.2 * j, work,
                                           _NEWTON_TOL, 80)
                if f2 < f:
                    u, v, f = u2, v2, f2
    d = math.sqrt(f)
    return (-d if _behind(face, th_w, th_face, in_face, pitch) else d), u, v


@numba.njit(cache=True, inline="always")
def _exact_surface(s, x, rho, th, params, shape, tables, work):
    """Exact signed distance to surface s (0 suction, 1 pressure, 2 hub, 3 shroud); th in channel 0."""
    if s < 2:
        return _exact_blade(s, x, rho, th, params, shape, tables, work)
    if s == 2:
        return _profile_signed(tables.hub_xb, tables.hub_c, tables.hub_b, 1.0, x, rho)
    return _profile_signed(tables.shroud_xb, tables.shroud_c, tables.shroud_b, -1.0, x, rho)


@numba.njit(cache=True)
def _channel_coordinates(x, y, z, channel_angle, params):
    """(rho, th) of a point in W: th its channel-0 angle about the grid's middle, as every exact query takes it."""
    rho = math.sqrt(y * y + z * z)
    th = math.atan2(z, y) - channel_angle
    th -= _TWO_PI * math.floor((th - params.tc + math.pi) / _TWO_PI)
    return rho, th


@numba.njit(cache=True, inline="always")
def _exact_at(s, x, y, z, channel_angle, params, shape, tables, work):
    """Exact signed distance of a point in W to surface s of the channel at ``channel_angle`` (``_exact_surface``)."""
    rho, th = _channel_coordinates(x, y, z, channel_angle, params)
    return _exact_surface(s, x, rho, th, params, shape, tables, work)


@numba.njit(cache=True, inline="always")
def _behind_at(face, x, y, z, channel_angle, params, shape, tables, work):
    """Whether a point in W lies behind wall ``face`` (0 suction, 1 pressure): the sign of ``_exact_at`` alone."""
    rho, th = _channel_coordinates(x, y, z, channel_angle, params)
    return _blade_behind(face, x, rho, th, params, shape, tables, work)


@numba.njit(cache=True)
def _behind_kernel(points, channel_angle, params, shape, tables):
    """(n, 2) bool: ``_behind_at`` for both walls."""
    params, shape, tables = named_exact(params, shape, tables)
    n = points.shape[0]
    out = np.zeros((n, 2), dtype=np.bool_)
    work = new_work()
    for k in range(n):
        for face in range(2):
            out[k, face] = _behind_at(face, points[k, 0], points[k, 1], points[k, 2], channel_angle, params, shape,
                                      tables, work)
    return out


@numba.njit(cache=True)
def _exact_blade_feet(points, channel_angle, params, shape, tables):
    """Exact signed distances to both walls and the feet's (u, v): (n, 2), (n, 2, 2)."""
    params, shape, tables = named_exact(params, shape, tables)
    n = points.shape[0]
    dist = np.empty((n, 2))
    uv = np.empty((n, 2, 2))
    work = new_work()
    for k in range(n):
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        rho = math.sqrt(y * y + z * z)
        th = math.atan2(z, y) - channel_angle
        th -= _TWO_PI * math.floor((th - params.tc + math.pi) / _TWO_PI)
        for face in range(2):
            d, u, v = _exact_blade_uv(face, x, rho, th, params, shape, tables, work)
            dist[k, face], uv[k, face, 0], uv[k, face, 1] = d, u, v
    return dist, uv
