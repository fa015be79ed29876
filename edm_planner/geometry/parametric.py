"""Parametric blades: quintic section profiles stacked from hub to shroud.

A blade section is built as in Liu Yuting et al. 2024 (section 2.2, eq. 3-5)
in the *unrolled* plane of a span fraction: ``x`` is the axial position and
``y`` the circumferential arc length ``r * theta`` [mm]. The section is
bounded by a leading-edge (LE) and a trailing-edge (TE) circle (centre and
radius) and by two sides, each a quintic ``y = f(x)`` fixed by position,
slope and second derivative at its two tangent points on the edge circles:

* the ``minus`` side is the face at lower ``y`` (towards -theta; the
  pressure face in this project's convention, see
  :class:`~edm_planner.geometry.sections.BladeSections`),
* the ``plus`` side is the face at higher ``y`` (towards +theta, suction).

A side whose direction angle at a circle is ``beta`` (slope ``tan(beta)``)
touches the circle at ``centre + radius * n`` with ``n`` the unit normal of
that direction on the side's outer side: ``(sin b, -cos b)`` for the minus
side, ``(-sin b, cos b)`` for the plus side.

Designer's parameterisation
---------------------------
Each definition section has a design camber line whose slope varies
linearly in x from ``tan(inlet_angle)`` at the LE circle centre
``(x_le, y_le)`` to ``tan(outlet_angle)`` at the TE circle centre
``(x_te, y_te)``; it only places the TE circle:
``y_te - y_le = (x_te - x_le) * (tan(inlet_angle) + tan(outlet_angle)) / 2``.
The sides leave the LE at ``inlet_angle -/+ le_wedge`` (minus/plus) and
reach the TE at ``outlet_angle +/- te_wedge``, so the wedge angles (with the
edge radii) set the thickness; their second derivatives at the ends are
``minus_curvature``/``plus_curvature`` (default 0). The section is shifted
in y so that its stacking point (mid-way between its two sides at
``x = stack_x``) lies at ``y = 0``, rotated by ``stagger`` about the
stacking point (positive: counter-clockwise in the (x, y) plane, i.e. it
adds to every side angle), and stacked at
``r = r_hub(x) + s * (r_shroud(x) - r_hub(x))``, ``theta = y / r + lean``.
All parameters are interpolated along the span fraction ``s`` between the
definition sections.

YAML schema of ``blade: parametric:`` (mm, rad)
-----------------------------------------------
::

    blade:
      parametric:
        interpolation: cubic    # 'linear' or 'cubic' (natural cubic spline
                                # through the definition sections; linear with
                                # two). Optional, default 'cubic'.
        span_extension: 0.03    # blade continued this fraction of the channel
                                # height inside hub and shroud (>= 0, <= 0.5),
                                # default 0.03; parameters are extrapolated.
        span_count: 21          # stacked sections from s = 0 to s = 1
                                # inclusive (>= 2), default 21; plus one at
                                # -span_extension and one at 1 + span_extension
                                # when span_extension > 0.
        station_count: 101      # chordwise stations per section, shared by both
                                # faces, cosine-clustered towards the edges
                                # (>= 8), default 101.
        sections:               # required, >= 1 definition sections; with 2 or
                                # more the first must be at span 0 and the last
                                # at span 1, spans strictly increasing.
          - span: 0.0           # required, span fraction in [0, 1]
            x_le: 0.5           # required, axial position of the LE circle centre [mm]
            x_te: 24.6          # required, axial position of the TE circle centre [mm], > x_le
            le_radius: 0.5      # required, LE circle radius [mm], > 0
            te_radius: 0.35     # required, TE circle radius [mm], > 0
            inlet_angle: 0.9    # required, camber-line angle at the LE [rad], |.| < pi/2
            outlet_angle: -1.0  # required, camber-line angle at the TE [rad], |.| < pi/2
            le_wedge: 0.3       # required, half wedge angle at the LE [rad], >= 0
            te_wedge: 0.1       # required, half wedge angle at the TE [rad], >= 0
            minus_curvature: [0.0, 0.0]  # optional, d2y/dx2 of the minus side at
                                         # its LE and TE tangent point [1/mm], default [0, 0]
            plus_curvature: [0.0, 0.0]   # optional, same for the plus side, default [0, 0]
            stagger: 0.0        # optional, rotation of the section about the
                                # stacking point [rad], |.| < pi/2, default 0
            lean: 0.0           # optional, angular shift of the stacking point
                                # about X [rad], |.| < pi, default 0
            stack_x: 12.55      # optional, axial position of the stacking point
                                # [mm], default (x_le + x_te) / 2

Every key is validated; unknown keys, NaN/inf, wrong types and impossible
shapes (crossing sides, sides turned beyond +-pi/2, chord too short for the
edge circles) raise :class:`~edm_planner.errors.GeometryError` naming the
key path, e.g. ``blade.parametric.sections[1].le_radius: must be > 0 mm,
got -0.3``.

Public API
----------
:func:`quintic_coefficients`, :func:`tangent_point`, :func:`section_outline`
(:class:`SectionOutline`), :class:`SectionDefinition`,
:func:`definition_outline`, :func:`interpolate_definitions`,
:func:`stack_sections`, :func:`parse_parametric`.
"""

import logging
import math
from dataclasses import dataclass, replace
from numbers import Real

import numpy as np
from scipy.interpolate import CubicSpline, make_interp_spline

from ..constants import SIZE
from ..errors import GeometryError
from .profiles import RevolutionProfile
from .sections import BladeSections

__all__ = ["quintic_coefficients", "tangent_point", "SectionOutline", "section_outline",
           "SectionDefinition", "definition_outline", "interpolate_definitions", "stack_sections",
           "parse_parametric"]

_log = logging.getLogger(__name__)

_HALF_PI = 0.5 * math.pi
#: samples used to invert a staggered quintic and to check the sides for crossing
_DENSE = 1201


# --------------------------------------------------------------------------
# Quintic sides (eq. 3-5)
# --------------------------------------------------------------------------
#
# The printed example of Liu et al. 2024 (Table 3 and the two polynomials after
# eq. 5) is not self-consistent: e.g. its pressure-side start point (-7.33, 5.08)
# lies 1.21 mm from the centre (-8.45, 5.53) of a circle of radius 0.35, and its
# y_s polynomial evaluates to about -1860 at its own end points. It is therefore
# not reproduced here; the tests check the construction against its own
# definition (end conditions, tangency) instead.

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
class _Quintic:
    """A quintic in the centred, scaled variable ``t = (x - xm) / h``."""

    xm: float
    h: float
    coef_t: np.ndarray  # (6,) highest power first, in t

    @classmethod
    def fit(cls, x0, y0, dy0, ddy0, x1, y1, dy1, ddy1):
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
    return _Quintic.fit(*vals).coefficients_in_x()


def tangent_point(centre, radius, beta, side):
    """Point where a side with direction angle ``beta`` touches an edge circle.

    Parameters
    ----------
    centre : (2,) float
        Circle centre (x, y) in the unrolled plane [mm].
    radius : float
        Circle radius [mm].
    beta : float
        Direction angle of the side at the tangent point [rad], slope
        ``tan(beta)``, ``|beta| < pi/2``.
    side : {'minus', 'plus'}
        ``minus``: the face at lower y, touching the lower half of the
        circle; ``plus``: the face at higher y, upper half.

    Returns
    -------
    point : (2,) float
        ``centre + radius * (sin b, -cos b)`` (minus) or
        ``centre + radius * (-sin b, cos b)`` (plus) [mm].
    """
    sign = {"minus": 1.0, "plus": -1.0}[side]
    c = np.asanyarray(centre, dtype=np.float64)
    return c + radius * sign * np.array([math.sin(beta), -math.cos(beta)])


# --------------------------------------------------------------------------
# One section in the unrolled plane
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class SectionOutline:
    """A blade section in the unrolled plane on stations shared by both sides.

    Parameters
    ----------
    x : (C,) float
        Axial stations [mm], strictly increasing, from the LE circle's
        extreme point to the TE circle's extreme point.
    y_minus, y_plus : (C,) float
        Circumferential arc length of the minus and plus side [mm];
        equal at the two end stations, ``y_plus > y_minus`` in between.
    le_centre, te_centre : (2,) float
        Edge circle centres (after stagger) [mm].
    le_radius, te_radius : float
        Edge circle radii [mm].
    """

    x: np.ndarray
    y_minus: np.ndarray
    y_plus: np.ndarray
    le_centre: np.ndarray
    te_centre: np.ndarray
    le_radius: float
    te_radius: float

    @property
    def thickness(self):
        """(C,) circumferential thickness ``y_plus - y_minus`` [mm]."""
        return self.y_plus - self.y_minus


def _rotation(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


class _Side:
    """One side (arc - quintic - arc), possibly rotated about a pivot, as y(x)."""

    def __init__(self, name, side, le_c, le_r, te_c, te_r, beta0, beta1, ddy0, ddy1, stagger, pivot):
        self.sign = -1.0 if side == "minus" else 1.0
        p0 = tangent_point(le_c, le_r, beta0, side)
        p1 = tangent_point(te_c, te_r, beta1, side)
        if not p1[0] - p0[0] > 1e-9 * max(1.0, abs(p0[0]), abs(p1[0])):
            raise GeometryError(
                f"{name}: {side} side: its tangent point on the TE circle (x = {p1[0]:.4g} mm) does not lie "
                f"downstream of the one on the LE circle (x = {p0[0]:.4g} mm); the chord is too short for "
                f"the edge radii and side angles")
        q = _Quintic.fit(p0[0], p0[1], math.tan(beta0), ddy0, p1[0], p1[1], math.tan(beta1), ddy1)
        # the quintic must meet the circles' tangent points with the circles' tangent slopes
        scale = max(1.0, float(np.max(np.abs(np.concatenate([p0, p1])))))
        for label, p, beta in (("LE", p0, beta0), ("TE", p1, beta1)):
            miss = abs(float(q(p[0])) - p[1])
            slope_miss = abs(float(q(p[0], 1)) - math.tan(beta))
            if not (miss <= 1e-9 * scale and slope_miss <= 1e-7 * max(1.0, abs(math.tan(beta)))):
                raise GeometryError(
                    f"{name}: {side} side: the quintic misses the {label} circle's tangent point "
                    f"by {miss:.3g} mm (slope by {slope_miss:.3g}); ill-conditioned end conditions")
        self.quintic = q
        self.u0, self.u1 = float(p0[0]), float(p1[0])
        rot = _rotation(stagger)
        self.pivot = np.asanyarray(pivot, dtype=np.float64)
        self.cos, self.sin = math.cos(stagger), math.sin(stagger)
        self.le_c = self.pivot + rot @ (np.asanyarray(le_c, dtype=np.float64) - self.pivot)
        self.te_c = self.pivot + rot @ (np.asanyarray(te_c, dtype=np.float64) - self.pivot)
        self.le_r, self.te_r = float(le_r), float(te_r)
        for label, beta in (("LE", beta0), ("TE", beta1)):
            if not abs(beta + stagger) < _HALF_PI:
                raise GeometryError(
                    f"{name}: {side} side: stagger {stagger:.4g} rad turns its direction at the {label} to "
                    f"{beta + stagger:.4g} rad, beyond +-pi/2; y would not be single-valued in x")
        u = np.linspace(self.u0, self.u1, _DENSE)
        dxr = self.cos - q(u, 1) * self.sin
        if np.any(dxr <= 0.0):
            k = int(np.argmin(dxr))
            raise GeometryError(
                f"{name}: {side} side: stagger {stagger:.4g} rad turns the side past perpendicular to X near "
                f"x = {u[k]:.4g} mm; y would not be single-valued in x")
        self._u_dense = u
        self._xr_dense = self._xr(u)
        self.t0 = self._xr_dense[0]
        self.t1 = self._xr_dense[-1]

    def _xr(self, u):
        px, py = self.pivot
        return px + (u - px) * self.cos - (self.quintic(u) - py) * self.sin

    def _yr(self, u):
        px, py = self.pivot
        return py + (u - px) * self.sin + (self.quintic(u) - py) * self.cos

    def __call__(self, x):
        x = np.asanyarray(x, dtype=np.float64)
        y = np.empty_like(x)
        le = x <= self.t0
        te = x >= self.t1
        mid = ~(le | te)
        dx = x[le] - self.le_c[0]
        y[le] = self.le_c[1] + self.sign * np.sqrt(np.maximum(self.le_r ** 2 - dx * dx, 0.0))
        dx = x[te] - self.te_c[0]
        y[te] = self.te_c[1] + self.sign * np.sqrt(np.maximum(self.te_r ** 2 - dx * dx, 0.0))
        xm = x[mid]
        u = np.interp(xm, self._xr_dense, self._u_dense)
        if self.sin != 0.0:
            for _ in range(6):  # Newton on x_rotated(u) = x
                g = self._xr(u) - xm
                u = np.clip(u - g / (self.cos - self.quintic(u, 1) * self.sin), self.u0, self.u1)
            y[mid] = self._yr(u)
        else:
            y[mid] = self.quintic(xm)
        return y


def _cosine_stations(x0, x1, n):
    k = np.arange(n)
    x = x0 + (x1 - x0) * 0.5 * (1.0 - np.cos(np.pi * k / (n - 1)))
    x[0], x[-1] = x0, x1
    return x


def _check_finite(name, **values):
    for key, v in values.items():
        a = np.asanyarray(v, dtype=np.float64)
        if not np.all(np.isfinite(a)):
            raise GeometryError(f"{name}: {key} must be finite, got {a.tolist()}")


def _make_sides(le_centre, le_radius, te_centre, te_radius, minus_angles, plus_angles,
                minus_curvature, plus_curvature, stagger, pivot, name):
    """Validate the section's inputs and build its two sides (see :func:`section_outline`)."""
    _check_finite(name, le_centre=le_centre, te_centre=te_centre, le_radius=le_radius,
                  te_radius=te_radius, minus_angles=minus_angles, plus_angles=plus_angles,
                  minus_curvature=minus_curvature, plus_curvature=plus_curvature,
                  stagger=stagger, pivot=pivot)
    for key, r in (("le_radius", le_radius), ("te_radius", te_radius)):
        if not r > 0:
            raise GeometryError(f"{name}: {key} must be > 0 mm, got {r:g}")
    for key, angles in (("minus_angles", minus_angles), ("plus_angles", plus_angles)):
        for label, a in zip(("LE", "TE"), angles):
            if not abs(a) < _HALF_PI:
                raise GeometryError(f"{name}: {key} at the {label} must lie within +-pi/2 rad, got {a:.4g}")
    sides = {}
    for side, angles, curv in (("minus", minus_angles, minus_curvature), ("plus", plus_angles, plus_curvature)):
        sides[side] = _Side(name, side, le_centre, le_radius, te_centre, te_radius,
                            float(angles[0]), float(angles[1]), float(curv[0]), float(curv[1]),
                            float(stagger), pivot)
    return sides


def section_outline(le_centre, le_radius, te_centre, te_radius, minus_angles, plus_angles,
                    minus_curvature=(0.0, 0.0), plus_curvature=(0.0, 0.0), stagger=0.0,
                    pivot=(0.0, 0.0), station_count=101, name="section"):
    """Section outline from edge circles and side end conditions (Liu 2.2).

    Each side is: the LE circle arc from the circle's extreme point (lowest
    x) to the side's tangent point, the quintic of eq. 3 between the two
    tangent points, the TE circle arc to the circle's extreme point
    (highest x). With ``stagger`` the whole section is rotated about
    ``pivot`` first, and both sides are evaluated exactly on the rotated
    outline's common stations.

    Parameters
    ----------
    le_centre, te_centre : (2,) float
        Edge circle centres (x, y) [mm], before stagger.
    le_radius, te_radius : float
        Edge circle radii [mm], > 0.
    minus_angles, plus_angles : (2,) float
        Direction angle of each side at its LE and at its TE tangent
        point [rad] (slope = tan), ``|angle| < pi/2``.
    minus_curvature, plus_curvature : (2,) float
        d2y/dx2 of each side at its LE and TE tangent point [1/mm].
    stagger : float
        Rotation of the section about ``pivot`` [rad], counter-clockwise
        in (x, y); ``|angle + stagger| < pi/2`` for every side angle.
    pivot : (2,) float
        Centre of the stagger rotation [mm].
    station_count : int
        Number C of common stations (>= 4), cosine-clustered towards the
        edges.
    name : str
        Names the section in error messages.

    Returns
    -------
    SectionOutline
        Stations from ``le_centre_x - le_radius`` to ``te_centre_x +
        te_radius`` (after stagger); thickness exactly 0 at both ends.

    Raises
    ------
    GeometryError
        Non-finite or out-of-range input, tangent points out of axial
        order, a quintic that misses its tangent point, stagger that makes
        a side multi-valued in x, or sides that touch or cross.
    """
    sides = _make_sides(le_centre, le_radius, te_centre, te_radius, minus_angles, plus_angles,
                        minus_curvature, plus_curvature, stagger, pivot, name)
    if int(station_count) < 4:
        raise GeometryError(f"{name}: station_count must be >= 4, got {station_count}")
    s = sides["minus"]
    le_c, te_c = s.le_c, s.te_c
    x0, x1 = le_c[0] - le_radius, te_c[0] + te_radius
    if not x1 > x0:
        raise GeometryError(f"{name}: the TE circle does not lie downstream of the LE circle")

    def evaluate(xs):
        ym, yp = sides["minus"](xs), sides["plus"](xs)
        ym[0] = yp[0] = le_c[1]
        ym[-1] = yp[-1] = te_c[1]
        return ym, yp

    # validate on a dense grid (the sides must not touch or cross between the ends)
    xd = _cosine_stations(x0, x1, max(_DENSE, int(station_count)))
    ym, yp = evaluate(xd)
    t = (yp - ym)[1:-1]
    if not np.all(t > 0.0):
        k = int(np.argmin(t)) + 1
        raise GeometryError(
            f"{name}: the minus and plus sides cross at x = {xd[k]:.4g} mm "
            f"(thickness {t[k - 1]:.3g} mm); increase the wedge angles or adjust the end curvatures")
    x = _cosine_stations(x0, x1, int(station_count))
    ym, yp = evaluate(x)
    if not np.all((yp - ym)[1:-1] > 0.0):
        raise GeometryError(f"{name}: the minus and plus sides cross between the ends")
    return SectionOutline(x, ym, yp, le_c.copy(), te_c.copy(), float(le_radius), float(te_radius))


# --------------------------------------------------------------------------
# Designer's parameters, span interpolation and stacking
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class SectionDefinition:
    """Designer's parameters of one section (see the module docstring).

    Parameters
    ----------
    span : float
        Span fraction s (0 hub, 1 shroud).
    x_le, x_te : float
        Axial positions of the LE and TE circle centres [mm].
    le_radius, te_radius : float
        Edge circle radii [mm].
    inlet_angle, outlet_angle : float
        Camber-line angles at the LE and TE [rad].
    le_wedge, te_wedge : float
        Half wedge angles at the LE and TE [rad].
    minus_curvature, plus_curvature : (2,) float
        d2y/dx2 of each side at its LE and TE tangent point [1/mm].
    stagger : float
        Rotation of the section about its stacking point [rad].
    lean : float
        Angular position of the stacking point about X [rad].
    stack_x : float or None
        Axial position of the stacking point [mm] (the point mid-way
        between the two sides there, before stagger); None: mid-way between
        ``x_le`` and ``x_te``.
    """

    span: float
    x_le: float
    x_te: float
    le_radius: float
    te_radius: float
    inlet_angle: float
    outlet_angle: float
    le_wedge: float
    te_wedge: float
    minus_curvature: tuple = (0.0, 0.0)
    plus_curvature: tuple = (0.0, 0.0)
    stagger: float = 0.0
    lean: float = 0.0
    stack_x: float = None

    @property
    def stacking_x(self):
        """Axial position of the stacking point [mm]."""
        return 0.5 * (self.x_le + self.x_te) if self.stack_x is None else float(self.stack_x)

    def camber_y(self, x):
        """Design camber line y(x) relative to the LE circle centre [mm] (before stagger).

        Places the TE circle centre at ``camber_y(x_te)``; the mid-line of
        the finished section deviates from it (the sides are quintics).
        """
        c = self.x_te - self.x_le
        u = np.asanyarray(x, dtype=np.float64) - self.x_le
        ti, to = math.tan(self.inlet_angle), math.tan(self.outlet_angle)
        return ti * u + (to - ti) * u * u / (2.0 * c)


def definition_outline(defn, station_count=101, name="section"):
    """Outline of a designer's section with its stacking point at (stack_x, 0).

    Parameters
    ----------
    defn : SectionDefinition
    station_count : int
        Number C of common stations.
    name : str
        Names the section in error messages.

    Returns
    -------
    SectionOutline
        After stagger about the stacking point; y is the circumferential
        arc length relative to the stacking point [mm].

    Raises
    ------
    GeometryError
        As :func:`section_outline`, or ``stack_x`` outside the section.
    """
    if not defn.x_te > defn.x_le:
        raise GeometryError(f"{name}: x_te must be > x_le, got x_le = {defn.x_le:g}, x_te = {defn.x_te:g} mm")
    xs = defn.stacking_x
    if not defn.x_le - defn.le_radius < xs < defn.x_te + defn.te_radius:
        raise GeometryError(f"{name}: stack_x = {xs:g} mm lies outside the section's axial extent")
    le_c = np.array([defn.x_le, 0.0])
    te_c = np.array([defn.x_te, float(defn.camber_y(defn.x_te))])
    angles = dict(minus_angles=(defn.inlet_angle - defn.le_wedge, defn.outlet_angle + defn.te_wedge),
                  plus_angles=(defn.inlet_angle + defn.le_wedge, defn.outlet_angle - defn.te_wedge),
                  minus_curvature=defn.minus_curvature, plus_curvature=defn.plus_curvature)
    # stacking point: mid-way between the two sides at x = stack_x, before stagger
    sides = _make_sides(le_c, defn.le_radius, te_c, defn.te_radius, stagger=0.0, pivot=(0.0, 0.0),
                        name=name, **angles)
    at = np.array([xs])
    shift = np.array([0.0, -0.5 * float(sides["minus"](at)[0] + sides["plus"](at)[0])])
    return section_outline(le_c + shift, defn.le_radius, te_c + shift, defn.te_radius,
                           stagger=defn.stagger, pivot=(xs, 0.0), station_count=station_count,
                           name=name, **angles)


_SCALARS = ("x_le", "x_te", "le_radius", "te_radius", "inlet_angle", "outlet_angle",
            "le_wedge", "te_wedge", "stagger", "lean")


def _as_vector(d):
    return np.array([getattr(d, k) for k in _SCALARS] + list(d.minus_curvature) + list(d.plus_curvature)
                    + [d.stacking_x], dtype=np.float64)


def _from_vector(span, v):
    n = len(_SCALARS)
    kw = dict(zip(_SCALARS, (float(a) for a in v[:n])))
    return SectionDefinition(span=float(span), minus_curvature=(float(v[n]), float(v[n + 1])),
                             plus_curvature=(float(v[n + 2]), float(v[n + 3])), stack_x=float(v[n + 4]), **kw)


def interpolate_definitions(definitions, spans, method="cubic"):
    """Designer's parameters at the given span fractions.

    Parameters
    ----------
    definitions : sequence of SectionDefinition
        Spans strictly increasing; one definition gives a constant blade.
    spans : (S,) float
        Span fractions wanted; values outside the definitions' range are
        extrapolated (linear, or the end polynomial of the cubic spline).
    method : {'linear', 'cubic'}
        Linear, or natural cubic spline (linear with two definitions).

    Returns
    -------
    list of SectionDefinition
        One per span, with ``stack_x`` filled in.
    """
    defs = list(definitions)
    spans = np.atleast_1d(np.asanyarray(spans, dtype=np.float64))
    if not defs:
        raise GeometryError("parametric blade: no definition sections")
    if method not in ("linear", "cubic"):
        raise GeometryError(f"parametric blade: interpolation must be 'linear' or 'cubic', got {method!r}")
    if len(defs) == 1:
        return [replace(defs[0], span=float(s), stack_x=defs[0].stacking_x) for s in spans]
    s_def = np.array([d.span for d in defs])
    if np.any(np.diff(s_def) <= 0):
        raise GeometryError("parametric blade: definition spans must be strictly increasing")
    values = np.stack([_as_vector(d) for d in defs])
    if method == "cubic":
        fn = CubicSpline(s_def, values, axis=0, bc_type="natural", extrapolate=True)
    else:
        fn = make_interp_spline(s_def, values, k=1, axis=0)
    out = fn(spans)
    return [_from_vector(s, v) for s, v in zip(spans, out)]


def stack_sections(definitions, hub, shroud, station_count=101, where="blade.parametric"):
    """Stack designer's sections between hub and shroud into :class:`BladeSections`.

    Each section's outline (in the unrolled plane, stacking point at y = 0)
    is placed at ``r = r_hub(x) + s * (r_shroud(x) - r_hub(x))`` for its
    span fraction s and at ``theta = y / r + lean``.

    Parameters
    ----------
    definitions : sequence of SectionDefinition
        One per stacked section, in span order (e.g. from
        :func:`interpolate_definitions`); S >= 2.
    hub, shroud : RevolutionProfile
        Meridional profiles; shroud above hub over the blade.
    station_count : int
        Stations C per section.
    where : str
        Key path used in error messages.

    Returns
    -------
    BladeSections
        (S, C) arrays; ``theta_minus``/``theta_plus`` are the minus/plus
        sides.
    """
    defs = list(definitions)
    if len(defs) < 2:
        raise GeometryError(f"{where}: need at least two stacked sections, got {len(defs)}")
    xs, rs, tm, tp = [], [], [], []
    for d in defs:
        name = f"{where}: section at span {d.span:.4g}"
        out = definition_outline(d, station_count=station_count, name=name)
        rh, rt = hub.radius_at(out.x), shroud.radius_at(out.x)
        height = rt - rh
        if np.any(height < SIZE.min_channel_height):
            k = int(np.argmin(height))
            raise GeometryError(
                f"{where}: shroud_profile must lie at least {SIZE.min_channel_height:g} mm above hub_profile "
                f"over the blade, channel height at x = {out.x[k]:.4g} mm is {height[k]:.4g} mm")
        r = rh + d.span * height
        if np.any(r <= 0):
            raise GeometryError(f"{name}: non-positive radius")
        xs.append(out.x)
        rs.append(r)
        tm.append(out.y_minus / r + d.lean)
        tp.append(out.y_plus / r + d.lean)
    for prof in (hub, shroud):
        lo, hi = prof.x_range
        x_all = np.concatenate(xs)
        if x_all.min() < lo or x_all.max() > hi:
            _log.warning("%s: blade spans x = [%.3f, %.3f] mm beyond %s x = [%.3f, %.3f] mm; "
                         "the profile is continued as a cylinder", where, x_all.min(), x_all.max(),
                         prof.name, lo, hi)
    return BladeSections(np.array(xs), np.array(rs), np.array(tm), np.array(tp))


# --------------------------------------------------------------------------
# YAML parsing with key paths
# --------------------------------------------------------------------------

_SECTION_REQUIRED = ("span", "x_le", "x_te", "le_radius", "te_radius", "inlet_angle", "outlet_angle",
                     "le_wedge", "te_wedge")
_SECTION_OPTIONAL = ("minus_curvature", "plus_curvature", "stagger", "lean", "stack_x")
#: default ``span_extension``: the blade continued this fraction of the channel height past hub and shroud
SPAN_EXTENSION = 0.03

_TOP_KEYS = ("interpolation", "span_extension", "span_count", "station_count", "sections")


def _number(value, path, unit=""):
    if isinstance(value, bool) or not isinstance(value, Real):
        raise GeometryError(f"{path}: must be a number{' in ' + unit if unit else ''}, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise GeometryError(f"{path}: must be a finite number, got {v}")
    return v


def _integer(value, path, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise GeometryError(f"{path}: must be an integer, got {value!r}")
    if value < minimum:
        raise GeometryError(f"{path}: must be >= {minimum}, got {value}")
    return int(value)


def _mapping(value, path, allowed):
    if not isinstance(value, dict):
        raise GeometryError(f"{path}: must be a mapping, got {type(value).__name__}")
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise GeometryError(f"{path}.{unknown[0]}: unknown key (allowed: {', '.join(allowed)})")
    return value


def _parse_section(spec, path):
    _mapping(spec, path, _SECTION_REQUIRED + _SECTION_OPTIONAL)
    for k in _SECTION_REQUIRED:
        if k not in spec:
            raise GeometryError(f"{path}.{k}: required key missing")
    units = {"x_le": "mm", "x_te": "mm", "le_radius": "mm", "te_radius": "mm", "stack_x": "mm",
             "inlet_angle": "rad", "outlet_angle": "rad", "le_wedge": "rad", "te_wedge": "rad",
             "stagger": "rad", "lean": "rad", "span": ""}
    # stack_x: null means the default (mid-way between x_le and x_te)
    v = {k: _number(spec[k], f"{path}.{k}", units[k]) for k in units
         if k in spec and not (k == "stack_x" and spec[k] is None)}
    for k in ("minus_curvature", "plus_curvature"):
        if k in spec:
            c = spec[k]
            if not isinstance(c, (list, tuple)) or len(c) != 2:
                raise GeometryError(f"{path}.{k}: must be a list [start, end] of two numbers in 1/mm, got {c!r}")
            v[k] = tuple(_number(c[i], f"{path}.{k}[{i}]", "1/mm") for i in range(2))
    if not 0.0 <= v["span"] <= 1.0:
        raise GeometryError(f"{path}.span: must lie in [0, 1], got {v['span']:g}")
    if not v["x_te"] > v["x_le"]:
        raise GeometryError(f"{path}.x_te: must be > x_le ({v['x_le']:g} mm), got {v['x_te']:g}")
    for k in ("le_radius", "te_radius"):
        if not v[k] > 0:
            raise GeometryError(f"{path}.{k}: must be > 0 mm, got {v[k]:g}")
        if v[k] > 0.25 * (v["x_te"] - v["x_le"]):
            raise GeometryError(f"{path}.{k}: must be at most a quarter of x_te - x_le, got {v[k]:g} mm")
    for k in ("inlet_angle", "outlet_angle"):
        if not abs(v[k]) < _HALF_PI:
            raise GeometryError(f"{path}.{k}: must lie strictly between -pi/2 and pi/2 rad, got {v[k]:g}")
    for k, base in (("le_wedge", "inlet_angle"), ("te_wedge", "outlet_angle")):
        if not v[k] >= 0:
            raise GeometryError(f"{path}.{k}: must be >= 0 rad, got {v[k]:g}")
        if not abs(v[base]) + v[k] < _HALF_PI:
            raise GeometryError(
                f"{path}.{k}: {base} +- {k} must lie strictly between -pi/2 and pi/2 rad, "
                f"got {v[base]:g} +- {v[k]:g}")
    if "stack_x" in v and not v["x_le"] - v["le_radius"] < v["stack_x"] < v["x_te"] + v["te_radius"]:
        raise GeometryError(f"{path}.stack_x: must lie within the section's axial extent "
                            f"({v['x_le'] - v['le_radius']:g} ... {v['x_te'] + v['te_radius']:g} mm), "
                            f"got {v['stack_x']:g}")
    if "stagger" in v and not abs(v["stagger"]) < _HALF_PI:
        raise GeometryError(f"{path}.stagger: must lie strictly between -pi/2 and pi/2 rad, got {v['stagger']:g}")
    if "lean" in v and not abs(v["lean"]) < math.pi:
        raise GeometryError(f"{path}.lean: must lie strictly between -pi and pi rad, got {v['lean']:g}")
    return SectionDefinition(**v)


def parse_parametric(spec, hub: RevolutionProfile, shroud: RevolutionProfile,
                     where: str = "blade.parametric") -> BladeSections:
    """Build a blade from the ``blade: parametric:`` mapping (schema in the module docstring).

    Parameters
    ----------
    spec : dict
        The mapping as loaded from YAML.
    hub, shroud : RevolutionProfile
        Meridional profiles of the channel.
    where : str
        Key path of ``spec``, prefixed to every error message.

    Returns
    -------
    BladeSections
        ``span_count`` sections from s = 0 to s = 1 inclusive, plus one at
        each extended end; ``station_count`` stations each.

    Raises
    ------
    GeometryError
        With the key path, for missing, unknown, mistyped or out-of-range
        keys and for impossible sections.
    """
    _mapping(spec, where, _TOP_KEYS)
    method = spec.get("interpolation", "cubic")
    if method not in ("linear", "cubic"):
        raise GeometryError(f"{where}.interpolation: must be 'linear' or 'cubic', got {method!r}")
    ext = _number(spec.get("span_extension", SPAN_EXTENSION), f"{where}.span_extension")
    if not 0.0 <= ext <= 0.5:
        raise GeometryError(f"{where}.span_extension: must lie in [0, 0.5], got {ext:g}")
    span_count = _integer(spec.get("span_count", 21), f"{where}.span_count", 2)
    station_count = _integer(spec.get("station_count", 101), f"{where}.station_count", 8)
    if "sections" not in spec:
        raise GeometryError(f"{where}.sections: required key missing")
    sections = spec["sections"]
    if not isinstance(sections, list) or not sections:
        raise GeometryError(f"{where}.sections: must be a non-empty list of sections")
    defs = [_parse_section(s, f"{where}.sections[{i}]") for i, s in enumerate(sections)]
    for i in range(1, len(defs)):
        if not defs[i].span > defs[i - 1].span:
            raise GeometryError(
                f"{where}.sections[{i}].span: must exceed the previous section's span "
                f"{defs[i - 1].span:g}, got {defs[i].span:g}")
    if len(defs) > 1:
        if defs[0].span != 0.0:
            raise GeometryError(f"{where}.sections[0].span: the first section must be at span 0, "
                                f"got {defs[0].span:g}")
        if defs[-1].span != 1.0:
            raise GeometryError(f"{where}.sections[{len(defs) - 1}].span: the last section must be at span 1, "
                                f"got {defs[-1].span:g}")
    spans = np.linspace(0.0, 1.0, span_count)
    if ext > 0:
        spans = np.concatenate([[-ext], spans, [1.0 + ext]])
    stacked = interpolate_definitions(defs, spans, method)
    blade = stack_sections(stacked, hub, shroud, station_count=station_count, where=where)
    _log.debug("%s: %d x %d blade sections from %d definition sections", where, *blade.shape, len(defs))
    return blade
