"""One section of a parametric blade in the unrolled plane: edge circles, quintic sides, designer's parameters.

A blade section is built as in Liu Yuting et al. 2024 (section 2.2, eq. 3-5)
in the *unrolled* plane of a span fraction: ``x`` is the axial position and
``y`` the circumferential arc length ``r * theta`` [mm]. The section is
bounded by a leading-edge (LE) and a trailing-edge (TE) circle (centre and
radius) and by two sides, each a quintic ``y = f(x)``
(:mod:`.parametric_quintic`) fixed by position, slope and second derivative
at its two tangent points on the edge circles:

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
Each definition section (:class:`SectionDefinition`) has a design camber
line whose slope varies linearly in x from ``tan(inlet_angle)`` at the LE
circle centre ``(x_le, y_le)`` to ``tan(outlet_angle)`` at the TE circle
centre ``(x_te, y_te)``; it only places the TE circle:
``y_te - y_le = (x_te - x_le) * (tan(inlet_angle) + tan(outlet_angle)) / 2``.
The sides leave the LE at ``inlet_angle -/+ le_wedge`` (minus/plus) and
reach the TE at ``outlet_angle +/- te_wedge``, so the wedge angles (with the
edge radii) set the thickness; their second derivatives at the ends are
``minus_curvature``/``plus_curvature`` (default 0). The section is shifted
in y so that its stacking point (mid-way between its two sides at
``x = stack_x``) lies at ``y = 0`` and rotated by ``stagger`` about the
stacking point (positive: counter-clockwise in the (x, y) plane, i.e. it
adds to every side angle) (:func:`definition_outline`); the sections are
stacked between hub and shroud by :mod:`.parametric_stacking`.
"""

import math
from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from .parametric_quintic import Quintic

__all__ = ["tangent_point", "SectionOutline", "section_outline", "SectionDefinition", "definition_outline"]

_HALF_PI = 0.5 * math.pi
#: samples used to invert a staggered quintic and to check the sides for crossing
_DENSE = 1201


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
        q = Quintic.fit(p0[0], p0[1], math.tan(beta0), ddy0, p1[0], p1[1], math.tan(beta1), ddy1)
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
