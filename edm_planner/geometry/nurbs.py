"""Cubic B-spline reconstruction of blade surfaces from measured points.

Implements section 3 (eq. 13-18) of Liu Yuting et al. 2024, "Research on
search algorithm of electrode motion trajectory of EDM for complex
cavity-type parts":

1. cumulative chord-length parameters of the data points (eq. 13-14);
2. a clamped cubic knot vector by averaging those parameters (eq. 15);
3. a cubic B-spline that passes through data point ``q_i`` at the knot
   ``u_{i+3}`` (the *node* of ``q_i``) with prescribed end derivatives
   (eq. 16-18);
4. a tensor-product surface through a (sections x stations) grid, built by
   interpolating every section along u and then the resulting control points
   along v (Piegl & Tiller, *The NURBS Book*, section 9.2.5).

The paper writes the surface as a NURBS, but it fits measured points, for
which every weight is 1: the result is a plain (non-rational) B-spline, so
scipy's :class:`~scipy.interpolate.BSpline` and
:class:`~scipy.interpolate.NdBSpline` represent it exactly, and the linear
system of eq. 18 is the one :func:`scipy.interpolate.make_interp_spline`
solves when given the knot vector and first-derivative end conditions.

Only degree 3 is supported: the knot rule and the two tangent conditions of
the paper together fix exactly ``n + 3`` control points for ``n + 1`` data
points, which works for cubics only. Millimetres throughout; parameters u, v
are dimensionless in [0, 1].
"""

from dataclasses import dataclass, field
import logging

import numpy as np
from scipy.interpolate import NdBSpline, make_interp_spline

from ..errors import GeometryError

_log = logging.getLogger(__name__)

DEGREE = 3
"""Degree of every spline built here (the paper's cubic, p = 3)."""

_COINCIDE_RTOL = 1e-12
"""A chord shorter than this times the polyline length counts as zero."""

_PARAM_TOL = 1e-9
"""Evaluation parameters this far outside [0, 1] are clipped, not refused."""


# --------------------------------------------------------------------------
# Parameters and knots (eq. 13-15)
# --------------------------------------------------------------------------

def _check_points(points, name):
    """Validate a polyline ``(n+1, dim)`` and return it as float64."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 1:
        raise GeometryError(f"{name}: points must be an (n, dim) array, got shape {pts.shape}")
    if pts.shape[0] < DEGREE + 1:
        raise GeometryError(
            f"{name}: need at least {DEGREE + 1} points for a cubic, got {pts.shape[0]}")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise GeometryError(f"{name}: point {int(np.flatnonzero(bad)[0])} is not finite")
    return pts


def _chord_params(pts, name, item="points"):
    """Chord-length parameters of a validated polyline (eq. 13-14)."""
    chords = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    total = float(chords.sum())
    short = chords <= _COINCIDE_RTOL * total
    if total <= 0.0 or short.any():
        i = int(np.flatnonzero(short)[0]) if short.any() else 0
        raise GeometryError(f"{name}: {item} {i} and {i + 1} coincide")
    params = np.empty(pts.shape[0])
    params[0] = 0.0
    params[1:] = np.cumsum(chords) / total
    params[-1] = 1.0
    return params


def chord_length_parameters(points, *, name="curve"):
    """Cumulative chord-length parameters of a polyline (eq. 13-14).

    Parameters
    ----------
    points : (n+1, dim) float
        Data points ``q_0 .. q_n`` [mm], ``n + 1 >= 4``.
    name : str, optional
        Label used in error messages.

    Returns
    -------
    params : (n+1,) float
        ``ubar_0 = 0``, ``ubar_n = 1``,
        ``ubar_i = ubar_{i-1} + |q_i - q_{i-1}| / d`` with ``d`` the polyline
        length. Strictly increasing.

    Raises
    ------
    GeometryError
        Fewer than 4 points, a non-finite point, or two consecutive points
        that coincide.
    """
    return _chord_params(_check_points(points, name), name)


def averaged_knots(params, degree=3):
    """Clamped cubic knot vector by averaging the parameters (eq. 15).

    Parameters
    ----------
    params : (n+1,) float
        Increasing data parameters ``ubar_0 = 0 .. ubar_n = 1``, ``n >= 3``.
    degree : int, optional
        Must be 3 (the paper's scheme is specific to cubics).

    Returns
    -------
    knots : (n+7,) float
        ``[0, 0, 0, 0, u_4, .., u_{n+2}, 1, 1, 1, 1]`` with the ``n - 1``
        interior knots ``u_{j+3} = (ubar_j + ubar_{j+1} + ubar_{j+2}) / 3``,
        ``j = 1 .. n-1``, where ``ubar_{n+1} = 1``.

    Notes
    -----
    Eq. 15 as printed (``u_{j+k} = 1/k sum_{i=j}^{j+k-1} u_i``,
    ``j = 1 .. n-k``) is ambiguous: it averages the knots themselves and
    yields only ``n - k`` interior knots, while the interpolation of eq. 16-18
    (``n + 3`` control points) needs ``n - 1``. Averaging three consecutive
    *parameters* starting at ``ubar_1``, with the parameter vector padded by
    one extra 1, is the form that reproduces the paper's worked example
    (its U and V vectors, section 3.2) to all printed digits; it is neither
    Piegl & Tiller's eq. 9.8 nor their eq. 9.22.
    """
    if degree != DEGREE:
        raise ValueError(f"averaged_knots: only degree 3 is supported, got {degree}")
    ubar = np.asarray(params, dtype=np.float64)
    if ubar.ndim != 1 or ubar.size < DEGREE + 1:
        raise GeometryError(
            f"averaged_knots: need a 1-D vector of at least {DEGREE + 1} parameters, "
            f"got shape {ubar.shape}")
    if not np.isfinite(ubar).all():
        raise GeometryError("averaged_knots: parameters must be finite")
    if not (np.diff(ubar) > 0).all():
        raise GeometryError("averaged_knots: parameters must be strictly increasing")
    padded = np.append(ubar, 1.0)                       # ubar_0 .. ubar_{n+1}
    n = ubar.size - 1
    interior = (padded[1:n] + padded[2:n + 1] + padded[3:n + 2]) / 3.0
    return np.concatenate([np.zeros(DEGREE + 1), interior, np.ones(DEGREE + 1)])


def chord_knots(params, degree=3):
    """Clamped cubic knot vector with the data at their chord-length parameters.

    The interior knots are ``ubar_1 .. ubar_{n-1}`` themselves (de Boor's
    "knots at the data" with end tangents), so the nodes of eq. 16 are the
    chord-length parameters. Not the paper's rule: with the paper's averaged
    knots the data sit at averaged positions and the error near the ends of a
    patch converges only as h^2 (6.8e-3 mm on a 13-point R = 110 mm arc against
    2.3e-7 mm with this rule), so the product uses this rule by default and
    keeps the paper's as ``knot_rule="paper"`` for comparison.

    Returns
    -------
    knots : (n+7,) float
    """
    if degree != DEGREE:
        raise ValueError(f"chord_knots: only degree 3 is supported, got {degree}")
    ubar = np.asarray(params, dtype=np.float64)
    if ubar.ndim != 1 or ubar.size < DEGREE + 1 or not (np.diff(ubar) > 0).all():
        raise GeometryError("chord_knots: need at least 4 strictly increasing parameters")
    return np.concatenate([np.zeros(DEGREE + 1), ubar[1:-1], np.ones(DEGREE + 1)])


#: knot rules for interpolation: the paper's (Liu 2024 eq. 15) and the accurate default
KNOT_RULES = {"paper": averaged_knots, "chord": chord_knots}


def _nodes(knots, n_points):
    """Node parameters ``u_3 .. u_{n+3}`` at which the data is interpolated."""
    return np.asarray(knots[DEGREE:DEGREE + n_points], dtype=np.float64)


# --------------------------------------------------------------------------
# Curve interpolation (eq. 16-18)
# --------------------------------------------------------------------------

def _parabola_slope(t, y, at):
    """Slope at ``t[at]`` of the parabola through ``(t[k], y[k])``, k = 0..2.

    ``t`` : (3,), ``y`` : (3, ...). Returns (...).
    """
    x = t[at]
    w = np.empty(3)
    for k in range(3):
        m, l_ = [i for i in range(3) if i != k]
        # d/dx of the Lagrange basis L_k at x
        w[k] = ((x - t[l_]) + (x - t[m])) / ((t[k] - t[m]) * (t[k] - t[l_]))
    return np.tensordot(w, y, axes=(0, 0))


def _bessel_tangents(nodes, values):
    """Bessel end derivatives (slopes of the end parabolas at the end nodes).

    ``nodes`` : (n+1,), ``values`` : (n+1, ...). Returns two (...) arrays.
    """
    start = _parabola_slope(nodes[:3], values[:3], 0)
    end = _parabola_slope(nodes[-3:], values[-3:], 2)
    return start, end


def _solve(nodes, knots, values, start, end):
    """Cubic spline with knots ``knots`` through ``values`` at ``nodes``.

    Eq. 16-18: ``d_0 = q_0`` and ``d_{n+2} = q_n`` hold automatically for a
    clamped knot vector; the end conditions are
    ``P'(0) = 3 (d_1 - d_0) / (u_4 - u_3) = q'_0`` and
    ``P'(1) = 3 (d_{n+2} - d_{n+1}) / (u_{n+3} - u_{n+2}) = q'_n``. (Eq. 17
    as printed is garbled - it equates a difference of control points to a
    point plus a scaled derivative; this is the consistent form of the cubic
    B-spline end derivative, and what eq. 18's rows ``[-1 1]`` encode up to
    the scale factor.) :func:`make_interp_spline` assembles and solves
    exactly this banded system.
    """
    try:
        return make_interp_spline(nodes, values, k=DEGREE, t=knots,
                                  bc_type=([(1, start)], [(1, end)]))
    except (ValueError, np.linalg.LinAlgError) as exc:    # singular collocation
        raise GeometryError(f"spline interpolation failed: {exc}") from exc


def interpolate_curve(points, start_tangent=None, end_tangent=None, *, knots=None, name="curve"):
    """Cubic B-spline through points with end-tangent conditions (eq. 13-18).

    Parameters
    ----------
    points : (n+1, dim) float
        Data points ``q_0 .. q_n`` [mm], ``n + 1 >= 4``; ``dim`` is usually
        2 or 3.
    start_tangent, end_tangent : (dim,) float, optional
        End derivatives ``dP/du`` at ``u = 0`` and ``u = 1`` [mm per unit
        parameter] - derivatives, not unit directions (their length is
        roughly the curve length). Each one left out is estimated by
        Bessel's end condition: the slope of the parabola through the first
        (last) three points at their node parameters.
    knots : (n+7,) float, optional
        Clamped cubic knot vector to use instead of the paper's
        chord-length + averaging one (e.g. to test the solver); the data are
        then interpolated at ``knots[3:n+4]``.
    name : str, optional
        Label used in error messages.

    Returns
    -------
    spline : scipy.interpolate.BSpline
        Cubic, domain [0, 1], ``n + 3`` control points ``spline.c`` of shape
        (n+3, dim), knot vector ``spline.t`` of shape (n+7,). It passes
        through ``q_i`` at the node ``u_{i+3} = spline.t[i + 3]`` (nodes
        ``0, u_4, .., u_{n+2}, 1``) - not at the chord-length parameters.

    Raises
    ------
    GeometryError
        Fewer than 4 points, non-finite values, coincident consecutive
        points, bad tangents or knots.
    """
    pts = _check_points(points, name)
    n_points, dim = pts.shape
    if knots is None:
        knots = averaged_knots(_chord_params(pts, name))
    else:
        knots = np.asarray(knots, dtype=np.float64)
        expected = n_points + 2 * DEGREE
        if knots.shape != (expected,) or not np.isfinite(knots).all():
            raise GeometryError(f"{name}: knots must be {expected} finite values, got shape {knots.shape}")
        inner = knots[DEGREE:n_points + DEGREE]
        if (np.diff(knots) < 0).any() or not (np.diff(inner) > 0).all():
            raise GeometryError(f"{name}: knots must be non-decreasing with distinct nodes")
    nodes = _nodes(knots, n_points)
    est_start, est_end = _bessel_tangents(nodes, pts)
    tangents = []
    for given, estimate, which in ((start_tangent, est_start, "start"), (end_tangent, est_end, "end")):
        if given is None:
            tangents.append(estimate)
            continue
        tan = np.asarray(given, dtype=np.float64)
        if tan.shape != (dim,) or not np.isfinite(tan).all():
            raise GeometryError(f"{name}: {which} tangent must be {dim} finite values, got {given!r}")
        tangents.append(tan)
    return _solve(nodes, knots, pts, tangents[0], tangents[1])


# --------------------------------------------------------------------------
# Surface interpolation
# --------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SplineSurface:
    """Bicubic tensor-product B-spline surface S(u, v), all weights 1.

    u runs along each section (the chord: data column index), v across the
    sections (the span: data row index); both in [0, 1].

    Parameters
    ----------
    control_points : (m+3, n+3, 3) float
        Control net ``P[j, i]`` [mm], j along v, i along u.
    knots_u : (n+7,) float
        Clamped cubic knot vector in u.
    knots_v : (m+7,) float
        Clamped cubic knot vector in v.
    nodes_u : (n+1,) float
        u of the data columns (``knots_u[3:n+4]``).
    nodes_v : (m+1,) float
        v of the data rows (``knots_v[3:m+4]``).

    Notes
    -----
    Data point ``grid[j, i]`` lies at ``S(nodes_u[i], nodes_v[j])``.
    Evaluation goes through :class:`scipy.interpolate.NdBSpline`; parameters
    outside [0, 1] by more than 1e-9 are refused.
    """

    control_points: np.ndarray
    knots_u: np.ndarray
    knots_v: np.ndarray
    nodes_u: np.ndarray
    nodes_v: np.ndarray
    _spline: NdBSpline = field(init=False, repr=False)

    def __post_init__(self):
        cp = np.asarray(self.control_points, dtype=np.float64)
        tu = np.asarray(self.knots_u, dtype=np.float64)
        tv = np.asarray(self.knots_v, dtype=np.float64)
        if cp.ndim != 3 or cp.shape[2] != 3:
            raise GeometryError(f"spline surface: control points must be (nv, nu, 3), got {cp.shape}")
        if tu.shape != (cp.shape[1] + DEGREE + 1,) or tv.shape != (cp.shape[0] + DEGREE + 1,):
            raise GeometryError("spline surface: knot vectors do not match the control net")
        object.__setattr__(self, "control_points", cp)
        object.__setattr__(self, "knots_u", tu)
        object.__setattr__(self, "knots_v", tv)
        object.__setattr__(self, "nodes_u", np.asarray(self.nodes_u, dtype=np.float64))
        object.__setattr__(self, "nodes_v", np.asarray(self.nodes_v, dtype=np.float64))
        object.__setattr__(self, "_spline", NdBSpline((tv, tu), cp, DEGREE))

    def _xi(self, u, v):
        """Stack (v, u) into NdBSpline's (..., 2) argument, checking the range."""
        u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
        xi = np.stack([v, u], axis=-1)
        if not np.isfinite(xi).all():
            raise GeometryError("spline surface: parameters must be finite")
        if (xi < -_PARAM_TOL).any() or (xi > 1.0 + _PARAM_TOL).any():
            raise GeometryError("spline surface: parameters must lie in [0, 1]")
        return np.clip(xi, 0.0, 1.0)

    def evaluate(self, u, v):
        """Points on the surface.

        Parameters
        ----------
        u, v : (...) float
            Parameters in [0, 1] (broadcast against each other).

        Returns
        -------
        points : (..., 3) float
            ``S(u, v)`` [mm].
        """
        return self._spline(self._xi(u, v))

    def derivatives(self, u, v):
        """First partial derivatives.

        Parameters
        ----------
        u, v : (...) float
            Parameters in [0, 1].

        Returns
        -------
        s_u, s_v : (..., 3) float
            ``dS/du`` and ``dS/dv`` [mm per unit parameter].
        """
        xi = self._xi(u, v)
        return self._spline(xi, nu=(0, 1)), self._spline(xi, nu=(1, 0))

    def normals(self, u, v):
        """Unit normals ``S_u x S_v / |S_u x S_v|``.

        The orientation is right-handed in (u, v): with u along the chord
        (leading to trailing edge) and v from hub to shroud, the normal is
        ``chord x span``; reversing either data direction flips it.

        Parameters
        ----------
        u, v : (...) float
            Parameters in [0, 1].

        Returns
        -------
        normals : (..., 3) float
            Unit vectors; zero vectors where the surface is degenerate
            (``S_u x S_v = 0``).
        """
        s_u, s_v = self.derivatives(u, v)
        n = np.cross(s_u, s_v)
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def grid(self, nu, nv):
        """Points on a uniform parameter grid, e.g. for meshing.

        Parameters
        ----------
        nu, nv : int
            Number of samples in u and v (>= 2), including 0 and 1.

        Returns
        -------
        points : (nv, nu, 3) float
            ``points[j, i] = S(i / (nu-1), j / (nv-1))`` [mm].
        """
        if int(nu) < 2 or int(nv) < 2:
            raise ValueError(f"spline surface grid: need nu, nv >= 2, got {nu}, {nv}")
        u, v = np.meshgrid(np.linspace(0.0, 1.0, int(nu)), np.linspace(0.0, 1.0, int(nv)))
        return self.evaluate(u, v)


def interpolate_surface(grid, *, name="surface", knot_rule="chord"):
    """Bicubic surface through a (sections x stations) grid of points.

    Parameters
    ----------
    grid : (S, C, 3) float
        ``grid[j, i]``: station i (along u, the chord) of section j (along v,
        the span) [mm]; ``S, C >= 4``.
    name : str, optional
        Label used in error messages (e.g. ``"blade"`` gives
        ``"blade section 3: points 5 and 6 coincide"``).

    Returns
    -------
    surface : SplineSurface
        Control net (S+2, C+2, 3); passes through every grid point at
        ``(nodes_u[i], nodes_v[j])``.

    Notes
    -----
    Piegl & Tiller's global surface interpolation with the paper's curve
    scheme in each direction: the u parameters are the chord-length
    parameters averaged over the sections, the v parameters those averaged
    over the stations; knots by :func:`averaged_knots`; every section is
    interpolated along u (Bessel end tangents) and the resulting control
    points along v (Bessel end tangents). All steps are linear, so the order
    of the two directions does not matter.

    Raises
    ------
    GeometryError
        Wrong shape, fewer than 4 sections or stations, non-finite values, or
        consecutive coincident points along a section or a station.
    """
    q = np.asarray(grid, dtype=np.float64)
    if q.ndim != 3 or q.shape[2] != 3:
        raise GeometryError(f"{name}: grid must be (sections, stations, 3), got shape {q.shape}")
    n_sec, n_sta = q.shape[:2]
    if n_sec < DEGREE + 1 or n_sta < DEGREE + 1:
        raise GeometryError(
            f"{name}: need at least {DEGREE + 1} sections of {DEGREE + 1} stations, got {n_sec} x {n_sta}")
    bad = ~np.isfinite(q).all(axis=2)
    if bad.any():
        j, i = np.argwhere(bad)[0]
        raise GeometryError(f"{name} section {j}: point {i} is not finite")

    ubar = np.mean([_chord_params(q[j], f"{name} section {j}") for j in range(n_sec)], axis=0)
    vbar = np.mean([_chord_params(q[:, i], f"{name} station {i}", "sections")
                    for i in range(n_sta)], axis=0)
    if knot_rule not in KNOT_RULES:
        raise GeometryError(f"{name}: knot_rule must be one of {sorted(KNOT_RULES)}, got {knot_rule!r}")
    knots_u, knots_v = KNOT_RULES[knot_rule](ubar), KNOT_RULES[knot_rule](vbar)
    nodes_u, nodes_v = _nodes(knots_u, n_sta), _nodes(knots_v, n_sec)

    # along u, all sections at once: values (C, S, 3) -> control points (C+2, S, 3)
    values = q.transpose(1, 0, 2)
    start, end = _bessel_tangents(nodes_u, values)
    rows = _solve(nodes_u, knots_u, values, start, end).c
    # along v, all control columns at once: (S, C+2, 3) -> (S+2, C+2, 3)
    values = rows.transpose(1, 0, 2)
    start, end = _bessel_tangents(nodes_v, values)
    net = _solve(nodes_v, knots_v, values, start, end).c
    _log.debug("%s: interpolated %d x %d grid, control net %s", name, n_sec, n_sta, net.shape)
    return SplineSurface(net, knots_u, knots_v, nodes_u, nodes_v)
