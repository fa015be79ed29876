"""The layout the fast field's numba kernels share: parameter-vector indices and constants.

The kernels of :mod:`.field_build`, :mod:`.field_query`, :mod:`.exact_solvers`
and :mod:`.min_search` take the field's float parameters ``fp`` and integer
parameters ``ip`` as flat vectors (numba passes them cheaply); the names
below index them. Units: mm, rad.
"""

import math

import numpy as np


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
