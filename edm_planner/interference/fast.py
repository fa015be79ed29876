"""Fast interference checking: a precomputed distance field with a measured error bound.

:class:`FastChannelField` answers the question of
:class:`~.exact_points.ExactChannelDistance` -- the signed distances of points
to the suction, pressure, hub and shroud surfaces of channel k -- from tables
built once per geometry:

* **Blade walls**: one 3-D grid over cylindrical coordinates (x, r, theta) of
  channel 0, two float32 values per node: the exact signed distance to the
  suction wall (blade 0's +theta face) and to the pressure wall (blade 0's
  -theta face turned by one pitch), with the sign rule of the exact method
  (negative behind a wall within its face's meridional footprint: up to one
  pitch below the suction wall, up to one pitch above the pressure wall).
  A query is trilinear, with weights shared by both values; channel k is
  channel 0 with the query angle turned by -k * pitch.
* **Hub and shroud**: surfaces of revolution, whose distance depends on
  (x, r) only (Chen & Dong eq. 4-8): an (x, r) table of the exact signed
  profile distance, bilinear; outside the table the exact distance itself
  (1-D Newton on the profile's cubic pieces, in numba).

Filling the grid takes millions of point-to-surface distances, which the
vectorised ``BladeFace.closest_points`` (about 4e4 points/s) cannot give in
seconds. They come from a small numba evaluator of the faces' bicubic
B-splines (the same control nets and knots; values, first and second
derivatives) and a numba Newton projection with backtracking, started from
the extrapolated closest points of the previous nodes along theta and checked
against the global closest points of a coarse grid (every 4th node, started
from the nearest sample of the face) wherever the closest point may jump.
Only nodes within ``band`` (2.7 mm) of a face are solved; the rest are
interpolated from the coarse grid, only to say "far".

Where trilinear interpolation is not accurate enough -- second differences
along the axes adding up to more than ``curvature_tol`` (leading and trailing
edge noses; less beside the faces' edges), or values jumping between
neighbours (where the sign rule changes) -- a node is stored as NaN, and a
query in a cell touching it goes to the exact numba solver (the slow path;
also for points outside the tables). The fast path pays one NaN test for it.

The error within 2 mm of the surfaces is measured at build against the exact
method on random points near each surface (both sides) and around the blade
edges, and exposed as :attr:`FastChannelField.error_bound`: no pose may be
accepted as clear on this method alone unless its clearance exceeds the
required one by more than the bound. Farther than 2 mm from a face the blade
values are not held to the bound (coarser, from the coarse grid) and outside
the grid they are conservative lower bounds (the value at the nearest grid
point minus the distance to it, or the distance to the faces' (x, r)
bounding box, whichever is larger), never larger than the truth.

Units: mm, rad. Frame W: X the blisk axis, theta = atan2(z, y).
"""

import contextlib
import fcntl
import hashlib
import heapq
import json
import logging
import math
import os
import pathlib
import re
import tempfile
import time

import numba
import numpy as np
from numba import types
from numba.typed import Dict
from scipy.spatial import cKDTree

from . import SURFACES
from ..geometry.frames import cylindrical_to_cartesian, rotation_about_x
from ..geometry.spline_kernels import (  # noqa: F401  (spline_surface_eval: public name kept)
    new_work, project, project_edge, spline_surface_eval, surface_eval, uv_at)
from .exact_points import ExactChannelDistance

_log = logging.getLogger(__name__)

#: format of the cached arrays; bump when the layout or the fill changes
CACHE_VERSION = "edm_planner.fast_field/5"
#: accuracy band the error bound is measured in [mm]
ACCURATE_WITHIN = 2.0

_TWO_PI = 2.0 * math.pi
#: Newton steps shorter than this [mm] end the projection with the model decrease
_NEWTON_TOL = 3e-4
#: the exact blade solver tries a grid of starts for points farther than this from the face [mm]
_FAR_START = 2.0


def _atan_coefficients(half_range=0.5, degree=10):
    """Coefficients c_k of atan(t) = t * sum_k c_k t^(2k) on |t| <= half_range.

    Chebyshev interpolation of atan(sqrt(s)) / sqrt(s) on s in [0, half_range^2];
    degree 10 gives 1e-15 rad on |t| <= 0.5.
    """
    from numpy.polynomial import chebyshev, polynomial
    top = half_range ** 2
    s = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1)) * top / 2 + top / 2
    c = chebyshev.chebfit(2 * s / top - 1, np.arctan(np.sqrt(s)) / np.sqrt(s), degree)
    p = polynomial.Polynomial(chebyshev.cheb2poly(c))(polynomial.Polynomial([-1.0, 2.0 / top]))
    return tuple(float(v) for v in p.coef)


#: the fast path's arctangent (|z/y| <= 0.5 about the grid's middle angle; atan2 costs twice as much)
_ATAN = _atan_coefficients()
# indices into the float parameter vector shared by the numba kernels
(_X0, _HX, _R0, _HR, _T0, _HT, _PITCH, _TC, _HX0, _HHX, _HR0, _HHR,
 _FX0, _FX1, _FR0, _FR1, _IHX, _IHR, _IHT, _IHHX, _IHHR, _JUMP, _CA, _SA, _SCALE) = range(25)
_NPAR = _SCALE + 4      # _SCALE .. _SCALE + 3: mm per unit u, v of the suction and the pressure face
# indices into the integer parameter vector
(_NX, _NR, _NT, _COARSE, _NCX, _NCR, _NCT, _NHX, _NHR, _NIPAR) = range(10)


# ===========================================================================
# Hub and shroud: the exact profile distance (numba)
# ===========================================================================

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


# ===========================================================================
# Grid filling (numba)
# ===========================================================================

@numba.njit(cache=True)
def _fill_lines(cp_s, tu_s, tv_s, cp_p, tu_p, tv_p, xs, rs, seeds):
    """Per (x, r): both faces' (u, v), footprint test and angle.

    Parameters
    ----------
    xs, rs : (n,) float
    seeds : (n, 2, 2) float
        Start (u, v) per face (0 suction, 1 pressure).

    Returns
    -------
    uv : (n, 2, 2) float
    theta : (n, 2) float
        theta_plus (suction face) and theta_minus (pressure face) of blade 0 [rad].
    inside : (n, 2) bool
        (x, r) lies in the suction (0) / pressure (1) face's footprint.
    """
    n = xs.shape[0]
    uv = np.empty((n, 2, 2))
    theta = np.empty((n, 2))
    inside = np.empty((n, 2), dtype=np.bool_)
    n_chunk = (n + 1023) // 1024
    for chunk in range(n_chunk):
        work = new_work()
        for k in range(chunk * 1024, min(n, chunk * 1024 + 1024)):
            u, v, in_s, th = uv_at(cp_s, tu_s, tv_s, xs[k], rs[k], seeds[k, 0, 0], seeds[k, 0, 1], work)
            uv[k, 0, 0], uv[k, 0, 1], theta[k, 0] = u, v, th
            u, v, in_p, th = uv_at(cp_p, tu_p, tv_p, xs[k], rs[k], seeds[k, 1, 0], seeds[k, 1, 1], work)
            uv[k, 1, 0], uv[k, 1, 1], theta[k, 1] = u, v, th
            inside[k, 0] = in_s
            inside[k, 1] = in_p
    return uv, theta, inside


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


@numba.njit(cache=True, parallel=True)
def _fill_coarse(cp_s, tu_s, tv_s, cp_p, tu_p, tv_p, fp, ip, line_theta, line_inside, seeds, far):
    """Values and closest points at the coarse nodes (every ``COARSE``-th fine node).

    ``seeds`` (ncx, ncr, nct, 2, 2) are the nearest samples of a sampling of
    each face; nodes marked ``far`` (certainly far from the face, their
    values only tell so) get at most 8 Newton steps, the others converge.

    Returns
    -------
    values : (ncx, ncr, nct, 2) float64
    feet_uv : (ncx, ncr, nct, 2, 2) float64
    feet_xyz : (ncx, ncr, nct, 2, 3) float64
    """
    C = ip[_COARSE]
    ncx, ncr, nct = ip[_NCX], ip[_NCR], ip[_NCT]
    values = np.empty((ncx, ncr, nct, 2))
    feet_uv = np.empty((ncx, ncr, nct, 2, 2))
    feet_xyz = np.empty((ncx, ncr, nct, 2, 3))
    pitch = fp[_PITCH]
    for cx in numba.prange(ncx):
        work = new_work()
        ev = work[2]
        x = fp[_X0] + cx * C * fp[_HX]
        for cr in range(ncr):
            r = fp[_R0] + cr * C * fp[_HR]
            for ct in range(nct):
                for face in range(2):
                    th = fp[_T0] + ct * C * fp[_HT] - face * pitch
                    u0, v0 = seeds[cx, cr, ct, face, 0], seeds[cx, cr, ct, face, 1]
                    behind = _behind(face, th, line_theta[cx * C, cr * C, face], line_inside[cx * C, cr * C, face],
                                     pitch)
                    mi = 8 if far[cx, cr, ct, face] else 80
                    px, py, pz = x, r * math.cos(th), r * math.sin(th)
                    if face == 0:
                        u, v, f = project_edge(cp_s, tu_s, tv_s, px, py, pz, u0, v0, work, _NEWTON_TOL, mi)
                        surface_eval(cp_s, tu_s, tv_s, u, v, work)
                    else:
                        u, v, f = project_edge(cp_p, tu_p, tv_p, px, py, pz, u0, v0, work, _NEWTON_TOL, mi)
                        surface_eval(cp_p, tu_p, tv_p, u, v, work)
                    d = math.sqrt(f)
                    values[cx, cr, ct, face] = -d if behind else d
                    feet_uv[cx, cr, ct, face, 0] = u
                    feet_uv[cx, cr, ct, face, 1] = v
                    for c in range(3):
                        feet_xyz[cx, cr, ct, face, c] = ev[0, c]
    return values, feet_uv, feet_xyz


@numba.njit(cache=True)
def _classify_coarse(values, feet_xyz, feet_uv, fp, ip, band, spread, turn):
    """Per coarse cell and face: 0 far (interpolate), 1 near (solve), 2 near and ambiguous.

    A cell is far when all 8 corners are more than ``band`` mm from the face and
    the values are consistent with a 1-Lipschitz function along the cell's
    edges (no sign jump inside). It is ambiguous when a medial surface of the
    face may cross it: its corners' closest points lie more than ``spread`` mm
    apart, or their directions to the closest points differ by more than
    ``turn`` rad, or some lie on the face's boundary and others inside it
    (the fine nodes then start from every distinct corner's closest point).
    """
    C = ip[_COARSE]
    ncx, ncr, nct = ip[_NCX], ip[_NCR], ip[_NCT]
    kind = np.zeros((ncx - 1, ncr - 1, nct - 1, 2), dtype=np.uint8)
    hx, hr, ht = C * fp[_HX], C * fp[_HR], C * fp[_HT]
    # unit directions from the closest point to the node (zero on the face)
    dirs = np.zeros((ncx, ncr, nct, 2, 3))
    for cx in range(ncx):
        x = fp[_X0] + cx * hx
        for cr in range(ncr):
            r = fp[_R0] + cr * hr
            for ct in range(nct):
                for face in range(2):
                    th = fp[_T0] + ct * ht - face * fp[_PITCH]
                    dx = x - feet_xyz[cx, cr, ct, face, 0]
                    dy = r * math.cos(th) - feet_xyz[cx, cr, ct, face, 1]
                    dz = r * math.sin(th) - feet_xyz[cx, cr, ct, face, 2]
                    n = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if n > 1e-6:
                        dirs[cx, cr, ct, face, 0] = dx / n
                        dirs[cx, cr, ct, face, 1] = dy / n
                        dirs[cx, cr, ct, face, 2] = dz / n
    cos_turn = math.cos(turn)
    for cx in range(ncx - 1):
        for cr in range(ncr - 1):
            rmax = fp[_R0] + (cr + 1) * hr
            chord_t = 2.0 * rmax * math.sin(0.5 * ht)
            for ct in range(nct - 1):
                for face in range(2):
                    far = True
                    for a in range(8):
                        ia, ja, ka = cx + (a & 1), cr + ((a >> 1) & 1), ct + ((a >> 2) & 1)
                        if abs(values[ia, ja, ka, face]) <= band:
                            far = False
                    if far:
                        # edges along x, r, theta: a jump means a sign change inside
                        for a in range(8):
                            ia, ja, ka = cx + (a & 1), cr + ((a >> 1) & 1), ct + ((a >> 2) & 1)
                            va = values[ia, ja, ka, face]
                            if (a & 1) == 0 and abs(values[ia + 1, ja, ka, face] - va) > 1.5 * hx:
                                far = False
                            if (a & 2) == 0 and abs(values[ia, ja + 1, ka, face] - va) > 1.5 * hr:
                                far = False
                            if (a & 4) == 0 and abs(values[ia, ja, ka + 1, face] - va) > 1.5 * chord_t:
                                far = False
                    if far:
                        continue
                    amb = False
                    on_edge = 0
                    for a in range(8):
                        ia, ja, ka = cx + (a & 1), cr + ((a >> 1) & 1), ct + ((a >> 2) & 1)
                        fu, fv = feet_uv[ia, ja, ka, face, 0], feet_uv[ia, ja, ka, face, 1]
                        if fu <= 0.0 or fu >= 1.0 or fv <= 0.0 or fv >= 1.0:
                            on_edge += 1
                        for b in range(a + 1, 8):
                            ib, jb, kb = cx + (b & 1), cr + ((b >> 1) & 1), ct + ((b >> 2) & 1)
                            dd = 0.0
                            cc = 0.0
                            for c in range(3):
                                dd += (feet_xyz[ia, ja, ka, face, c] - feet_xyz[ib, jb, kb, face, c]) ** 2
                                cc += dirs[ia, ja, ka, face, c] * dirs[ib, jb, kb, face, c]
                            if dd > spread * spread or cc < cos_turn:
                                amb = True
                    if 0 < on_edge < 8:
                        amb = True
                    kind[cx, cr, ct, face] = 2 if amb else 1
    return kind


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


@numba.njit(cache=True, parallel=True)
def _fill_fine(cp_s, tu_s, tv_s, cp_p, tu_p, tv_p, fp, ip, line_theta, line_inside,
               coarse_values, coarse_uv, kind, scales, jump, grid, edge):
    """Fill ``grid`` (nx, nr, nt, 2) float32: solved near the faces, interpolated far away.

    Each solved node starts from the extrapolated closest points of its two
    predecessors along theta and is checked against the coarse nodes'
    closest points (``_solve_node``; ``scales`` (4,): mm per unit u and v of
    the suction and the pressure face). ``edge`` (nx, nr, nt, 2) uint8
    receives 1 where a solved node's closest point lies on an edge of the
    face.

    Returns
    -------
    solved, rechecked : int
        Nodes solved, and nodes solved from more than one start.
    """
    nx, nr, nt, C = ip[_NX], ip[_NR], ip[_NT], ip[_COARSE]
    ncx, ncr, nct = ip[_NCX], ip[_NCR], ip[_NCT]
    pitch = fp[_PITCH]
    solved_x = np.zeros(nx, dtype=np.int64)
    rechecked_x = np.zeros(nx, dtype=np.int64)
    for ix in numba.prange(nx):
        work = new_work()
        solved = 0
        rechecked = 0
        x = fp[_X0] + ix * fp[_HX]
        cx = min(ix // C, ncx - 2)
        wx = (ix - cx * C) / C
        kx = min((ix + C // 2) // C, ncx - 1)
        for ir in range(nr):
            r = fp[_R0] + ir * fp[_HR]
            cr = min(ir // C, ncr - 2)
            wr = (ir - cr * C) / C
            kr = min((ir + C // 2) // C, ncr - 1)
            for face in range(2):
                pu, pv = np.nan, np.nan          # continuation along theta: last two feet
                qu, qv = np.nan, np.nan
                for it in range(nt):
                    ct = min(it // C, nct - 2)
                    k = kind[cx, cr, ct, face]
                    if k == 0:
                        wt = (it - ct * C) / C
                        acc = 0.0
                        for a in range(8):
                            w = ((wx if a & 1 else 1.0 - wx) * (wr if a & 2 else 1.0 - wr)
                                 * (wt if a & 4 else 1.0 - wt))
                            acc += w * coarse_values[cx + (a & 1), cr + ((a >> 1) & 1), ct + ((a >> 2) & 1), face]
                        grid[ix, ir, it, face] = acc
                        edge[ix, ir, it, face] = 0
                        pu, pv = np.nan, np.nan
                        continue
                    th = fp[_T0] + it * fp[_HT]
                    if face == 1:
                        th -= pitch
                    su, sv = pu, pv
                    if pu == pu and qu == qu:    # linear extrapolation of the foot
                        su = min(max(2.0 * pu - qu, 0.0), 1.0)
                        sv = min(max(2.0 * pv - qv, 0.0), 1.0)
                    px, py, pz = x, r * math.cos(th), r * math.sin(th)
                    kt = min((it + C // 2) // C, nct - 1)
                    if face == 0:
                        u, v, f, extra = _solve_node(cp_s, tu_s, tv_s, px, py, pz, su, sv, coarse_uv, 0, cx, cr, ct,
                                                     kx, kr, kt, k == 2, scales[0], scales[1], jump, work)
                    else:
                        u, v, f, extra = _solve_node(cp_p, tu_p, tv_p, px, py, pz, su, sv, coarse_uv, 1, cx, cr, ct,
                                                     kx, kr, kt, k == 2, scales[2], scales[3], jump, work)
                    rechecked += extra > 0
                    solved += 1
                    d = math.sqrt(f)
                    if _behind(face, th, line_theta[ix, ir, face], line_inside[ix, ir, face], pitch):
                        d = -d
                    grid[ix, ir, it, face] = d
                    edge[ix, ir, it, face] = _on_edge(u, v) != 0
                    qu, qv = pu, pv
                    pu, pv = u, v
        solved_x[ix] = solved
        rechecked_x[ix] = rechecked
    return solved_x.sum(), rechecked_x.sum()


@numba.njit(cache=True)
def _jump(a, b, length, tol, far, far_tol):
    """The values a, b of neighbouring nodes ``length`` mm apart differ more than a distance can."""
    t = far_tol if (abs(a) > far and abs(b) > far) else tol
    return abs(a - b) > length + t


@numba.njit(cache=True)
def _flag_nodes(grid, edge, fp, ip, curvature_tol, edge_curvature_tol, accurate_within, jump_tol):
    """Mark nodes whose cells trilinear interpolation does not represent (NaN in place).

    A node is marked for a face where the value jumps to a neighbour (more
    than the edge length plus ``jump_tol``, or plus 0.5 mm where both lie
    beyond ``accurate_within`` + 0.5 mm, whose values come from the coarse
    grid: the sign rule changes) or, within ``accurate_within`` mm of the
    face, where the second differences along the three axes add up to more
    than ``curvature_tol`` mm (trilinear error about an eighth of that in a
    smoothly curved field), or more than ``edge_curvature_tol`` where the
    node or a neighbour has its closest point on an edge of the face (there
    the field bends sharply between nodes, across the normal plane of the
    edge, and the error can reach a quarter). Returns the number of marked
    (node, face) pairs.
    """
    nx, nr, nt = ip[_NX], ip[_NR], ip[_NT]
    mark = np.zeros((nx, nr, nt, 2), dtype=np.uint8)
    hx, hr = fp[_HX], fp[_HR]
    far = accurate_within + 0.5
    count_x = np.zeros(nx, dtype=np.int64)
    for ix in range(nx):
        for ir in range(nr):
            for it in range(nt):
                for face in range(2):
                    g = grid[ix, ir, it, face]
                    jump = False
                    if ix + 1 < nx and _jump(g, grid[ix + 1, ir, it, face], hx, jump_tol, far, 0.5):
                        jump = True
                    elif ix > 0 and _jump(g, grid[ix - 1, ir, it, face], hx, jump_tol, far, 0.5):
                        jump = True
                    elif ir + 1 < nr and _jump(g, grid[ix, ir + 1, it, face], hr, jump_tol, far, 0.5):
                        jump = True
                    elif ir > 0 and _jump(g, grid[ix, ir - 1, it, face], hr, jump_tol, far, 0.5):
                        jump = True
                    else:
                        chord_hi = 2.0 * (fp[_R0] + (ir + 1) * hr) * math.sin(0.5 * fp[_HT])
                        if it + 1 < nt and _jump(g, grid[ix, ir, it + 1, face], chord_hi, jump_tol, far, 0.5):
                            jump = True
                        elif it > 0 and _jump(g, grid[ix, ir, it - 1, face], chord_hi, jump_tol, far, 0.5):
                            jump = True
                    if jump:
                        mark[ix, ir, it, face] = 1
                        continue
                    if abs(g) > accurate_within:
                        continue
                    s = 0.0
                    if 0 < ix < nx - 1:
                        s += abs(grid[ix - 1, ir, it, face] - 2.0 * g + grid[ix + 1, ir, it, face])
                    if 0 < ir < nr - 1:
                        s += abs(grid[ix, ir - 1, it, face] - 2.0 * g + grid[ix, ir + 1, it, face])
                    if 0 < it < nt - 1:
                        s += abs(grid[ix, ir, it - 1, face] - 2.0 * g + grid[ix, ir, it + 1, face])
                    tol = curvature_tol
                    if s > edge_curvature_tol and (
                            edge[ix, ir, it, face] or (ix > 0 and edge[ix - 1, ir, it, face])
                            or (ix + 1 < nx and edge[ix + 1, ir, it, face]) or (ir > 0 and edge[ix, ir - 1, it, face])
                            or (ir + 1 < nr and edge[ix, ir + 1, it, face]) or (it > 0 and edge[ix, ir, it - 1, face])
                            or (it + 1 < nt and edge[ix, ir, it + 1, face])):
                        tol = edge_curvature_tol
                    if s > tol:
                        mark[ix, ir, it, face] = 1
    for ix in range(nx):
        c = 0
        for ir in range(nr):
            for it in range(nt):
                for face in range(2):
                    if mark[ix, ir, it, face]:
                        grid[ix, ir, it, face] = np.nan
                        c += 1
        count_x[ix] = c
    return count_x.sum()


# ===========================================================================
# Queries (numba)
# ===========================================================================

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


@numba.njit(cache=True)
def _exact_blade(face, x, rho, th, fp, ip, slow, work):
    """Exact signed distance of (x, rho, th) (channel-0 angle) to a wall: the slow path."""
    d, _, _ = _exact_blade_uv(face, x, rho, th, fp, ip, slow, work)
    return d


@numba.njit(cache=True)
def _wall_angle(face, x, rho, th, fp, ip, slow, work):
    """The face's footprint test and angle at (x, rho), for the sign rule (``_behind``) of ``_exact_blade_uv``.

    Returns
    -------
    in_face : bool
        (x, rho) lies in the face's meridional footprint.
    th_face : float
        The face's angle there [rad] (0 outside the footprint).
    """
    if face == 0:
        cp, tu, tv = slow[0], slow[1], slow[2]
    else:
        cp, tu, tv = slow[3], slow[4], slow[5]
    line_theta, line_inside = slow[9], slow[10]
    nx, nr = ip[_NX], ip[_NR]
    pitch = fp[_PITCH]
    th_w = th - pitch if face == 1 else th
    # the face's angle at (x, rho) for the sign rule; the grid covers the footprint
    in_face = False
    th_face = 0.0
    lx = (x - fp[_X0]) / fp[_HX]
    lr = (rho - fp[_R0]) / fp[_HR]
    if 0.0 <= lx <= nx - 1 and 0.0 <= lr <= nr - 1:
        # where the 4 x 4 surrounding (x, r) lines lie in the footprint and the point is off the
        # face's angle by more than 4 times the bilinear error estimate (from the lines' second
        # differences), the bilinear angle decides; else Newton
        ix, ir = min(int(lx), nx - 2), min(int(lr), nr - 2)
        ax, ar = lx - ix, lr - ir
        decided = False
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
            if abs(rel) > margin and abs(abs(rel) - pitch) > margin:
                decided = True
                in_face = True
                th_face = est
        if not decided:
            # Newton from the start ``BladeFace.uv_at`` takes (the nearest of its 64 x 64 samples in
            # scaled (x, r)): near the leading and trailing edges the map (u, v) -> (x, r) can fold,
            # and then the footprint test depends on the start
            xr_uv = slow[18]
            j_best = _nearest_start(face, x, rho, slow[17], slow[19], slow[20], slow[21], slow[22])
            _, _, in_face, th_face = uv_at(cp, tu, tv, x, rho, xr_uv[face, j_best, 0], xr_uv[face, j_best, 1],
                                            work)
    return in_face, th_face


@numba.njit(cache=True)
def _blade_behind(face, x, rho, th, fp, ip, slow, work):
    """The sign of ``_exact_blade`` alone (no closest point): is (x, rho, th) (channel-0 angle) behind the wall?"""
    in_face, th_face = _wall_angle(face, x, rho, th, fp, ip, slow, work)
    pitch = fp[_PITCH]
    return _behind(face, th - pitch if face == 1 else th, th_face, in_face, pitch)


@numba.njit(cache=True)
def _exact_blade_uv(face, x, rho, th, fp, ip, slow, work):
    """Exact signed distance of (x, rho, th) (channel-0 angle) to a wall and its foot's (u, v).

    The sign rule as in the fill; the closest point from the nearest coarse
    node's, checked against the other corners' where the coarse cell is
    ambiguous (``_solve_node``) and restarted from inside when it ends on an
    edge of the face.
    """
    if face == 0:
        cp, tu, tv = slow[0], slow[1], slow[2]
    else:
        cp, tu, tv = slow[3], slow[4], slow[5]
    coarse_uv, kind = slow[7], slow[8]
    C = ip[_COARSE]
    pitch = fp[_PITCH]
    th_w = th - pitch if face == 1 else th
    in_face, th_face = _wall_angle(face, x, rho, th, fp, ip, slow, work)
    gx = min(max((x - fp[_X0]) / (C * fp[_HX]), 0.0), ip[_NCX] - 1.0)
    gr = min(max((rho - fp[_R0]) / (C * fp[_HR]), 0.0), ip[_NCR] - 1.0)
    gt = min(max((th - fp[_T0]) / (C * fp[_HT]), 0.0), ip[_NCT] - 1.0)
    cx, cr, ct = min(int(gx), ip[_NCX] - 2), min(int(gr), ip[_NCR] - 2), min(int(gt), ip[_NCT] - 2)
    kx, kr, kt = int(round(gx)), int(round(gr)), int(round(gt))
    px, py, pz = x, rho * math.cos(th_w), rho * math.sin(th_w)
    amb = kind[cx, cr, ct, face] == 2
    u, v, f, _ = _solve_node(cp, tu, tv, px, py, pz, np.nan, np.nan, coarse_uv, face, cx, cr, ct, kx, kr, kt, amb,
                             fp[_SCALE + 2 * face], fp[_SCALE + 2 * face + 1], fp[_JUMP], work)
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
def _fast_point(x, y, z, flat, hs, fp, ip):
    """The fast path: (suction, pressure, hub, shroud, ok); ok False sends the point to ``_slow_point``.

    Trilinear in the blade grid (float32, both walls with shared weights),
    bilinear in the hub/shroud table; outside the blade grid the slow
    path's lower bound from the nearest grid point. Not ok: outside the
    hub/shroud table, or a cell marked for the exact solver (NaN). ``fp`` holds the cosine and sine
    of the grid's middle angle turned into the query's channel (``_CA``,
    ``_SA``).
    """
    rho = math.sqrt(y * y + z * z)
    # the angle about the grid's middle angle (turned into channel k): (y', z') = R(-a) (y, z)
    yr = y * fp[_CA] + z * fp[_SA]
    zr = z * fp[_CA] - y * fp[_SA]
    if not (yr > 0.0 and abs(zr) <= 0.5 * yr):
        return np.nan, np.nan, np.nan, np.nan, False
    t = zr / yr
    s2 = t * t
    c = _ATAN
    phi = t * (c[0] + s2 * (c[1] + s2 * (c[2] + s2 * (c[3] + s2 * (c[4] + s2 * (c[5] + s2 * (
        c[6] + s2 * (c[7] + s2 * (c[8] + s2 * (c[9] + s2 * c[10]))))))))))
    gx = (x - fp[_X0]) * fp[_IHX]
    gr = (rho - fp[_R0]) * fp[_IHR]
    gt = (phi + (fp[_TC] - fp[_T0])) * fp[_IHT]
    hx = (x - fp[_HX0]) * fp[_IHHX]
    hr = (rho - fp[_HR0]) * fp[_IHHR]
    nan = np.nan
    if not (0.0 <= hx < ip[_NHX] - 1 and 0.0 <= hr < ip[_NHR] - 1 and gx == gx and gr == gr and gt == gt):
        return nan, nan, nan, nan, False
    # outside the blade grid (an electrode on its way in or out, past the blades or turned beyond the
    # grid's angles): the slow path's bound max(value at the nearest grid point q - |p - q|, box
    # distance), from the tables alone
    gap = 0.0
    if not (0.0 <= gx < ip[_NX] - 1 and 0.0 <= gr < ip[_NR] - 1 and 0.0 <= gt < ip[_NT] - 1):
        qx = min(max(gx, 0.0), ip[_NX] - 1.0)
        qr = min(max(gr, 0.0), ip[_NR] - 1.0)
        qt = min(max(gt, 0.0), ip[_NT] - 1.0)
        dx = (gx - qx) * fp[_HX]
        rq = fp[_R0] + qr * fp[_HR]
        half = 0.5 * (gt - qt) * fp[_HT]                 # half the angle between p and q about the axis
        sh = math.sin(half)
        gap = math.sqrt(dx * dx + (rho - rq) * (rho - rq) + 4.0 * rho * rq * sh * sh)
        gx, gr, gt = qx, qr, qt
    ix, ir, it = min(int(gx), ip[_NX] - 2), min(int(gr), ip[_NR] - 2), min(int(gt), ip[_NT] - 2)
    wx, wr, wt = np.float32(gx - ix), np.float32(gr - ir), np.float32(gt - it)
    # unsigned indices: no negative-index wrap-around code; float32 arithmetic on the (s, p) pairs
    sr = np.uint64(2 * ip[_NT])
    sx = np.uint64(2 * ip[_NT] * ip[_NR])
    one, two, three = np.uint64(1), np.uint64(2), np.uint64(3)
    b0 = np.uint64(ix) * sx + np.uint64(ir) * sr + np.uint64(it) * two
    b1 = b0 + sr
    b2 = b0 + sx
    b3 = b2 + sr
    s00 = flat[b0] + wt * (flat[b0 + two] - flat[b0])
    p00 = flat[b0 + one] + wt * (flat[b0 + three] - flat[b0 + one])
    s01 = flat[b1] + wt * (flat[b1 + two] - flat[b1])
    p01 = flat[b1 + one] + wt * (flat[b1 + three] - flat[b1 + one])
    s10 = flat[b2] + wt * (flat[b2 + two] - flat[b2])
    p10 = flat[b2 + one] + wt * (flat[b2 + three] - flat[b2 + one])
    s11 = flat[b3] + wt * (flat[b3 + two] - flat[b3])
    p11 = flat[b3 + one] + wt * (flat[b3 + three] - flat[b3 + one])
    s0 = s00 + wr * (s01 - s00)
    s1 = s10 + wr * (s11 - s10)
    p0 = p00 + wr * (p01 - p00)
    p1 = p10 + wr * (p11 - p10)
    s = s0 + wx * (s1 - s0)
    p = p0 + wx * (p1 - p0)
    if s != s or p != p:
        return nan, nan, nan, nan, False
    sb, pb = float(s), float(p)
    if gap > 0.0:
        ex = max(fp[_FX0] - x, 0.0, x - fp[_FX1])
        er = max(fp[_FR0] - rho, 0.0, rho - fp[_FR1])
        rect = math.sqrt(ex * ex + er * er)
        sb, pb = max(sb - gap, rect), max(pb - gap, rect)
    jx, jr = int(hx), int(hr)
    ax, ar = np.float32(hx - jx), np.float32(hr - jr)
    hsr = np.uint64(2 * ip[_NHR])
    c0 = np.uint64(jx) * hsr + np.uint64(jr) * two
    c1 = c0 + hsr
    h0 = hs[c0] + ar * (hs[c0 + two] - hs[c0])
    h1 = hs[c1] + ar * (hs[c1 + two] - hs[c1])
    k0 = hs[c0 + one] + ar * (hs[c0 + three] - hs[c0 + one])
    k1 = hs[c1 + one] + ar * (hs[c1 + three] - hs[c1 + one])
    return sb, pb, float(h0 + ax * (h1 - h0)), float(k0 + ax * (k1 - k0)), True


@numba.njit(cache=True)
def _trilinear(flat, ip, gx, gr, gt, face):
    """Trilinear value of one wall at fractional grid indices inside the grid (float64)."""
    nr, nt = ip[_NR], ip[_NT]
    ix = min(int(gx), ip[_NX] - 2)
    ir = min(int(gr), nr - 2)
    it = min(int(gt), nt - 2)
    wx, wr, wt = gx - ix, gr - ir, gt - it
    acc = 0.0
    for a in range(8):
        jx, jr, jt = ix + (a & 1), ir + ((a >> 1) & 1), it + ((a >> 2) & 1)
        w = (wx if a & 1 else 1.0 - wx) * (wr if a & 2 else 1.0 - wr) * (wt if a & 4 else 1.0 - wt)
        acc += w * flat[((jx * nr + jr) * nt + jt) * 2 + face]
    return acc


@numba.njit(cache=True)
def _slow_point(x, y, z, channel_angle, flat, hs, fp, ip, slow, work):
    """The general path of a query (any point): returns (suction, pressure, hub, shroud).

    Inside the grid: trilinear, or the exact solver in cells marked for it.
    Outside: the conservative lower bound ``max(value at the nearest grid
    point q - |p - q|, distance to the faces' (x, r) bounding box)``. Hub and
    shroud: the table, or the exact profile distance outside it.
    """
    rho = math.sqrt(y * y + z * z)
    th = math.atan2(z, y) - channel_angle
    th -= _TWO_PI * math.floor((th - fp[_TC] + math.pi) / _TWO_PI)
    nx, nr, nt = ip[_NX], ip[_NR], ip[_NT]
    gx = (x - fp[_X0]) / fp[_HX]
    gr = (rho - fp[_R0]) / fp[_HR]
    gt = (th - fp[_T0]) / fp[_HT]
    outside = not (0.0 <= gx <= nx - 1 and 0.0 <= gr <= nr - 1 and 0.0 <= gt <= nt - 1)
    qx, qr, qt = min(max(gx, 0.0), nx - 1.0), min(max(gr, 0.0), nr - 1.0), min(max(gt, 0.0), nt - 1.0)
    xq = fp[_X0] + qx * fp[_HX]
    rq = fp[_R0] + qr * fp[_HR]
    tq = fp[_T0] + qt * fp[_HT]
    s = _trilinear(flat, ip, qx, qr, qt, 0)
    if s != s:
        s = _exact_blade(0, xq, rq, tq, fp, ip, slow, work)
    p = _trilinear(flat, ip, qx, qr, qt, 1)
    if p != p:
        p = _exact_blade(1, xq, rq, tq, fp, ip, slow, work)
    if outside:
        dx = x - xq
        dy = rho * math.cos(th) - rq * math.cos(tq)
        dz = rho * math.sin(th) - rq * math.sin(tq)
        gap = math.sqrt(dx * dx + dy * dy + dz * dz)
        # the faces lie in [FX0, FX1] x [FR0, FR1] of the (x, r) half-plane: a second lower bound
        ex = max(fp[_FX0] - x, 0.0, x - fp[_FX1])
        er = max(fp[_FR0] - rho, 0.0, rho - fp[_FR1])
        rect = math.sqrt(ex * ex + er * er)
        s = max(s - gap, rect)
        p = max(p - gap, rect)
    hx = (x - fp[_HX0]) / fp[_HHX]
    hr = (rho - fp[_HR0]) / fp[_HHR]
    nhx, nhr = ip[_NHX], ip[_NHR]
    if 0.0 <= hx <= nhx - 1 and 0.0 <= hr <= nhr - 1:
        jx = min(int(hx), nhx - 2)
        jr = min(int(hr), nhr - 2)
        ax, ar = hx - jx, hr - jr
        i00, i01 = (jx * nhr + jr) * 2, (jx * nhr + jr + 1) * 2
        i10, i11 = ((jx + 1) * nhr + jr) * 2, ((jx + 1) * nhr + jr + 1) * 2
        h = ((1 - ax) * ((1 - ar) * hs[i00] + ar * hs[i01]) + ax * ((1 - ar) * hs[i10] + ar * hs[i11]))
        c_ = ((1 - ax) * ((1 - ar) * hs[i00 + 1] + ar * hs[i01 + 1])
              + ax * ((1 - ar) * hs[i10 + 1] + ar * hs[i11 + 1]))
    else:
        h = _profile_signed(slow[11], slow[12], slow[13], 1.0, x, rho)
        c_ = _profile_signed(slow[14], slow[15], slow[16], -1.0, x, rho)
    return s, p, h, c_


@numba.njit(cache=True)
def _points_kernel(points, channel_angle, mode, flat, hs, fpt, ipt, fp, ip, slow):
    """(n, 4) per point: the field (mode 0), the exact solvers (mode 1) or fast-path flags (mode 2).

    Mode 0: the four clearances as ``FastChannelField.clearances``. Mode 1:
    the exact signed distances, numba blade solver and profile solver, no
    table. Mode 2: 1.0 in column 0 where the fast path answers. One kernel
    for the three, so that the slow path is compiled once more only.
    """
    n = points.shape[0]
    out = np.zeros((n, 4))
    work = new_work()
    for k in range(n):
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        if mode == 1:
            rho = math.sqrt(y * y + z * z)
            th = math.atan2(z, y) - channel_angle
            th -= _TWO_PI * math.floor((th - fp[_TC] + math.pi) / _TWO_PI)
            out[k, 0] = _exact_blade(0, x, rho, th, fp, ip, slow, work)
            out[k, 1] = _exact_blade(1, x, rho, th, fp, ip, slow, work)
            out[k, 2] = _profile_signed(slow[11], slow[12], slow[13], 1.0, x, rho)
            out[k, 3] = _profile_signed(slow[14], slow[15], slow[16], -1.0, x, rho)
            continue
        s, p, h, c, ok = _fast_point(x, y, z, flat, hs, fpt, ipt)
        if mode == 2:
            out[k, 0] = 1.0 if ok else 0.0
            continue
        if not ok:
            s, p, h, c = _slow_point(x, y, z, channel_angle, flat, hs, fp, ip, slow, work)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = s, p, h, c
    return out


@numba.njit(cache=True, parallel=True)
def _pose_kernel(poses, points, channel_angle, flat, hs, fpt, ipt, fp, ip, slow):
    """Per pose the minimum of each column over the points, and the point attaining it.

    Blocks of 64 poses x 128 points: a point under neighbouring poses reads
    the same cells while they are in cache; the running minima of a pose
    stay in registers over a block of points. Pose blocks run in parallel
    (each writes its own rows). ``fpt``, ``ipt`` are the parameter vectors
    as tuples (passed by value: no reloads after stores).
    """
    n_pose, n_pt = poses.shape[0], points.shape[0]
    best = np.full((n_pose, 4), np.inf)
    arg = np.zeros((n_pose, 4), dtype=np.int64)
    # at least 8 blocks when there are few poses, so that every thread gets some
    block = max(1, min(64, n_pose // 8))
    for b in numba.prange((n_pose + block - 1) // block):
        q0 = b * block
        q1 = min(q0 + block, n_pose)
        work = new_work()
        for k0 in range(0, n_pt, 128):
            k1 = min(k0 + 128, n_pt)
            for q in range(q0, q1):
                m00, m01, m02, m03 = poses[q, 0, 0], poses[q, 0, 1], poses[q, 0, 2], poses[q, 0, 3]
                m10, m11, m12, m13 = poses[q, 1, 0], poses[q, 1, 1], poses[q, 1, 2], poses[q, 1, 3]
                m20, m21, m22, m23 = poses[q, 2, 0], poses[q, 2, 1], poses[q, 2, 2], poses[q, 2, 3]
                b0, b1, b2, b3 = best[q, 0], best[q, 1], best[q, 2], best[q, 3]
                a0, a1, a2, a3 = arg[q, 0], arg[q, 1], arg[q, 2], arg[q, 3]
                for k in range(k0, k1):
                    ex, ey, ez = points[k, 0], points[k, 1], points[k, 2]
                    x = m00 * ex + m01 * ey + m02 * ez + m03
                    y = m10 * ex + m11 * ey + m12 * ez + m13
                    z = m20 * ex + m21 * ey + m22 * ez + m23
                    s, p, h, c, ok = _fast_point(x, y, z, flat, hs, fpt, ipt)
                    if not ok:
                        s, p, h, c = _slow_point(x, y, z, channel_angle, flat, hs, fp, ip, slow, work)
                    if s < b0:
                        b0, a0 = s, k
                    if p < b1:
                        b1, a1 = p, k
                    if h < b2:
                        b2, a2 = h, k
                    if c < b3:
                        b3, a3 = c, k
                best[q, 0], best[q, 1], best[q, 2], best[q, 3] = b0, b1, b2, b3
                arg[q, 0], arg[q, 1], arg[q, 2], arg[q, 3] = a0, a1, a2, a3
    return best, arg


@numba.njit(cache=True)
def _exact_surface(s, x, rho, th, fp, ip, slow, work):
    """Exact signed distance to surface s (0 suction, 1 pressure, 2 hub, 3 shroud); th in channel 0."""
    if s < 2:
        return _exact_blade(s, x, rho, th, fp, ip, slow, work)
    if s == 2:
        return _profile_signed(slow[11], slow[12], slow[13], 1.0, x, rho)
    return _profile_signed(slow[14], slow[15], slow[16], -1.0, x, rho)


@numba.njit(cache=True)
def _exact_pose_kernel(poses, points, channel_angle, near_bound, far_bound, flat, hs, fpt, ipt, fp, ip, slow):
    """Per pose the exact minimum of each surface's signed distance over the points (branch and bound).

    Per point the field gives a lower bound of the exact distance: its value
    minus ``near_bound`` where it is certainly within 2 mm of the surface,
    minus ``far_bound`` elsewhere inside the tables, the value itself outside
    them (there it is a lower bound already). Per surface the point with the
    lowest bound is solved exactly first; every other point is solved only
    while its bound does not exceed the smallest exact value found so far, so
    the result is the exact minimum over all points whatever the order.

    Returns
    -------
    best : (P, 4) float, arg : (P, 4) int, solved : (P,) int (exact solves per pose)
    """
    n_pose, n_pt = poses.shape[0], points.shape[0]
    best = np.full((n_pose, 4), np.inf)
    arg = np.zeros((n_pose, 4), dtype=np.int64)
    solved = np.zeros(n_pose, dtype=np.int64)
    world = np.empty((n_pt, 3))
    low = np.empty((n_pt, 4))
    work = new_work()
    nx, nr, nt, nhx, nhr = ip[_NX], ip[_NR], ip[_NT], ip[_NHX], ip[_NHR]
    sure_near = ACCURATE_WITHIN - far_bound       # |value| below this: |exact| <= 2 mm
    for q in range(n_pose):
        first = np.zeros(4, dtype=np.int64)
        lmin = np.full(4, np.inf)
        for k in range(n_pt):
            ex, ey, ez = points[k, 0], points[k, 1], points[k, 2]
            x = poses[q, 0, 0] * ex + poses[q, 0, 1] * ey + poses[q, 0, 2] * ez + poses[q, 0, 3]
            y = poses[q, 1, 0] * ex + poses[q, 1, 1] * ey + poses[q, 1, 2] * ez + poses[q, 1, 3]
            z = poses[q, 2, 0] * ex + poses[q, 2, 1] * ey + poses[q, 2, 2] * ez + poses[q, 2, 3]
            world[k, 0], world[k, 1], world[k, 2] = x, y, z
            s, p, h, c, ok = _fast_point(x, y, z, flat, hs, fpt, ipt)
            in_grid, in_table = True, True
            if not ok:
                s, p, h, c = _slow_point(x, y, z, channel_angle, flat, hs, fp, ip, slow, work)
                rho = math.sqrt(y * y + z * z)
                th = math.atan2(z, y) - channel_angle
                th -= _TWO_PI * math.floor((th - fp[_TC] + math.pi) / _TWO_PI)
                gx, gr, gt = (x - fp[_X0]) / fp[_HX], (rho - fp[_R0]) / fp[_HR], (th - fp[_T0]) / fp[_HT]
                in_grid = 0.0 <= gx <= nx - 1 and 0.0 <= gr <= nr - 1 and 0.0 <= gt <= nt - 1
                hx, hr = (x - fp[_HX0]) / fp[_HHX], (rho - fp[_HR0]) / fp[_HHR]
                in_table = 0.0 <= hx <= nhx - 1 and 0.0 <= hr <= nhr - 1
            vals = (s, p, h, c)
            for j in range(4):
                v = vals[j]
                inside = in_grid if j < 2 else in_table
                if inside:
                    v -= near_bound if abs(v) <= sure_near else far_bound
                low[k, j] = v
                if v < lmin[j]:
                    lmin[j], first[j] = v, k
        for j in range(4):
            ub, a = np.inf, first[j]
            for step in range(n_pt + 1):
                k = first[j] if step == 0 else step - 1
                if (step > 0 and k == first[j]) or low[k, j] > ub:
                    continue
                x, y, z = world[k, 0], world[k, 1], world[k, 2]
                rho = math.sqrt(y * y + z * z)
                th = math.atan2(z, y) - channel_angle
                th -= _TWO_PI * math.floor((th - fp[_TC] + math.pi) / _TWO_PI)
                d = _exact_surface(j, x, rho, th, fp, ip, slow, work)
                solved[q] += 1
                if d < ub:
                    ub, a = d, k
            best[q, j], arg[q, j] = ub, a
    return best, arg, solved


@numba.njit(cache=True)
def _channel_coordinates(x, y, z, channel_angle, fp):
    """(rho, th) of a point in W: th its channel-0 angle about the grid's middle, as every exact query takes it."""
    rho = math.sqrt(y * y + z * z)
    th = math.atan2(z, y) - channel_angle
    th -= _TWO_PI * math.floor((th - fp[_TC] + math.pi) / _TWO_PI)
    return rho, th


@numba.njit(cache=True)
def _exact_at(s, x, y, z, channel_angle, fp, ip, slow, work):
    """Exact signed distance of a point in W to surface s of the channel at ``channel_angle`` (``_exact_surface``)."""
    rho, th = _channel_coordinates(x, y, z, channel_angle, fp)
    return _exact_surface(s, x, rho, th, fp, ip, slow, work)


@numba.njit(cache=True)
def _behind_at(face, x, y, z, channel_angle, fp, ip, slow, work):
    """Whether a point in W lies behind wall ``face`` (0 suction, 1 pressure): the sign of ``_exact_at`` alone."""
    rho, th = _channel_coordinates(x, y, z, channel_angle, fp)
    return _blade_behind(face, x, rho, th, fp, ip, slow, work)


@numba.njit(cache=True)
def _behind_kernel(points, channel_angle, fp, ip, slow):
    """(n, 2) bool: ``_behind_at`` for both walls."""
    n = points.shape[0]
    out = np.zeros((n, 2), dtype=np.bool_)
    work = new_work()
    for k in range(n):
        for face in range(2):
            out[k, face] = _behind_at(face, points[k, 0], points[k, 1], points[k, 2], channel_angle, fp, ip, slow,
                                      work)
    return out


@numba.njit(cache=True)
def _exact_blade_feet(points, channel_angle, fp, ip, slow):
    """Exact signed distances to both walls and the feet's (u, v): (n, 2), (n, 2, 2)."""
    n = points.shape[0]
    dist = np.empty((n, 2))
    uv = np.empty((n, 2, 2))
    work = new_work()
    for k in range(n):
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        rho = math.sqrt(y * y + z * z)
        th = math.atan2(z, y) - channel_angle
        th -= _TWO_PI * math.floor((th - fp[_TC] + math.pi) / _TWO_PI)
        for face in range(2):
            d, u, v = _exact_blade_uv(face, x, rho, th, fp, ip, slow, work)
            dist[k, face], uv[k, face, 0], uv[k, face, 1] = d, u, v
    return dist, uv


# ===========================================================================
# Exact minimum over a pose sequence (numba): the kernels of
# ``planning.export.verify_poses``
# ===========================================================================

# The exact minimum over every (sample, vertex) pair, by branch and bound.
#
# The signed distance to a wall is the distance to the face, negative behind it (within the face's
# meridional footprint, up to one pitch behind its angle). The distance is 1-Lipschitz, so for a pair q of
# positive sign and any point e of exact value v, d(q) >= |v| - |q - e| >= v - |q - e|; the hub and the
# shroud are surfaces of revolution continued as cylinders, their signed distances 1-Lipschitz everywhere.
# A node of the search is a sample interval S (represented by its middle sample) times a vertex cluster C
# (represented by the vertex c nearest the middle of its box); every pair of the node lies within
#     reach = r_C + rho_S |c - o| + tau_S
# of the representative pair's position (r_C the cluster's radius about c, rho_S the largest |R_t - R_mid|
# in S, tau_S the largest travel of the electrode origin o relative to the middle sample), so the
# representative's exact value less the reach bounds the node. Nodes are taken best bound first and split
# (the sample interval or the cluster, whichever contributes more to the reach) while their bound lies
# below the smallest exact value found; a node of one sample and one vertex is its own exact value. The
# search ends when every bound left lies above the smallest value found: that value is the exact minimum
# over all pairs of positive sign. Pairs behind a wall (negative sign) are found by the side test alone
# (the sign rule without the closest point, mostly answered by the field's tables or the (x, r) lines),
# for every vertex at anchor samples and at every sample between two anchors where its side differs or is
# behind at either; each is evaluated exactly and seeds the search.

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
                seed_t, seed_k, seed_v, tol, channel_angle, fp, ip, slow):
    """Exact minimum of one surface's signed distance over every (sample, vertex) pair (best-first bound).

    ``seed_*``: pairs evaluated already (behind a wall). Returns the minimum, its sample and vertex, the
    number of exact evaluations and the keys ``t * m + k`` of every pair evaluated.
    """
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
    heap = [(-np.inf, np.int64(0), np.int64(0))]
    while len(heap) > 0:
        prior, sn, cn = heapq.heappop(heap)
        if prior >= best + tol:
            break
        t, k = s_mid[sn], c_rep[cn]
        key = t * m + k
        px, py, pz = _place(poses, V, t, k)
        if key in done:
            v = done[key]
        else:
            v = _exact_at(surface, px, py, pz, channel_angle, fp, ip, slow, work)
            done[key] = v
            evaluations += 1
            if v < best or (v == best and key < best_key):
                best, best_key = v, key
        bound = max(prior, v - _reach(c_rad[cn], s_rho[sn], c_off[cn], s_tau[sn]))
        if bound >= best + tol or (s_left[sn] < 0 and c_left[cn] < 0):
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
            if child < best + tol:
                heapq.heappush(heap, (child, sc, cc))
    keys = np.empty(len(done), dtype=np.int64)
    i = 0
    for key in done.keys():
        keys[i] = key
        i += 1
    return best, best_key // m, best_key % m, evaluations, keys


@numba.njit(cache=True, inline="always")
def _sides(x, y, z, channel_angle, flat, hs, fpt, ipt, fp, ip, slow, work):
    """Is the point behind the suction / pressure wall: the sign rule alone, screened by the field.

    Beyond the faces' (x, r) box the point lies outside both footprints: in front. Where the field's
    tables answer and put the point more than ``_SIDE_SCREEN`` in front of a wall (cells across a change of
    sign are marked for the exact solver), it is in front of that wall; elsewhere the exact sign rule
    decides (``_behind_at``).
    """
    rho = math.sqrt(y * y + z * z)
    if (x < fp[_FX0] - _BOX_MARGIN or x > fp[_FX1] + _BOX_MARGIN
            or rho < fp[_FR0] - _BOX_MARGIN or rho > fp[_FR1] + _BOX_MARGIN):
        return False, False                    # beyond the faces' (x, r) box: outside both footprints
    s, p, _, _, ok = _fast_point(x, y, z, flat, hs, fpt, ipt)
    behind_s = False if ok and s > _SIDE_SCREEN else _behind_at(0, x, y, z, channel_angle, fp, ip, slow, work)
    behind_p = False if ok and p > _SIDE_SCREEN else _behind_at(1, x, y, z, channel_angle, fp, ip, slow, work)
    return behind_s, behind_p


@numba.njit(cache=True, parallel=True)
def _anchor_sides(poses, V, anchors, channel_angle, flat, hs, fpt, ipt, fp, ip, slow):
    """(anchors, m, 2) bool: every vertex behind the suction / pressure wall at the anchor samples."""
    m = V.shape[0]
    out = np.zeros((anchors.shape[0], m, 2), dtype=np.bool_)
    for i in numba.prange(anchors.shape[0]):
        work = new_work()
        for k in range(m):
            x, y, z = _place(poses, V, anchors[i], k)
            out[i, k, 0], out[i, k, 1] = _sides(x, y, z, channel_angle, flat, hs, fpt, ipt, fp, ip, slow, work)
    return out


@numba.njit(cache=True, parallel=True)
def _sweep_sides(poses, V, face, vertex, first, last, channel_angle, flat, hs, fpt, ipt, fp, ip, slow):
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
            out[start[i] + t - first[i]] = _sides(x, y, z, channel_angle, flat, hs, fpt, ipt, fp, ip, slow,
                                                  work)[face[i]]
    return out, start


@numba.njit(cache=True, parallel=True)
def _exact_pairs(poses, V, t, k, surface, channel_angle, fp, ip, slow):
    """Exact signed distances of the given (sample, vertex, surface) triples."""
    out = np.empty(t.shape[0])
    for i in numba.prange(t.shape[0]):
        work = new_work()
        x, y, z = _place(poses, V, t[i], k[i])
        out[i] = _exact_at(surface[i], x, y, z, channel_angle, fp, ip, slow, work)
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


# ===========================================================================
# The field
# ===========================================================================

def _face_arrays(face):
    """Control net by coordinate (3, nv, nu) and the knot vectors of a face's spline."""
    s = face.surface
    return (np.ascontiguousarray(np.moveaxis(s.control_points, 2, 0), dtype=np.float64),
            np.ascontiguousarray(s.knots_u, dtype=np.float64),
            np.ascontiguousarray(s.knots_v, dtype=np.float64))


def _profile_arrays(profile):
    """Breakpoints (n,), cubic coefficients (4, n-1) and (max|r'|, max|r''|) of a profile.

    The PCHIP pieces of ``RevolutionProfile`` (the interpolant ``ProfileDistance`` uses).
    """
    interp = profile._interp
    xb = np.ascontiguousarray(interp.x, dtype=np.float64)
    t = np.linspace(xb[0], xb[-1], 20 * len(xb) + 200)
    bounds = np.array([np.abs(interp.derivative()(t)).max() * 1.1 + 1e-9,
                       np.abs(interp.derivative(2)(t)).max() * 1.1 + 1e-9])
    return xb, np.ascontiguousarray(interp.c, dtype=np.float64), bounds


@contextlib.contextmanager
def _build_lock(path):
    """Exclusive lock of a field's cache file while it is built (``<cache>.lock``, flock); none without a cache.

    The lock is the kernel's (released when its holder exits, also by kill -9),
    so a crashed builder never blocks the next one. Where the lock file cannot
    be made (a read-only cache directory) the field is built unlocked.
    """
    if path is None:
        yield
        return
    lock = path.with_name(path.name + ".lock")
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        _log.warning("fast field: no build lock %s (%s); building without it", lock, exc)
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            _log.info("fast field: another process is building %s; waiting for it", path.name)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)                     # closing releases the lock


def _axis(lo, hi, step, multiple):
    """Node count (a multiple of ``multiple`` intervals plus one) and spacing <= step covering [lo, hi]."""
    m = max(multiple, int(math.ceil((hi - lo) / step / multiple - 1e-9)) * multiple)
    return m + 1, (hi - lo) / m


class FastChannelField:
    """Signed distances to a channel's four surfaces from a precomputed field.

    Parameters
    ----------
    blisk : Blisk
    spacing : float
        Grid spacing [mm] of the blade grid in x and r; in theta it is
        ``spacing / r_mid``. The hub/shroud (x, r) table has the same.
    cache_dir : path, optional
        Directory of the cached arrays (``.npz``); with ``cache_key``, the
        field is loaded from there when a matching file exists and written
        there after a build.
    cache_key : str, optional
        Identifies the geometry (the loader's geometry id).
    band : float
        Nodes farther than this from a face [mm] are interpolated from the
        coarse grid instead of solved (their values only need to say "far").
    curvature_tol, edge_curvature_tol : float
        Summed absolute second differences [mm] above which a node is left to
        the exact solver (the trilinear error is about an eighth of it); the
        second applies beside the faces' edges (``_flag_nodes``).
    error_samples : int
        Random points per surface for the error measurement at build.

    Attributes
    ----------
    error_bound : float
        [mm] Bound of ``|fast - exact|`` for points within ``ACCURATE_WITHIN``
        (2 mm) of a surface and inside the grid: the largest error measured
        at build times 1.5, plus the float32 quantisation. No pose may be
        taken as clear on this method alone unless its clearance exceeds the
        required one by more than this. Beyond 2 mm from a blade face the
        blade values are coarser (not held to the bound); outside the grid
        they are lower bounds.
    measured_max_error : dict
        Surface name -> max ``|fast - exact|`` [mm] measured at build (the
        exact reference refined as in :meth:`reference_clearances`).
    error_sample_count : dict
        Surface name -> number of measured points within 2 mm of it.
    far_error_bound : float
        [mm] The same (measured maximum times 1.5) for points inside the grid
        farther than 2 mm from a surface, where the blade values come from
        the coarse grid: tens of micrometres up to 3-5 mm, about 0.1-0.2 mm
        beyond.
    exact_method_excess : float
        [mm] How far ``ExactChannelDistance`` was from the refined reference
        on the measured points (where its closest-point solvers stop short).
    build_seconds : float
        Time of the build (0 when loaded from the cache).
    stats : dict
        Figures of the build: grid shape and spacing, fractions of solved
        nodes and of nodes left to the exact solver, stage times [s].

    Notes
    -----
    Memory: two float32 per node; the default blisk at 0.1 mm has 345 x 245 x
    305 nodes (197 MB). The numba kernels run on numba's threads for the
    build (``numba.set_num_threads``) and on one thread for queries.
    """

    def __init__(self, blisk, spacing=0.1, cache_dir=None, cache_key=None, *, band=2.7,
                 curvature_tol=0.024, edge_curvature_tol=0.016, error_samples=1500):
        self.blisk = blisk
        self.spacing = float(spacing)
        self.band = float(band)
        self.curvature_tol = float(curvature_tol)
        self.edge_curvature_tol = float(edge_curvature_tol)
        self._cp_s, self._tu_s, self._tv_s = _face_arrays(blisk.suction_face)
        self._cp_p, self._tu_p, self._tv_p = _face_arrays(blisk.pressure_face)
        self._hub_xb, self._hub_c, self._hub_b = _profile_arrays(blisk.hub)
        self._sh_xb, self._sh_c, self._sh_b = _profile_arrays(blisk.shroud)
        self._fingerprint = self._geometry_fingerprint()
        self.build_seconds = 0.0
        path = self._cache_path(cache_dir, cache_key)
        if path is not None and self._load(path):
            _log.info("fast field: loaded %s", path)
            return
        # one build per field and machine: processes that need the same field at once (the planner and
        # the checker starting together, the set designer's workers) wait for the one building it
        with _build_lock(path):
            if path is not None and self._load(path):
                _log.info("fast field: loaded %s (built by another process meanwhile)", path)
                return
            t = time.perf_counter()
            self._build()
            self._measure_error(error_samples)
            self.build_seconds = time.perf_counter() - t
            _log.info("fast field: built in %.2f s, grid %s, error bound %.2e mm",
                      self.build_seconds, self._grid.shape[:3], self.error_bound)
            if path is not None:
                self._save(path)

    # -- building ------------------------------------------------------------
    def _geometry_fingerprint(self):
        h = hashlib.sha256()
        for a in (self._cp_s, self._tu_s, self._tv_s, self._cp_p, self._tu_p, self._tv_p,
                  self._hub_xb, self._hub_c, self._hub_b, self._sh_xb, self._sh_c, self._sh_b):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(np.float64(self.blisk.pitch).tobytes())
        h.update(json.dumps([CACHE_VERSION, self.spacing, self.band, self.curvature_tol,
                             self.edge_curvature_tol]).encode())
        return h.hexdigest()

    def _layout(self):
        """Grid extents: the float and integer parameter vectors of the kernels."""
        b = self.blisk
        h = self.spacing
        coarse = 4
        x0, x1 = b.axial_range
        xs = np.linspace(x0 - 4.0, x1 + 4.0, 800)
        r_lo = float(b.hub.radius_at(xs).min()) - 1.0
        r_hi = float(b.shroud.radius_at(xs).max()) + 1.0
        uu, vv = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 101))
        th_s = b.suction_face.surface.evaluate(uu, vv)
        th_p = b.pressure_face.surface.evaluate(uu, vv)
        fx = np.concatenate([th_s[..., 0].ravel(), th_p[..., 0].ravel()])
        fr = np.concatenate([np.hypot(th_s[..., 1], th_s[..., 2]).ravel(),
                             np.hypot(th_p[..., 1], th_p[..., 2]).ravel()])
        t_lo = float(np.arctan2(th_s[..., 2], th_s[..., 1]).min()) - 3.0 / r_lo
        t_hi = float(np.arctan2(th_p[..., 2], th_p[..., 1]).max()) + b.pitch + 3.0 / r_lo
        r_mid = 0.5 * (r_lo + r_hi)
        nx, hx = _axis(x0 - 4.0, x1 + 4.0, h, coarse)
        nr, hr = _axis(r_lo, r_hi, h, coarse)
        nt, ht = _axis(t_lo, t_hi, h / r_mid, coarse)
        # hub/shroud table: longer in x, so that an electrode leaving the channel axially (its far end
        # an electrode length past the blades) stays in it
        ext = max(10.0, 1.25 * (x1 - x0))
        nhx, hhx = _axis(x0 - 4.0 - ext, x1 + 4.0 + ext, h, 1)
        nhr, hhr = _axis(r_lo, r_hi, h, 1)
        fp = np.zeros(_NPAR)
        fp[[_X0, _HX, _R0, _HR, _T0, _HT]] = x0 - 4.0, hx, r_lo, hr, t_lo, ht
        fp[_PITCH] = b.pitch
        fp[_TC] = 0.5 * (t_lo + t_hi)
        fp[[_HX0, _HHX, _HR0, _HHR]] = x0 - 4.0 - ext, hhx, r_lo, hhr
        fp[[_FX0, _FX1, _FR0, _FR1]] = fx.min() - 0.01, fx.max() + 0.01, fr.min() - 0.01, fr.max() + 0.01
        fp[[_IHX, _IHR, _IHT, _IHHX, _IHHR]] = 1.0 / hx, 1.0 / hr, 1.0 / ht, 1.0 / hhx, 1.0 / hhr
        # a coarse cell's diagonal: how far apart two of its corners' closest points may lie
        fp[_JUMP] = coarse * math.sqrt(hx ** 2 + hr ** 2 + r_hi ** 2 * ht ** 2)
        for k, face in enumerate((b.suction_face, b.pressure_face)):
            s_u, s_v = face.surface.derivatives(*np.meshgrid(np.linspace(0, 1, 21), np.linspace(0, 1, 21)))
            fp[_SCALE + 2 * k] = np.linalg.norm(s_u, axis=-1).mean()
            fp[_SCALE + 2 * k + 1] = np.linalg.norm(s_v, axis=-1).mean()
        ip = np.zeros(_NIPAR, dtype=np.int64)
        ip[[_NX, _NR, _NT, _COARSE]] = nx, nr, nt, coarse
        ip[[_NCX, _NCR, _NCT]] = (nx - 1) // coarse + 1, (nr - 1) // coarse + 1, (nt - 1) // coarse + 1
        ip[[_NHX, _NHR]] = nhx, nhr
        return fp, ip

    def _xr_starts(self, n=64):
        """The starts of ``BladeFace.uv_at``: n x n face samples in (x, r) scaled by their extent.

        The footprint test must start where the exact method starts (see
        ``_exact_blade``); this repeats ``BladeFace``'s sampling.

        Returns
        -------
        samples : (2, n*n, 2) float
            Scaled (x, r) of the suction and the pressure face's samples.
        uv : (2, n*n, 2) float
        scale : (2, 2) float
        box, start, items
            Bins of the samples for ``_nearest_start``.
        """
        samples = np.empty((2, n * n, 2))
        uv = np.empty((2, n * n, 2))
        scale = np.empty((2, 2))
        nb = n // 2                                   # bins of the nearest-sample search
        box = np.empty((2, 4))
        start = np.empty((2, nb * nb + 1), dtype=np.int64)
        items = np.empty((2, n * n), dtype=np.int64)
        uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
        for k, face in enumerate((self.blisk.suction_face, self.blisk.pressure_face)):
            pts = face.surface.evaluate(uu, vv).reshape(-1, 3)
            xr = np.column_stack([pts[:, 0], np.hypot(pts[:, 1], pts[:, 2])])
            scale[k] = np.ptp(xr, axis=0) + 1e-9
            samples[k] = xr / scale[k]
            uv[k] = np.column_stack([uu.ravel(), vv.ravel()])
            lo = samples[k].min(axis=0)
            size = (samples[k].max(axis=0) - lo) / nb + 1e-12
            box[k] = lo[0], lo[1], size[0], size[1]
            cell = np.minimum(((samples[k] - lo) / size).astype(np.int64), nb - 1)
            bins = cell[:, 0] * nb + cell[:, 1]
            items[k] = np.argsort(bins, kind="stable")
            start[k] = np.searchsorted(bins[items[k]], np.arange(nb * nb + 1))
        return samples, uv, scale, box, start, items

    @staticmethod
    def _face_seeds(face, points, near_cut):
        """Global starts for Newton: the nearest sample of the face.

        A 32 x 32 sampling first; points whose distance to it is below
        ``near_cut`` plus that sampling's gap get the nearest of a 96 x 96
        sampling instead.

        Returns
        -------
        uv : (m, 2) float
        far : (m,) bool
            Certainly farther than ``near_cut`` from the face.
        """
        def sampling(n):
            uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
            s = face.surface.evaluate(uu, vv)
            diag = np.maximum(np.linalg.norm(s[1:, 1:] - s[:-1, :-1], axis=-1),
                              np.linalg.norm(s[1:, :-1] - s[:-1, 1:], axis=-1))
            # no face point lies farther than ``gap`` from a sample
            return np.column_stack([uu.ravel(), vv.ravel()]), s.reshape(-1, 3), 0.6 * float(diag.max())

        uv_c, s_c, gap_c = sampling(32)
        workers = numba.get_num_threads()
        dist, idx = cKDTree(s_c).query(points, workers=workers)
        uv = uv_c[idx]
        near = dist < near_cut + gap_c
        uv_f, s_f, _ = sampling(96)
        _, idx_f = cKDTree(s_f).query(points[near], workers=workers)
        uv[near] = uv_f[idx_f]
        return uv, ~near

    def _build(self):
        b = self.blisk
        times = {}
        t = time.perf_counter()
        fp, ip = self._layout()
        nx, nr, nt, C = (int(v) for v in ip[[_NX, _NR, _NT, _COARSE]])
        ncx, ncr, nct = (int(v) for v in ip[[_NCX, _NCR, _NCT]])
        xg = fp[_X0] + fp[_HX] * np.arange(nx)
        rg = fp[_R0] + fp[_HR] * np.arange(nr)
        tg = fp[_T0] + fp[_HT] * np.arange(nt)
        faces = (b.suction_face, b.pressure_face)
        kern = (self._cp_s, self._tu_s, self._tv_s, self._cp_p, self._tu_p, self._tv_p)

        # 1. per (x, r): both faces' angles and the footprint (the sign rule)
        X, R = np.meshgrid(xg, rg, indexing="ij")
        seeds = np.empty((nx * nr, 2, 2))
        xr_s, xr_uv, xr_scale = self._xr_starts()[:3]
        for k in range(2):
            _, idx = cKDTree(xr_s[k]).query(np.column_stack([X.ravel() / xr_scale[k, 0], R.ravel() / xr_scale[k, 1]]),
                                            workers=numba.get_num_threads())
            seeds[:, k] = xr_uv[k, idx]
        line_uv, line_theta, line_inside = _fill_lines(*kern, X.ravel(), R.ravel(), seeds)
        line_uv = line_uv.reshape(nx, nr, 2, 2)
        line_theta = line_theta.reshape(nx, nr, 2)
        line_inside = line_inside.reshape(nx, nr, 2)
        times["lines_s"] = time.perf_counter() - t

        # 2. coarse nodes: global closest points from a dense sampling, then Newton
        t = time.perf_counter()
        cX, cR, cT = np.meshgrid(xg[::C], rg[::C], tg[::C], indexing="ij")
        cseeds = np.empty((ncx, ncr, nct, 2, 2))
        cfar = np.empty((ncx, ncr, nct, 2), dtype=bool)
        diag = fp[_JUMP]
        for k, face in enumerate(faces):
            pts = cylindrical_to_cartesian(cX, cR, cT - k * b.pitch).reshape(-1, 3)
            # corners of far cells next to solved ones lie within band + diag: those get the fine starts
            uv, far = self._face_seeds(face, pts, self.band + diag + 0.1)
            cseeds[..., k, :] = uv.reshape(ncx, ncr, nct, 2)
            cfar[..., k] = far.reshape(ncx, ncr, nct)
        coarse_values, coarse_uv, coarse_xyz = _fill_coarse(*kern, fp, ip, line_theta, line_inside, cseeds, cfar)
        kind = _classify_coarse(coarse_values, coarse_xyz, coarse_uv, fp, ip, self.band, 1.5 * diag, 0.35)
        times["coarse_s"] = time.perf_counter() - t

        # 3. fine nodes: solved near the faces, interpolated far from them
        t = time.perf_counter()
        grid = np.empty((nx, nr, nt, 2), dtype=np.float32)
        edge = np.empty((nx, nr, nt, 2), dtype=np.uint8)
        scales = fp[_SCALE:_SCALE + 4].copy()
        solved, rechecked = _fill_fine(*kern, fp, ip, line_theta, line_inside, coarse_values, coarse_uv, kind,
                                       scales, diag, grid, edge)
        times["fine_s"] = time.perf_counter() - t
        t = time.perf_counter()
        flagged = _flag_nodes(grid, edge, fp, ip, self.curvature_tol, self.edge_curvature_tol,
                              ACCURATE_WITHIN + 0.25, 0.05)
        del edge
        times["flag_s"] = time.perf_counter() - t

        # 4. hub and shroud: the exact profile distance on an (x, r) table
        t = time.perf_counter()
        nhx, nhr = int(ip[_NHX]), int(ip[_NHR])
        hs = np.empty((nhx, nhr, 2), dtype=np.float32)
        table = (fp[_HX0], fp[_HHX], nhx, fp[_HR0], fp[_HHR], nhr)
        hs[..., 0] = _fill_profile_table(self._hub_xb, self._hub_c, self._hub_b, 1.0, *table)
        hs[..., 1] = _fill_profile_table(self._sh_xb, self._sh_c, self._sh_b, -1.0, *table)
        times["hub_shroud_s"] = time.perf_counter() - t

        self._fp, self._ip = fp, ip
        self._grid = grid
        self._hs = hs
        self._line_uv = np.ascontiguousarray(line_uv)
        self._coarse_uv = np.ascontiguousarray(coarse_uv)
        self._kind = kind
        self._line_theta = np.ascontiguousarray(line_theta)
        self._line_inside = np.ascontiguousarray(line_inside)
        nodes = 2.0 * nx * nr * nt
        self.stats = {
            "grid_shape": [nx, nr, nt],
            "grid_spacing_mm": [float(fp[_HX]), float(fp[_HR]), float(fp[_HT] * (fp[_R0] + 0.5 * (nr - 1) * fp[_HR]))],
            "grid_megabytes": round(grid.nbytes / 2**20, 1),
            "solved_node_fraction": round(solved / nodes, 4),
            "ambiguous_cell_fraction": round(float((kind == 2).mean()), 4),
            "restarted_node_fraction": round(rechecked / nodes, 4),
            "exact_fallback_node_fraction": round(flagged / nodes, 4),
            "hub_shroud_table_shape": [nhx, nhr],
            **{k: round(v, 3) for k, v in times.items()},
        }

    # -- queries ---------------------------------------------------------------
    def _kernel_args(self, channel=0):
        """The arrays the numba kernels take: (flat grid, flat hub/shroud table, fp tuple, ip tuple, fp, ip, slow)."""
        if getattr(self, "_xr_cache", None) is None:
            self._xr_cache = self._xr_starts()
        slow = (self._cp_s, self._tu_s, self._tv_s, self._cp_p, self._tu_p, self._tv_p, self._line_uv,
                self._coarse_uv, self._kind, self._line_theta, self._line_inside, self._hub_xb, self._hub_c,
                self._hub_b, self._sh_xb, self._sh_c, self._sh_b) + self._xr_cache
        fpt = self._fp.copy()
        angle = self._fp[_TC] + channel * self.blisk.pitch
        fpt[_CA], fpt[_SA] = math.cos(angle), math.sin(angle)
        return (self._grid.reshape(-1), self._hs.reshape(-1), tuple(float(v) for v in fpt),
                tuple(int(v) for v in self._ip), self._fp, self._ip, slow)

    def clearances(self, points, channel=0):
        """Signed distances of points in W to channel k's four surfaces.

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        (n, 4) float
            [mm], columns in the order of ``SURFACES``; within ``error_bound``
            of ``ExactChannelDistance.clearances`` for points within 2 mm of a
            surface, a lower bound of it outside the grid.
        """
        return self._points(points, channel, 0)

    def _points(self, points, channel, mode):
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must be (n, 3), got {p.shape}")
        return _points_kernel(p, float(channel) * self.blisk.pitch, mode, *self._kernel_args(channel))

    def pose_clearances(self, poses, points, channel=0):
        """Per pose and surface: the minimum signed distance over the electrode points.

        Transform, lookup and minimum run in one numba loop (no (P, M, 3)
        temporaries).

        Parameters
        ----------
        poses : (P, 4, 4) float
            Electrode frame -> W.
        points : (M, 3) float
            In the electrode frame [mm].
        channel : int

        Returns
        -------
        minimum : (P, 4) float
            [mm], columns in the order of ``SURFACES``.
        argmin : (P, 4) int
            Index of the electrode point that attains it.
        """
        poses = np.ascontiguousarray(np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4))
        pts = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise ValueError(f"pose_clearances: points must be (M, 3) with M >= 1, got {pts.shape}")
        return _pose_kernel(poses, pts, float(channel) * self.blisk.pitch, *self._kernel_args(channel))

    def exact_pose_clearances(self, poses, points, channel=0):
        """Per pose and surface: the exact minimum signed distance over the electrode points.

        The field prunes (``_exact_pose_kernel``): only points whose field value
        is within the field's error bounds of the smallest exact value found
        are solved exactly, by the numba solvers of ``exact_blade_distances``
        and ``exact_profile_distances``; the result is the exact minimum over
        all points.

        Parameters
        ----------
        poses : (P, 4, 4) float
            Electrode frame -> W.
        points : (M, 3) float
            In the electrode frame [mm].
        channel : int

        Returns
        -------
        minimum : (P, 4) float
            [mm], columns in the order of ``SURFACES``.
        argmin : (P, 4) int
        solved : (P,) int
            Exact solves per pose (the pruning's cost).
        """
        poses = np.ascontiguousarray(np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4))
        pts = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise ValueError(f"exact_pose_clearances: points must be (M, 3) with M >= 1, got {pts.shape}")
        far = float(getattr(self, "far_error_bound", np.inf))
        far = max(far, self.error_bound) if np.isfinite(far) else np.inf     # unknown: prune nothing
        return _exact_pose_kernel(poses, pts, float(channel) * self.blisk.pitch, float(self.error_bound), far,
                                  *self._kernel_args(channel))

    def exact_blade_feet(self, points, channel=0):
        """Exact signed distances to the two walls (as ``exact_blade_distances``) and their closest points.

        Returns
        -------
        distances : (n, 2) float
            [mm], suction and pressure wall.
        feet : (n, 2, 3) float
            The closest points on the walls, in W [mm].
        """
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        args = self._kernel_args(channel)
        dist, uv = _exact_blade_feet(p, float(channel) * self.blisk.pitch, *args[4:])
        feet = np.empty((len(p), 2, 3))
        for face, cp in enumerate((self.blisk.suction_face, self.blisk.pressure_face)):
            s = cp.surface
            local = spline_surface_eval(s.control_points, s.knots_u, s.knots_v, uv[:, face, 0], uv[:, face, 1])[:, 0]
            # blade 0's face -> the wall of channel k (the pressure wall is blade k+1's)
            feet[:, face] = local @ rotation_about_x((channel + face) * self.blisk.pitch)[:3, :3].T
        return dist, feet

    def fast_path(self, points, channel=0):
        """Which points are answered from the tables alone (no exact solve, inside the hub/shroud table).

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        (n,) bool
        """
        return self._points(points, channel, 2)[:, 0] > 0.5

    def inside_grid(self, points, channel=0):
        """Which points lie inside the blade grid (elsewhere the blade values are lower bounds).

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.

        Returns
        -------
        (n,) bool
        """
        p = np.atleast_2d(np.asanyarray(points, dtype=np.float64))
        (x0, x1), (r0, r1), (t0, t1) = self.grid_bounds
        rho = np.hypot(p[:, 1], p[:, 2])
        th = np.arctan2(p[:, 2], p[:, 1]) - channel * self.blisk.pitch
        th -= 2 * np.pi * np.floor((th - self._fp[_TC] + np.pi) / (2 * np.pi))
        return (p[:, 0] >= x0) & (p[:, 0] <= x1) & (rho >= r0) & (rho <= r1) & (th >= t0) & (th <= t1)

    @property
    def grid_bounds(self):
        """((x_min, x_max), (r_min, r_max), (theta_min, theta_max)) of the blade grid [mm, rad], channel 0."""
        fp, ip = self._fp, self._ip
        return tuple((fp[o], fp[o] + (ip[n] - 1) * fp[h])
                     for o, h, n in ((_X0, _HX, _NX), (_R0, _HR, _NR), (_T0, _HT, _NT)))

    # -- error measurement -------------------------------------------------------
    def error_sample_points(self, n=1500, seed=0):
        """Random points within 2 mm of channel 0's surfaces, for the error measurement.

        Per surface ``n`` points at -0.5 ... 2 mm from it (nominal; on both
        sides: a shallow penetration must be seen as well), spread over the
        channel, and ``n`` points within 2 mm of the leading and trailing
        edges of blades 0 and 1 (all around the edge).

        Returns
        -------
        (m, 3) float
            Points in W [mm].
        """
        b = self.blisk
        rng = np.random.default_rng(seed)
        x0, x1 = b.full_span_axial_range
        out = []
        x = rng.uniform(x0, x1, 4 * n)
        hub, shr = b.hub.radius_at(x), b.shroud.radius_at(x)
        r = hub + rng.uniform(0.02, 0.98, 4 * n) * (shr - hub)
        th_s, th_p, inside = b.wall_angles(x, r)
        delta = rng.uniform(-0.5, 2.0, 4 * n)
        frac = rng.uniform(0, 1, 4 * n)
        th_any = th_s + frac * (th_p - th_s)
        sl = [slice(k * n, (k + 1) * n) for k in range(4)]
        out.append(cylindrical_to_cartesian(x[sl[0]], r[sl[0]], th_s[sl[0]] + delta[sl[0]] / r[sl[0]]))
        out.append(cylindrical_to_cartesian(x[sl[1]], r[sl[1]], th_p[sl[1]] - delta[sl[1]] / r[sl[1]]))
        out.append(cylindrical_to_cartesian(x[sl[2]], hub[sl[2]] + delta[sl[2]], th_any[sl[2]]))
        out.append(cylindrical_to_cartesian(x[sl[3]], shr[sl[3]] - delta[sl[3]], th_any[sl[3]]))
        # around the edges: balls of 2 mm about the faces' leading and trailing edge lines
        v = rng.uniform(0.03, 0.97, n)
        u = rng.integers(0, 2, n).astype(float)
        edge = b.suction_face.surface.evaluate(u, v)
        ex, er, et = edge[:, 0], np.hypot(edge[:, 1], edge[:, 2]), np.arctan2(edge[:, 2], edge[:, 1])
        et = et + b.pitch * rng.integers(0, 2, n)          # blade 0 or blade 1
        d = rng.normal(size=(n, 3))
        d *= (rng.uniform(0, 1, n) ** (1 / 3) * 2.0 / np.linalg.norm(d, axis=1))[:, None]
        out.append(cylindrical_to_cartesian(ex, er, et) + d)
        return np.concatenate(out)

    def exact_blade_distances(self, points, channel=0):
        """Exact signed distances to the two blade walls by the numba solver (no grid).

        The same sign rule and the same surfaces as ``ExactChannelDistance``;
        the closest point from the coarse grid's closest points, Newton with
        an active set on the face's edges.

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        (n, 2) float
            [mm], suction and pressure wall.
        """
        return self._points(points, channel, 1)[:, :2]

    def behind_walls(self, points, channel=0):
        """Which points lie behind the suction / pressure wall: the sign of ``exact_blade_distances`` alone.

        Far cheaper than the distances (no closest point): the face's angle at
        the point's (x, r) from the (x, r) lines, Newton where they cannot decide.

        Returns
        -------
        (n, 2) bool
            True where the exact signed distance to that wall is negative.
        """
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        return _behind_kernel(p, float(channel) * self.blisk.pitch, *self._kernel_args(channel)[4:])

    def kernel_args(self, channel=0):
        """What numba callers pass on for channel k: ``(channel_angle, flat, hs, fpt, ipt, fp, ip, slow)``.

        ``_fast_point(x, y, z, flat, hs, fpt, ipt)`` answers from the tables,
        ``_exact_at(s, x, y, z, channel_angle, fp, ip, slow, work)`` and
        ``_behind_at(face, ...)`` solve exactly (``work = new_work()``).
        """
        return (float(channel) * self.blisk.pitch,) + self._kernel_args(channel)

    def exact_profile_distances(self, points):
        """Exact signed distances to the hub and the shroud by the numba profile solver (no table).

        Returns
        -------
        (n, 2) float
            [mm], hub and shroud.
        """
        return self._points(points, 0, 1)[:, 2:]

    def reference_clearances(self, points, channel=0, exact=None):
        """The best known signed distances: ``ExactChannelDistance``, refined by the numba solvers.

        Every closest-point solver returns the distance to an actual surface
        point, an upper bound of the true distance; where a numba solver finds
        a closer point than the exact method (``BladeFace.closest_points`` can
        stop short of the minimum when the closest point lies on an edge of
        the face, ``ProfileDistance.signed`` when it lies on the kink at an end
        of the profile), its distance is taken, with the exact method's sign.

        Returns
        -------
        reference : (n, 4) float
            [mm], columns in the order of ``SURFACES``.
        exact : (n, 4) float
            ``ExactChannelDistance.clearances`` unchanged.
        """
        exact = exact or ExactChannelDistance(self.blisk)
        ref = exact.clearances(points, channel)
        mine = self._points(points, channel, 1)
        closer = (np.abs(mine) < np.abs(ref)) & (np.sign(mine) == np.sign(ref))
        return np.where(closer, mine, ref), ref

    def _measure_error(self, n):
        # near the surfaces, and (for the far-field figure) anywhere in the grid
        (x0, x1), (r0, r1), (t0, t1) = self.grid_bounds
        rng = np.random.default_rng(1)
        anywhere = cylindrical_to_cartesian(rng.uniform(x0, x1, n), rng.uniform(r0, r1, n), rng.uniform(t0, t1, n))
        pts = np.concatenate([self.error_sample_points(n), anywhere])
        ref, raw = self.reference_clearances(pts)
        got = self.clearances(pts)
        err = np.abs(got - ref)
        # outside the grid the values are lower bounds by design, not approximations
        inside = self.inside_grid(pts)[:, None]
        far = (np.abs(ref) > ACCURATE_WITHIN) & inside
        self.far_error_bound = 1.5 * float(err[far].max(initial=0.0))
        near = (np.abs(ref) <= ACCURATE_WITHIN) & inside
        self.measured_max_error = {name: float(err[near[:, k], k].max(initial=0.0))
                                   for k, name in enumerate(SURFACES)}
        self.error_sample_count = {name: int(near[:, k].sum()) for k, name in enumerate(SURFACES)}
        # how far BladeFace.closest_points stopped short of the minimum on these points (for the record)
        self.exact_method_excess = float(np.abs(raw - ref)[near].max(initial=0.0))
        # float32 storage: half an ulp of the largest stored value within the band
        quantum = float(np.spacing(np.float32(ACCURATE_WITHIN + 1.0))) / 2
        self.error_bound = 1.5 * max(self.measured_max_error.values()) + quantum

    # -- cache -------------------------------------------------------------------
    def _cache_path(self, cache_dir, cache_key):
        if cache_dir is None or not cache_key:
            return None
        key = str(cache_key)
        if not re.fullmatch(r"[A-Za-z0-9_.\-]{1,100}", key):
            key = hashlib.sha256(key.encode()).hexdigest()
        return pathlib.Path(cache_dir) / f"{key}.fast_field.s{self.spacing:g}.npz"

    _ARRAYS = ("_fp", "_ip", "_grid", "_hs", "_line_uv", "_coarse_uv", "_kind", "_line_theta", "_line_inside")

    def _save(self, path):
        meta = {"version": CACHE_VERSION, "fingerprint": self._fingerprint,
                "error_bound": self.error_bound, "measured_max_error": self.measured_max_error,
                "exact_method_excess": self.exact_method_excess, "far_error_bound": self.far_error_bound,
                "error_sample_count": self.error_sample_count, "stats": self.stats,
                "build_seconds": self.build_seconds}
        tmp = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
            with os.fdopen(fd, "wb") as f:
                np.savez(f, meta=np.array(json.dumps(meta)),
                         **{name.lstrip("_"): getattr(self, name) for name in self._ARRAYS})
            os.replace(tmp, path)          # atomic: a reader sees the old file or the new one
            tmp = None
        except OSError as exc:
            _log.warning("fast field: cannot write the cache %s: %s", path, exc)
        finally:
            if tmp is not None and os.path.exists(tmp):
                os.unlink(tmp)

    def _load(self, path):
        """Load the arrays from ``path``; False (and a rebuild) if missing, stale or corrupt."""
        if not path.is_file():
            return False
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                if meta.get("version") != CACHE_VERSION or meta.get("fingerprint") != self._fingerprint:
                    _log.info("fast field: cache %s is for another geometry or version; rebuilding", path)
                    return False
                arrays = {name: data[name.lstrip("_")] for name in self._ARRAYS}
            fp, ip = arrays["_fp"], arrays["_ip"]
            if fp.shape != (_NPAR,) or ip.shape != (_NIPAR,) or ip.dtype != np.int64:
                raise ValueError("parameter vectors")
            nx, nr, nt = (int(v) for v in ip[[_NX, _NR, _NT]])
            ncx, ncr, nct = (int(v) for v in ip[[_NCX, _NCR, _NCT]])
            expect = {"_grid": ((nx, nr, nt, 2), np.float32), "_hs": ((int(ip[_NHX]), int(ip[_NHR]), 2), np.float32),
                      "_line_uv": ((nx, nr, 2, 2), np.float64), "_coarse_uv": ((ncx, ncr, nct, 2, 2), np.float64),
                      "_kind": ((ncx - 1, ncr - 1, nct - 1, 2), np.uint8),
                      "_line_theta": ((nx, nr, 2), np.float64), "_line_inside": ((nx, nr, 2), np.bool_)}
            for name, (shape, dtype) in expect.items():
                if arrays[name].shape != shape or arrays[name].dtype != dtype:
                    raise ValueError(f"{name}: {arrays[name].shape} {arrays[name].dtype}, expected {shape}")
            ref_fp, ref_ip = self._layout()
            if not (np.array_equal(ip, ref_ip) and np.allclose(fp, ref_fp, rtol=0, atol=1e-9)):
                raise ValueError("grid layout differs")
            error_bound = float(meta["error_bound"])
            measured = {k: float(meta["measured_max_error"][k]) for k in SURFACES}
            if not (np.isfinite(error_bound) and error_bound >= 0):
                raise ValueError("error bound")
        except Exception as exc:     # noqa: BLE001 -- any unreadable cache means: rebuild
            _log.warning("fast field: cache %s unusable (%s); rebuilding", path, exc)
            return False
        for name, value in arrays.items():
            setattr(self, name, np.ascontiguousarray(value))
        self.error_bound = error_bound
        self.measured_max_error = measured
        self.error_sample_count = meta.get("error_sample_count", {})
        self.exact_method_excess = float(meta.get("exact_method_excess", float("nan")))
        self.far_error_bound = float(meta.get("far_error_bound", float("nan")))
        self.stats = dict(meta.get("stats", {}), loaded_from=str(path))
        return True
