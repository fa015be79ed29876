"""The quintic side of a parametric blade section (Liu Yuting et al. 2024, section 2.2, eq. 3-5).

A side of a section is a quintic ``y = f(x)`` in the unrolled plane of a span
fraction (``x`` axial, ``y`` the circumferential arc length ``r * theta``
[mm]), fixed by its value, slope and second derivative at its two ends.
:func:`quintic_coefficients` solves eq. 4/5 for the coefficients of eq. 3;
:class:`Quintic` evaluates it and its derivatives in a centred, scaled
variable, well conditioned.

The printed example of Liu et al. 2024 (Table 3 and the two polynomials after
eq. 5) is not self-consistent: e.g. its pressure-side start point (-7.33, 5.08)
lies 1.21 mm from the centre (-8.45, 5.53) of a circle of radius 0.35, and its
y_s polynomial evaluates to about -1860 at its own end points. It is therefore
not reproduced here; the tests check the construction against its own
definition (end conditions, tangency) instead.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError

__all__ = ["Quintic", "quintic_coefficients"]


def _quintic_system(t0, t1):
    """Matrix of eq. 4/5 for end abscissae ``t0``, ``t1``.

    Returns
    -------
    m : (6, 6) float
        Rows: value, first and second derivative at ``t0``, then at ``t1``;
        columns: coefficients of t^5 ... t^0.
    """
    rows = []
    for t in (t0, t1):
        rows.append([t ** 5, t ** 4, t ** 3, t ** 2, t, 1.0])
        # Eq. 4 as printed has ``x_s2`` in the 4th column of its 5th row; the
        # derivative of x^2 is ``2 x``, as eq. 5 and row 2 of eq. 4 have it.
        rows.append([5 * t ** 4, 4 * t ** 3, 3 * t ** 2, 2 * t, 1.0, 0.0])
        rows.append([20 * t ** 3, 12 * t ** 2, 6 * t, 2.0, 0.0, 0.0])
    return np.array(rows, dtype=np.float64)


@dataclass(frozen=True)
class Quintic:
    """A quintic in the centred, scaled variable ``t = (x - xm) / h``.

    Parameters
    ----------
    xm : float
        Centre of the interval [mm].
    h : float
        Half its length [mm].
    coef_t : (6,) float
        Coefficients in t, highest power first.
    """

    xm: float
    h: float
    coef_t: np.ndarray  # (6,) highest power first, in t

    @classmethod
    def fit(cls, x0, y0, dy0, ddy0, x1, y1, dy1, ddy1):
        """The quintic with value, slope and second derivative ``y0, dy0, ddy0`` at ``x0`` and ``y1, dy1, ddy1`` at ``x1``."""
        xm, h = 0.5 * (x0 + x1), 0.5 * (x1 - x0)
        # eq. 4 for t0 = -1, t1 = +1: same system, well conditioned
        rhs = np.array([y0, dy0 * h, ddy0 * h * h, y1, dy1 * h, ddy1 * h * h], dtype=np.float64)
        coef = np.linalg.solve(_quintic_system(-1.0, 1.0), rhs)
        return cls(xm, h, coef)

    def __call__(self, x, nu=0):
        """``nu``-th derivative with respect to x at ``x`` (nu in 0, 1, 2)."""
        t = (np.asanyarray(x, dtype=np.float64) - self.xm) / self.h
        c = self.coef_t
        for _ in range(nu):
            c = np.polyder(c)
        return np.polyval(c, t) / self.h ** nu

    def coefficients_in_x(self):
        """Coefficients [a0..a5] of eq. 3 in x (highest power first)."""
        p_t = np.polynomial.Polynomial(self.coef_t[::-1])
        p_x = p_t(np.polynomial.Polynomial([-self.xm / self.h, 1.0 / self.h]))
        coef = np.zeros(6)
        coef[: len(p_x.coef)] = p_x.coef
        return coef[::-1]


def quintic_coefficients(x0, y0, dy0, ddy0, x1, y1, dy1, ddy1):
    """Coefficients of the quintic side ``y = f(x)`` of eq. 3 from its end conditions.

    Solves the 6x6 linear system of eq. 4/5 (Liu et al. 2024): value, slope
    and second derivative at the start ``x0`` and at the end ``x1``. The
    system is solved in the centred, scaled variable ``t = (x - xm) / h``
    (``xm = (x0 + x1) / 2``, ``h = (x1 - x0) / 2``) for conditioning and the
    result is expanded back to powers of x.

    Parameters
    ----------
    x0, y0, dy0, ddy0 : float
        Start point [mm], slope dy/dx [-], second derivative d2y/dx2 [1/mm].
    x1, y1, dy1, ddy1 : float
        Same at the end, ``x1 > x0``.

    Returns
    -------
    coefficients : (6,) float
        ``[a0, a1, a2, a3, a4, a5]`` of ``a0 x^5 + a1 x^4 + ... + a5``
        (highest power first, as in eq. 3; usable with ``numpy.polyval``).

    Raises
    ------
    GeometryError
        Non-finite input or ``x1 <= x0``.
    """
    vals = np.array([x0, y0, dy0, ddy0, x1, y1, dy1, ddy1], dtype=np.float64)
    if not np.all(np.isfinite(vals)):
        raise GeometryError(f"quintic end conditions must be finite, got {vals.tolist()}")
    if not x1 > x0:
        raise GeometryError(f"quintic end abscissa must exceed the start: x0 = {x0:g}, x1 = {x1:g} mm")
    return Quintic.fit(*vals).coefficients_in_x()
