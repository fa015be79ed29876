"""The layout the fast field's numba kernels share: their named arguments and constants.

The kernels of :mod:`.field_build`, :mod:`.field_query`, :mod:`.exact_solvers`
and :mod:`.min_search` take the field's scalars as :class:`FieldParams`
(floats) and :class:`GridShape` (node counts), and the arrays of the exact
solvers as :class:`ExactTables`: named tuples, which numba passes by value
(the scalars stay in registers) and whose fields the kernels read by name
(``params.x0``, ``tables.line_theta``). :class:`KernelArgs` is what
:meth:`.fast.FastChannelField.kernel_args` hands numba callers. The cache
stores ``FieldParams`` and ``GridShape`` as flat vectors in field order
(``np.array(params)``; ``FieldParams(*vector)`` reads one back). Units: mm, rad.
"""

import math
from typing import NamedTuple

import numba
import numpy as np
from numpy.polynomial import chebyshev, polynomial


#: format of the cached arrays; bump when the layout or the fill changes
CACHE_VERSION = "edm_planner.fast_field/8"


#: accuracy band the error bound is measured in [mm]
ACCURATE_WITHIN = 2.0


#: A node marked for the exact solver is a quiet NaN whose low 22 mantissa bits carry n = floor(|value| / q) + 1
#: (q = ``NODE_QUANTUM`` mm; n = 0, the plain NaN: nothing carried), for nodes solved within
#: ``ACCURATE_WITHIN`` of the face: (n - 1) q is a lower bound of the node's unsigned distance, from which
#: the pose minimum bounds a point's distance without solving it (``field_query._unsigned_bound``).
NODE_QUANTUM = 2.0 ** -18
NAN_BITS = 0x7FC00000
PAYLOAD_MASK = 0x3FFFFF


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
    top = half_range ** 2
    s = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1)) * top / 2 + top / 2
    c = chebyshev.chebfit(2 * s / top - 1, np.arctan(np.sqrt(s)) / np.sqrt(s), degree)
    p = polynomial.Polynomial(chebyshev.cheb2poly(c))(polynomial.Polynomial([-1.0, 2.0 / top]))
    return tuple(float(v) for v in p.coef)


#: the fast path's arctangent (|z/y| <= 0.5 about the grid's middle angle; atan2 costs twice as much)
_ATAN = _atan_coefficients()


class FieldParams(NamedTuple):
    """The field's float parameters (by value in the kernels; the cache's ``fp`` vector in this order)."""

    x0: float       #: first node of the blade grid along x [mm]
    hx: float       #: its spacing along x [mm]
    r0: float       #: first node along r [mm]
    hr: float       #: spacing along r [mm]
    t0: float       #: first node along theta (channel 0) [rad]
    ht: float       #: spacing along theta [rad]
    pitch: float    #: blade pitch [rad]
    tc: float       #: the grid's middle angle [rad]
    hx0: float      #: first node of the hub/shroud table along x [mm]
    hhx: float      #: its spacing along x [mm]
    hr0: float      #: its first node along r [mm]
    hhr: float      #: its spacing along r [mm]
    fx0: float      #: the faces' (x, r) box: x min [mm]
    fx1: float      #: x max [mm]
    fr0: float      #: r min [mm]
    fr1: float      #: r max [mm]
    ihx: float      #: 1 / hx
    ihr: float      #: 1 / hr
    iht: float      #: 1 / ht
    ihhx: float     #: 1 / hhx
    ihhr: float     #: 1 / hhr
    jump: float     #: a coarse cell's diagonal: how far apart its corners' closest points may lie [mm]
    ca: float       #: cos of the grid's middle angle turned into the query's channel (0 as stored)
    sa: float       #: sin of it (0 as stored)
    scale_su: float     #: mm per unit u of the suction face
    scale_sv: float     #: mm per unit v of the suction face
    scale_pu: float     #: mm per unit u of the pressure face
    scale_pv: float     #: mm per unit v of the pressure face


class GridShape(NamedTuple):
    """The field's node counts (by value in the kernels; the cache's ``ip`` vector in this order)."""

    nx: int         #: blade grid nodes along x
    nr: int         #: along r
    nt: int         #: along theta
    coarse: int     #: fine nodes per coarse interval
    ncx: int        #: coarse grid nodes along x
    ncr: int        #: along r
    nct: int        #: along theta
    nhx: int        #: hub/shroud table nodes along x
    nhr: int        #: along r


class ExactTables(NamedTuple):
    """The arrays of the exact solvers: the faces' splines, the (x, r) lines, the coarse grid, the profiles."""

    cp_s: np.ndarray            #: (3, nv, nu) suction face control net by coordinate
    tu_s: np.ndarray            #: its knots in u
    tv_s: np.ndarray            #: its knots in v
    cp_p: np.ndarray            #: (3, nv, nu) pressure face control net
    tu_p: np.ndarray            #: its knots in u
    tv_p: np.ndarray            #: its knots in v
    line_uv: np.ndarray         #: (nx, nr, 2, 2) per (x, r) node and face the (u, v) of the face there
    coarse_uv: np.ndarray       #: (ncx, ncr, nct, 2, 2) the coarse nodes' closest points (u, v)
    kind: np.ndarray            #: (ncx-1, ncr-1, nct-1, 2) uint8 coarse cells: 0 far, 1 near, 2 ambiguous
    line_theta: np.ndarray      #: (nx, nr, 2) the faces' angles per (x, r) node [rad]
    line_inside: np.ndarray     #: (nx, nr, 2) bool (x, r) node in the face's footprint
    hub_xb: np.ndarray          #: hub profile breakpoints
    hub_c: np.ndarray           #: its cubic coefficients (4, n-1)
    hub_b: np.ndarray           #: its (max|r'|, max|r''|)
    shroud_xb: np.ndarray       #: shroud profile breakpoints
    shroud_c: np.ndarray        #: its cubic coefficients
    shroud_b: np.ndarray        #: its (max|r'|, max|r''|)
    start_samples: np.ndarray   #: (2, n*n, 2) faces' samples in scaled (x, r) (``BladeFace.uv_at``'s starts)
    start_uv: np.ndarray        #: (2, n*n, 2) their (u, v)
    start_scale: np.ndarray     #: (2, 2) the scale of (x, r)
    start_box: np.ndarray       #: (2, 4) bins of the samples: lower corner and bin size
    start_first: np.ndarray     #: (2, nb*nb+1) first item of each bin
    start_items: np.ndarray     #: (2, n*n) samples by bin


class KernelArgs(NamedTuple):
    """What numba callers pass on for channel k (:meth:`.fast.FastChannelField.kernel_args`).

    The fast path (``_fast_point``) reads ``grid, walls, fast, fast_shape``;
    the exact solvers (``_exact_at``, ``_behind_at``) ``channel_angle,
    params, shape, tables``. ``fast`` is ``params`` with ``ca, sa`` turned
    into the channel; ``fast_shape`` is ``shape``. The positions are the
    ones the kernels take them in (``kernel(..., *args)``).
    """

    channel_angle: float        #: k * pitch [rad]
    grid: np.ndarray            #: the blade grid flattened: (nx * nr * nt * 2,) float32
    walls: np.ndarray           #: the hub/shroud table flattened: (nhx * nhr * 2,) float32
    fast: FieldParams
    fast_shape: GridShape
    params: FieldParams
    shape: GridShape
    tables: ExactTables


@numba.njit(cache=True, inline="always")
def named_exact(params, shape, tables):
    """``(params, shape, tables)`` as ``FieldParams``, ``GridShape``, ``ExactTables``, also from plain tuples.

    numba types a plain tuple argument from its fingerprint in C, a named
    tuple in Python (about 20 us more per call for the field's five), so the
    field's methods pass plain tuples in field order and the entry kernels
    name them here, once; in the compiled code the two are the same values.
    """
    return FieldParams(*params), GridShape(*shape), ExactTables(*tables)


@numba.njit(cache=True, inline="always")
def named_args(fast, fast_shape, params, shape, tables):
    """``named_exact`` and the fast path's ``(fast, fast_shape)`` as ``FieldParams``, ``GridShape``."""
    params, shape, tables = named_exact(params, shape, tables)
    return FieldParams(*fast), GridShape(*fast_shape), params, shape, tables
