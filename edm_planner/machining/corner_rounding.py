"""The EDM corner rounding: the stock an ideal electrode leaves in the channel's concave corners.

Computed from the blisk's wall geometry alone (:func:`corner_rounding_stock`),
independent of the electrode design code, so that the electrode set's
acceptance (:func:`~.electrode_set.acceptance`) never writes a fault of the
design off as inherent.

Plain numpy/scipy; no rclpy. Units: mm, rad.
"""

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.frames import cylindrical_to_cartesian
from .removal_tolerances import REMOVAL


#: wall of each concave channel corner and the ring it meets; the surfaces that meet at each
CORNERS = (("suction", "hub"), ("suction", "shroud"), ("pressure", "hub"), ("pressure", "shroud"))


def corner_rounding_stock(blisk, samples, gap, resolution=0.005):
    """The stock an ideal electrode leaves at the wall samples: the EDM corner rounding, from the walls alone.

    The ideal electrode is the channel shrunk by the gap g; what it erodes,
    E + B(g), is the channel with every concave corner rounded by a ball of
    radius g. This computes that stock directly from the blisk's wall
    geometry (the blade faces' angles and their gradients, the hub and shroud
    profiles), independent of the electrode design code: along each of the
    four corners where a blade wall meets the hub or shroud, the interior
    angle phi between the two surfaces (from their normals) puts the ball's
    contact at t = g / tan(phi / 2) from the corner line on either surface;
    a sample at distance s < t from the corner keeps sqrt((t - s)^2 + g^2) - g
    (g (1 / sin(phi / 2) - 1) on the corner line), elsewhere nothing. Exact for
    planar faces meeting in a straight corner; the walls' curvature over the
    strip (t <= 0.3 mm on the default blisk, wall radii tens of mm) changes it
    by microns. The distance to the corner is the distance to the corner line
    sampled every ``resolution`` mm (projected on its segments).

    Parameters
    ----------
    blisk : Blisk
    samples : dict
        :func:`wall_samples` output (channel 0).
    gap : float
        Discharge gap [mm].
    resolution : float
        Corner line sample spacing along x [mm].

    Returns
    -------
    dict
        surface name -> (n,) inherent stock [mm] per sample of ``samples[name]`` (0 where invalid).
    """
    g = float(gap)
    lines = corner_lines(blisk, g, resolution)
    out = {}
    for name, smp in samples.items():
        stock = np.zeros(len(smp.points))
        for key in CORNERS:
            if name not in key:
                continue
            pts, reach, _ = lines[key]
            # a sample whose nearest line point lies beyond the largest reach plus a segment's length is beyond
            # every reach from the line's segments too (its foot on a segment is within half a segment of a
            # line point): no stock, and no need to find that point (a far query on a line's k-d tree visits
            # most of it: 12 s of Rotor 37's samples)
            step = np.linalg.norm(np.diff(pts, axis=0), axis=1).max(initial=0.0)
            _, i = cKDTree(pts).query(smp.points, distance_upper_bound=float(reach.max()) + step + 1e-9)
            near = np.flatnonzero(i < len(pts))
            p, i = smp.points[near], i[near]
            s = np.full(len(p), np.inf)
            for a, b in ((np.maximum(i - 1, 0), i), (i, np.minimum(i + 1, len(pts) - 1))):
                seg = pts[b] - pts[a]
                length2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-300)
                u = np.clip(np.einsum("ij,ij->i", p - pts[a], seg) / length2, 0.0, 1.0)
                s = np.minimum(s, np.linalg.norm(p - (pts[a] + u[:, None] * seg), axis=1))
            t = reach[i]
            stock[near] = np.maximum(stock[near], np.where(s < t, np.sqrt((t - s) ** 2 + g * g) - g, 0.0))
        out[name] = np.where(smp.valid, stock, 0.0)
    return out


def corner_lines(blisk, gap, resolution=0.005):
    """The four corner lines: (wall, ring) -> (points (n, 3) every ``resolution`` mm along x, reach t (n,), phi (n,)).

    ``reach`` is where the rounding ball of radius ``gap`` touches either surface, measured from the corner
    line [mm]; ``phi`` the corner's interior angle [rad] (see :func:`corner_rounding_stock`).
    """
    g = float(gap)
    x0, x1 = blisk.full_span_axial_range
    xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / resolution)) + 1))
    lines = {}
    for ring, profile, sign in (("hub", blisk.hub, 1.0), ("shroud", blisk.shroud, -1.0)):
        R = profile.radius_at(xs)
        th_s, th_p, _, (g_s, g_p) = blisk.wall_angles(xs, R + sign * REMOVAL.wall_inset, with_gradient=True)
        for wall, th, grad, side in (("suction", th_s, g_s, 1.0), ("pressure", th_p, g_p, -1.0)):
            e_r = np.stack([np.zeros_like(th), np.cos(th), np.sin(th)], axis=1)
            e_t = np.stack([np.zeros_like(th), -np.sin(th), np.cos(th)], axis=1)
            e_x = np.broadcast_to([1.0, 0.0, 0.0], e_r.shape)
            # blade wall theta = f(x, r): tangents along x and r; normal towards the channel (theta inside)
            n_w = np.cross(e_x + (R * grad[:, 0])[:, None] * e_t, e_r + (R * grad[:, 1])[:, None] * e_t)
            n_w *= (side * np.sign(np.einsum("ij,ij->i", n_w, e_t)))[:, None]
            # hub / shroud r = R(x): tangents along x and theta; normal towards the channel (r inside)
            n_r = np.cross(e_x + profile.slope_at(xs)[:, None] * e_r, e_t)
            n_r *= (sign * np.sign(np.einsum("ij,ij->i", n_r, e_r)))[:, None]
            cos = np.einsum("ij,ij->i", n_w, n_r) / (np.linalg.norm(n_w, axis=1) * np.linalg.norm(n_r, axis=1))
            phi = np.pi - np.arccos(np.clip(cos, -1.0, 1.0))          # interior angle of the corner
            reach = np.where(phi < np.pi, g / np.tan(np.minimum(phi, np.pi - 1e-12) / 2), 0.0)
            lines[wall, ring] = (cylindrical_to_cartesian(xs, R, th), reach, phi)
    return lines
