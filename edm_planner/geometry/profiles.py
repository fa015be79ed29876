"""Meridional profiles: the hub and the shroud as surfaces of revolution.

A profile is a curve r(x) in the (x, r) half-plane, interpolated with a
monotone piecewise cubic (PCHIP: C1, no overshoot between measured points)
and continued as a cylinder beyond its first and last point.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PchipInterpolator

from ..errors import GeometryError


@dataclass(frozen=True)
class RevolutionProfile:
    """A surface of revolution about X given by its meridional profile.

    Parameters
    ----------
    points : (n, 2) float
        ``[x, r]`` pairs [mm], x strictly increasing, r > 0, n >= 2.
    name : str
        Used in error messages (``hub_profile``, ``shroud_profile``).
    """

    points: np.ndarray
    name: str = "profile"
    _interp: PchipInterpolator = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        pts = np.asanyarray(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise GeometryError(f"{self.name}: expected a list of at least two [x, r] pairs in mm")
        if not np.all(np.isfinite(pts)):
            raise GeometryError(f"{self.name}: contains NaN or infinite values")
        if np.any(np.diff(pts[:, 0]) <= 0):
            raise GeometryError(f"{self.name}: x must be strictly increasing")
        if np.any(pts[:, 1] <= 0):
            raise GeometryError(f"{self.name}: radii must be positive (mm)")
        pts = pts.copy()
        pts.flags.writeable = False
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "_interp", PchipInterpolator(pts[:, 0], pts[:, 1], extrapolate=False))

    @property
    def x_range(self):
        """(x_min, x_max) of the given points [mm]."""
        return float(self.points[0, 0]), float(self.points[-1, 0])

    def radius_at(self, x):
        """Radius r(x) [mm]; constant continuation outside the given x range.

        Parameters
        ----------
        x : (...) float
        """
        x = np.asanyarray(x, dtype=np.float64)
        lo, hi = self.x_range
        return self._interp(np.clip(x, lo, hi))

    def slope_at(self, x):
        """dr/dx at x (0 outside the given range)."""
        x = np.asanyarray(x, dtype=np.float64)
        lo, hi = self.x_range
        inside = (x >= lo) & (x <= hi)
        return np.where(inside, self._interp.derivative()(np.clip(x, lo, hi)), 0.0)

    def sample(self, x_min, x_max, step=0.25):
        """Points of the profile on [x_min, x_max], at most ``step`` mm apart, with the knots included.

        Returns
        -------
        points : (m, 2) float
        """
        n = max(2, int(np.ceil((x_max - x_min) / step)) + 1)
        xs = np.linspace(x_min, x_max, n)
        knots = self.points[:, 0]
        xs = np.unique(np.concatenate([xs, knots[(knots > x_min) & (knots < x_max)]]))
        return np.column_stack([xs, self.radius_at(xs)])

    def offset(self, distance, x_min, x_max, step=0.25):
        """Profile offset by ``distance`` [mm] along its normal in the (x, r) plane.

        Positive distance moves outwards (larger r). Used for the discharge
        gap (hub side: +gap, shroud side: -gap) and the radial reduction.

        Returns
        -------
        RevolutionProfile
        """
        pts = self.sample(x_min, x_max, step)
        slope = self.slope_at(pts[:, 0])
        normal = np.column_stack([-slope, np.ones_like(slope)]) / np.hypot(slope, 1.0)[:, None]
        moved = pts + distance * normal
        if np.any(np.diff(moved[:, 0]) <= 0):
            raise GeometryError(
                f"{self.name}: offset by {distance} mm folds the profile (curvature radius below the offset)")
        return RevolutionProfile(moved, name=f"{self.name} offset {distance:+g} mm")
