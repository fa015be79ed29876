"""A blisk as measured: every blade its own, every channel planned on its own two blades (no rclpy).

A forged or milled blisk's blades are off nominal by a few hundredths to a
tenth of a millimetre, blade by blade: as much as the electrode's 0.1 mm
discharge gap. A plan certified on the nominal channel is therefore not
certified on the part. Inspection data gives some or all blades as measured
(sections or a mesh, each in its own place on the part: blade k near
``k * pitch``); the others stay nominal.

Channel k lies between the suction face of blade k and the pressure face of
blade k+1. :func:`channel_blisk` makes it a :class:`~.blisk.Blisk` of its own:
``blade`` is blade k and ``pressure_blade`` blade k+1, both turned back into
blade 0's position. That blisk's channel k *is* the part's channel k, so the
periodic machinery (the fast field turned by k pitches, the exact checks, a
plan turned to channel k) applies unchanged, and the electrode is designed,
the path planned and the removal proven on the channel's own walls.

:func:`wall_deviation` measures how far two channels' walls differ (the
largest arc ``r * |d theta|`` over a meridional grid, an upper bound of how
far a wall point moves along the circle, so of how much any clearance to it
changes, at the grid's points), and :func:`channel_groups` puts channels that
agree within a tolerance into one group that shares one plan.
"""

import hashlib
from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from .blisk import Blisk
from .sections import BladeSections

#: meridional grid of :func:`wall_deviation`: stations along the axis and across the span
DEVIATION_GRID = (60, 24)
#: inset of that grid from the full-span axial range and from hub and shroud, as a fraction
DEVIATION_INSET = 0.01


@dataclass(frozen=True)
class MeasuredBlades:
    """Blades given as measured, each turned back into blade 0's position.

    Attributes
    ----------
    blades : dict
        Blade index -> :class:`~.sections.BladeSections` [mm, rad]; absent blades are nominal.
    tolerance : float
        Channels whose walls agree within this [mm] (:func:`wall_deviation`) share a plan.
    sources : dict
        Blade index -> what the blade was read from (for reports).
    scan : dict
        What the whole-blisk scan's reading found (:func:`~.blisk_scan.read_blisk_scan`'s report), None without.
    nominal_field_key : str
        The field-cache key of the channels with nominal walls: the id of the same geometry without its
        ``as_measured`` section, so they share the nominal blisk's field (None: the part's geometry id).
    """

    blades: dict
    tolerance: float = 0.005
    sources: dict = None
    scan: dict = None
    nominal_field_key: str = None

    def to_dict(self):
        """Plain data (the geometry topic's ``model_json`` carries it under ``as_measured``)."""
        return {"tolerance": self.tolerance, "sources": {str(k): v for k, v in (self.sources or {}).items()},
                "scan": self.scan, "nominal_field_key": self.nominal_field_key,
                "blades": {str(k): {"x": b.x.tolist(), "r": b.r.tolist(), "theta_minus": b.theta_minus.tolist(),
                                    "theta_plus": b.theta_plus.tolist()} for k, b in self.blades.items()}}

    @classmethod
    def from_dict(cls, data):
        """From :meth:`to_dict` output; None for None."""
        if data is None:
            return None
        blades = {int(k): BladeSections(b["x"], b["r"], b["theta_minus"], b["theta_plus"])
                  for k, b in data["blades"].items()}
        return cls(blades, float(data["tolerance"]), {int(k): v for k, v in data.get("sources", {}).items()},
                   data.get("scan"), data.get("nominal_field_key"))

    def channel_blades(self, channel, blade_count):
        """(blade k, blade k+1) of channel k as given, None where nominal."""
        return self.blades.get(channel), self.blades.get((channel + 1) % blade_count)


def channel_field_key(geometry_id, channel):
    """The field-cache key of channel ``channel``'s own geometry on the blisk ``geometry_id`` as measured."""
    return hashlib.sha256(f"{geometry_id}/channel/{int(channel)}".encode()).hexdigest()


def to_blade_zero(sections, blade_index, blade_count):
    """Blade ``blade_index`` measured in its own place on the part, turned back into blade 0's position."""
    return sections.rotated(-2.0 * np.pi * blade_index / blade_count)


def channel_blisk(nominal, measured, channel):
    """Channel k of the part as a Blisk of its own (``nominal`` itself where both its blades are nominal).

    Parameters
    ----------
    nominal : Blisk
    measured : MeasuredBlades
    channel : int

    Raises
    ------
    GeometryError
        The measured blades intersect each other or leave the hub/shroud range.
    """
    suction, pressure = measured.channel_blades(channel, nominal.blade_count)
    if suction is None and pressure is None:
        return nominal
    try:
        return Blisk(nominal.blade_count, nominal.hub, nominal.shroud, suction or nominal.blade,
                     name=f"{nominal.name}, channel {channel} as measured".strip(", "), source=nominal.source,
                     knot_rule=nominal.knot_rule, part_axial_range=nominal.part_axial_range,
                     pressure_blade=pressure or nominal.blade)
    except GeometryError as exc:
        raise GeometryError(f"channel {channel} as measured (blades {channel} and "
                            f"{(channel + 1) % nominal.blade_count}): {exc.message}") from None


def _grid(blisk):
    x0, x1 = blisk.full_span_axial_range
    nx, nr = DEVIATION_GRID
    inset = DEVIATION_INSET * (x1 - x0)
    x = np.linspace(x0 + inset, x1 - inset, nx)
    lo, hi = blisk.hub.radius_at(x), blisk.shroud.radius_at(x)
    rho = np.linspace(DEVIATION_INSET, 1 - DEVIATION_INSET, nr)
    R = lo[:, None] + rho[None, :] * (hi - lo)[:, None]
    return np.repeat(x, nr), R.ravel()


def _deviation(walls_a, walls_b, r):
    """Largest ``r * |d theta|`` of either wall where both channels have it (inf where none)."""
    (a_s, a_p, a_in), (b_s, b_p, b_in) = walls_a, walls_b
    both = a_in & b_in
    if not both.any():
        return np.inf
    return float(max(np.max(np.abs(a_s - b_s)[both] * r[both]), np.max(np.abs(a_p - b_p)[both] * r[both])))


def wall_deviation(a, b):
    """How far the walls of channel 0 of two blisks differ [mm]: the largest ``r * |d theta|`` of the suction
    and of the pressure wall over a 60 x 24 meridional grid of ``a`` (a sampled figure, not a bound between
    the grid's points)."""
    x, r = _grid(a)
    dev = _deviation(a.wall_angles(x, r), b.wall_angles(x, r), r)
    if not np.isfinite(dev):
        raise GeometryError("wall_deviation: the two channels' walls have no meridional point in common")
    return dev


def channel_groups(views, tolerance):
    """Channels that share a plan: each joins the first earlier group whose representative's walls agree
    with its own within ``tolerance`` [mm] (:func:`wall_deviation`, on channel 0's grid).

    Parameters
    ----------
    views : list of Blisk
        Channel k's blisk (:func:`channel_blisk`) at index k; the same object for equal channels.

    Returns
    -------
    list of (int, list of int, list of float)
        (representative channel, member channels, each member's wall deviation from it [mm]).
    """
    x, r = _grid(views[0])
    angles = {}                     # the walls' angles per distinct view, once each

    def walls(view):
        if id(view) not in angles:
            angles[id(view)] = view.wall_angles(x, r)
        return angles[id(view)]

    groups = []
    for k, view in enumerate(views):
        for rep, members, devs in groups:
            dev = 0.0 if views[rep] is view else _deviation(walls(views[rep]), walls(view), r)
            if dev <= tolerance:
                members.append(k)
                devs.append(dev)
                break
        else:
            groups.append((k, [k], [0.0]))
    return groups
