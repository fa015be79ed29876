"""Cylindrical <-> Cartesian coordinates and rotations about the blisk axis X.

Convention (workpiece frame W): ``y = r cos(theta)``, ``z = r sin(theta)``.
"""

import numpy as np


def cylindrical_to_cartesian(x, r, theta):
    """Map cylindrical coordinates to W.

    Parameters
    ----------
    x, r, theta : (...) float
        Axial position [mm], radius [mm], angle about X [rad].

    Returns
    -------
    points : (..., 3) float
        Cartesian points in W [mm].
    """
    x, r, theta = np.broadcast_arrays(
        np.asanyarray(x, dtype=np.float64),
        np.asanyarray(r, dtype=np.float64),
        np.asanyarray(theta, dtype=np.float64),
    )
    return np.stack([x, r * np.cos(theta), r * np.sin(theta)], axis=-1)


def cartesian_to_cylindrical(points):
    """Map points in W to cylindrical coordinates.

    Parameters
    ----------
    points : (..., 3) float

    Returns
    -------
    x, r, theta : (...) float
        ``theta`` in (-pi, pi].
    """
    p = np.asanyarray(points, dtype=np.float64)
    return p[..., 0], np.hypot(p[..., 1], p[..., 2]), np.arctan2(p[..., 2], p[..., 1])


def rotation_about_x(angle):
    """Homogeneous 4x4 rotation by ``angle`` [rad] about the X axis of W."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.eye(4)
    m[1, 1], m[1, 2], m[2, 1], m[2, 2] = c, -s, s, c
    return m
