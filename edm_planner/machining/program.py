"""Programs of several cycles: an electrode set in one channel, the whole blisk (no rclpy).

A *sequence* is an ordered list of (plan id, channel) steps (kept in the plan
store, :meth:`~edm_planner.planning.store.PlanStore.put_sequence`):

``electrode_set``
    the set's electrodes in machining order, all in one channel;
``blisk_program``
    every channel k = 0 .. N-1 with the first electrode, then every channel
    with the next (:func:`blisk_program_steps`): one tool change per electrode.

Each step runs the plan's whole machining cycle (approach, feed, process,
return, retract, clear; :mod:`.cycle`) moved from the plan's channel to the
step's (A += (k - plan channel) * pitch; the blisk is periodic), starting from
the clear position (the cycle's clear leg reversed) and ending there. With wear
compensation (the plan's ``reach.compensation_depths``) the j-th channel of an
electrode's life runs the cycle moved ``compensation_depths[j]`` along the
electrode's front (the wear it has taken by then), and after the last one a new
electrode of the same plan takes over (a tool change). Between two steps of the
same electrode an **index** leg turns A by the channel difference (and moves X,
Y, Z by the change of the wear compensation, :func:`index_leg`) at the clear
position, certified by the cycle's :class:`~.cycle.ClearZone`: the electrode's
bounding sphere stays beyond the part's axial envelope whatever A does, by at
least the separation at the leg's ends (X moves linearly along it). Between two
electrodes a **tool change**: each electrode's trajectory ends at its clear
position and the next one starts at its own; the NC program switches to G94,
changes the tool there and moves to the next clear position X first
(:mod:`edm_planner.cnc.post`).

A four-axis machine (X, Y, Z, C) has no A: its channel is indexed outside the
program, so a step in another channel than its plan's is refused.
"""

import csv
import hashlib
import json
import pathlib
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import EdmError, ErrorCode
from .cycle import ClearZone, Leg, MachiningCycle, ProcessReach

#: phase names of the program besides the cycle's (edm_planner.machining.cycle.PHASES)
INDEX, TOOL_CHANGE = "index", "tool_change"


def blisk_program_steps(set_plan_ids, blade_count):
    """Steps of the whole-blisk program: each electrode of the set through every channel, then the next.

    Parameters
    ----------
    set_plan_ids : sequence of str
        The set's plans in machining order (one per electrode).
    blade_count : int
        N: channels 0 .. N-1.

    Returns
    -------
    list of (str, int)
        [(plan id, channel)], len(set_plan_ids) * N steps.
    """
    ids = [str(p) for p in set_plan_ids]
    if not ids:
        raise EdmError(ErrorCode.INVALID_REQUEST, "a blisk program needs at least one electrode plan")
    if len(set(ids)) != len(ids):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"a blisk program names each electrode's plan once, got {ids}")
    n = int(blade_count)
    if n < 1 or n != blade_count:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"blade_count must be a positive integer, got {blade_count!r}")
    return [(p, k) for p in ids for k in range(n)]


def channel_program_steps(groups, group_plan_ids, blade_count, partial=False):
    """Steps of the whole-blisk program of a blisk as measured: each channel machined with its own plans.

    Channels whose walls agree within the geometry's tolerance form a group
    (:meth:`~edm_planner.geometry.loader.LoadedGeometry.channel_groups`) that shares the plans made on its
    representative's own walls; each electrode of a group's set runs through the group's channels, then the
    next electrode, then the next group's set.

    Parameters
    ----------
    groups : sequence of (int, sequence of int, ...)
        (representative channel, member channels, ...) as ``channel_groups`` gives them.
    group_plan_ids : dict
        Representative channel -> its set's plan ids in machining order.
    blade_count : int
    partial : bool
        Allow groups that leave channels out (a program of some channels: one group's set alone).

    Returns
    -------
    list of (str, int)
        [(plan id, channel)]: every channel once per electrode of its group's set.
    """
    n = int(blade_count)
    seen = sorted(k for g in groups for k in g[1])
    if len(set(seen)) != len(seen) or not set(seen) <= set(range(n)) or (not partial and seen != list(range(n))):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"the channel groups must cover channels 0 .. {n - 1} once each, "
                                                  f"got {seen}")
    steps = []
    for group in groups:
        rep, members = int(group[0]), [int(k) for k in group[1]]
        ids = [str(p) for p in group_plan_ids.get(rep, ())]
        if not ids:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"no plans for the group of channel {rep} (channels "
                                                      f"{members}): every group needs its own electrode set")
        if len(set(ids)) != len(ids):
            raise EdmError(ErrorCode.INVALID_REQUEST, f"the group of channel {rep} names a plan twice: {ids}")
        steps += [(p, k) for p in ids for k in members]
    return steps


def sequence_id_for(kind, steps, geometry_id=""):
    """A deterministic sequence id (16 hex digits, like plan ids) of a kind and its steps."""
    doc = json.dumps([kind, geometry_id, [[str(p), int(c)] for p, c in steps]])
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


def shift_to_channel(samples, axis_names, from_channel, to_channel, pitch):
    """Axis values of a plan's channel moved to channel ``to_channel`` (A += (k - plan channel) pitch).

    Raises
    ------
    EdmError
        INVALID_REQUEST for another channel on a four-axis plan (no A: the channel is indexed outside the
        program).
    """
    out = np.array(samples, dtype=np.float64, copy=True)
    delta = int(to_channel) - int(from_channel)
    if not delta:
        return out
    names = list(axis_names)
    if "A" not in names:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"a {len(names)}-axis plan ({', '.join(names)}) has no A axis: it cannot move from channel "
                       f"{from_channel} to channel {to_channel} within a program; the blisk is indexed to each "
                       f"channel outside the program on such a machine (plan with 5 or 6 axes for a whole-blisk "
                       f"program)")
    out[:, names.index("A")] += delta * float(pitch)
    return out


@dataclass
class PlanCycle:
    """What a program needs of one plan (from a Plan, a store record or a ChannelPlan message).

    Attributes
    ----------
    plan_id, geometry_id, electrode_id : str
    channel : int
    axis_names : tuple of str
    final_pose : (4, 4) float
        Electrode frame -> W with every axis at 0 in channel 0 (what the axis values are measured from) [mm].
    samples : (n, k) float
        The feed (plan's channel) [mm, rad].
    cycle : MachiningCycle or None
        Axis values in the plan's channel.
    """

    plan_id: str
    geometry_id: str
    electrode_id: str
    channel: int
    axis_names: tuple
    final_pose: np.ndarray
    samples: np.ndarray
    cycle: object = None

    @classmethod
    def of_plan(cls, plan):
        """From a :class:`~edm_planner.planning.plan.Plan` (whose final_pose is channel 0's)."""
        return cls(plan.plan_id, plan.geometry_id, plan.electrode_id, int(plan.channel), tuple(plan.axis_names),
                   np.asarray(plan.final_pose, dtype=np.float64), np.asarray(plan.samples, dtype=np.float64),
                   getattr(plan, "cycle", None))

    @classmethod
    def of_stored(cls, stored, where="the plan store"):
        """Deprecated (until 0.3.0): :func:`edm_planner.records.store.plan_cycle_of_stored`."""
        # a deprecated alias only: the records layer reads stored plans (.importlinter allows this import)
        from ..records.store import plan_cycle_of_stored

        warnings.warn("PlanCycle.of_stored is deprecated: use edm_planner.records.store.plan_cycle_of_stored "
                      "(issue 27); removed in 0.3.0", DeprecationWarning, stacklevel=2)
        return plan_cycle_of_stored(stored, where)


@dataclass
class ProgramLeg:
    """One rest-to-rest move of a program: a cycle leg in a channel, or an index.

    Attributes
    ----------
    phase, label : str
    samples : (n, k) float
        Axis values, first and last at rest [mm, rad].
    channel : int
        The channel the leg machines in (index: the channel it turns to).
    plan : PlanCycle
    regime : str
        Discharge regime of a cutting leg ('' : the generator is off); see :class:`~.cycle.Leg`.
    removed_volume : float
        [mm^3], NaN where not computed.
    clearance_lower_bound : (4,) float
        Certified lower bound of the per-surface clearance along the leg [mm] (index: the clear zone's
        separation from the whole part, the same for every surface).
    """

    phase: str
    label: str
    samples: np.ndarray
    channel: int
    plan: PlanCycle
    regime: str = ""
    removed_volume: float = float("nan")
    clearance_lower_bound: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))


@dataclass
class ElectrodeRun:
    """The steps of one electrode in a row: one trajectory, ended by a tool change when another electrode follows.

    Attributes
    ----------
    order : int
        0 for the first electrode of the sequence.
    plan : PlanCycle
    channels : list of int
    legs : list of ProgramLeg
        Consecutive legs share their rest sample.
    """

    order: int
    plan: PlanCycle
    channels: list
    legs: list = field(default_factory=list)
    replacement: int = 0           # the n-th fresh electrode of the same plan (wear compensation's life)

    @property
    def label(self):
        name = self.plan.electrode_id or f"electrode {self.order + 1}"
        cycle = self.plan.cycle
        if cycle is not None and any(leg.regime == "rough" for leg in cycle.legs):
            name = f"rough-{name}"     # a roughing twin keeps its finishing electrode's id: say which it is
        return f"{name} (replacement {self.replacement})" if self.replacement else name


def index_leg(q_from, q_to, axis_names, plan, channel, compensation=0.0):
    """The A turn at the clear position from one channel's to another's: one straight leg in axis space.

    It moves A only, and with wear compensation X, Y, Z by the change of the compensation
    (``compensation`` [mm], the depth added along the front; :func:`~edm_planner.cnc.kinematics.offset_axes`
    moves X, Y, Z by the same amount at any A). Certified by the plan's clear zone
    (:class:`~edm_planner.machining.cycle.ClearZone`): the separation from the part's envelope depends on X
    alone, which moves linearly, so its smaller end value bounds the whole leg; INFEASIBLE where that is
    below the cycle's machining margin, INVALID_REQUEST for a cycle without a clear zone.
    """
    q_from, q_to = np.asarray(q_from, dtype=np.float64), np.asarray(q_to, dtype=np.float64)
    diff = np.flatnonzero(q_from != q_to)
    names = list(axis_names)
    ia = names.index("A")
    xyz = [names.index(n) for n in "XYZ"]
    allowed = {ia} | (set(xyz) if compensation else set())
    if len(diff) and not set(diff) <= allowed:
        raise EdmError(ErrorCode.INTERNAL, f"an index move may turn A only (and move X, Y, Z by a change of the "
                                           f"wear compensation), it would move axes {[axis_names[i] for i in diff]}")
    zone = plan.cycle.clear_zone if plan.cycle is not None else None
    if zone is None:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"plan {plan.plan_id} (electrode {plan.electrode_id or '-'}): its cycle has no clear position "
                       f"(planned before clear legs existed, or received without it): an index move there cannot "
                       f"be certified; plan the set again")
    ix = names.index("X")
    separation = float(min(zone.separation(q_from[ix]), zone.separation(q_to[ix])))
    if not separation >= plan.cycle.margin:
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"plan {plan.plan_id}: the index to channel {channel} would pass {separation:.3f} mm from the "
                       f"part's envelope, less than the machining margin {plan.cycle.margin:.3f} mm")
    label = f"index A {q_to[ia] - q_from[ia]:+.5f} rad to channel {channel} at the clear position"
    if compensation:
        label += f", wear compensation {compensation:+.4f} mm"
    return ProgramLeg(INDEX, label, np.vstack([q_from, q_to]), channel, plan,
                      clearance_lower_bound=np.full(4, separation))


def cycle_legs(plan, channel, pitch, use=0):
    """The legs of a plan's cycle in channel ``channel``, the ``use``-th channel of its electrode's life
    (with wear compensation, the cycle moved ``reach.compensation_depths[use]`` along the front).

    INVALID_REQUEST when the plan has no cycle, INFEASIBLE when its cycle is not certified (a leg that may
    come closer to a final surface than the machining margin would overcut it).
    """
    if plan.cycle is None:
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"plan {plan.plan_id} (electrode {plan.electrode_id or '-'}) has no machining cycle: a "
                       f"program runs each electrode's whole cycle (plan the channel's electrode set, "
                       f"`edm-plan plan` without a design, to get one)")
    if not plan.cycle.certified:
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"the machining cycle of plan {plan.plan_id} (electrode {plan.electrode_id or '-'}) is not "
                       f"certified: {plan.cycle.message or 'no reason recorded'}; it is not sent nor written")
    depths = plan.cycle.reach.compensation_depths
    legs = plan.cycle.with_compensation_depth(depths[use], plan.final_pose) if depths else list(plan.cycle.legs)
    if legs and legs[-1].phase == "clear":         # from the clear position and back to it
        out = legs[-1]
        back = replace(out, label=f"clear: back in from X {out.samples[-1][list(plan.axis_names).index('X')]:.3f} "
                                  f"mm (the clear leg reversed)", samples=out.samples[::-1].copy())
        legs = [back] + legs
    return [ProgramLeg(leg.phase, leg.label,
                       shift_to_channel(leg.samples, plan.axis_names, plan.channel, channel, pitch), int(channel), plan,
                       leg.regime, leg.removed_volume, np.asarray(leg.clearance_lower_bound, dtype=np.float64).copy())
            for leg in legs]


def program_runs(steps, plans, pitch=None):
    """The electrode runs of a sequence: cycles in their channels, index legs between channels.

    Parameters
    ----------
    steps : sequence of (plan_id, channel)
    plans : dict plan_id -> PlanCycle
    pitch : float, optional
        2 pi / N [rad]; needed when a step's channel differs from its plan's.

    Returns
    -------
    list of ElectrodeRun
        One per run of consecutive steps with the same plan (and, with wear compensation, the same
        electrode's life); a tool change lies between two runs.

    Raises
    ------
    EdmError
        UNKNOWN_ID (a step's plan missing), INVALID_REQUEST (a plan without cycle, a four-axis plan in another
        channel, no pitch where one is needed, axes differing between electrodes), INFEASIBLE (a cycle not
        certified).
    """
    runs = []
    names = None
    uses = {}                      # plan id -> channels its electrode machined so far
    for plan_id, channel in steps:
        plan = plans.get(plan_id)
        if plan is None:
            raise EdmError(ErrorCode.UNKNOWN_ID, f"plan {plan_id} of the sequence is not known")
        if names is None:
            names = tuple(plan.axis_names)
        elif tuple(plan.axis_names) != names:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"plan {plan_id} has axes {list(plan.axis_names)}, the "
                                                      f"sequence's first plan {list(names)}")
        if int(channel) != plan.channel and pitch is None:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"plan {plan_id} is for channel {plan.channel}, its step for "
                                                      f"channel {channel}: the blade count (pitch) is needed")
        depths = plan.cycle.reach.compensation_depths if plan.cycle is not None else ()
        life = len(depths)
        use = uses.get(plan_id, 0)
        uses[plan_id] = use + 1
        legs = cycle_legs(plan, channel, pitch, use % life if life else 0)
        if runs and runs[-1].plan.plan_id == plan_id and not (life and use % life == 0):
            run = runs[-1]
            home_from, home_to = run.legs[-1].samples[-1], legs[0].samples[0]
            change = depths[use % life] - depths[use % life - 1] if life else 0.0
            if not np.array_equal(home_from, home_to):
                run.legs.append(index_leg(home_from, home_to, names, plan, int(channel), compensation=change))
        else:
            run = ElectrodeRun(len(runs), plan, [], replacement=use // life if life else 0)
            runs.append(run)
        run.channels.append(int(channel))
        run.legs.extend(legs)
    return runs


def read_exported_cycle(export_dir, doc):
    """The MachiningCycle of a plan export directory (plan.json's ``cycle`` section and cycle.csv), or None.

    Parameters
    ----------
    export_dir : path
    doc : dict
        The directory's plan.json, read.

    Raises
    ------
    EdmError
        FILE_ERROR when cycle.csv is missing, differs from the checksum plan.json records, or does not agree
        with the legs plan.json lists.
    """
    section = doc.get("cycle")
    if not section:
        return None
    path = pathlib.Path(export_dir) / "cycle.csv"
    meta = (doc.get("files") or {}).get("cycle") or {}
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"{path}: {exc.strerror or exc} (plan.json has a cycle)") from None
    if meta.get("sha256") and hashlib.sha256(raw).hexdigest() != meta["sha256"]:
        raise EdmError(ErrorCode.FILE_ERROR, f"{path}: sha256 differs from the one plan.json records (file replaced "
                                             f"or damaged)")
    names = tuple(section["axis_names"])
    try:
        rows = list(csv.reader(raw.decode().splitlines()))
        # phase, leg, the axes, then (since the process model) the leg's regime
        body = np.array([[float(v) for v in r[2:2 + len(names)]] for r in rows[1:]],
                        dtype=np.float64).reshape(-1, len(names))
    except (ValueError, IndexError, UnicodeDecodeError) as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"{path}: malformed: {exc}") from None
    legs = []
    for i, leg in enumerate(section["legs"]):
        a, b = int(leg["first"]), int(leg["last"])
        if not 0 <= a < b < len(body) or (legs and a != int(section["legs"][i - 1]["last"])):
            raise EdmError(ErrorCode.FILE_ERROR, f"{path}: leg {i} ({leg.get('phase')}) samples {a}..{b} do not fit "
                                                 f"the {len(body)} rows or the leg before")
        clear = leg.get("clearance_lower_bound_mm") or leg.get("min_clearance_lower_bound_mm") or {}
        low = np.array([np.nan if clear.get(s) is None else float(clear[s])
                        for s in ("suction", "pressure", "hub", "shroud")])
        volume = leg.get("removed_volume_mm3")
        legs.append(Leg(leg["phase"], leg["label"], body[a:b + 1].copy(), low, leg.get("regime", "") or "",
                        np.nan if volume is None else float(volume)))
    if not legs or int(section["legs"][-1]["last"]) != len(body) - 1:
        raise EdmError(ErrorCode.FILE_ERROR, f"{path}: {len(body)} rows, plan.json's legs end elsewhere")
    reach = ProcessReach.from_dict(section.get("reach") or {})
    return MachiningCycle(names, legs, reach, float(section.get("margin_mm", np.nan)),
                          bool(section.get("certified", False)), section.get("message", ""),
                          ClearZone.from_dict(section.get("clear_zone")))
