"""Cylindrical <-> Cartesian coordinates, rotations about the blisk axis X, distances between poses, and the
hull points that bound how far a solid moves between them.

Convention (workpiece frame W): ``y = r cos(theta)``, ``z = r sin(theta)``.
"""

import numpy as np
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation


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


def is_rigid(pose, tolerance=1e-6):
    """Whether a 4x4 matrix is a rigid motion: orthonormal rotation (to ``tolerance``), det +1, last row 0 0 0 1."""
    r = pose[:3, :3]
    return bool(np.abs(r.T @ r - np.eye(3)).max() <= tolerance and np.linalg.det(r) > 0
                and np.array_equal(pose[3], [0, 0, 0, 1]))


def hull_points(vertices):
    """The vertices of the points' convex hull, in their input order (every point for a flat or degenerate set).

    They stand for a whole solid wherever a function convex in the point is maximised over it: how far a
    point v moves between two poses, |(P_k+1 - P_k) v|, or where the solid reaches along an axis (a linear
    function's extremes, the same values as over every point).
    """
    v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64))
    try:
        return np.ascontiguousarray(v[ConvexHull(v).vertices])
    except (QhullError, ValueError):              # flat or too few points: every one
        return v


def pose_difference(a, b):
    """(distance between the origins [mm], angle of the rotation taking one to the other [rad]) of two poses."""
    return (float(np.linalg.norm(a[:3, 3] - b[:3, 3])),
            float(Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).magnitude()))
