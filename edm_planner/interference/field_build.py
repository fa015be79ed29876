"""Filling the fast field's blade grid (numba).

The blade walls' grid over (x, r, theta) is filled in passes: the closest
points along lines of theta (``_fill_lines``), a coarse grid of global
closest points (``_fill_coarse``, classified by ``_classify_coarse``), the
fine grid near the faces started from them (``_fill_fine``), and the nodes
where trilinear interpolation is not accurate enough marked for the exact
solver (``_flag_nodes``). :func:`build_tables` drives the passes and fills
the hub/shroud table (for :class:`.fast.FastChannelField`, which measures the
error bound, :mod:`.field_error`). Units: mm, rad.
"""

import math
import time

import numba
import numpy as np
from scipy.spatial import cKDTree

from ..geometry.spline_kernels import new_work, project_edge, surface_eval, uv_at
from ..geometry.frames import cylindrical_to_cartesian
from .exact_solvers import _behind, _fill_profile_table, _on_edge, _solve_node
from .field_layout import uv_starts
from .field_params import ACCURATE_WITHIN, NAN_BITS, NODE_QUANTUM, _NEWTON_TOL


@numba.njit(cache=True, parallel=True)
def _fill_lines(cp_s, tu_s, tv_s, cp_p, tu_p, tv_p, xs, rs, seeds):
    """Per (x, r): both faces' (u, v), footprint test and angle.

    Chunks of 1024 points in parallel, each with its own solver scratch (every point is solved on its own:
    the same values on any number of threads).

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
    for chunk in numba.prange(n_chunk):
        work = new_work()
        for k in range(chunk * 1024, min(n, chunk * 1024 + 1024)):
            u, v, in_s, th = uv_at(cp_s, tu_s, tv_s, xs[k], rs[k], seeds[k, 0, 0], seeds[k, 0, 1], work)
            uv[k, 0, 0], uv[k, 0, 1], theta[k, 0] = u, v, th
            u, v, in_p, th = uv_at(cp_p, tu_p, tv_p, xs[k], rs[k], seeds[k, 1, 0], seeds[k, 1, 1], work)
            uv[k, 1, 0], uv[k, 1, 1], theta[k, 1] = u, v, th
            inside[k, 0] = in_s
            inside[k, 1] = in_p
    return uv, theta, inside


@numba.njit(cache=True, parallel=True)
def _fill_coarse(cp_s, tu_s, tv_s, cp_p, tu_p, tv_p, params, shape, line_theta, line_inside, seeds, far):
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
    C = shape.coarse
    ncx, ncr, nct = shape.ncx, shape.ncr, shape.nct
    values = np.empty((ncx, ncr, nct, 2))
    feet_uv = np.empty((ncx, ncr, nct, 2, 2))
    feet_xyz = np.empty((ncx, ncr, nct, 2, 3))
    pitch = params.pitch
    for cx in numba.prange(ncx):
        work = new_work()
        ev = work[2]
        x = params.x0 + cx * C * params.hx
        for cr in range(ncr):
            r = params.r0 + cr * C * params.hr
            for ct in range(nct):
                for face in range(2):
                    th = params.t0 + ct * C * params.ht - face * pitch
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
def _classify_coarse(values, feet_xyz, feet_uv, params, shape, band, spread, turn):
    """Per coarse cell and face: 0 far (interpolate), 1 near (solve), 2 near and ambiguous.

    A cell is far when all 8 corners are more than ``band`` mm from the face and
    the values are consistent with a 1-Lipschitz function along the cell's
    edges (no sign jump inside). It is ambiguous when a medial surface of the
    face may cross it: its corners' closest points lie more than ``spread`` mm
    apart, or their directions to the closest points differ by more than
    ``turn`` rad, or some lie on the face's boundary and others inside it
    (the fine nodes then start from every distinct corner's closest point).
    """
    C = shape.coarse
    ncx, ncr, nct = shape.ncx, shape.ncr, shape.nct
    kind = np.zeros((ncx - 1, ncr - 1, nct - 1, 2), dtype=np.uint8)
    hx, hr, ht = C * params.hx, C * params.hr, C * params.ht
    # unit directions from the closest point to the node (zero on the face)
    dirs = np.zeros((ncx, ncr, nct, 2, 3))
    for cx in range(ncx):
        x = params.x0 + cx * hx
        for cr in range(ncr):
            r = params.r0 + cr * hr
            for ct in range(nct):
                for face in range(2):
                    th = params.t0 + ct * ht - face * params.pitch
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
            rmax = params.r0 + (cr + 1) * hr
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


@numba.njit(cache=True, parallel=True)
def _fill_fine(cp_s, tu_s, tv_s, cp_p, tu_p, tv_p, params, shape, line_theta, line_inside,
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
    nx, nr, nt, C = shape.nx, shape.nr, shape.nt, shape.coarse
    ncx, ncr, nct = shape.ncx, shape.ncr, shape.nct
    pitch = params.pitch
    solved_x = np.zeros(nx, dtype=np.int64)
    rechecked_x = np.zeros(nx, dtype=np.int64)
    for ix in numba.prange(nx):
        work = new_work()
        solved = 0
        rechecked = 0
        x = params.x0 + ix * params.hx
        cx = min(ix // C, ncx - 2)
        wx = (ix - cx * C) / C
        kx = min((ix + C // 2) // C, ncx - 1)
        for ir in range(nr):
            r = params.r0 + ir * params.hr
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
                    th = params.t0 + it * params.ht
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


@numba.njit(cache=True, parallel=True)
def _flag_nodes(grid, edge, params, shape, curvature_tol, edge_curvature_tol, accurate_within, jump_tol,
                carry_within):
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
    edge, and the error can reach a quarter). A marked node becomes a NaN that
    carries its unsigned value where that lies within ``carry_within``
    (``_carrying_nan``). Returns the number of marked (node, face) pairs.
    Both passes run over x planes in parallel: the first writes only its plane's marks from the values as
    built, the second (after all marks) only its plane's NaNs, so any number of threads gives the same bits.
    """
    nx, nr, nt = shape.nx, shape.nr, shape.nt
    mark = np.zeros((nx, nr, nt, 2), dtype=np.uint8)
    hx, hr = params.hx, params.hr
    far = accurate_within + 0.5
    count_x = np.zeros(nx, dtype=np.int64)
    for ix in numba.prange(nx):
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
                        chord_hi = 2.0 * (params.r0 + (ir + 1) * hr) * math.sin(0.5 * params.ht)
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
    bits = grid.view(np.uint32)
    for ix in numba.prange(nx):
        c = 0
        for ir in range(nr):
            for it in range(nt):
                for face in range(2):
                    if mark[ix, ir, it, face]:
                        bits[ix, ir, it, face] = _carrying_nan(grid[ix, ir, it, face], carry_within)
                        c += 1
        count_x[ix] = c
    return count_x.sum()


@numba.njit(cache=True)
def _carrying_nan(value, carry_within):
    """The bits of a quiet NaN that carries a lower bound of ``|value|`` (``field_params.NODE_QUANTUM``).

    Only values within ``carry_within`` mm (solved nodes, not the coarse grid's interpolation) are carried.
    """
    mag = abs(float(value))
    if not mag <= carry_within:
        return np.uint32(NAN_BITS)
    return np.uint32(NAN_BITS | (int(math.floor(mag / NODE_QUANTUM)) + 1))


def face_seeds(face, points, near_cut):
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


def build_tables(blisk, params, shape, splines, hub, shroud, band, curvature_tol, edge_curvature_tol):
    """The field's tables: the blade grid, the hub/shroud table and what the exact solver starts from.

    Parameters
    ----------
    blisk : Blisk
    params : FieldParams
    shape : GridShape
        The layout (:func:`.field_layout.grid_layout`).
    splines : tuple of 6 arrays
        ``face_arrays`` of the suction and then the pressure face.
    hub, shroud : tuple of 3 arrays
        ``profile_arrays`` of the profiles.
    band, curvature_tol, edge_curvature_tol : float
        As :class:`.fast.FastChannelField` takes them.

    Returns
    -------
    tables : dict
        ``grid`` (nx, nr, nt, 2) float32, ``hs`` (nhx, nhr, 2) float32,
        ``line_uv``, ``coarse_uv``, ``kind``, ``line_theta``, ``line_inside``.
    stats : dict
        Figures of the build (fractions of solved and flagged nodes, stage times [s]).
    """
    b = blisk
    times = {}
    t = time.perf_counter()
    nx, nr, nt, C = shape.nx, shape.nr, shape.nt, shape.coarse
    ncx, ncr, nct = shape.ncx, shape.ncr, shape.nct
    xg = params.x0 + params.hx * np.arange(nx)
    rg = params.r0 + params.hr * np.arange(nr)
    tg = params.t0 + params.ht * np.arange(nt)
    faces = (b.suction_face, b.pressure_face)

    # 1. per (x, r): both faces' angles and the footprint (the sign rule)
    X, R = np.meshgrid(xg, rg, indexing="ij")
    seeds = np.empty((nx * nr, 2, 2))
    xr_s, xr_uv, xr_scale = uv_starts(b)[:3]
    for k in range(2):
        _, idx = cKDTree(xr_s[k]).query(np.column_stack([X.ravel() / xr_scale[k, 0], R.ravel() / xr_scale[k, 1]]),
                                        workers=numba.get_num_threads())
        seeds[:, k] = xr_uv[k, idx]
    line_uv, line_theta, line_inside = _fill_lines(*splines, X.ravel(), R.ravel(), seeds)
    line_uv = line_uv.reshape(nx, nr, 2, 2)
    line_theta = line_theta.reshape(nx, nr, 2)
    line_inside = line_inside.reshape(nx, nr, 2)
    times["lines_s"] = time.perf_counter() - t

    # 2. coarse nodes: global closest points from a dense sampling, then Newton
    t = time.perf_counter()
    cX, cR, cT = np.meshgrid(xg[::C], rg[::C], tg[::C], indexing="ij")
    cseeds = np.empty((ncx, ncr, nct, 2, 2))
    cfar = np.empty((ncx, ncr, nct, 2), dtype=bool)
    diag = params.jump
    for k, face in enumerate(faces):
        pts = cylindrical_to_cartesian(cX, cR, cT - k * b.pitch).reshape(-1, 3)
        # corners of far cells next to solved ones lie within band + diag: those get the fine starts
        uv, far = face_seeds(face, pts, band + diag + 0.1)
        cseeds[..., k, :] = uv.reshape(ncx, ncr, nct, 2)
        cfar[..., k] = far.reshape(ncx, ncr, nct)
    coarse_values, coarse_uv, coarse_xyz = _fill_coarse(*splines, params, shape, line_theta, line_inside, cseeds, cfar)
    kind = _classify_coarse(coarse_values, coarse_xyz, coarse_uv, params, shape, band, 1.5 * diag, 0.35)
    times["coarse_s"] = time.perf_counter() - t

    # 3. fine nodes: solved near the faces, interpolated far from them
    t = time.perf_counter()
    grid = np.empty((nx, nr, nt, 2), dtype=np.float32)
    edge = np.empty((nx, nr, nt, 2), dtype=np.uint8)
    scales = np.array([params.scale_su, params.scale_sv, params.scale_pu, params.scale_pv])
    solved, rechecked = _fill_fine(*splines, params, shape, line_theta, line_inside, coarse_values, coarse_uv, kind,
                                   scales, diag, grid, edge)
    times["fine_s"] = time.perf_counter() - t
    t = time.perf_counter()
    flagged = _flag_nodes(grid, edge, params, shape, curvature_tol, edge_curvature_tol, ACCURATE_WITHIN + 0.25, 0.05,
                          ACCURATE_WITHIN)
    del edge
    times["flag_s"] = time.perf_counter() - t

    # 4. hub and shroud: the exact profile distance on an (x, r) table
    t = time.perf_counter()
    nhx, nhr = shape.nhx, shape.nhr
    hs = np.empty((nhx, nhr, 2), dtype=np.float32)
    table = (params.hx0, params.hhx, nhx, params.hr0, params.hhr, nhr)
    hs[..., 0] = _fill_profile_table(*hub, 1.0, *table)
    hs[..., 1] = _fill_profile_table(*shroud, -1.0, *table)
    times["hub_shroud_s"] = time.perf_counter() - t

    nodes = 2.0 * nx * nr * nt
    stats = {
        "grid_shape": [nx, nr, nt],
        "grid_spacing_mm": [params.hx, params.hr, params.ht * (params.r0 + 0.5 * (nr - 1) * params.hr)],
        "grid_megabytes": round(grid.nbytes / 2**20, 1),
        "solved_node_fraction": round(solved / nodes, 4),
        "ambiguous_cell_fraction": round(float((kind == 2).mean()), 4),
        "restarted_node_fraction": round(rechecked / nodes, 4),
        "exact_fallback_node_fraction": round(flagged / nodes, 4),
        "hub_shroud_table_shape": [nhx, nhr],
        **{k: round(v, 3) for k, v in times.items()},
    }
    tables = {"grid": grid, "hs": hs, "line_uv": np.ascontiguousarray(line_uv),
              "coarse_uv": np.ascontiguousarray(coarse_uv), "kind": kind,
              "line_theta": np.ascontiguousarray(line_theta), "line_inside": np.ascontiguousarray(line_inside)}
    return tables, stats
