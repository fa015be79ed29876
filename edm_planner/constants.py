"""Tolerances and limits in one place (after trimesh.constants).

Units: millimetres and radians throughout.
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """Numerical tolerances of the geometry core."""

    #: two points closer than this are the same point [mm]
    merge: float = 1e-6
    #: smallest blade thickness or channel width accepted as real [mm]
    min_feature: float = 1e-3
    #: accuracy of a measured blade surface, the figure the papers work to [mm]
    blade_accuracy: float = 0.03
    #: accuracy the electrode offset (discharge gap) is achieved to [mm]
    offset: float = 2e-3


@dataclass(frozen=True)
class PlausibleSize:
    """Bounds that catch unit mix-ups (metres or inches given as millimetres)."""

    #: smallest blisk hub radius that is a real part [mm]
    min_radius: float = 5.0
    #: largest blisk radius that is a real part [mm]
    max_radius: float = 3000.0
    #: smallest channel height (shroud minus hub radius) [mm]
    min_channel_height: float = 0.5


TOL = Tolerances()

#: |R^T R - I| and |det R - 1| accepted as a rigid rotation (poses are products of exact rotations)
RIGID_TOLERANCE = 1e-9
#: slack on exact distances (converged Gauss-Newton / Newton) when bounding them [mm]
EXACT_TOLERANCE = 1e-6
SIZE = PlausibleSize()
