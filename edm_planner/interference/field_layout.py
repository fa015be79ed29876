"""The fast field's layout: the splines' arrays, the grids' extents and the faces' start samples.

What the build (:mod:`.field_build`), the cache check (:mod:`.field_cache`)
and the queries (:class:`.fast.FastChannelField`) derive from the blisk
alone: the faces' control nets and knots and the profiles' cubic pieces as
the numba kernels take them, the blade grid's and the hub/shroud table's
extents and spacing (:class:`.field_params.FieldParams`,
:class:`.field_params.GridShape`), and the binned face samples the exact
solver starts from. Units: mm, rad.
"""

import math

import numpy as np

from .field_params import FieldParams, GridShape


def face_arrays(face):
    """Control net by coordinate (3, nv, nu) and the knot vectors of a face's spline."""
    s = face.surface
    return (np.ascontiguousarray(np.moveaxis(s.control_points, 2, 0), dtype=np.float64),
            np.ascontiguousarray(s.knots_u, dtype=np.float64),
            np.ascontiguousarray(s.knots_v, dtype=np.float64))


def profile_arrays(profile):
    """Breakpoints (n,), cubic coefficients (4, n-1) and (max|r'|, max|r''|) of a profile.

    The PCHIP pieces of ``RevolutionProfile`` (the interpolant ``ProfileDistance`` uses).
    """
    interp = profile._interp
    xb = np.ascontiguousarray(interp.x, dtype=np.float64)
    t = np.linspace(xb[0], xb[-1], 20 * len(xb) + 200)
    bounds = np.array([np.abs(interp.derivative()(t)).max() * 1.1 + 1e-9,
                       np.abs(interp.derivative(2)(t)).max() * 1.1 + 1e-9])
    return xb, np.ascontiguousarray(interp.c, dtype=np.float64), bounds


def grid_axis(lo, hi, step, multiple):
    """Node count (a multiple of ``multiple`` intervals plus one) and spacing <= step covering [lo, hi]."""
    m = max(multiple, int(math.ceil((hi - lo) / step / multiple - 1e-9)) * multiple)
    return m + 1, (hi - lo) / m


def grid_layout(blisk, spacing, coarse=4):
    """The grids' extents and spacing for a blisk.

    Parameters
    ----------
    blisk : Blisk
    spacing : float
        [mm] in x and r; in theta ``spacing / r_mid``.
    coarse : int
        Fine intervals per coarse interval.

    Returns
    -------
    params : FieldParams
        (``ca``, ``sa`` 0: the channel's turn is set per query.)
    shape : GridShape
    """
    b = blisk
    h = spacing
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
    nx, hx = grid_axis(x0 - 4.0, x1 + 4.0, h, coarse)
    nr, hr = grid_axis(r_lo, r_hi, h, coarse)
    nt, ht = grid_axis(t_lo, t_hi, h / r_mid, coarse)
    # hub/shroud table: longer in x, so that an electrode leaving the channel axially (its far end
    # an electrode length past the blades) stays in it
    ext = max(10.0, 1.25 * (x1 - x0))
    nhx, hhx = grid_axis(x0 - 4.0 - ext, x1 + 4.0 + ext, h, 1)
    nhr, hhr = grid_axis(r_lo, r_hi, h, 1)
    scale = []                   # mm per unit u, v of the suction and the pressure face
    for face in (b.suction_face, b.pressure_face):
        s_u, s_v = face.surface.derivatives(*np.meshgrid(np.linspace(0, 1, 21), np.linspace(0, 1, 21)))
        scale += [np.linalg.norm(s_u, axis=-1).mean(), np.linalg.norm(s_v, axis=-1).mean()]
    values = dict(
        x0=x0 - 4.0, hx=hx, r0=r_lo, hr=hr, t0=t_lo, ht=ht, pitch=b.pitch, tc=0.5 * (t_lo + t_hi),
        hx0=x0 - 4.0 - ext, hhx=hhx, hr0=r_lo, hhr=hhr,
        fx0=fx.min() - 0.01, fx1=fx.max() + 0.01, fr0=fr.min() - 0.01, fr1=fr.max() + 0.01,
        ihx=1.0 / hx, ihr=1.0 / hr, iht=1.0 / ht, ihhx=1.0 / hhx, ihhr=1.0 / hhr,
        # a coarse cell's diagonal: how far apart two of its corners' closest points may lie
        jump=coarse * math.sqrt(hx ** 2 + hr ** 2 + r_hi ** 2 * ht ** 2),
        ca=0.0, sa=0.0, scale_su=scale[0], scale_sv=scale[1], scale_pu=scale[2], scale_pv=scale[3])
    # through a float64 vector: the values the cache stores, bit for bit
    params = FieldParams(*(float(v) for v in np.array([values[name] for name in FieldParams._fields])))
    shape = GridShape(nx=nx, nr=nr, nt=nt, coarse=coarse, ncx=(nx - 1) // coarse + 1, ncr=(nr - 1) // coarse + 1,
                      nct=(nt - 1) // coarse + 1, nhx=nhx, nhr=nhr)
    return params, GridShape(*(int(v) for v in shape))


def uv_starts(blisk, n=64):
    """The starts of ``BladeFace.uv_at``: n x n face samples in (x, r) scaled by their extent.

    The footprint test must start where the exact method starts (see
    ``exact_solvers._exact_blade``); this repeats ``BladeFace``'s sampling.

    Returns
    -------
    samples : (2, n*n, 2) float
        Scaled (x, r) of the suction and the pressure face's samples.
    uv : (2, n*n, 2) float
    scale : (2, 2) float
    box, start, items
        Bins of the samples for ``exact_solvers._nearest_start``.
    """
    samples = np.empty((2, n * n, 2))
    uv = np.empty((2, n * n, 2))
    scale = np.empty((2, 2))
    nb = n // 2                                   # bins of the nearest-sample search
    box = np.empty((2, 4))
    start = np.empty((2, nb * nb + 1), dtype=np.int64)
    items = np.empty((2, n * n), dtype=np.int64)
    uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    for k, face in enumerate((blisk.suction_face, blisk.pressure_face)):
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
