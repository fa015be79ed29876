"""Samples of the four surfaces of a channel on structured grids, area-weighted, for the removal proof.

:func:`wall_samples` samples the suction and pressure walls on an (x, span)
grid and the hub and shroud on an (x, angle between the walls) grid, with
neighbouring samples at most a given spacing apart in W and extra rows graded
towards every edge (:data:`~.removal_tolerances.REMOVAL_EDGE_DEPTHS`).

Plain numpy; no rclpy. Units: mm, rad.
"""

from dataclasses import dataclass

import numpy as np

from ..geometry.frames import cylindrical_to_cartesian
from .removal_tolerances import REMOVAL, REMOVAL_EDGE_DEPTHS


@dataclass(frozen=True, eq=False)
class WallSamples:
    """Samples of one channel surface on a structured grid.

    Attributes
    ----------
    surface : str
        'suction', 'pressure', 'hub' or 'shroud'.
    points : (n, 3) float
        Sample points in W [mm], n = rows * cols, row-major in ``shape``.
    u, v : (rows, cols) float
        Unrolled map coordinates [mm]: blade walls x and r; hub/shroud x and
        arc length r * theta.
    weights : (n,) float
        Area weights [mm^2] (Jacobian of the parametrisation x trapezoid rule); 0 where invalid.
    valid : (n,) bool
        The walls exist at the sample (always true on a blisk whose full-span range is sound).
    spacing : float
        Largest distance between neighbouring samples in W [mm].
    """

    surface: str
    points: np.ndarray
    u: np.ndarray
    v: np.ndarray
    weights: np.ndarray
    valid: np.ndarray
    spacing: float

    @property
    def shape(self):
        """(rows, cols) of the grid."""
        return self.u.shape

    @property
    def area(self):
        """Area of the sampled surface [mm^2]."""
        return float(self.weights.sum())


def _trapezoid(t):
    w = np.zeros_like(t)
    d = np.diff(t)
    w[:-1] += d / 2
    w[1:] += d / 2
    return w


def _steps(pts, inside, shape):
    """Largest distance in W between neighbouring samples along x and across, where both lie on the wall.

    Samples outside the walls' footprint carry no meaningful position and are left out.
    """
    grid, ok = pts.reshape(*shape, 3), np.asarray(inside).reshape(shape)
    dx = np.linalg.norm(np.diff(grid, axis=1), axis=2)[ok[:, 1:] & ok[:, :-1]]
    dt = np.linalg.norm(np.diff(grid, axis=0), axis=2)[ok[1:] & ok[:-1]]
    return float(dx.max(initial=0.0)), float(dt.max(initial=0.0))


def _graded(params, stretch, depths=REMOVAL_EDGE_DEPTHS):
    """``params`` (increasing) with extra values at physical ``depths`` [mm] inside both ends.

    ``stretch``: mm per unit of the parameter (its largest rate over the surface).
    """
    lo, hi = params[0], params[-1]
    first = params[1] - lo
    extra = [d / stretch for d in depths if d / stretch < 0.5 * first]
    return np.unique(np.concatenate([params, lo + np.asarray(extra), hi - np.asarray(extra)]))


def _grid_count(length, stretch, spacing):
    return max(2, int(np.ceil(length * stretch / spacing)) + 1)


def wall_samples(blisk, spacing=REMOVAL.spacing):
    """Sample the four surfaces of channel 0 over its closed axial range.

    Over ``blisk.full_span_axial_range`` (where both blade faces span hub to
    shroud): the blade walls on an (x, normalised span) grid at theta =
    wall_angles (suction: theta_suction, pressure: theta_pressure, both in
    channel-0 position), hub and shroud on an (x, normalised angle between
    the two walls) grid at the hub/shroud radius. The grid counts are chosen
    so that neighbouring samples are at most ``spacing`` apart in W (sized on
    a pilot grid). Wall angles at the hub/shroud radius are evaluated
    ``REMOVAL.wall_inset`` (1e-6 mm) inside the channel, since the spline
    footprint may report "outside" exactly on its edge; the blade-wall rows
    at the ends of the span lie that far inside too.

    Parameters
    ----------
    blisk : Blisk
    spacing : float
        Largest sample spacing [mm].

    Returns
    -------
    dict
        surface name -> :class:`WallSamples`, in ``CHANNEL_SURFACES`` order.
    """
    x0, x1 = blisk.full_span_axial_range
    eps = REMOVAL.wall_inset

    def span(x):
        lo = blisk.hub.radius_at(x) + eps
        return lo, blisk.shroud.radius_at(x) - eps - lo

    def blade(xx, ss, which):
        r_lo, h = span(xx)
        r = r_lo + ss * h
        th_s, th_p, inside, (g_s, g_p) = blisk.wall_angles(xx.ravel(), r.ravel(), with_gradient=True)
        th, grad = (th_s, g_s) if which == "suction" else (th_p, g_p)
        r = r.ravel()
        # |dP/dx x dP/dr| for theta = f(x, r); times dr/ds = h
        jac = np.sqrt(1.0 + r**2 * (grad[:, 0] ** 2 + grad[:, 1] ** 2)) * np.broadcast_to(h, xx.shape).ravel()
        return cylindrical_to_cartesian(xx.ravel(), r, th), r, inside, jac

    def ring(xx, tt, profile, sign):
        R = profile.radius_at(xx)
        th_s, th_p, inside = blisk.wall_angles(xx.ravel(), (R + sign * eps).ravel())
        th = th_s + tt.ravel() * (th_p - th_s)
        jac = R.ravel() * np.sqrt(1.0 + profile.slope_at(xx).ravel() ** 2) * (th_p - th_s)
        return cylindrical_to_cartesian(xx.ravel(), R.ravel(), th), R.ravel() * th, inside, jac

    def build(surface, make):
        # pilot grid: how far samples move in W per unit of each grid parameter
        a = np.linspace(0.0, 1.0, REMOVAL.pilot)
        xx, tt = np.meshgrid(x0 + a * (x1 - x0), a)
        pts, _, inside, _ = make(xx, tt)
        along_x, across = (s * (REMOVAL.pilot - 1) for s in _steps(pts, inside, xx.shape))
        nx, nt = _grid_count(1.0, along_x, spacing), _grid_count(1.0, across, spacing)
        cap = REMOVAL.max_grid
        for _ in range(4):
            xs, ts = np.linspace(x0, x1, nx), np.linspace(0.0, 1.0, nt)
            xx, tt = np.meshgrid(xs, ts)
            pts, v, inside, jac = make(xx, tt)
            step_x, step_t = _steps(pts, inside, xx.shape)
            if max(step_x, step_t) <= spacing or max(nx, nt) >= cap:
                break
            # the pilot grid missed a tighter bend: refine by the excess (never beyond the cap: a
            # degenerate corner of the surface must not take the memory)
            nx = min(int(np.ceil((nx - 1) * max(step_x / spacing, 1.0))) + 1, cap)
            nt = min(int(np.ceil((nt - 1) * max(step_t / spacing, 1.0))) + 1, cap)
        reach = max(step_x, step_t)
        # rows graded towards every edge: the corner fillets (about gap (sqrt 2 - 1) deep, a few
        # hundredths wide) and the end strips are narrower than the spacing, and a boundary row's
        # half-cell weight would count them several times too wide
        xs = _graded(xs, along_x / (x1 - x0))
        ts = _graded(ts, across)
        xx, tt = np.meshgrid(xs, ts)
        pts, v, inside, jac = make(xx, tt)
        nt, nx = len(ts), len(xs)
        weights = jac * np.outer(_trapezoid(ts), _trapezoid(xs)).ravel() * inside
        return WallSamples(surface, pts, xx, v.reshape(nt, nx), weights, inside, float(reach))

    return {
        "suction": build("suction", lambda xx, ss: blade(xx, ss, "suction")),
        "pressure": build("pressure", lambda xx, ss: blade(xx, ss, "pressure")),
        "hub": build("hub", lambda xx, tt: ring(xx, tt, blisk.hub, +1.0)),
        "shroud": build("shroud", lambda xx, tt: ring(xx, tt, blisk.shroud, -1.0)),
    }
