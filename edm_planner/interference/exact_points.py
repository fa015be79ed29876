"""Exact signed distance of points to the four surfaces of a channel.

Blade faces: the closest point on the reconstructed bicubic face
(``BladeFace.closest_points``, converged Gauss-Newton with backtracking).
Hub and shroud: surfaces of revolution, so the closest point of a point at
(x, rho) lies in its own meridional half-plane and the 3-D problem reduces
to the distance from (x, rho) to the profile curve r(x) (Chen & Dong eq. 4-8:
the optimal rotation angle is the point's own, eq. 6, leaving the univariate
d(u) of eq. 7), minimised by Newton's method on the profile's cubic pieces.

Signs: positive in the channel, negative behind a wall: within the blade's
meridional footprint, below the suction wall (inside blade k or through it
into channel k-1) or above the pressure wall; below the hub; above the shroud.
"""

import numpy as np
from scipy.spatial import cKDTree

from . import SURFACES
from ..geometry.frames import cartesian_to_cylindrical, cylindrical_to_cartesian


class ProfileDistance:
    """Exact distance from meridional points (x, rho) to a profile curve r(x).

    Parameters
    ----------
    profile : RevolutionProfile
    material_below : bool
        True for the hub (material at r < r(x)), False for the shroud.
    """

    def __init__(self, profile, material_below):
        self.profile = profile
        self.sign = 1.0 if material_below else -1.0
        lo, hi = profile.x_range
        span = hi - lo
        # the profile continues as a cylinder: sample it well beyond its points
        xs = np.linspace(lo - span, hi + span, 12001)
        self._samples = np.column_stack([xs, profile.radius_at(xs)])
        self._tree = cKDTree(self._samples)
        d1 = profile._interp.derivative()
        d2 = profile._interp.derivative(2)
        self._d1 = lambda t: np.where((t >= lo) & (t <= hi), d1(np.clip(t, lo, hi)), 0.0)
        self._d2 = lambda t: np.where((t > lo) & (t < hi), d2(np.clip(t, lo, hi)), 0.0)

    def signed(self, x, rho, iterations=30):
        """Signed distance [mm] (positive on the channel side) and the foot (x_f, r_f).

        Parameters
        ----------
        x, rho : (n,) float
        """
        x = np.asanyarray(x, dtype=np.float64)
        rho = np.asanyarray(rho, dtype=np.float64)
        _, idx = self._tree.query(np.column_stack([x, rho]))
        t = self._samples[idx, 0].copy()
        for _ in range(iterations):
            r, r1, r2 = self.profile.radius_at(t), self._d1(t), self._d2(t)
            g1 = (t - x) + (r - rho) * r1
            g2 = 1.0 + r1**2 + (r - rho) * r2
            g2 = np.where(g2 > 1e-3, g2, 1.0 + r1**2)   # keep Newton a descent step
            step = g1 / g2
            t = t - step
            if np.abs(step).max() < 1e-13:
                break
        r = self.profile.radius_at(t)
        dist = np.hypot(t - x, r - rho)
        above = rho - self.profile.radius_at(x)
        return np.where(self.sign * above >= 0, dist, -dist), t, r


class ExactChannelDistance:
    """Signed distances of points to the suction, pressure, hub and shroud surfaces of a channel."""

    def __init__(self, blisk):
        self.blisk = blisk
        self.hub = ProfileDistance(blisk.hub, material_below=True)
        self.shroud = ProfileDistance(blisk.shroud, material_below=False)

    def _blade(self, face, points_local, inside):
        """Distance to a face of blade 0 for points already rotated into blade 0's position."""
        foot, dist, _ = face.closest_points(points_local)
        return np.where(inside, -dist, dist), foot

    def clearances(self, points, channel=0, closest=False):
        """Signed distances of points in W to channel k's four surfaces.

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int
        closest : bool
            Also return the foot points.

        Returns
        -------
        distances : (n, 4) float
            [mm], columns in the order of ``SURFACES``.
        feet : (n, 4, 3) float, only with ``closest``
            The closest surface points in W.
        """
        b = self.blisk
        p = np.atleast_2d(np.asanyarray(points, dtype=np.float64))
        x, rho, th = cartesian_to_cylindrical(p)
        # behind the suction wall (inside blade k, or through it into channel k-1) / behind the
        # pressure wall, wherever the blade exists at the point's (x, r); beyond the blade's
        # meridional footprint there is no wall to be behind
        th_k = np.mod(th - channel * b.pitch + np.pi, 2 * np.pi) - np.pi
        th_k1 = np.mod(th_k - b.pitch + np.pi, 2 * np.pi) - np.pi
        th_minus, in_m = b.pressure_face.theta_at(x, rho)
        th_plus, in_p = b.suction_face.theta_at(x, rho)
        wrap = lambda a: np.mod(a + np.pi, 2 * np.pi) - np.pi   # noqa: E731
        rel_s = wrap(th_k - th_plus)
        rel_p = wrap(th_k1 - th_minus)
        in_blade_k = in_p & (rel_s < 0) & (rel_s > -b.pitch)
        in_blade_k1 = in_m & (rel_p > 0) & (rel_p < b.pitch)
        local_s = cylindrical_to_cartesian(x, rho, th_k)
        local_p = cylindrical_to_cartesian(x, rho, th_k1)
        d_s, f_s = self._blade(b.suction_face, local_s, in_blade_k)
        d_p, f_p = self._blade(b.pressure_face, local_p, in_blade_k1)
        d_h, xh, rh = self.hub.signed(x, rho)
        d_c, xc, rc = self.shroud.signed(x, rho)
        dist = np.column_stack([d_s, d_p, d_h, d_c])
        if not closest:
            return dist
        fx, fr, fth = cartesian_to_cylindrical(f_s)
        foot_s = cylindrical_to_cartesian(fx, fr, fth + channel * b.pitch)
        fx, fr, fth = cartesian_to_cylindrical(f_p)
        foot_p = cylindrical_to_cartesian(fx, fr, fth + (channel + 1) * b.pitch)
        feet = np.stack([foot_s, foot_p, cylindrical_to_cartesian(xh, rh, th),
                         cylindrical_to_cartesian(xc, rc, th)], axis=1)
        return dist, feet


def transform_points(poses, points):
    """Electrode points under a batch of poses.

    Parameters
    ----------
    poses : (P, 4, 4) float
        Electrode frame -> W.
    points : (M, 3) float
        In the electrode frame [mm].

    Returns
    -------
    (P, M, 3) float
    """
    poses = np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    pts = np.asanyarray(points, dtype=np.float64)
    return np.einsum("pij,mj->pmi", poses[:, :3, :3], pts) + poses[:, None, :3, 3]


def pose_clearances(distance_fn, poses, points, channel=0):
    """Per pose and surface: the minimum signed distance over the electrode points.

    Parameters
    ----------
    distance_fn : callable
        ``(n, 3) points in W, channel -> (n, 4)`` signed distances.
    poses : (P, 4, 4) float
    points : (M, 3) float

    Returns
    -------
    minimum : (P, 4) float
        [mm], columns in the order of ``SURFACES``.
    argmin : (P, 4) int
        Index of the electrode point that attains it.
    """
    world = transform_points(poses, points)
    P, M, _ = world.shape
    d = distance_fn(world.reshape(-1, 3), channel).reshape(P, M, len(SURFACES))
    return d.min(axis=1), d.argmin(axis=1)
