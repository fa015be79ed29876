"""The full machining cycle of one electrode in one channel: approach, feed, process, return, retract.

A certified feed plan brings the electrode to its machining pose. Copy
processing (Huang III: "the electrode at the end position rotates a
corresponding angle around the X axis to remove the material") then brings
each reduced face to the discharge gap of its wall:

* circumferential: the side faces were rotated about X by h towards the
  channel middle (Huang's H_h), so an A rotation of -h_left takes the left
  face back onto the suction wall's gap offset and +h_right the right face
  onto the pressure wall's -- exactly, since the hub and shroud faces are
  surfaces of revolution that the rotation keeps at their gap;
* radial: the shroud face was contracted by the radial reduction, so a
  translation radially outwards (the electrode frame's Z) brings it back to
  the shroud's gap offset, as far as the blades' lean lets the side faces
  follow; the distance reached is the largest certified one, and what it
  does not reach is named as stock left for another electrode.

Every process, approach and retract leg is a straight line in axis space,
certified continuously like the feed (:class:`~edm_planner.planning.certify.PathCertifier`)
with the machining margin: no electrode vertex comes closer to a final
surface than the discharge gap less the tolerance (closer, the sparks would
erode the finished wall); the feed (and the return, which runs it
backwards) carries the planner's certificate, whose margins must be at
least that machining margin. Approach and retract move along X between the feed's start and a point further out.

Legs are rest to rest (the axes stop where the motion turns back), so the
axis bridge times each leg on its own and sends the whole cycle in order.

After the retract a **clear** leg moves X alone on, away from the blisk, to the
*clear position*: there the electrode's bounding sphere about its origin (the C
axis' pivot: a C turn does not move it) lies wholly beyond a plane normal to X
outside the part's axial envelope (``Blisk.part_envelope``: the geometry file's
``part_axial_range``, else the hub, shroud and blades; extended by ``envelope_margin``),
by ``clearance``. A turns about X and Y, Z move in planes
normal to it, so at that X no move of A, C, Y or Z can bring the electrode to the
part: channel indexes and tool changes happen there (:mod:`.program`), with that
separation as their certificate (:class:`ClearZone`). The clear leg itself is
certified against the channel's walls (the certifier) up to where the sphere is
separated, by the separation beyond, and against every blade by the electrode's
axial distance from the blades' range where it is outside it.
"""

import logging
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import CubicSpline

from ..interference import SURFACES
from ..cnc.kinematics import axis_poses, offset_axes
from ..planning.certify import PathCertifier

_log = logging.getLogger(__name__)

PHASES = ("approach", "feed", "process", "return", "retract", "clear")


@dataclass(frozen=True)
class CycleOptions:
    """Settings of the machining cycle (mm, rad).

    Attributes
    ----------
    tolerance : float
        How far below the discharge gap an electrode vertex may come to a final
        surface during processing (the overcut tolerance) [mm].
    approach_distance : float
        Length of the approach and retract moves along X beyond the feed's start [mm].
    radial_process : bool
        Take the radial reduction back by a radial move (where the blades let it).
    radial_resolution : float
        Bisection resolution of the radial reach [mm].
    wall_steps : int
        Even A steps towards each wall, each with a radial plunge (where there is a radial
        reduction), then four more halving the last step (:func:`comb_shares`).
    sample_spacing : float
        Largest move of any electrode vertex between consecutive samples of a leg [mm].
    """

    tolerance: float = 0.02
    approach_distance: float = 5.0
    radial_process: bool = True
    radial_resolution: float = 0.01
    sample_spacing: float = 0.05
    wall_steps: int = 4
    envelope_margin: float = 5.0
    clearance: float = 2.0

    def __post_init__(self):
        for name in ("tolerance", "approach_distance", "radial_resolution", "sample_spacing", "envelope_margin",
                     "clearance"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number [mm], got {v!r}")
        if int(self.wall_steps) < 1:
            raise ValueError(f"wall_steps must be >= 1, got {self.wall_steps!r}")


@dataclass
class Leg:
    """One rest-to-rest move of the cycle.

    Attributes
    ----------
    phase : str
        One of PHASES.
    label : str
        What the leg does (for the NC program's comments and the logs).
    samples : (n, k) float
        Axis values, first and last at rest [mm, rad].
    clearance_lower_bound : (4,) float
        Certified lower bound of the per-surface clearance along the leg [mm] (NaN: not certified here).
    regime : str
        Discharge regime of a cutting leg (the process model's ``rough`` or ``finish``); '' for a leg that
        cuts nothing or whose process was not planned (the generator stays off: a dry run).
    removed_volume : float
        Blisk material the leg removes [mm^3], a model estimate (:mod:`edm_planner.process.volume`); NaN
        where not computed.
    """

    phase: str
    label: str
    samples: np.ndarray
    clearance_lower_bound: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))
    regime: str = ""
    removed_volume: float = float("nan")


@dataclass
class ProcessReach:
    """What copy processing achieves for one electrode (mm, rad).

    ``rotation_*`` are the A rotations done towards each wall (0: that wall is
    not this electrode's), ``radial_reach`` the radial move achieved against
    the ``radial_reduction`` asked for at each rotation (A = 0 first), and
    ``radial_stock`` what is left on the shroud for another electrode to take.

    Wear compensation by feed depth (the machine YAML's ``process.wear_compensation``;
    :func:`edm_planner.process.set_process.add_wear_compensation`): in the j-th channel of one
    electrode's life the whole cycle runs with the electrode moved ``compensation_depths[j]`` mm along
    ``compensation_front`` (a unit vector, electrode frame), a tool offset (:meth:`MachiningCycle.with_compensation_depth`);
    after ``len(compensation_depths)`` channels a fresh electrode takes over. Empty: no compensation.
    """

    rotation_suction: float = 0.0
    rotation_pressure: float = 0.0
    radial_reduction: float = 0.0
    radial_reach: tuple = ()
    radial_stock: float = 0.0
    axes_without_a: bool = False
    compensation_front: tuple = ()
    compensation_depths: tuple = ()

    def to_dict(self):
        return {"rotation_suction_rad": self.rotation_suction, "rotation_pressure_rad": self.rotation_pressure,
                "radial_reduction_mm": self.radial_reduction, "radial_reach_mm": list(self.radial_reach),
                "radial_stock_mm": self.radial_stock, "axes_without_a": self.axes_without_a,
                "compensation_front": list(self.compensation_front),
                "compensation_depths_mm": list(self.compensation_depths)}

    @classmethod
    def from_dict(cls, r):
        """From :meth:`to_dict` (records and exports written before wear compensation have none)."""
        return cls(rotation_suction=r.get("rotation_suction_rad", 0.0), rotation_pressure=r.get("rotation_pressure_rad", 0.0),
                   radial_reduction=r.get("radial_reduction_mm", 0.0), radial_reach=tuple(r.get("radial_reach_mm", ())),
                   radial_stock=r.get("radial_stock_mm", 0.0), axes_without_a=bool(r.get("axes_without_a", False)),
                   compensation_front=tuple(float(v) for v in r.get("compensation_front", ())),
                   compensation_depths=tuple(float(v) for v in r.get("compensation_depths_mm", ())))


@dataclass(frozen=True)
class ClearZone:
    """Where the electrode is clear of the whole part, and by how much (mm; W: X is the blisk's axis).

    The electrode's origin lies on its C axis, so its bounding sphere about the origin (radius
    ``sphere_radius``, over the mesh's vertices plus its chord tolerance) does not move with C; A turns about
    X. The origin's W x is ``X + origin_x`` for axis value X (Huang eq. 2: ``R_x(A) T(X, Y, Z) T_final``), so
    the sphere's distance from the envelope's plane on the electrode's ``side`` is a function of X alone
    (:meth:`separation`), whatever A, C, Y and Z do: a lower bound of the distance to anything of the part
    inside the envelope ``envelope`` (the part's axial extent, ``Blisk.part_envelope``, extended by the
    cycle's ``envelope_margin``). ``clear_x`` is the clear position's X, where that separation is at least the
    cycle's ``clearance``. ``blade_gap``: the electrode's axial distance from the blades' range at the
    home point (the retract's end), a lower bound of its distance to every blade of the blisk along the
    clear leg (NaN where the electrode overlaps the blades' range there).
    """

    side: float
    envelope: tuple
    sphere_radius: float
    origin_x: float
    clear_x: float
    blade_gap: float = float("nan")

    def separation(self, x):
        """Lower bound of the electrode's distance from the part at axis value X = x [mm] (any A, C, Y, Z)."""
        edge = self.envelope[1] if self.side > 0 else -self.envelope[0]
        return self.side * (np.asarray(x, dtype=np.float64) + self.origin_x) - self.sphere_radius - edge

    def to_dict(self):
        return {"side": self.side, "envelope_x_mm": list(self.envelope), "sphere_radius_mm": self.sphere_radius,
                "origin_x_mm": self.origin_x, "clear_x_mm": self.clear_x,
                # unrounded: the certificate digest covers these values bit for bit
                "blade_gap_mm": float(self.blade_gap) if np.isfinite(self.blade_gap) else None,
                "separation_at_clear_x_mm": _f(float(self.separation(self.clear_x)))}

    @classmethod
    def from_dict(cls, r):
        if not r:
            return None
        gap = r.get("blade_gap_mm")
        return cls(float(r["side"]), tuple(float(v) for v in r["envelope_x_mm"]), float(r["sphere_radius_mm"]),
                   float(r["origin_x_mm"]), float(r["clear_x_mm"]), float("nan") if gap is None else float(gap))


@dataclass
class MachiningCycle:
    """The whole cycle of one electrode: legs in order, each certified.

    Attributes
    ----------
    axis_names : tuple of str
    legs : list of Leg
    reach : ProcessReach
    margin : float
        The machining margin every process leg was certified with (gap - tolerance) [mm].
    certified : bool
        Every leg certified; False with ``message`` saying where and why.
    message : str
    clear_zone : ClearZone or None
        Where the last leg (phase ``clear``) ends: index moves and tool changes happen there. None for a cycle
        built or stored before clear legs existed (a program refuses it: plan again).
    """

    axis_names: tuple
    legs: list
    reach: ProcessReach
    margin: float
    certified: bool = True
    message: str = ""
    clear_zone: ClearZone = None

    @property
    def samples(self):
        """(N, k) axis values of the whole cycle; the shared rest sample between legs appears once."""
        parts = [self.legs[0].samples] + [leg.samples[1:] for leg in self.legs[1:]]
        return np.vstack(parts)

    @property
    def leg_ranges(self):
        """[(phase, label, first, last)] sample indices of each leg in :attr:`samples` (inclusive)."""
        out, start = [], 0
        for leg in self.legs:
            stop = start + len(leg.samples) - 1
            out.append((leg.phase, leg.label, start, stop))
            start = stop
        return out

    @property
    def phase_ranges(self):
        """[(phase, first, last)]: consecutive legs of the same phase merged."""
        out = []
        for phase, _, a, b in self.leg_ranges:
            if out and out[-1][0] == phase:
                out[-1] = (phase, out[-1][1], b)
            else:
                out.append((phase, a, b))
        return out

    def with_compensation_depth(self, depth, final_pose):
        """The legs run with the wear compensation ``depth`` [mm]: every pose moved that far along the
        front in the electrode frame (:func:`~edm_planner.cnc.kinematics.offset_axes`); the legs as they
        are without compensation or at depth 0.

        Certified by inclusion, with no new certificate: the wear model recedes the front uniformly along
        it (:mod:`edm_planner.process.report`), so an electrode worn at least ``depth`` deep is inside
        E n (E - depth front), and moved ``depth`` along the front inside E n (E + depth front), a part of
        the unworn electrode E at the very same pose. Every clearance the cycle certifies holds for it, and
        its front reaches where the unworn front did. The schedule only ever offsets wear already done.
        """
        front = self.reach.compensation_front
        if not front or depth == 0.0:
            return list(self.legs)
        if not (np.isfinite(depth) and depth > 0.0):
            raise ValueError(f"a wear compensation depth must be finite and >= 0 mm, got {depth!r}")
        offset = depth * np.asarray(front, dtype=np.float64)
        return [replace(leg, samples=offset_axes(final_pose, self.axis_names, leg.samples, offset)) for leg in self.legs]

    def clearance_lower_bound(self, phase=None):
        """(4,) certified lower bound per surface over the legs (of one phase) [mm]."""
        rows = [leg.clearance_lower_bound for leg in self.legs if phase is None or leg.phase == phase]
        return np.nanmin(np.vstack(rows), axis=0) if rows else np.full(4, np.nan)

    def to_dict(self):
        return {"axis_names": list(self.axis_names), "margin_mm": self.margin, "certified": self.certified,
                "message": self.message, "reach": self.reach.to_dict(),
                "clear_zone": self.clear_zone.to_dict() if self.clear_zone is not None else None,
                "legs": [{"phase": p, "label": lab, "first": a, "last": b,
                          "clearance_lower_bound_mm": {s: _f(v) for s, v in zip(SURFACES, leg.clearance_lower_bound)},
                          "regime": leg.regime, "removed_volume_mm3": _f(leg.removed_volume)}
                         for (p, lab, a, b), leg in zip(self.leg_ranges, self.legs)]}


def _f(v):
    return None if not np.isfinite(v) else round(float(v), 6)


def comb_shares(steps):
    """Shares of a wall rotation at which copy processing plunges radially: even steps, then halving
    towards the wall (1 - 1/(2 steps), 1 - 1/(4 steps), ...), where the blades' lean stops the plunge
    and the uncovered strip of shroud shrinks with every halving."""
    even = [i / steps for i in range(1, steps)]
    near = [1.0 - 0.5 ** k / steps for k in range(1, 5)]
    return tuple(even + near + [1.0])


def electrode_walls(electrode_id):
    """Which blade walls an electrode's side faces machine: left/right halves take one each."""
    return {"left": ("suction",), "right": ("pressure",)}.get(electrode_id, ("suction", "pressure"))


def side_rotations(design, electrode_id):
    """A rotations (rad) that take the reduced side faces onto their walls: {'suction': -h_l, 'pressure': +h_r}."""
    h = float(design.circumferential_reduction)
    left = {"left": h, "right": 0.0}.get(design.reduction_side, 0.5 * h)
    right = {"left": 0.0, "right": h}.get(design.reduction_side, 0.5 * h)
    out = {}
    for wall in electrode_walls(electrode_id):
        angle = -left if wall == "suction" else right
        if abs(angle) > 0:
            out[wall] = angle
    return out


class CycleBuilder:
    """Builds and certifies the machining cycle of one electrode (channel 0 axis values).

    Parameters
    ----------
    field : FastChannelField
    electrode : Electrode
    design : ElectrodeDesign
    axis_names : tuple of str
    options : CycleOptions
    """

    def __init__(self, field, electrode, design, axis_names, options=None):
        self.options = options or CycleOptions()
        self.design = design
        self.electrode = electrode
        self.axis_names = tuple(axis_names)
        self.margin = float(design.discharge_gap) - self.options.tolerance
        margins = np.full(4, self.margin)
        self.certifier = PathCertifier(
            field, electrode.mesh.vertices, lambda q: axis_poses(electrode.final_pose, self.axis_names, q),
            self.axis_names, margins, electrode.final_pose[:3, 3], allowance=float(design.chord_tolerance),
            faces=electrode.mesh.faces)

    # -- one straight leg ------------------------------------------------------------------
    def leg(self, phase, label, q0, q1):
        """A straight leg q0 -> q1, certified and sampled; (Leg, Certificate)."""
        q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
        spline = CubicSpline([0.0, 1.0], np.vstack([q0, q1]))          # two points: a straight line
        cert = self.certifier.certify(spline, 0.0, 1.0)
        params, _ = self.certifier.sample(spline, 0.0, 1.0, self.options.sample_spacing)
        samples = spline(params)
        samples[0], samples[-1] = q0, q1
        return Leg(phase, label, samples, cert.lower_bound.copy()), cert

    # -- copy processing ---------------------------------------------------------------------
    def radial_reach(self, q_base, limit, lean=0.0):
        """Largest certified radial move (<= limit) from q_base, by bisection; (reach, leg out).

        ``lean`` [rad/mm]: A turned per mm of radial move, to follow a leaning wall.
        """
        if limit <= 0 or not self.options.radial_process:
            return 0.0, None
        direction = self._radial_axes()
        if lean:
            direction[self.axis_names.index("A")] = lean
        leg, cert = self.leg("process", "radial out", q_base, q_base + limit * direction)
        if cert.certified:
            return float(limit), leg
        lo, hi, best = 0.0, float(limit), None
        while hi - lo > self.options.radial_resolution:
            mid = 0.5 * (lo + hi)
            trial, cert = self.leg("process", "radial out", q_base, q_base + mid * direction)
            if cert.certified:
                lo, best = mid, trial
            else:
                hi = mid
        return lo, best

    def wall_lean(self, q_side, wall):
        """Median dtheta/dr [rad/mm] of a wall where the electrode's side face meets it near its top."""
        blisk = getattr(self.certifier.field, "blisk", None)
        if blisk is None or "A" not in self.axis_names:
            return 0.0
        face = self.electrode.samples["left" if wall == "suction" else "right"]
        pose = axis_poses(self.electrode.final_pose, self.axis_names, q_side[None])[0]
        pts = face @ pose[:3, :3].T + pose[:3, 3]
        r = np.hypot(pts[:, 1], pts[:, 2])
        top = r >= r.max() - max(self.design.radial_reduction, 0.5)
        x = pts[top, 0]
        _, _, inside, grads = blisk.wall_angles(x, r[top], with_gradient=True)
        g = grads[0] if wall == "suction" else grads[1]
        return float(np.median(g[inside, 1])) if inside.any() else 0.0

    def _radial_axes(self):
        """Axis-value direction of a unit move along the electrode frame's Z (radial at its centre)."""
        d = np.zeros(len(self.axis_names))
        ez = self.electrode.final_pose[:3, 2]
        for i, name in enumerate(("X", "Y", "Z")):
            d[self.axis_names.index(name)] = ez[i]
        return d

    def clear_leg(self, q_home, q_final):
        """The straight X move from the home point out to the clear position; (Leg or None, ClearZone, failure).

        Certified by the certifier (channel walls) from the home point to where the bounding sphere is
        separated from the envelope by the margin, by that separation beyond it (it only grows), and against
        every blade by the electrode's axial distance from their range where that is positive.
        """
        blisk = getattr(self.certifier.field, "blisk", None)
        if blisk is None:
            return None, None, "no blisk model to take the part's envelope from: no clear position"
        ix = self.axis_names.index("X")
        side = float(np.sign(q_home[ix] - q_final[ix]) or 1.0)
        verts = np.asarray(self.electrode.mesh.vertices, dtype=np.float64)
        radius = float(np.linalg.norm(verts, axis=1).max()) + float(self.design.chord_tolerance)
        blade = blisk.axial_range
        lo = blisk.part_envelope[0] - self.options.envelope_margin
        hi = blisk.part_envelope[1] + self.options.envelope_margin
        origin_x = float(self.electrode.final_pose[0, 3])
        probe = ClearZone(side, (float(lo), float(hi)), radius, origin_x, 0.0)
        # X where the separation is s: side * (X + origin_x) - radius - edge = s
        x_at = lambda sep: float(side * (sep + radius + (hi if side > 0 else -lo)) - origin_x)  # noqa: E731
        x_home = float(q_home[ix])
        x_clear = x_home if probe.separation(x_home) >= self.options.clearance else x_at(self.options.clearance)
        pose = axis_poses(self.electrode.final_pose, self.axis_names, q_home[None])[0]
        xs = verts @ pose[:3, 0] + pose[0, 3]
        blade_gap = float(xs.min() - blade[1] if side > 0 else blade[0] - xs.max())
        zone = ClearZone(side, (float(lo), float(hi)), radius, origin_x, x_clear,
                         blade_gap if blade_gap > 0 else float("nan"))
        if x_clear == x_home:
            return None, zone, ""
        q_clear = q_home.copy()
        q_clear[ix] = x_clear
        # the certifier over the whole move where it can (the tightest bound), else up to where the
        # sphere's separation reaches the margin and the separation beyond (it only grows)
        _, cert = self.leg("clear", "clear", q_home, q_clear)
        bound, failure = cert.lower_bound.copy(), ""
        if not cert.certified and zone.separation(x_home) >= self.margin:
            bound, failure = np.full(4, float(zone.separation(x_home))), ""
        elif not cert.certified:
            x_sep = x_at(self.margin)
            q_sep = q_home.copy()
            q_sep[ix] = x_sep
            _, cert = self.leg("clear", "clear", q_home, q_sep)
            if not cert.certified:
                failure = (f"the move out to the clear position is not certified near the blisk "
                           f"({cert.failure_surface})")
            bound = np.minimum(cert.lower_bound, zone.separation(x_sep))
        label = f"clear: X out to {x_clear:.3f} mm, {zone.separation(x_clear):.3f} mm beyond the part's envelope"
        return Leg("clear", label, np.vstack([q_home, q_clear]), bound), zone, failure

    def approach_leg(self, feed_samples):
        """The approach to the feed's start from further out; (Leg, Certificate).

        The feed ends outside the blades, but the hub and shroud may run on
        beyond them and narrow, so the way further out follows the feed's first
        millimetre backwards (its tangent, all axes) before plain X is tried;
        along the first certified direction the longest certified distance up to
        ``approach_distance`` is taken (bisection).
        """
        q_start = feed_samples[0]
        ix = self.axis_names.index("X")
        travel = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(feed_samples[:, :3], axis=0), axis=1)])
        j = int(min(np.searchsorted(travel, 1.0), len(feed_samples) - 1))
        tangent = q_start - feed_samples[max(j, 1)]
        norm = np.linalg.norm(tangent[:3])
        along_x = np.zeros_like(q_start)
        along_x[ix] = np.sign(q_start[ix] - feed_samples[-1][ix]) or 1.0
        directions = ([tangent / norm] if norm > 1e-9 else []) + [along_x]
        d_max = self.options.approach_distance
        best = None
        for direction in directions:
            lo, hi = 0.0, d_max
            leg, cert = self.leg("approach", "approach", q_start + d_max * direction, q_start)
            if cert.certified:
                return leg, cert
            while hi - lo > 0.05 * d_max:
                mid = 0.5 * (lo + hi)
                trial = self.leg("approach", "approach", q_start + mid * direction, q_start)
                if trial[1].certified:
                    lo, best = mid, trial
                else:
                    hi = mid
            if best is not None:
                return best
        return leg, cert                              # not certified: build() reports it

    def process_legs(self, q_final):
        """Legs of copy processing from the machining pose and back to it; (legs, ProcessReach, failure).

        At A = 0 a radial plunge takes the shroud's radial reduction. Towards
        each wall A turns in ``wall_steps`` steps to the wall's rotation, with a
        radial plunge at every step (as far as certified): the blades' lean
        stops the plunge near the wall, and the steps before it take the
        shroud strip the last plunge cannot reach (a comb along the boundary of
        the reachable (A, radial) set).
        """
        legs = []
        reach = ProcessReach(radial_reduction=float(self.design.radial_reduction))
        has_a = "A" in self.axis_names
        rotations = side_rotations(self.design, self.electrode.electrode_id)
        reach.axes_without_a = not has_a and bool(rotations)
        reaches = []

        def plunge(q_base, where, wall=None):
            r, out = self.radial_reach(q_base, reach.radial_reduction)
            if wall is not None and r < reach.radial_reduction:
                # at the wall the blade's lean stops a radial plunge: follow the lean instead
                lean = self.wall_lean(q_base, wall)
                r2, out2 = self.radial_reach(q_base, reach.radial_reduction, lean) if lean else (0.0, None)
                if r2 > r:
                    r, out = r2, out2
                    where += f" following the wall's lean {lean:+.5f} rad/mm"
            reaches.append(r)
            if out is not None and r > 0:
                out.label = f"radial out {r:.3f} mm{where}"
                back, _ = self.leg("process", f"radial back{where}", out.samples[-1], q_base)
                back.clearance_lower_bound = out.clearance_lower_bound.copy()
                legs.extend([out, back])
            return r

        plunge(q_final, "")
        ia = self.axis_names.index("A") if has_a else None
        radial = reach.radial_reduction > 0 and self.options.radial_process
        shares = comb_shares(self.options.wall_steps) if radial else (1.0,)
        for wall, angle in rotations.items():
            if not has_a:
                break
            q_prev = q_final
            wall_reach = []
            for share in shares:
                q_step = q_final.copy()
                q_step[ia] += angle * share
                where = f" at the {wall} wall" if share == 1.0 else f" at A {angle * share:+.4f} rad"
                leg, cert = self.leg("process", f"A {angle * share:+.4f} rad towards the {wall} wall",
                                     q_prev, q_step)
                if not cert.certified:
                    return legs, reach, (f"copy processing towards the {wall} wall is not certified: "
                                         f"{cert.failure_surface} clearance may fall {cert.penetration_bound:.4f} mm "
                                         f"below the machining margin {self.margin:.3f} mm")
                legs.append(leg)
                if radial:
                    wall_reach.append(plunge(q_step, where, wall if share == 1.0 else None))
                q_prev = q_step
            setattr(reach, f"rotation_{wall}", float(angle))
            back, _ = self.leg("process", f"A back from the {wall} wall", q_prev, q_final)
            back.clearance_lower_bound = legs[-1].clearance_lower_bound.copy()
            legs.append(back)
        reach.radial_reach = tuple(reaches)
        reach.radial_stock = float(max(0.0, reach.radial_reduction - min(reaches, default=0.0)))
        return legs, reach, None

    # -- the whole cycle -----------------------------------------------------------------------
    def build(self, feed_samples, feed_margin, feed_clearance, required_feed_margin=None):
        """The cycle around a certified feed.

        Parameters
        ----------
        feed_samples : (n, k) float
            Channel-0 axis values, feed order, last = the machining pose.
        feed_margin : float
            The smallest margin the feed was certified with (continuously, by the planner) [mm].
        feed_clearance : (4,) float
            The feed certificate's per-surface clearance lower bounds [mm].
        required_feed_margin : float, optional
            The margin the feed must have been certified with [mm]; default the machining margin (a roughing
            twin's feed needs only its spark gap less the tolerance: no overcut, its allowance aside).
        """
        feed_samples = np.asarray(feed_samples, float)
        feed_clearance = np.asarray(feed_clearance, float)
        q_start, q_final = feed_samples[0], feed_samples[-1].copy()
        approach, c1 = self.approach_leg(feed_samples)
        q_home = approach.samples[0]
        feed = Leg("feed", "feed", feed_samples, feed_clearance.copy())
        process, reach, failure = self.process_legs(q_final)
        back = Leg("return", "return (the feed reversed)", feed_samples[::-1].copy(), feed_clearance.copy())
        retract, _ = self.leg("retract", "retract (the approach reversed)", q_start, q_home)
        retract.clearance_lower_bound = approach.clearance_lower_bound.copy()
        clear, zone, clear_failure = self.clear_leg(q_home, q_final)
        legs = [approach, feed] + process + [back, retract] + ([clear] if clear is not None else [])
        cycle = MachiningCycle(self.axis_names, legs, reach, self.margin, clear_zone=zone)
        problems = []
        if failure:
            problems.append(failure)
        if clear_failure:
            problems.append(clear_failure)
        if not c1.certified:
            problems.append(f"the approach is not certified ({c1.failure_surface})")
        required = self.margin if required_feed_margin is None else float(required_feed_margin)
        if feed_margin < required - 1e-12:
            problems.append(f"the feed was certified with a margin of {feed_margin:.3f} mm, less than the "
                            f"{required:.3f} mm it needs (discharge gap less the tolerance): it may overcut")
        if reach.axes_without_a:
            problems.append("no A axis: the circumferential reduction cannot be taken by copy processing")
        cycle.certified = not problems
        cycle.message = "; ".join(problems) if problems else (
            f"{len(legs)} legs certified with the machining margin {self.margin:.3f} mm")
        return cycle


def shift_channel(samples, axis_names, channel, pitch):
    """Axis values moved from channel 0 to channel k (A += k pitch; 4 axes index outside the path)."""
    out = np.array(samples, dtype=float, copy=True)
    if channel and "A" in axis_names:
        out[:, list(axis_names).index("A")] += channel * pitch
    return out
