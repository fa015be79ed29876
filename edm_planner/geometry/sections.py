"""The one internal form of a blade: spanwise sections with both faces.

Every blade source (parametric quintic sections, measured sections, a CAD
mesh) is turned into :class:`BladeSections`: S sections from hub to shroud,
each with C stations along the chord that are shared by both faces, and at
every station the angles of the blade's two faces. This is exactly the form
of measured data such as the NASA Rotor 37 table (x, r, theta1, theta2).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from .frames import cylindrical_to_cartesian


@dataclass(frozen=True)
class BladeSections:
    """One blade (blade 0 of the blisk) as S x C stations.

    Parameters
    ----------
    x : (S, C) float
        Axial position of each station [mm].
    r : (S, C) float
        Radius of each station [mm].
    theta_minus : (S, C) float
        Angle of the blade's face that looks towards -theta [rad]
        (the *pressure* face in this project's convention).
    theta_plus : (S, C) float
        Angle of the face that looks towards +theta [rad] (the *suction*
        face); ``theta_plus >= theta_minus`` everywhere.

    Notes
    -----
    Section 0 is at (or inside) the hub, section S-1 at (or inside) the
    shroud; station 0 and C-1 are the leading and trailing edge, where the
    thickness may be zero. Channel k lies between the plus face of blade k
    and the minus face of blade k+1.
    """

    x: np.ndarray
    r: np.ndarray
    theta_minus: np.ndarray
    theta_plus: np.ndarray

    def __post_init__(self):
        arrays = {}
        for name in ("x", "r", "theta_minus", "theta_plus"):
            a = np.array(getattr(self, name), dtype=np.float64)
            if a.ndim != 2:
                raise GeometryError(f"blade sections: '{name}' must be a 2-D (sections x stations) array")
            arrays[name] = a
        shape = arrays["x"].shape
        if any(a.shape != shape for a in arrays.values()):
            raise GeometryError("blade sections: x, r, theta_minus, theta_plus must have the same shape")
        if shape[0] < 2 or shape[1] < 4:
            raise GeometryError(
                f"blade sections: need at least 2 sections of 4 stations, got {shape[0]} x {shape[1]}")
        for name, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise GeometryError(f"blade sections: '{name}' contains NaN or infinite values")
        if np.any(arrays["r"] <= 0):
            raise GeometryError("blade sections: radii must be positive (mm)")
        thickness = arrays["theta_plus"] - arrays["theta_minus"]
        if np.any(thickness < -1e-12):
            s, c = np.unravel_index(np.argmin(thickness), shape)
            raise GeometryError(
                f"blade sections: faces cross at section {s}, station {c} "
                f"(theta_plus < theta_minus by {-thickness[s, c]:.3g} rad)")
        for name, a in arrays.items():
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    @property
    def shape(self):
        """(S, C)"""
        return self.x.shape

    def face_points(self, face):
        """Cartesian points of one face in W.

        Parameters
        ----------
        face : {'minus', 'plus'}

        Returns
        -------
        points : (S, C, 3) float
        """
        theta = {"minus": self.theta_minus, "plus": self.theta_plus}[face]
        return cylindrical_to_cartesian(self.x, self.r, theta)

    def rotated(self, angle):
        """The same blade rotated by ``angle`` [rad] about X."""
        return BladeSections(self.x, self.r, self.theta_minus + angle, self.theta_plus + angle)
