"""The whole blisk in one call: every channel group planned on its own walls, each group a task (no rclpy).

A blisk as measured has channels of their own walls; channels whose walls agree within the geometry's
tolerance form a group (:meth:`~edm_planner.geometry.loader.LoadedGeometry.channel_groups`) that shares the
plans made on its representative channel's own walls (``geometry.for_channel(rep)``). A nominal blisk is one
group of every channel. :func:`plan_blisk` plans every group as one task:

- with a fixed electrode design (the file's ``electrode:`` section, or a design given): each electrode of
  the design planned in the representative channel (:func:`~edm_planner.planning.planner.plan_channel`, as
  ``edm-plan plan --channel REP`` does, bit for bit) and its machining cycle built and certified
  (:class:`~.cycle.CycleBuilder`, the cycle the whole-blisk program runs);
- otherwise the channel's electrode set designed (:class:`~.electrode_set.SetDesigner`; inside a local
  task with the local cores left to it, ``BliskRequest.set_workers``; serial in a Ray task).

The tasks run on an executor of :mod:`.executors`: local spawn worker processes, or Ray tasks (a local Ray,
or a cluster by address); a task whose worker dies is run again (Ray). The caller's ``stored`` callback
answers a group already planned (the plan store: nothing is planned twice across a crash or a rerun), its
``keep`` callback takes each group as it finishes (the plan store, the exports) and ``report`` hears of it
(which group, which channels, which node and worker, how long). A group that fails is kept as failed, with
its error code and message; the others go on. The whole-blisk program's steps
(:func:`~.program.channel_program_steps`, every channel once per electrode of its group's plans) are made
only when every group succeeded: never a program with a channel missing.

The geometry goes to each worker once (pickled, in the executor's initializer); each worker loads the group's
distance field from the field cache (``cache_dir``, the same path on every node of a cluster) or builds it.
Units: mm, rad, s.
"""

import concurrent.futures
import logging
import os
import pickle
import socket
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import EdmError, ErrorCode
from ..geometry.electrode import design_electrodes
from ..interference.fast import FastChannelField
from ..planning.planner import plan_channel
from .cycle import CycleBuilder, CycleOptions, shift_channel
from .executors import LOCAL, kind_for, make_executor
from .program import channel_program_steps, sequence_id_for

_log = logging.getLogger(__name__)

#: the distance field's spacing [mm]: the planner's (``edm-plan plan`` builds the same field)
FIELD_SPACING = 0.1
PLANNED, STORED, FAILED = "planned", "stored", "failed"
SURFACES = ("suction", "pressure", "hub", "shroud")


@dataclass(frozen=True)
class BliskRequest:
    """What every group is planned with (picklable: it goes to every worker).

    Attributes
    ----------
    options : PlanOptions
    fixed_design : bool
        True: every group plans the electrodes of a fixed design (``design``, or the geometry's own); False:
        every group's electrode set is designed.
    design : ElectrodeDesign or None
        The fixed design where one is given (the geometry file's design with the command line's changes);
        None: the geometry's own (``edm-plan plan`` passes None where nothing is changed).
    electrode_ids : tuple of str
        The fixed design's electrodes to plan, in machining order (:func:`design_electrode_ids`).
    cycle_options : CycleOptions
        The machining cycle of a fixed design's plans (its tolerance: how far below the discharge gap
        copy processing may come [mm]); a set's cycles follow the set's tolerance.
    cache_dir : str
        The distance-field cache (every worker loads its group's field from it).
    set_options, process, process_step, process_resolution, stock_mesh
        The electrode-set designer's settings (:class:`~.electrode_set.SetDesigner`), used without a design.
    set_workers : int
        The set designer's own local worker processes inside a group's task (:func:`plan_blisk` sets it: the
        local workers shared among the groups to plan, so that a nominal blisk's one group designs as fast as
        ``edm-plan plan --channel``; 1 in a Ray task, which holds one CPU of the cluster).
    """

    options: object
    fixed_design: bool = True
    design: object = None
    electrode_ids: tuple = ()
    cycle_options: CycleOptions = field(default_factory=CycleOptions)
    cache_dir: str = None
    set_options: object = None
    process: object = None
    process_step: object = None
    process_resolution: float = 0.5
    stock_mesh: object = None
    set_workers: int = 1


@dataclass
class GroupPlan:
    """One group's outcome.

    Attributes
    ----------
    representative : int
        The channel whose own walls the group is planned on.
    members : list of int
        The group's channels (they share its plans).
    deviations : list of float
        Each member's wall deviation from the representative [mm].
    status : str
        "planned" (by a task of this run), "stored" (from the plan store) or "failed".
    plans : list of Plan
        With their certified machining cycles, in machining order, in the representative channel.
    labels : list of str
        Each plan's electrode label.
    electrode_set : ElectrodeSet or None
        The designed set (no fixed design; also a failed one, for its report).
    error_code : ErrorCode
    message : str
    node, worker : str
        Where the task ran: the Ray node id or the host name; the worker process ("pid N").
    elapsed_s : float
        The task's own time [s] (NaN for a group from the store).
    """

    representative: int
    members: list
    deviations: list
    status: str = PLANNED
    plans: list = field(default_factory=list)
    labels: list = field(default_factory=list)
    electrode_set: object = None
    error_code: ErrorCode = ErrorCode.SUCCESS
    message: str = ""
    node: str = ""
    worker: str = ""
    elapsed_s: float = float("nan")

    @property
    def ok(self):
        return self.status != FAILED

    @property
    def name(self):
        """The group by its channels, for reports: "channel 43" or "channels 0-42, 44-59 (group of 0)"."""
        if len(self.members) == 1:
            return f"channel {self.representative}"
        return f"channels {channel_ranges(self.members)} (group of channel {self.representative})"

    def clearance(self, which):
        """Per surface, the smallest of the group's plans [mm]: ``which`` "clearance_lower_bound" (certified
        over the whole continuous path) or "clearance_exact" (exact minimum at the samples)."""
        values = [np.asarray(getattr(p.metrics, which), dtype=np.float64) for p in self.plans]
        if not values:
            return {}
        low = np.fmin.reduce(values, axis=0)        # NaN where a plan has none (a roughing twin's exact minimum)
        return {s: float(v) for s, v in zip(SURFACES, low)}

    def to_dict(self):
        """JSON-safe summary (no plans: their ids)."""
        return {"representative": self.representative, "members": list(self.members),
                "wall_deviation_mm": [float(d) for d in self.deviations], "status": self.status,
                "error_code": self.error_code.name, "message": self.message,
                "plan_ids": [p.plan_id for p in self.plans], "labels": list(self.labels),
                "clearance_lower_bound_mm": self.clearance("clearance_lower_bound"),
                "clearance_exact_mm": self.clearance("clearance_exact"),
                "node": self.node, "worker": self.worker,
                "elapsed_s": None if self.elapsed_s != self.elapsed_s else float(self.elapsed_s)}


@dataclass
class BliskPlan:
    """Every group's outcome (in :meth:`channel_groups` order) and, when all succeeded, the program's steps.

    Attributes
    ----------
    geometry_id : str
    blade_count : int
    groups : list of GroupPlan
    steps : list of (plan id, channel) or None
        The whole-blisk program (:func:`~.program.channel_program_steps`); None when a group failed.
    program_id : str
        The program's sequence id ('' without steps).
    executor : str
        Where the tasks ran (the executor's description; '' when every group came from the store).
    elapsed_s : float
    """

    geometry_id: str
    blade_count: int
    groups: list
    steps: list = None
    program_id: str = ""
    executor: str = ""
    elapsed_s: float = 0.0

    @property
    def failed(self):
        return [g for g in self.groups if not g.ok]

    def to_dict(self):
        return {"geometry_id": self.geometry_id, "blade_count": self.blade_count, "program_id": self.program_id,
                "complete": self.steps is not None, "executor": self.executor, "elapsed_s": self.elapsed_s,
                "groups": [g.to_dict() for g in self.groups],
                "steps": None if self.steps is None else [[p, int(k)] for p, k in self.steps]}


def channel_ranges(channels):
    """Channels as ranges: [0, 1, 2, 5] -> "0-2, 5"."""
    out, run = [], []
    for k in sorted(channels):
        if run and k == run[-1] + 1:
            run.append(k)
            continue
        if run:
            out.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
        run = [k]
    if run:
        out.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
    return ", ".join(out)


def design_electrode_ids(geometry, design=None, electrode_id=""):
    """The electrodes a fixed design plans, in machining order: ``electrode_id`` alone when given (refused
    with UNKNOWN_ID when the design has none of that id), else every electrode of the design (its split)."""
    ids = [e.electrode_id for e in (design_electrodes(geometry.blisk, design) if design is not None
                                    else geometry.electrodes)]
    if electrode_id:
        if electrode_id not in ids:
            raise EdmError(ErrorCode.UNKNOWN_ID, f"electrode {electrode_id!r} is not one of the design's {ids}")
        return (electrode_id,)
    return tuple(ids)


def plan_blisk(geometry, request, *, workers=None, ray_address="", kind=None, stored=None, keep=None,
               report=None, max_retries=None, groups=None):
    """Plan every channel group of ``geometry`` as tasks; the whole-blisk program's steps when all succeed.

    Parameters
    ----------
    geometry : LoadedGeometry
        Nominal (one group) or as measured.
    request : BliskRequest
    workers : int, optional
        Worker processes (local) or a local Ray's CPUs (default: the CPU count, at most one per group).
    ray_address : str
        "" (local workers, unless ``kind`` is "ray"), "local" (a local Ray) or a Ray cluster's address.
    kind : str, optional
        "local" or "ray" (:func:`~.executors.kind_for`).
    stored : callable, optional
        ``stored(group) -> GroupPlan or None``: a group (representative, members, deviations) already planned
        with this request (status "stored"); it is not planned again.
    keep : callable, optional
        ``keep(GroupPlan)``, in this thread, as each group finishes (failed ones too): the caller's plan store
        and files. An EdmError it raises fails that group (the others are kept).
    report : callable, optional
        ``report(GroupPlan, done, total)`` after ``keep``; ``report(None, 0, total, message)`` once the tasks
        are handed out.
    max_retries : int, optional
        Ray only: how often a task whose worker died is run again (default :data:`~.executors.MAX_RETRIES`).
    groups : list, optional
        ``geometry.channel_groups()`` where the caller has them already (they take a second or two to find).

    Returns
    -------
    BliskPlan
    """
    t0 = time.perf_counter()
    n = geometry.blisk.blade_count
    groups = [(int(rep), [int(k) for k in members], [float(d) for d in devs])
              for rep, members, devs in (geometry.channel_groups() if groups is None else groups)]
    done, pending = {}, []
    for group in groups:
        found = stored(group) if stored is not None else None
        if found is not None:
            found.status = STORED
            done[group[0]] = _kept(found, keep)
            if report is not None:
                report(done[group[0]], len(done), len(groups))
        else:
            pending.append(group)
    executor = None
    described = ""
    try:
        if pending:
            count = max(1, min(int(workers or os.cpu_count() or 1), len(pending)))
            extra = {} if max_retries is None else {"max_retries": int(max_retries)}
            if not request.fixed_design:
                # a set designer's own workers inside each task: the local cores shared among the groups
                total = int(workers or os.cpu_count() or 1)
                request = replace(request, set_workers=max(1, total // len(pending))
                                  if kind_for(ray_address, kind) == LOCAL else 1)
            executor = make_executor(count, _start_worker, (pickle.dumps(geometry), request), address=ray_address,
                                     kind=kind, **extra)
            described = executor.describe()
            futures = {executor.submit(_plan_group, *group): group for group in pending}
            if report is not None:
                report(None, len(done), len(groups), f"{len(pending)} group(s) to plan on {described}"
                       + (f", {len(done)} from the plan store" if done else ""))
            for future in concurrent.futures.as_completed(futures):
                outcome = _outcome(future, futures[future])
                done[outcome.representative] = _kept(outcome, keep)
                if report is not None:
                    report(outcome, len(done), len(groups))
    except BaseException:
        if executor is not None:
            executor.terminate()
        raise
    finally:
        if executor is not None:
            executor.shutdown(wait=True, cancel_futures=True)
    result = BliskPlan(geometry.geometry_id, n, [done[g[0]] for g in groups], executor=described)
    if not result.failed:
        result.steps = channel_program_steps([(g.representative, g.members) for g in result.groups],
                                             {g.representative: [p.plan_id for p in g.plans] for g in result.groups},
                                             n)
        result.program_id = sequence_id_for("blisk_program", result.steps, geometry.geometry_id)
    result.elapsed_s = time.perf_counter() - t0
    return result


def _outcome(future, group):
    """A finished task's GroupPlan; a task that raised (a bug, its worker lost for good) as a failed group."""
    rep, members, devs = group
    try:
        outcome = future.result()
    except EdmError as exc:
        return GroupPlan(rep, members, devs, FAILED, error_code=exc.code, message=exc.message)
    except Exception as exc:                      # the worker died (retries used up) or a bug in the task
        return GroupPlan(rep, members, devs, FAILED, error_code=ErrorCode.INTERNAL,
                         message=f"the task failed: {exc!r}")
    if getattr(future, "node_id", None):          # a Ray task: the node it ran on (its last try)
        outcome.node = future.node_id
    return outcome


def _kept(outcome, keep):
    """``keep(outcome)``; its EdmError (a store or a file that cannot take the group) fails the group."""
    if keep is None:
        return outcome
    try:
        keep(outcome)
    except EdmError as exc:
        outcome.status, outcome.error_code = FAILED, exc.code
        outcome.message = f"{outcome.message}; not kept: {exc.message}".lstrip("; ")
    return outcome


# -- in the worker -------------------------------------------------------------------------------------------

#: in a worker process: (geometry, request), set by :func:`_start_worker`
_WORKER = None


def _start_worker(geometry_blob, request, reports=None):
    """Worker process: the geometry (its channels' own blisks made on demand) and the request."""
    global _WORKER
    _WORKER = (pickle.loads(geometry_blob), request)


def _plan_group(representative, members, deviations):
    """A group's task: its plans (fixed design) or its electrode set; a failed GroupPlan for a refusal."""
    geometry, request = _WORKER
    t0 = time.perf_counter()
    outcome = GroupPlan(representative, members, deviations, node=socket.gethostname(), worker=f"pid {os.getpid()}")
    try:
        if request.fixed_design:
            outcome.plans = plan_group_fixed(geometry, representative, request)
            outcome.labels = [p.electrode_id for p in outcome.plans]
            outcome.message = f"{len(outcome.plans)} plan(s) certified, cycles certified"
        else:
            outcome.electrode_set = design_group_set(geometry, representative, request)
            found = outcome.electrode_set
            outcome.message = found.message
            if found.chosen is None:
                raise EdmError(ErrorCode.INFEASIBLE, f"electrode set: {found.message}")
            outcome.plans = [p.plan for p in found.chosen.pieces]
            outcome.labels = [p.label for p in found.chosen.pieces]
    except EdmError as exc:
        outcome.status, outcome.error_code, outcome.message = FAILED, exc.code, exc.message
        outcome.plans, outcome.labels = [], []
    outcome.elapsed_s = time.perf_counter() - t0
    return outcome


def plan_group_fixed(geometry, channel, request):
    """The fixed design's plans in ``channel`` on its own walls, each with its certified machining cycle.

    The plans are :func:`~edm_planner.planning.planner.plan_channel`'s for (geometry, channel, electrode,
    options, design): those of ``edm-plan plan --channel`` with the same settings, bit for bit.

    Raises
    ------
    EdmError
        The plan's error (INFEASIBLE, ...) or INFEASIBLE for a cycle that is not certified, naming the electrode.
    """
    own = geometry.for_channel(channel)
    field_ = FastChannelField(own.blisk, spacing=FIELD_SPACING, cache_dir=request.cache_dir, cache_key=own.field_key)
    design = request.design or geometry.design
    search = request.options.search
    margin = min(search.margin_blade, search.margin_hub_shroud)
    plans = []
    for eid in request.electrode_ids:
        plan = plan_channel(geometry, channel, eid, request.options, field=field_, design=request.design,
                            cache_dir=request.cache_dir)
        if not plan.success:
            raise EdmError(plan.error_code, f"electrode {eid or plan.electrode_id}: {plan.message} (furthest node "
                                            f"{plan.furthest_node}, {plan.furthest_reference:.3f} mm)")
        electrode = design_electrodes(own.blisk, design, only=plan.electrode_id)[0]
        builder = CycleBuilder(field_, electrode, design, plan.axis_names, request.cycle_options)
        # the cycle is built in channel 0 of the channel's own blisk (its every channel is this one) and moved back
        pitch = own.blisk.pitch
        cycle = builder.build(shift_channel(plan.samples, plan.axis_names, -channel, pitch), margin,
                              np.asarray(plan.metrics.clearance_lower_bound))
        for leg in cycle.legs:
            leg.samples = shift_channel(leg.samples, plan.axis_names, channel, pitch)
        if not cycle.certified:
            raise EdmError(ErrorCode.INFEASIBLE,
                           f"electrode {plan.electrode_id}: the feed plan {plan.plan_id} is certified, its machining "
                           f"cycle is not: {cycle.message} (the cycle's margin is the discharge gap less "
                           f"{request.cycle_options.tolerance:g} mm; plan with --margin-blade and "
                           f"--margin-hub-shroud at least that)")
        plan.cycle = cycle
        plans.append(plan)
    return plans


def design_group_set(geometry, channel, request):
    """The electrode set of ``channel`` on its own walls (the designer's own local workers: ``set_workers``)."""
    from .electrode_set import SetDesigner            # heavy (the removal proof's modules): the set path only

    own = geometry.for_channel(channel)
    field_ = FastChannelField(own.blisk, spacing=FIELD_SPACING, cache_dir=request.cache_dir, cache_key=own.field_key)
    # its cycle options follow the set's tolerance (the designer's own default, as edm-plan plan's set)
    designer = SetDesigner(own, field_, request.options, request.set_options,
                           field_cache=(request.cache_dir, own.field_key), workers=request.set_workers,
                           process=request.process,
                           process_resolution=request.process_resolution, stock_mesh=request.stock_mesh,
                           process_step=request.process_step, executor="local")
    return designer.design(channel)

