"""Bicubic B-spline faces in numba: evaluation, closest points, meridional inversion.

scipy's BSpline / NdBSpline cannot be called from numba code, so this small
evaluator of a clamped cubic tensor-product B-spline is written out here
(Piegl & Tiller, The NURBS Book, A2.1 and eq. 2.5, 2.9). It evaluates exactly
the surface of ``nurbs.SplineSurface``: same control net, same knots. On it
sit the point queries every layer needs: the closest point of a face to a
point (Newton with backtracking), and the face's parameters at a meridional
position (x, r). The distance field (``interference.fast``), the exact
verification and the electrode design (``geometry.surfaces.BladeFace``) all
use these kernels; no library offers point projection onto a B-spline
surface callable from numba, hence written by hand.

Control nets are passed by coordinate, (3, nv, nu), contiguous; knots as
clamped cubic vectors. Units: mm.
"""

import math

import numba
import numpy as np

@numba.njit(cache=True)
def find_span(knots, n_ctrl, t):
    """Knot span i with knots[i] <= t < knots[i+1], i in [3, n_ctrl - 1] (clamped cubic)."""
    if t >= knots[n_ctrl]:
        return n_ctrl - 1
    if t <= knots[3]:
        return 3
    lo, hi = 3, n_ctrl
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if t < knots[mid]:
            hi = mid
        else:
            lo = mid
    return lo


@numba.njit(cache=True)
def basis3(t, i, x, out):
    """The 4 non-zero cubic basis functions ``N_{i-3..i}`` at x and their first two derivatives.

    Cox-de Boor written out for degree 3 on the span ``t[i] <= x < t[i+1]``
    (every denominator spans that non-empty interval); ``out`` (3, 4)
    receives ``d^k N_{i-3+j} / dx^k`` in ``out[k, j]``.
    """
    tm2, tm1, t0, t1, t2, t3 = t[i - 2], t[i - 1], t[i], t[i + 1], t[i + 2], t[i + 3]
    # degree 1: N_{i-1,1}, N_{i,1}
    b1 = (x - t0) / (t1 - t0)
    a1 = 1.0 - b1
    # degree 2: N_{i-2,2}, N_{i-1,2}, N_{i,2}
    d1a = t1 - tm1
    d1b = t2 - t0
    ba = a1 / d1a                     # N_{i-1,1} / (t_{i+1} - t_{i-1})
    bb = b1 / d1b                     # N_{i,1} / (t_{i+2} - t_i)
    n2a = (t1 - x) * ba
    n2b = (x - tm1) * ba + (t2 - x) * bb
    n2c = (x - t0) * bb
    # degree 3
    d2a = t1 - tm2
    d2b = t2 - tm1
    d2c = t3 - t0
    aa = n2a / d2a
    ab = n2b / d2b
    ac = n2c / d2c
    out[0, 0] = (t1 - x) * aa
    out[0, 1] = (x - tm2) * aa + (t2 - x) * ab
    out[0, 2] = (x - tm1) * ab + (t3 - x) * ac
    out[0, 3] = (x - t0) * ac
    out[1, 0] = -3.0 * aa
    out[1, 1] = 3.0 * (aa - ab)
    out[1, 2] = 3.0 * (ab - ac)
    out[1, 3] = 3.0 * ac
    # second derivatives: N'_{j,2} = 2 (N_{j,1}/(t_{j+2}-t_j) - N_{j+1,1}/(t_{j+3}-t_{j+1}))
    ca = -2.0 * ba / d2a
    cb = 2.0 * (ba - bb) / d2b
    cc = 2.0 * bb / d2c
    out[2, 0] = -3.0 * ca
    out[2, 1] = 3.0 * (ca - cb)
    out[2, 2] = 3.0 * (cb - cc)
    out[2, 3] = 3.0 * cc


@numba.njit(cache=True)
def new_work():
    """Scratch arrays of one evaluator: (bu, bv, ev)."""
    return (np.empty((3, 4)), np.empty((3, 4)), np.empty((6, 3)))


@numba.njit(cache=True)
def surface_eval(cp, tu, tv, u, v, work):
    """S, S_u, S_v, S_uu, S_uv, S_vv at (u, v) into ``work[2]`` (6, 3).

    ``cp`` is the control net by coordinate, (3, nv, nu): each coordinate's
    4 x 4 block is read row by row from contiguous memory.
    """
    bu, bv, ev = work
    su = find_span(tu, cp.shape[2], u)
    sv = find_span(tv, cp.shape[1], v)
    basis3(tu, su, u, bu)
    basis3(tv, sv, v, bv)
    for c in range(3):
        net = cp[c]
        s00 = s01 = s02 = s10 = s11 = s20 = 0.0
        for j in range(4):
            row = sv - 3 + j
            a0 = a1 = a2 = 0.0
            for i in range(4):
                q = net[row, su - 3 + i]
                a0 += bu[0, i] * q
                a1 += bu[1, i] * q
                a2 += bu[2, i] * q
            s00 += bv[0, j] * a0
            s01 += bv[0, j] * a1
            s02 += bv[0, j] * a2
            s10 += bv[1, j] * a0
            s11 += bv[1, j] * a1
            s20 += bv[2, j] * a0
        ev[0, c] = s00
        ev[1, c] = s01
        ev[2, c] = s10
        ev[3, c] = s02
        ev[4, c] = s11
        ev[5, c] = s20


@numba.njit(cache=True)
def eval_many(cp, tu, tv, u, v):
    out = np.empty((u.shape[0], 6, 3))
    work = new_work()
    for k in range(u.shape[0]):
        surface_eval(cp, tu, tv, min(max(u[k], 0.0), 1.0), min(max(v[k], 0.0), 1.0), work)
        out[k] = work[2]
    return out


def spline_surface_eval(control_points, knots_u, knots_v, u, v):
    """Evaluate a clamped bicubic B-spline surface and its derivatives with the numba evaluator.

    Parameters
    ----------
    control_points : (nv, nu, 3) float
        Control net, ``[j, i]`` with j along v, i along u (as ``SplineSurface``).
    knots_u, knots_v : (nu + 4,), (nv + 4,) float
        Clamped cubic knot vectors.
    u, v : (n,) float
        Parameters in [0, 1] (clipped).

    Returns
    -------
    (n, 6, 3) float
        ``S, S_u, S_v, S_uu, S_uv, S_vv`` at each (u, v) [mm, per unit parameter].
    """
    cp = np.ascontiguousarray(np.moveaxis(np.asarray(control_points, dtype=np.float64), 2, 0))
    u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64).ravel(), np.asarray(v, dtype=np.float64).ravel())
    return eval_many(cp, np.ascontiguousarray(knots_u, dtype=np.float64),
                      np.ascontiguousarray(knots_v, dtype=np.float64),
                      np.ascontiguousarray(u), np.ascontiguousarray(v))



@numba.njit(cache=True)
def project(cp, tu, tv, px, py, pz, u, v, work, tol, max_iter):
    """Closest point of the face to p by Newton's method with backtracking.

    Minimises ``f = |S(u, v) - p|^2`` over [0, 1]^2 from (u, v): full Newton
    where the Hessian is positive definite, Gauss-Newton otherwise; a
    parameter at its bound whose gradient points outwards is held (active
    set); a step is kept only where it does not increase f (halved up to 30
    times otherwise), as in ``BladeFace.closest_points``. Once a Newton step
    would move the surface point by less than ``tol`` [mm], the step's model
    decrease of f is taken and the iteration stops (the error left is of
    third order in the step); Gauss-Newton steps iterate down to 1e-9 mm.
    Where the face curves away from p (the Hessian is not positive definite,
    beyond a centre of curvature) an accepted Gauss-Newton step is doubled
    while that keeps decreasing f. At most ``max_iter`` steps.

    Returns
    -------
    u, v, f : float
        The foot's parameters and the squared distance [mm^2].
    """
    ev = work[2]
    surface_eval(cp, tu, tv, u, v, work)
    dx, dy, dz = ev[0, 0] - px, ev[0, 1] - py, ev[0, 2] - pz
    f = dx * dx + dy * dy + dz * dz
    for _ in range(max_iter):
        sux, suy, suz = ev[1, 0], ev[1, 1], ev[1, 2]
        svx, svy, svz = ev[2, 0], ev[2, 1], ev[2, 2]
        gu = sux * dx + suy * dy + suz * dz
        gv = svx * dx + svy * dy + svz * dz
        a11 = sux * sux + suy * suy + suz * suz
        a12 = sux * svx + suy * svy + suz * svz
        a22 = svx * svx + svy * svy + svz * svz
        h11 = a11 + ev[3, 0] * dx + ev[3, 1] * dy + ev[3, 2] * dz
        h12 = a12 + ev[4, 0] * dx + ev[4, 1] * dy + ev[4, 2] * dz
        h22 = a22 + ev[5, 0] * dx + ev[5, 1] * dy + ev[5, 2] * dz
        fix_u = (u <= 0.0 and gu > 0.0) or (u >= 1.0 and gu < 0.0)
        fix_v = (v <= 0.0 and gv > 0.0) or (v >= 1.0 and gv < 0.0)
        if fix_u and fix_v:
            break
        # Newton on the free parameters where its Hessian is positive definite, else Gauss-Newton
        newton = True
        if fix_u:
            if h22 <= 1e-9 * a22:
                h22 = a22
                newton = False
            du, dv = 0.0, gv / max(h22, 1e-300)
        elif fix_v:
            if h11 <= 1e-9 * a11:
                h11 = a11
                newton = False
            du, dv = gu / max(h11, 1e-300), 0.0
        else:
            if h11 <= 0.0 or h22 <= 0.0 or h11 * h22 - h12 * h12 <= 1e-9 * (a11 * a22):
                h11, h12, h22 = a11, a12, a22
                newton = False
            det = max(h11 * h22 - h12 * h12, 1e-300)
            du = (h22 * gu - h12 * gv) / det
            dv = (h11 * gv - h12 * gu) / det
        big = max(abs(du), abs(dv))
        if big > 0.1:
            du *= 0.1 / big
            dv *= 0.1 / big
        mx = sux * du + svx * dv
        my = suy * du + svy * dv
        mz = suz * du + svz * dv
        move2 = mx * mx + my * my + mz * mz
        if move2 < 1e-18:
            break
        if newton and move2 < tol * tol and 0.0 <= u - du <= 1.0 and 0.0 <= v - dv <= 1.0:
            f = max(f - (gu * du + gv * dv), 0.0)  # Newton model: f(x - H^-1 g) = f - g.H^-1 g
            u -= du
            v -= dv
            break
        scale = 1.0
        accepted = False
        for _ in range(30):
            un = min(max(u - scale * du, 0.0), 1.0)
            vn = min(max(v - scale * dv, 0.0), 1.0)
            surface_eval(cp, tu, tv, un, vn, work)
            ex, ey, ez = ev[0, 0] - px, ev[0, 1] - py, ev[0, 2] - pz
            fn = ex * ex + ey * ey + ez * ez
            if fn <= f:
                accepted = True
                break
            scale *= 0.5
        if not accepted:
            break
        if not newton and scale == 1.0:
            # the Gauss-Newton model underestimates the step where the face curves away: expand
            tried = False
            while 2.0 * scale * max(abs(du), abs(dv)) <= 0.1:
                tried = True
                uc = min(max(u - 2.0 * scale * du, 0.0), 1.0)
                vc = min(max(v - 2.0 * scale * dv, 0.0), 1.0)
                surface_eval(cp, tu, tv, uc, vc, work)
                cx, cy, cz = ev[0, 0] - px, ev[0, 1] - py, ev[0, 2] - pz
                fc = cx * cx + cy * cy + cz * cz
                if fc >= fn:
                    break
                un, vn, fn, ex, ey, ez = uc, vc, fc, cx, cy, cz
                scale *= 2.0
            if tried:
                surface_eval(cp, tu, tv, un, vn, work)    # derivatives at the accepted point
        moved = max(abs(un - u), abs(vn - v))
        u, v, f = un, vn, fn
        dx, dy, dz = ex, ey, ez
        if moved < 1e-14:
            break
    return u, v, f


@numba.njit(cache=True)
def project_edge(cp, tu, tv, px, py, pz, u, v, work, tol, max_iter):
    """``project``, restarted from inside when it ends on the face's boundary.

    A closest point on an edge of the parameter square can be a constrained
    local minimum while the global one lies just inside (around the leading
    and trailing edge noses); the restart from 0.03 inside the edge finds it.
    """
    u, v, f = project(cp, tu, tv, px, py, pz, u, v, work, tol, max_iter)
    if f > 0.0 and (u <= 0.0 or u >= 1.0 or v <= 0.0 or v >= 1.0):
        u2, v2, f2 = project(cp, tu, tv, px, py, pz, min(max(u, 0.03), 0.97), min(max(v, 0.03), 0.97),
                              work, tol, max_iter)
        if f2 < f:
            return u2, v2, f2
    return u, v, f


@numba.njit(cache=True)
def _meridional_step(ev, x0, r0):
    """Newton step (du, dv) towards (x(u, v), r(u, v)) = (x0, r0) from ``ev``, damped to 0.25, and the residual."""
    r = math.hypot(ev[0, 1], ev[0, 2])
    r_u = (ev[0, 1] * ev[1, 1] + ev[0, 2] * ev[1, 2]) / r
    r_v = (ev[0, 1] * ev[2, 1] + ev[0, 2] * ev[2, 2]) / r
    res0 = ev[0, 0] - x0
    res1 = r - r0
    j00, j01, j10, j11 = ev[1, 0], ev[2, 0], r_u, r_v
    det = j00 * j11 - j01 * j10
    if abs(det) < 1e-300:
        det = 1e-300
    du = (j11 * res0 - j01 * res1) / det
    dv = (-j10 * res0 + j00 * res1) / det
    big = max(abs(du), abs(dv))
    if big > 0.25:
        du *= 0.25 / big
        dv *= 0.25 / big
    return du, dv, math.hypot(res0, res1)


@numba.njit(cache=True)
def _uv_at_descending(cp, tu, tv, x0, r0, u, v, work):
    """``uv_at``'s Newton with every step halved until the residual falls: (u, v, residual).

    Plain Newton can cycle where x(u) bends sharply (a faceted blade's
    trailing-edge rounding: u = 1 and u = 0.97 step onto each other for
    ever); a step that must lower the residual cannot.
    """
    ev = work[2]
    surface_eval(cp, tu, tv, u, v, work)
    du, dv, f = _meridional_step(ev, x0, r0)
    for _ in range(60):
        t = 1.0
        moved = False
        for _ in range(20):
            un = min(max(u - t * du, 0.0), 1.0)
            vn = min(max(v - t * dv, 0.0), 1.0)
            if un == u and vn == v:
                break
            surface_eval(cp, tu, tv, un, vn, work)
            dun, dvn, fn = _meridional_step(ev, x0, r0)
            if fn < f:
                moved = True
                break
            t *= 0.5
        if not moved:
            break
        step = max(abs(un - u), abs(vn - v))
        u, v, du, dv, f = un, vn, dun, dvn, fn
        if step < 1e-11 or f < 1e-12:
            break
    return u, v, f


@numba.njit(cache=True)
def uv_at(cp, tu, tv, x0, r0, u, v, work):
    """Face parameters at a meridional position, as ``BladeFace.uv_at`` (numba).

    Newton on ``(x(u, v), r(u, v)) = (x0, r0)`` with steps damped to 0.25 and
    clipped to [0, 1]. Where it ends off the position (outside, or a Newton
    cycle), a descending Newton from the same start decides
    (``_uv_at_descending``); the first answer stands unless that one lands on
    the position, so every point plain Newton finds keeps its bits.

    Returns
    -------
    u, v : float
    inside : bool
        (x0, r0) lies in the face's meridional footprint (residual < 1e-7 mm).
    theta : float
        Angle of the face point [rad].
    """
    ev = work[2]
    u_start, v_start = u, v
    cycled = True
    for _ in range(30):
        surface_eval(cp, tu, tv, u, v, work)
        du, dv, _ = _meridional_step(ev, x0, r0)
        un = min(max(u - du, 0.0), 1.0)
        vn = min(max(v - dv, 0.0), 1.0)
        stalled = un == u and vn == v
        u, v = un, vn
        if max(abs(du), abs(dv)) < 1e-11 or stalled:
            cycled = False
            break
    surface_eval(cp, tu, tv, u, v, work)
    r = math.hypot(ev[0, 1], ev[0, 2])
    resid = math.hypot(ev[0, 0] - x0, r - r0)
    if resid >= 1e-7 and cycled:
        u2, v2, resid2 = _uv_at_descending(cp, tu, tv, x0, r0, u_start, v_start, work)
        if resid2 < 1e-7:
            u, v, resid = u2, v2, resid2
        surface_eval(cp, tu, tv, u, v, work)
    return u, v, resid < 1e-7, math.atan2(ev[0, 2], ev[0, 1])


@numba.njit(cache=True)
def closest_points_many(cp, tu, tv, points, uv0, tol, max_iter):
    """Closest face points of many points: ``project_edge`` from each start.

    Returns
    -------
    feet : (n, 3) float
    sq_distance : (n,) float
    uv : (n, 2) float
    """
    n = points.shape[0]
    feet = np.empty((n, 3))
    f_out = np.empty(n)
    uv = np.empty((n, 2))
    work = new_work()
    ev = work[2]
    for k in range(n):
        u, v, f = project_edge(cp, tu, tv, points[k, 0], points[k, 1], points[k, 2], uv0[k, 0], uv0[k, 1], work,
                               tol, max_iter)
        surface_eval(cp, tu, tv, u, v, work)
        feet[k, 0], feet[k, 1], feet[k, 2] = ev[0, 0], ev[0, 1], ev[0, 2]
        dx, dy, dz = ev[0, 0] - points[k, 0], ev[0, 1] - points[k, 1], ev[0, 2] - points[k, 2]
        f_out[k] = dx * dx + dy * dy + dz * dz
        uv[k, 0], uv[k, 1] = u, v
    return feet, f_out, uv


@numba.njit(cache=True)
def uv_at_many(cp, tu, tv, x, r, uv0):
    """``uv_at`` for many meridional positions: (uv (n, 2), inside (n,) bool)."""
    n = x.shape[0]
    uv = np.empty((n, 2))
    inside = np.empty(n, dtype=np.bool_)
    work = new_work()
    for k in range(n):
        u, v, ok, _ = uv_at(cp, tu, tv, x[k], r[k], uv0[k, 0], uv0[k, 1], work)
        uv[k, 0], uv[k, 1] = u, v
        inside[k] = ok
    return uv, inside


def kernel_net(surface):
    """(control net by coordinate (3, nv, nu), knots_u, knots_v) of a ``SplineSurface``, contiguous float64."""
    cp = np.ascontiguousarray(np.moveaxis(np.asarray(surface.control_points, dtype=np.float64), 2, 0))
    return (cp, np.ascontiguousarray(surface.knots_u, dtype=np.float64),
            np.ascontiguousarray(surface.knots_v, dtype=np.float64))
