"""Queries of the fast field (numba): per point, per pose, and the exact minimum per pose.

``_fast_point`` is the fast path (trilinear in the float32 blade grid,
bilinear in the hub/shroud table, lower bounds outside the grid);
``_slow_point`` answers the cells marked for the exact solver and points
outside the hub/shroud table. ``_points_kernel`` loops them over points;
``_pose_kernel`` and ``_posed_kernel`` over (pose, point) pairs, in blocks of
points run in three stages (``_block_cells``: the cells in a loop LLVM
vectorises; ``_block_values``: the loads and interpolation in 4-wide SIMD
(``cell_simd``), with the cells ahead prefetched; then the values, with the
points off the common case answered in full by ``_off_point``), bit for bit
the per-point values; ``_exact_pose_kernel`` prunes by the field and solves
exactly only the points that can attain a pose's minimum. Units: mm, rad.
"""

import math

import numba
import numpy as np

from ..geometry.spline_kernels import new_work
from .field_params import ACCURATE_WITHIN, NODE_QUANTUM, PAYLOAD_MASK, _ATAN, _TWO_PI, named_args
from .exact_solvers import _blade_behind, _exact_blade, _exact_surface, _profile_signed
from .cell_simd import cell_values
from .prefetch import prefetch




@numba.njit(cache=True, inline="always")
def _turned(y, z, params):
    """(rho, y', z'): the radius, and (y, z) turned by minus the grid's middle angle in the query's channel."""
    return math.sqrt(y * y + z * z), y * params.ca + z * params.sa, z * params.ca - y * params.sa


@numba.njit(cache=True, inline="always")
def _grid_coords(x, rho, yr, zr, params):
    """Fractional indices (gx, gr, gt) in the blade grid and (hx, hr) in the hub/shroud table.

    The angle is the arctangent of z'/y' (``_ATAN``'s polynomial, valid for
    |z'| <= y'/2); one definition for the per-point path and the vectorised
    stage, so that both give the same bits. The polynomial in Estrin's form
    (pairs, then pairs of pairs): a chain of 5 multiply-adds instead of
    Horner's 11, which latency bound the vectorised stage (AMD Zen 3: 11.8
    -> 8.7 ns per point for stage 1).
    """
    t = zr / yr
    s2 = t * t
    s4 = s2 * s2
    s8 = s4 * s4
    c = _ATAN
    low = (c[0] + s2 * c[1]) + s4 * (c[2] + s2 * c[3])
    mid = (c[4] + s2 * c[5]) + s4 * (c[6] + s2 * c[7])
    high = (c[8] + s2 * c[9]) + s4 * c[10]
    phi = t * ((low + s8 * mid) + (s8 * s8) * high)
    return ((x - params.x0) * params.ihx, (rho - params.r0) * params.ihr, (phi + (params.tc - params.t0)) * params.iht,
            (x - params.hx0) * params.ihhx, (rho - params.hr0) * params.ihhr)


@numba.njit(cache=True, inline="always")
def _fast_point(x, y, z, flat, hs, params, shape):
    """The fast path: (suction, pressure, hub, shroud, ok); ok False sends the point to ``_slow_point``.

    Trilinear in the blade grid (float32, both walls with shared weights),
    bilinear in the hub/shroud table; outside the blade grid the slow
    path's lower bound from the nearest grid point. Not ok: outside the
    hub/shroud table, or a cell marked for the exact solver (NaN). ``params`` holds the cosine and sine
    of the grid's middle angle turned into the query's channel (``ca``,
    ``sa``).
    """
    # the angle about the grid's middle angle (turned into channel k): (y', z') = R(-a) (y, z)
    rho, yr, zr = _turned(y, z, params)
    if not (yr > 0.0 and abs(zr) <= 0.5 * yr):
        return np.nan, np.nan, np.nan, np.nan, False
    gx, gr, gt, hx, hr = _grid_coords(x, rho, yr, zr, params)
    nan = np.nan
    if not (0.0 <= hx < shape.nhx - 1 and 0.0 <= hr < shape.nhr - 1 and gx == gx and gr == gr and gt == gt):
        return nan, nan, nan, nan, False
    # outside the blade grid (an electrode on its way in or out, past the blades or turned beyond the
    # grid's angles): the slow path's bound max(value at the nearest grid point q - |p - q|, box
    # distance), from the tables alone
    gap = 0.0
    if not (0.0 <= gx < shape.nx - 1 and 0.0 <= gr < shape.nr - 1 and 0.0 <= gt < shape.nt - 1):
        qx = min(max(gx, 0.0), shape.nx - 1.0)
        qr = min(max(gr, 0.0), shape.nr - 1.0)
        qt = min(max(gt, 0.0), shape.nt - 1.0)
        dx = (gx - qx) * params.hx
        rq = params.r0 + qr * params.hr
        half = 0.5 * (gt - qt) * params.ht                 # half the angle between p and q about the axis
        sh = math.sin(half)
        gap = math.sqrt(dx * dx + (rho - rq) * (rho - rq) + 4.0 * rho * rq * sh * sh)
        gx, gr, gt = qx, qr, qt
    ix, ir, it = min(int(gx), shape.nx - 2), min(int(gr), shape.nr - 2), min(int(gt), shape.nt - 2)
    jx, jr = int(hx), int(hr)
    # unsigned indices: no negative-index wrap-around code
    sr, sx, hsr = np.uint64(2 * shape.nt), np.uint64(2 * shape.nt * shape.nr), np.uint64(2 * shape.nhr)
    two = np.uint64(2)
    s, p, h, c = cell_values(flat, np.uint64(ix) * sx + np.uint64(ir) * sr + np.uint64(it) * two, sr, sx,
                             np.float32(gx - ix), np.float32(gr - ir), np.float32(gt - it),
                             hs, np.uint64(jx) * hsr + np.uint64(jr) * two, hsr, np.float32(hx - jx),
                             np.float32(hr - jr))
    if s != s or p != p:
        return nan, nan, nan, nan, False
    sb, pb = float(s), float(p)
    if gap > 0.0:
        ex = max(params.fx0 - x, 0.0, x - params.fx1)
        er = max(params.fr0 - rho, 0.0, rho - params.fr1)
        rect = math.sqrt(ex * ex + er * er)
        sb, pb = max(sb - gap, rect), max(pb - gap, rect)
    return sb, pb, float(h), float(c), True


@numba.njit(cache=True)
def _trilinear(flat, shape, gx, gr, gt, face):
    """Trilinear value of one wall at fractional grid indices inside the grid (float64)."""
    nr, nt = shape.nr, shape.nt
    ix = min(int(gx), shape.nx - 2)
    ir = min(int(gr), nr - 2)
    it = min(int(gt), nt - 2)
    wx, wr, wt = gx - ix, gr - ir, gt - it
    acc = 0.0
    for a in range(8):
        jx, jr, jt = ix + (a & 1), ir + ((a >> 1) & 1), it + ((a >> 2) & 1)
        w = (wx if a & 1 else 1.0 - wx) * (wr if a & 2 else 1.0 - wr) * (wt if a & 4 else 1.0 - wt)
        acc += w * flat[((jx * nr + jr) * nt + jt) * 2 + face]
    return acc


@numba.njit(cache=True, inline="always")
def _slow_parts(x, y, z, channel_angle, flat, hs, params, shape, tables):
    """``_slow_point`` up to its exact solves: (s, p, h, c, xq, rq, tq, th, rho, gap, rect, outside, qx, qr, qt).

    s and p are NaN where the cell is marked for the exact solver (the solve
    is at (xq, rq, tq), the nearest grid point); outside the grid the caller
    takes ``max(value - gap, rect)``.
    """
    rho = math.sqrt(y * y + z * z)
    th = math.atan2(z, y) - channel_angle
    th -= _TWO_PI * math.floor((th - params.tc + math.pi) / _TWO_PI)
    nx, nr, nt = shape.nx, shape.nr, shape.nt
    gx = (x - params.x0) / params.hx
    gr = (rho - params.r0) / params.hr
    gt = (th - params.t0) / params.ht
    outside = not (0.0 <= gx <= nx - 1 and 0.0 <= gr <= nr - 1 and 0.0 <= gt <= nt - 1)
    qx, qr, qt = min(max(gx, 0.0), nx - 1.0), min(max(gr, 0.0), nr - 1.0), min(max(gt, 0.0), nt - 1.0)
    xq = params.x0 + qx * params.hx
    rq = params.r0 + qr * params.hr
    tq = params.t0 + qt * params.ht
    s = _trilinear(flat, shape, qx, qr, qt, 0)
    p = _trilinear(flat, shape, qx, qr, qt, 1)
    gap, rect = 0.0, 0.0
    if outside:
        dx = x - xq
        dy = rho * math.cos(th) - rq * math.cos(tq)
        dz = rho * math.sin(th) - rq * math.sin(tq)
        gap = math.sqrt(dx * dx + dy * dy + dz * dz)
        # the faces lie in [FX0, FX1] x [FR0, FR1] of the (x, r) half-plane: a second lower bound
        ex = max(params.fx0 - x, 0.0, x - params.fx1)
        er = max(params.fr0 - rho, 0.0, rho - params.fr1)
        rect = math.sqrt(ex * ex + er * er)
    hx = (x - params.hx0) / params.hhx
    hr = (rho - params.hr0) / params.hhr
    nhx, nhr = shape.nhx, shape.nhr
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
        h = _profile_signed(tables.hub_xb, tables.hub_c, tables.hub_b, 1.0, x, rho)
        c_ = _profile_signed(tables.shroud_xb, tables.shroud_c, tables.shroud_b, -1.0, x, rho)
    return s, p, h, c_, xq, rq, tq, th, rho, gap, rect, outside, qx, qr, qt


@numba.njit(cache=True)
def _slow_point(x, y, z, channel_angle, flat, hs, params, shape, tables, work):
    """The general path of a query (any point): returns (suction, pressure, hub, shroud).

    Inside the grid: trilinear, or the exact solver in cells marked for it.
    Outside: the conservative lower bound ``max(value at the nearest grid
    point q - |p - q|, distance to the faces' (x, r) bounding box)``. Hub and
    shroud: the table, or the exact profile distance outside it.
    """
    s, p, h, c, xq, rq, tq, _, _, gap, rect, outside, _, _, _ = _slow_parts(x, y, z, channel_angle, flat, hs, params,
                                                                            shape, tables)
    s, p = _slow_walls(s, p, xq, rq, tq, gap, rect, outside, params, shape, tables, work)
    return s, p, h, c


@numba.njit(cache=True, inline="always")
def _slow_walls(s, p, xq, rq, tq, gap, rect, outside, params, shape, tables, work):
    """The walls' values of ``_slow_point`` from ``_slow_parts``: the exact solves, then the bound outside."""
    if s != s:
        s = _exact_blade(0, xq, rq, tq, params, shape, tables, work)
    if p != p:
        p = _exact_blade(1, xq, rq, tq, params, shape, tables, work)
    if outside:
        s = max(s - gap, rect)
        p = max(p - gap, rect)
    return s, p


@numba.njit(cache=True, inline="always")
def _node_magnitude(flat, bits, k):
    """A lower bound of |value| at flat index k of the blade grid [mm], or -1.0 where the node tells none.

    A number within ``ACCURATE_WITHIN`` (solved; less its float32 rounding), or
    the bound a marked node's NaN carries (``field_build._carrying_nan``).
    """
    v = flat[k]
    if v == v:
        m = abs(float(v))
        return m * (1.0 - 2.0 ** -23) if m <= ACCURATE_WITHIN else -1.0
    n = bits[k] & PAYLOAD_MASK
    return (n - 1) * NODE_QUANTUM if n > 0 else -1.0


@numba.njit(cache=True)
def _unsigned_bound(face, flat, bits, shape, params, x, rho, th, qx, qr, qt):
    """A lower bound of the unsigned distance to wall ``face`` at (x, rho, th) inside the grid [mm].

    The unsigned distance is 1-Lipschitz: at least ``|value at node c| - |p - c|``
    for each of the cell's 8 nodes that tells its value (``_node_magnitude``);
    -inf where none does.
    """
    nr, nt = shape.nr, shape.nt
    ix, ir, it = min(int(qx), shape.nx - 2), min(int(qr), nr - 2), min(int(qt), nt - 2)
    best = -np.inf
    for a in range(8):
        jx, jr, jt = ix + (a & 1), ir + ((a >> 1) & 1), it + ((a >> 2) & 1)
        m = _node_magnitude(flat, bits, ((jx * nr + jr) * nt + jt) * 2 + face)
        if m < 0.0:
            continue
        dx = x - (params.x0 + jx * params.hx)
        rc = params.r0 + jr * params.hr
        sh = math.sin(0.5 * (th - (params.t0 + jt * params.ht)))
        best = max(best, m - math.sqrt(dx * dx + (rho - rc) * (rho - rc) + 4.0 * rho * rc * sh * sh))
    return best


@numba.njit(cache=True)
def _points_kernel(points, channel_angle, mode, flat, hs, fast, fast_shape, params, shape, tables):
    """(n, 4) per point: the field (mode 0), the exact solvers (mode 1) or fast-path flags (mode 2).

    Mode 0: the four clearances as ``FastChannelField.clearances``. Mode 1:
    the exact signed distances, numba blade solver and profile solver, no
    table. Mode 2: 1.0 in column 0 where the fast path answers. One kernel
    for the three, so that the slow path is compiled once more only.
    """
    fast, fast_shape, params, shape, tables = named_args(fast, fast_shape, params, shape, tables)
    n = points.shape[0]
    out = np.zeros((n, 4))
    work = new_work()
    for k in range(n):
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        if mode == 1:
            rho = math.sqrt(y * y + z * z)
            th = math.atan2(z, y) - channel_angle
            th -= _TWO_PI * math.floor((th - params.tc + math.pi) / _TWO_PI)
            out[k, 0] = _exact_blade(0, x, rho, th, params, shape, tables, work)
            out[k, 1] = _exact_blade(1, x, rho, th, params, shape, tables, work)
            out[k, 2] = _profile_signed(tables.hub_xb, tables.hub_c, tables.hub_b, 1.0, x, rho)
            out[k, 3] = _profile_signed(tables.shroud_xb, tables.shroud_c, tables.shroud_b, -1.0, x, rho)
            continue
        s, p, h, c, ok = _fast_point(x, y, z, flat, hs, fast, fast_shape)
        if mode == 2:
            out[k, 0] = 1.0 if ok else 0.0
            continue
        if not ok:
            s, p, h, c = _slow_point(x, y, z, channel_angle, flat, hs, params, shape, tables, work)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = s, p, h, c
    return out


@numba.njit(cache=True, inline="always")
def _rows(poses, q):
    """The top three rows of pose q as a 12-tuple (kept in registers over a loop of points)."""
    return (poses[q, 0, 0], poses[q, 0, 1], poses[q, 0, 2], poses[q, 0, 3],
            poses[q, 1, 0], poses[q, 1, 1], poses[q, 1, 2], poses[q, 1, 3],
            poses[q, 2, 0], poses[q, 2, 1], poses[q, 2, 2], poses[q, 2, 3])


@numba.njit(cache=True, inline="always")
def _posed(m, ex, ey, ez):
    """A point of the electrode frame placed by the pose rows ``m``."""
    return (m[0] * ex + m[1] * ey + m[2] * ez + m[3],
            m[4] * ex + m[5] * ey + m[6] * ez + m[7],
            m[8] * ex + m[9] * ey + m[10] * ez + m[11])


#: points per block of the pose kernels' three stages (their scratch arrays stay in L1/L2)
_BLOCK = 512

#: how many points ahead ``_block_values`` prefetches the grid cells (24: measured best of 12, 24, 48)
_AHEAD = 24


@numba.njit(cache=True)
def _block_scratch():
    """The pose kernels' per-thread scratch arrays for one block of points (see ``_block_cells``)."""
    xyz = np.empty((3, _BLOCK))
    cell = np.empty((2, _BLOCK), dtype=np.int64)
    weight = np.empty((5, _BLOCK), dtype=np.float32)
    ok = np.empty(_BLOCK, dtype=np.bool_)
    values = np.empty((_BLOCK, 4), dtype=np.float32)
    off = np.empty(_BLOCK, dtype=np.int64)
    return xyz, cell, weight, ok, values, off


@numba.njit(cache=True, error_model="numpy")
def _block_cells(m, pts, k0, n, fast, fast_shape, xyz, cell, weight, ok):
    """Stage 1 of a block (SIMD): place points k0..k0+n-1 by the pose rows ``m``, find their cells.

    The arithmetic of ``_fast_point`` up to its loads, with no branch, so
    that LLVM vectorises the loop (``error_model="numpy"``: a division by
    zero gives inf instead of raising, which would need a branch; the
    points are read through slices of the block, since ``pts[0, k0 + i]``
    could be a negative index for all LLVM knows, and its wrap-around made
    the loads gathers). ``ok`` is False where ``_fast_point`` would leave its
    common case (outside the blade grid or the hub/shroud table, or beyond
    the angle range); those points get cell 0 (a safe load) and are
    answered again by ``_fast_point`` and ``_slow_point`` in stage 3.
    ``pts`` is (3, M): coordinates in rows.
    """
    lx, lr, lt = fast_shape.nx - 1.0, fast_shape.nr - 1.0, fast_shape.nt - 1.0
    lhx, lhr = fast_shape.nhx - 1.0, fast_shape.nhr - 1.0
    # indices in int32 (AVX2 has no packed float64 <-> int64 conversion nor int64 minimum: LLVM scalarised
    # them); the strides as int32 too, so that the products are 32 x 32 -> 64-bit multiplies (pmuldq)
    i32, i64 = np.int32, np.int64
    mx, mr, mt = i32(fast_shape.nx - 2), i32(fast_shape.nr - 2), i32(fast_shape.nt - 2)
    sr, sx, hsr = i64(i32(2 * fast_shape.nt)), i64(i32(2 * fast_shape.nt * fast_shape.nr)), i64(i32(2 * fast_shape.nhr))
    px, py, pz = pts[0, k0:k0 + n], pts[1, k0:k0 + n], pts[2, k0:k0 + n]
    for i in range(n):
        x, y, z = _posed(m, px[i], py[i], pz[i])
        xyz[0, i], xyz[1, i], xyz[2, i] = x, y, z
        rho, yr, zr = _turned(y, z, fast)
        gx, gr, gt, hx, hr = _grid_coords(x, rho, yr, zr, fast)      # y' = 0 gives inf/NaN here: not ok
        # bitwise & on the comparisons: no short-circuit branches (NaN compares False: not ok)
        good = ((yr > 0.0) & (abs(zr) <= 0.5 * yr) & (gx >= 0.0) & (gx < lx) & (gr >= 0.0) & (gr < lr)
                & (gt >= 0.0) & (gt < lt) & (hx >= 0.0) & (hx < lhx) & (hr >= 0.0) & (hr < lhr))
        ok[i] = good
        gx, gr, gt = (gx, gr, gt) if good else (0.0, 0.0, 0.0)
        hx, hr = (hx, hr) if good else (0.0, 0.0)
        ix, ir, it = min(i32(gx), mx), min(i32(gr), mr), min(i32(gt), mt)
        weight[0, i], weight[1, i], weight[2, i] = np.float32(gx - ix), np.float32(gr - ir), np.float32(gt - it)
        cell[0, i] = i64(ix) * sx + i64(ir) * sr + i64(it) * 2
        jx, jr = i32(hx), i32(hr)
        weight[3, i], weight[4, i] = np.float32(hx - jx), np.float32(hr - jr)
        cell[1, i] = i64(jx) * hsr + i64(jr) * 2


@numba.njit(cache=True, inline="always")
def _prefetch_cell(flat, b0, sr, sx):
    """Prefetch the four (x, r) corners of a blade-grid cell (theta and both walls share a line)."""
    b = np.uint64(b0)
    prefetch(flat, b)
    prefetch(flat, b + sr)
    prefetch(flat, b + sx)
    prefetch(flat, b + sx + sr)


@numba.njit(cache=True, error_model="numpy")
def _block_values(n, flat, hs, fast_shape, cell, weight, values):
    """Stage 2 of a block: the loads and the float32 interpolation of ``_fast_point``, bit for bit.

    One ``cell_values`` (4-wide SIMD) per point into its row of ``values``.
    The four cache lines of the cell of point i + ``_AHEAD`` are prefetched
    while point i is interpolated (about 7 % more points per second near the
    final pose, where the cells come from L2 or memory).
    """
    sr = np.uint64(2 * fast_shape.nt)
    sx = np.uint64(2 * fast_shape.nt * fast_shape.nr)
    hsr = np.uint64(2 * fast_shape.nhr)
    for i in range(min(_AHEAD, n)):
        _prefetch_cell(flat, cell[0, i], sr, sx)
    for i in range(n):
        if i + _AHEAD < n:
            _prefetch_cell(flat, cell[0, i + _AHEAD], sr, sx)
        values[i, 0], values[i, 1], values[i, 2], values[i, 3] = cell_values(
            flat, np.uint64(cell[0, i]), sr, sx, weight[0, i], weight[1, i], weight[2, i],
            hs, np.uint64(cell[1, i]), hsr, weight[3, i], weight[4, i])


@numba.njit(cache=True, inline="always")
def _common(i, ok, values):
    """Whether stage 2 answered point i: the common case, and a cell not marked for the exact solver."""
    return ok[i] and values[i, 0] == values[i, 0] and values[i, 1] == values[i, 1]


@numba.njit(cache=True, inline="always")
def _off_point(i, xyz, channel_angle, flat, hs, fast, fast_shape, params, shape, tables, work):
    """Stage 3 for a point off the common case: its four clearances in full (``_fast_point``, ``_slow_point``)."""
    x, y, z = xyz[0, i], xyz[1, i], xyz[2, i]
    s, p, h, c, good = _fast_point(x, y, z, flat, hs, fast, fast_shape)
    if not good:
        s, p, h, c = _slow_point(x, y, z, channel_angle, flat, hs, params, shape, tables, work)
    return s, p, h, c


@numba.njit(cache=True, inline="always")
def _lower(v, k, best, arg):
    """(best, arg) after offering value v of point k, out of order: ties go to the lower index, NaN never wins.

    The same (best, arg) as offering the points in index order with a strict ``<``.
    """
    if v < best or (v == best and k < arg):
        return v, k
    return best, arg


@numba.njit(cache=True)
def _posed_kernel(poses, points, channel_angle, flat, hs, fast, fast_shape, params, shape, tables):
    """``_posed_kernel_named`` on the arguments named (``named_args``): what the field's methods call."""
    return _posed_kernel_named(poses, points, channel_angle, flat, hs,
                               *named_args(fast, fast_shape, params, shape, tables))


@numba.njit(cache=True, parallel=True)
def _posed_kernel_named(poses, points, channel_angle, flat, hs, fast, fast_shape, params, shape, tables):
    """(P, M, 4): the four clearances of every point under every pose, transform and lookup in one loop.

    Blocks of ``_BLOCK`` points of one pose run in parallel (each writes its
    own rows), in the three stages of ``_pose_kernel``; no (P, M, 3)
    temporary of transformed points.
    """
    n_pose, n_pt = poses.shape[0], points.shape[0]
    pts = np.ascontiguousarray(points.T)
    out = np.empty((n_pose, n_pt, 4))
    per_pose = (n_pt + _BLOCK - 1) // _BLOCK
    for b in numba.prange(n_pose * per_pose):
        q, k0 = b // per_pose, (b % per_pose) * _BLOCK
        n = min(_BLOCK, n_pt - k0)
        work = new_work()
        xyz, cell, weight, ok, values, _ = _block_scratch()
        _block_cells(_rows(poses, q), pts, k0, n, fast, fast_shape, xyz, cell, weight, ok)
        _block_values(n, flat, hs, fast_shape, cell, weight, values)
        rows = out[q, k0:k0 + n]
        for i in range(n):
            if _common(i, ok, values):
                rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3] = values[i, 0], values[i, 1], values[i, 2], values[i, 3]
            else:
                rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3] = _off_point(i, xyz, channel_angle, flat, hs, fast,
                                                                            fast_shape, params, shape, tables, work)
    return out


@numba.njit(cache=True)
def _pose_kernel(poses, points, margin, channel_angle, flat, hs, fast, fast_shape, params, shape, tables):
    """``_pose_kernel_named`` on the arguments named (``named_args``): what the field's methods call."""
    return _pose_kernel_named(poses, points, margin, channel_angle, flat, hs,
                              *named_args(fast, fast_shape, params, shape, tables))


#: exact solves a thread of ``_pose_kernel_named`` may put off to the end of its block of poses
_DEFERRED = 8192


@numba.njit(cache=True, parallel=True)
def _pose_kernel_named(poses, points, margin, channel_angle, flat, hs, fast, fast_shape, params, shape, tables):
    """Per pose the minimum of each column over the points, the point attaining it, and the exact solves made.

    Blocks of 64 poses x ``_BLOCK`` points: a point under neighbouring poses
    reads the same cells while they are in cache. Each (pose, block of
    points) runs in three stages: the cells of every point in a branch-free
    loop LLVM vectorises (``_block_cells``: transform, arctangent, indices),
    the loads and interpolation in SIMD (``_block_values``), then the
    minima: the points stage 2 answered in a tight loop, then those off the
    common case (``_lower`` keeps the first index of a tie, as one pass in
    order would). Pose blocks run in parallel (each writes its own rows).

    A point in a cell marked for the exact solver is solved only where it can
    attain the minimum: its unsigned distance is at least
    ``_unsigned_bound`` - ``margin`` (``margin`` covers the nodes' values
    against the solver's, the field's error bound), so where that lies above
    the pose's minimum so far and the point is not behind the wall (its
    distance is then the unsigned one) the solve cannot change the result.
    The solves not settled so at once are put off to the end of the block of
    poses, lowest bound first, when the minima are lower. Results are bit for
    bit those of ``_fast_point``/``_slow_point`` per point.
    """
    n_pose, n_pt = poses.shape[0], points.shape[0]
    pts = np.ascontiguousarray(points.T)
    bits = flat.view(np.uint32)
    best = np.full((n_pose, 4), np.inf)
    arg = np.zeros((n_pose, 4), dtype=np.int64)
    solved = np.zeros(n_pose, dtype=np.int64)
    # at least 8 blocks when there are few poses, so that every thread gets some
    block = max(1, min(64, n_pose // 8))
    for b in numba.prange((n_pose + block - 1) // block):
        q0 = b * block
        q1 = min(q0 + block, n_pose)
        work = new_work()
        xyz, cell, weight, ok, values, off = _block_scratch()
        put_off = np.empty((_DEFERRED, 3), dtype=np.int64)        # pose, point, wall
        put_at = np.empty((_DEFERRED, 4))                         # bound, xq, rq, tq
        n_put = 0
        for k0 in range(0, n_pt, _BLOCK):
            n = min(_BLOCK, n_pt - k0)
            for q in range(q0, q1):
                _block_cells(_rows(poses, q), pts, k0, n, fast, fast_shape, xyz, cell, weight, ok)
                _block_values(n, flat, hs, fast_shape, cell, weight, values)
                b0, b1, b2, b3 = best[q, 0], best[q, 1], best[q, 2], best[q, 3]
                a0, a1, a2, a3 = arg[q, 0], arg[q, 1], arg[q, 2], arg[q, 3]
                n_off = 0
                for i in range(n):
                    if not _common(i, ok, values):
                        off[n_off] = i
                        n_off += 1
                        continue
                    s, p, h, c = values[i, 0], values[i, 1], values[i, 2], values[i, 3]
                    if s < b0:
                        b0, a0 = s, k0 + i
                    if p < b1:
                        b1, a1 = p, k0 + i
                    if h < b2:
                        b2, a2 = h, k0 + i
                    if c < b3:
                        b3, a3 = c, k0 + i
                for j in range(n_off):
                    i = off[j]
                    k = k0 + i
                    x, y, z = xyz[0, i], xyz[1, i], xyz[2, i]
                    s, p, h, c, good = _fast_point(x, y, z, flat, hs, fast, fast_shape)
                    if not good:
                        s, p, h, c, xq, rq, tq, th, rho, gap, rect, outside, qx, qr, qt = _slow_parts(
                            x, y, z, channel_angle, flat, hs, params, shape, tables)
                        if outside:
                            s, p = _slow_walls(s, p, xq, rq, tq, gap, rect, outside, params, shape, tables, work)
                        else:
                            for face in range(2):
                                if (s if face == 0 else p) == (s if face == 0 else p):
                                    continue
                                low = _unsigned_bound(face, flat, bits, shape, params, xq, rq, tq, qx, qr, qt) - margin
                                if low > (b0 if face == 0 else b1) and not _blade_behind(
                                        face, xq, rq, tq, params, shape, tables, work):
                                    v = np.inf                        # cannot attain the minimum
                                elif low > -np.inf and n_put < _DEFERRED:
                                    put_off[n_put, 0], put_off[n_put, 1], put_off[n_put, 2] = q, k, face
                                    put_at[n_put, 0], put_at[n_put, 1] = low, xq
                                    put_at[n_put, 2], put_at[n_put, 3] = rq, tq
                                    n_put += 1
                                    v = np.inf                        # settled at the end of the block
                                else:
                                    v = _exact_blade(face, xq, rq, tq, params, shape, tables, work)
                                    solved[q] += 1
                                if face == 0:
                                    s = v
                                else:
                                    p = v
                    b0, a0 = _lower(s, k, b0, a0)
                    b1, a1 = _lower(p, k, b1, a1)
                    b2, a2 = _lower(h, k, b2, a2)
                    b3, a3 = _lower(c, k, b3, a3)
                best[q, 0], best[q, 1], best[q, 2], best[q, 3] = b0, b1, b2, b3
                arg[q, 0], arg[q, 1], arg[q, 2], arg[q, 3] = a0, a1, a2, a3
        for m in np.argsort(put_at[:n_put, 0]):
            q, k, face = put_off[m, 0], put_off[m, 1], put_off[m, 2]
            low, xq, rq, tq = put_at[m, 0], put_at[m, 1], put_at[m, 2], put_at[m, 3]
            if low > best[q, face] and not _blade_behind(face, xq, rq, tq, params, shape, tables, work):
                continue
            v = _exact_blade(face, xq, rq, tq, params, shape, tables, work)
            solved[q] += 1
            best[q, face], arg[q, face] = _lower(v, k, best[q, face], arg[q, face])
    return best, arg, solved


@numba.njit(cache=True)
def _exact_pose_kernel(poses, points, channel_angle, near_bound, far_bound, flat, hs, fast, fast_shape, params, shape,
                       tables):
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
    fast, fast_shape, params, shape, tables = named_args(fast, fast_shape, params, shape, tables)
    n_pose, n_pt = poses.shape[0], points.shape[0]
    best = np.full((n_pose, 4), np.inf)
    arg = np.zeros((n_pose, 4), dtype=np.int64)
    solved = np.zeros(n_pose, dtype=np.int64)
    world = np.empty((n_pt, 3))
    low = np.empty((n_pt, 4))
    work = new_work()
    nx, nr, nt, nhx, nhr = shape.nx, shape.nr, shape.nt, shape.nhx, shape.nhr
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
            s, p, h, c, ok = _fast_point(x, y, z, flat, hs, fast, fast_shape)
            in_grid, in_table = True, True
            if not ok:
                s, p, h, c = _slow_point(x, y, z, channel_angle, flat, hs, params, shape, tables, work)
                rho = math.sqrt(y * y + z * z)
                th = math.atan2(z, y) - channel_angle
                th -= _TWO_PI * math.floor((th - params.tc + math.pi) / _TWO_PI)
                gx, gr, gt = (x - params.x0) / params.hx, (rho - params.r0) / params.hr, (th - params.t0) / params.ht
                in_grid = 0.0 <= gx <= nx - 1 and 0.0 <= gr <= nr - 1 and 0.0 <= gt <= nt - 1
                hx, hr = (x - params.hx0) / params.hhx, (rho - params.hr0) / params.hhr
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
                th -= _TWO_PI * math.floor((th - params.tc + math.pi) / _TWO_PI)
                d = _exact_surface(j, x, rho, th, params, shape, tables, work)
                solved[q] += 1
                if d < ub:
                    ub, a = d, k
            best[q, j], arg[q, j] = ub, a
    return best, arg, solved
