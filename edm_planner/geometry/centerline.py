"""Channel centerline from inscribed circles between adjacent blades (Liu 2024, 4.2).

At mid span, along the chord, the circle (in 3-D: the ball) tangent to the
suction face of blade k at a point p and touching the pressure face of blade
k+1 has its centre at ``p + t n`` (n: the face normal into the channel) where
``dist(p + t n, pressure face) = t``; t is found by bisection on exact
closest-point distances to the reconstructed face. The centres, fitted with
the cubic B-spline of :mod:`.nurbs`, are the centerline; ``2 t`` is the local
channel width (inscribed diameter).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from .frames import cartesian_to_cylindrical, rotation_about_x
from .nurbs import interpolate_curve


@dataclass(frozen=True)
class Centerline:
    """Channel 0's centerline between the blade edges.

    Attributes
    ----------
    centres : (n, 3) float
        Inscribed-ball centres in W [mm], leading to trailing edge.
    radii : (n,) float
        Inscribed radii [mm] (half the local channel width).
    spline : scipy.interpolate.BSpline
        Cubic B-spline through the centres, parameter in [0, 1].
    """

    centres: np.ndarray
    radii: np.ndarray
    spline: object

    @property
    def min_width(self):
        """Smallest inscribed diameter [mm]."""
        return float(2 * self.radii.min())

    def sample(self, n=200):
        """(n, 3) points along the fitted centerline."""
        return self.spline(np.linspace(0, 1, n))

    @property
    def length(self):
        """Length of the fitted centerline [mm]."""
        p = self.sample(2000)
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    @property
    def sweep(self):
        """Circumferential turn of the centerline from leading to trailing edge [rad]."""
        _, _, th = cartesian_to_cylindrical(self.sample(400))
        th = np.unwrap(th)
        return float(th[-1] - th[0])

    def for_channel(self, channel, pitch):
        """Centres of channel k (rotated by k * pitch) as (n, 3)."""
        rot = rotation_about_x(channel * pitch)[:3, :3]
        return self.centres @ rot.T


def channel_centerline(blisk, n_stations=61, span_fraction=0.5, edge_inset=0.02):
    """Inscribed-ball centerline of channel 0 at a span fraction.

    Parameters
    ----------
    blisk : Blisk
    n_stations : int
        Points along the chord.
    span_fraction : float
        0 = hub, 1 = shroud.
    edge_inset : float
        Fraction of the chord left out at each blade edge, where the faces end.

    Returns
    -------
    Centerline
    """
    x0, x1 = blisk.full_span_axial_range
    inset = edge_inset * (x1 - x0)
    x = np.linspace(x0 + inset, x1 - inset, n_stations)
    r = blisk.hub.radius_at(x) + span_fraction * (blisk.shroud.radius_at(x) - blisk.hub.radius_at(x))
    suction, pressure = blisk.suction_face, blisk.pressure_face
    u, v, inside = suction.uv_at(x, r)
    if not inside.all():
        raise GeometryError("centerline: the suction face does not cover the mid span between the blade edges")
    p = suction.surface.evaluate(u, v)
    n = suction.surface.normals(u, v)
    _, _, th = cartesian_to_cylindrical(p)
    e_theta = np.column_stack([np.zeros_like(th), -np.sin(th), np.cos(th)])
    n *= np.sign(np.einsum("ij,ij->i", n, e_theta))[:, None]      # into the channel
    # the pressure wall of channel 0 is blade 1's minus face: rotate queries back by one pitch
    back = rotation_about_x(-blisk.pitch)[:3, :3]

    def excess(t):
        c = p + t[:, None] * n
        return pressure.closest_points(c @ back.T)[1] - t

    th_s, th_p, _ = blisk.wall_angles(x, r)
    hi = (th_p - th_s) * r                      # the arc across the channel bounds the ball's radius
    lo = np.zeros_like(hi)
    if np.any(excess(hi) > 0):
        raise GeometryError("centerline: no inscribed circle found (the channel is not closed by the two blades)")
    for _ in range(48):                          # bisection to ~1e-14 of the width
        mid = 0.5 * (lo + hi)
        pos = excess(mid) > 0
        lo = np.where(pos, mid, lo)
        hi = np.where(pos, hi, mid)
    t = 0.5 * (lo + hi)
    centres = p + t[:, None] * n
    return Centerline(centres=centres, radii=t, spline=interpolate_curve(centres, name="centerline"))
