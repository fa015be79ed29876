"""trajectory_planner node: certified channel plans over DDS.

Builds its models from the geometry_loader's latched ``geometry`` topic (the
exact blisk and the electrode design in ``model_json``; electrodes are
re-designed here because the search needs their labelled surface samples)
and serves ``plan_channel`` (edm_planner_msgs/PlanChannel) and
``plan_roughing`` (edm_planner_msgs/PlanRoughing: Chen & Dong plunge roughing,
``edm_planner.roughing``). Both kinds of plan go on ``plan`` and into the plan
store, so the axis bridge executes either by id.

Topics: ``plan`` (edm_planner_msgs/ChannelPlan, TRANSIENT_LOCAL, the latest
certified plan), ``plan_progress`` (edm_planner_msgs/PlanProgress, while
planning).

Parameters
----------
cache_dir : str
    Directory of cached distance fields, designed electrodes and workpiece deviations ('' : ~/.cache/edm_planner).
fast_spacing : float
    Distance-field spacing [mm].
time_budget : float
    Default time budget of a request [s] (PlannerSettings.time_budget 0 or NaN).
export_dir : str
    Where ``write_export`` requests write plan exports ('' : ~/.local/share/edm_planner/plans), as
    ``<plan id>/`` or ``<set id>/``: plain names only, never through a symbolic link (``edm_planner.paths``).
geometry_wait : float
    How long a request waits for a geometry still being prepared [s].
unknown_geometry_wait : float
    How long a request for a geometry id not seen yet waits for it on ``geometry`` [s].
set_wait : float
    How long a PlanElectrodeSet service call waits while another set is being designed (one at a time)
    before it is answered TIMEOUT [s]; an action goal meanwhile is rejected at once.
plan_store : str
    Directory of the persistent plan store ('' : ~/.local/share/edm_planner/plan_store, 'none' : off).
    A request equal to an earlier one (same geometry content, channel, electrode, settings) is answered
    from the store at once; the axis bridge reads the same store.
"""

import json
import os
import threading
import time
from dataclasses import replace

import numpy as np
from edm_planner_msgs.action import PlanElectrodeSet as PlanElectrodeSetAction
from edm_planner_msgs.msg import (AxisPath, AxisPoint, BliskGeometry, ChannelPlan, ElectrodeProcess,
                                  ElectrodeSetCandidate, PlanMetrics, PlanProgress, RoughingStatistics)
from edm_planner_msgs.srv import PlanChannel, PlanElectrodeSet, PlanRoughing
from geometry_msgs.msg import PoseArray
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node

from ..ros.startup import prepare_process

#: this entry point's set-up, before the core's kernel modules load (numba reads its cache directory then) and
#: before rclpy.init (Fast DDS on loopback): :func:`edm_planner.ros.startup.prepare_process`
DDS_SETUP = prepare_process()

from .. import CACHE_ROOT
from ..errors import EdmError, ErrorCode
from ..geometry.as_measured import MeasuredBlades
from ..geometry.blisk import Blisk
from ..geometry.electrode import ElectrodeDesign
from ..geometry.electrode_cache import cached_design
from ..geometry.loader import LoadedGeometry
from ..interference import SURFACES
from ..interference.fast import FastChannelField
from ..cnc.config import load_machine
from ..machining.cycle import CycleOptions
from ..machining.electrode_set import SetDesigner, SetOptions, set_id_for
from ..machining.program import blisk_program_steps
from ..machining.set_progress import SetDesignCancelled, SetProgress
from ..paths import export_path
from ..planning.objective import Weights
from ..planning.plan import PlanMetrics as CorePlanMetrics
from ..planning.plan import PlanOptions
from ..planning.planner import plan_channel
from ..planning.search import SearchOptions
from ..process.set_process import add_process
from ..process.volume import load_stock_mesh
from ..records.certificate import META_KEY, NotCertifiedError, verify_record
from ..records.plan_export import write_plan
from ..records.set_files import write_set, write_stored_set
from ..records.store import (PlanStoreError, cycle_from_record, plan_to_stored, request_key, roughing_to_stored,
                             stored_to_plan)
from ..ros.conversions import cycle_fields, design_override, error_code, machining_figures, matrices_to_poses
from ..ros.runtime import answer, declare_plan_store, default_machine_file, end_canceled, spin_node
from ..roughing import RoughingOptions, plan_roughing, roughing_plan_id
from ..ros.received import ReceivedGeometries
from ..ros.shared import LATCHED


def plan_options(settings, default_budget):
    """PlannerSettings message -> PlanOptions (NaN / 0 / empty take the defaults)."""
    d = SearchOptions()

    def value(x, default):
        x = float(x)
        return default if (np.isnan(x) or x == 0.0) else x

    def weights(values, default):
        return tuple(values) if len(values) else default

    try:
        w = Weights(smoothness=weights(settings.weights_smoothness, Weights().smoothness),
                    margin=weights(settings.weights_margin, Weights().margin),
                    total=weights(settings.weights_total, Weights().total))
        reference = {settings.REFERENCE_X_AXIS: "x_axis", settings.REFERENCE_CENTERLINE: "centerline"}.get(
            settings.reference)
        if reference is None:
            raise ValueError(f"reference must be 0 (x axis) or 1 (centerline), got {settings.reference}")
        search = SearchOptions(
            method=settings.method or d.method, reference=reference, axes=int(settings.axes) or d.axes,
            step=value(settings.step, d.step), margin_hub_shroud=value(settings.margin_hub_shroud, d.margin_hub_shroud),
            margin_blade=value(settings.margin_blade, d.margin_blade),
            exit_distance=value(settings.exit_distance, d.exit_distance), weights=w, seed=int(settings.seed),
            time_budget=value(settings.time_budget, default_budget))
        return PlanOptions(search=search, size_electrode=bool(settings.size_electrode))
    except ValueError as exc:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"settings: {exc}") from None


def metrics_to_msg(m, cycle=None, removal=None):
    """PlanMetrics (core) -> PlanMetrics message, with the machining figures of a cycle and a removal proof."""
    msg = PlanMetrics(node_count=int(m.node_count), path_length=float(m.path_length), objfun1=float(m.objfun1),
                      objfun2=float(m.objfun2), axis_names=list(m.axis_names),
                      smoothness=[float(v) for v in m.smoothness], sharp_points=[int(v) for v in m.sharp_points],
                      solver_evaluations=int(m.solver_evaluations), planning_time=float(m.planning_time),
                      certified=bool(m.certified), circumferential_reduction=float(m.circumferential_reduction),
                      **machining_figures(cycle, removal))
    for name in m.CLEARANCES:
        for surface, value in m.by_surface(name).items():
            setattr(msg, f"{name}_{surface}", value)
    return msg


def axis_path_msg(axis_names, samples):
    return AxisPath(axis_names=list(axis_names), points=[AxisPoint(positions=row) for row in samples.tolist()])


def pose_array_msg(poses, frame_id):
    msg = PoseArray()
    msg.header.frame_id = frame_id
    msg.poses = matrices_to_poses(poses)
    return msg


def roughing_options(request):
    """PlanRoughing request -> RoughingOptions (0 / NaN take the defaults)."""
    d = RoughingOptions()

    def given(x):
        x = float(x)
        return None if (np.isnan(x) or x == 0.0) else x

    radius, mu, allowance = given(request.tool_radius), given(request.safeguard_factor), given(request.allowance)
    return RoughingOptions(tool_radius=radius, mu=d.mu if mu is None else mu,
                           allowance=d.allowance if allowance is None else allowance)


def fill_process(response, meta):
    """The set's process figures (model estimates) from its record (a fresh design's or the store's)."""
    delivered = next((c for c in meta.get("candidates", []) if c.get("name") == meta.get("delivered")), None)
    pieces = (delivered or {}).get("pieces", [])
    response.electrode_regimes = [p.get("regime", "finish") for p in pieces]
    proc = (delivered or {}).get("process")
    if not proc:
        return
    for e in proc["electrodes"]:
        low, high = e["removed_volume_bracket_mm3"]
        comp = e.get("wear_compensation") or {}
        response.process.append(ElectrodeProcess(
            label=e["label"], regime=e["regime"], condition_code=e["condition_code"],
            removed_volume=float(e["removed_volume_mm3"]), removed_volume_lower=float(low),
            removed_volume_upper=float(high), eroding_time=3600.0 * float(e["eroding_time_h"]),
            wear_volume=float(e["wear_volume_mm3"]), frontal_area=float(e["frontal_area_mm2"]),
            frontal_wear=float(e["frontal_wear_per_channel_mm"]),
            worst_face_wear=float(e["worst_face_wear_per_channel_mm"]), wear_limit=float(e["wear_limit_mm"]),
            electrodes_per_channel=int(e["electrodes_per_channel"]), electrodes_per_blisk=int(e["electrodes_per_blisk"]),
            compensation_direction=[float(v) for v in comp.get("front_direction", [])],
            compensation_depths=[float(d) for d in comp.get("depths_mm", [])],
            compensation_note=str(comp.get("note", ""))))
    response.channel_removed_volume = float(proc["channel"]["removed_volume_mm3"])
    response.channel_eroding_time = 3600.0 * float(proc["channel"]["eroding_time_h"])
    response.blisk_eroding_time = 3600.0 * float(proc["blisk"]["eroding_time_h"])


def electrode_set_options(request, design):
    """PlanElectrodeSet request -> SetOptions (0 / NaN take the defaults)."""

    d = SetOptions()

    def given(x, default):
        x = float(x)
        return default if (np.isnan(x) or x == 0.0) else x

    try:
        return SetOptions(tolerance=given(request.tolerance, d.tolerance),
                          max_area_above=given(request.max_area_above, d.max_area_above),
                          max_electrodes=int(request.max_electrodes) or d.max_electrodes)
    except ValueError as exc:
        raise EdmError(ErrorCode.INVALID_REQUEST, f"electrode set: {exc}") from None


def candidate_msg(c):
    """A candidate of ElectrodeSet.to_dict() -> ElectrodeSetCandidate message."""
    msg = ElectrodeSetCandidate(name=c["name"], electrode_count=int(c["electrodes"]), status=c["status"],
                                reason=c["reason"], electrode_volume=float(c["electrode_volume_mm3"]))
    sized = [p for p in c["pieces"] if p.get("plan_id")]
    msg.circumferential_reduction = [float(p["design"]["circumferential_reduction"]) for p in sized]
    msg.radial_reduction = [float(p["design"]["radial_reduction"]) for p in sized]
    removal = c.get("removal")
    if removal:
        surfaces = [removal["surfaces"][s] for s in ("suction", "pressure", "hub", "shroud")]
        msg.stock_max_exact = [float(s["stock_max_mm"]) for s in surfaces]
        msg.stock_mean = [float(s["stock_mean_mm"]) for s in surfaces]
        msg.stock_area_fraction_above = [float(s["area_fraction_above_tolerance"]) for s in surfaces]
        msg.overcut_max = [float(s["overcut_max_mm"]) for s in surfaces]
    return msg


def set_feedback_msg(record, stage="electrode set"):
    """A SetProgress record (``edm_planner.machining.set_progress``) -> PlanElectrodeSet action feedback."""
    return PlanElectrodeSetAction.Feedback(
        candidate=record.candidate, candidate_index=int(record.candidate_index),
        candidate_count=int(record.candidate_count), piece=record.piece, piece_index=int(record.piece_index),
        piece_count=int(record.piece_count), sizing_parameter=record.sizing_parameter,
        sizing_step=int(record.sizing_step), circumferential_reduction=float(record.circumferential_reduction),
        radial_reduction=float(record.radial_reduction), fraction=float(record.fraction),
        estimated_time_left=float(record.estimated_time_left), elapsed=float(record.elapsed), stage=stage,
        message=record.message)


class _FeedbackThrottle:
    """Publishes a goal's feedback at most every ``period`` seconds, and at once when the candidate or piece changes."""

    def __init__(self, goal_handle, period=0.1):
        self.goal_handle, self.period = goal_handle, period
        self.last, self.where, self.count = -float("inf"), None, 0

    def __call__(self, msg):
        where = (msg.candidate, msg.piece, msg.stage)
        now = time.monotonic()
        if where == self.where and now - self.last < self.period:
            return
        self.last, self.where = now, where
        self.count += 1
        self.goal_handle.publish_feedback(msg)


class _SetJob:
    """The set design of one action goal: a cancel reaches its designer whenever it comes (before it exists too)."""

    def __init__(self):
        self._lock = threading.Lock()
        self.designer = None
        self.cancelled = False

    def attach(self, designer):
        with self._lock:
            self.designer = designer
            if self.cancelled:
                designer.cancel()

    def cancel(self):
        with self._lock:
            self.cancelled = True
            designer = self.designer
        if designer is not None:
            designer.cancel()            # terminates the sizing workers: outside the lock

    def check(self):
        if self.cancelled:
            raise SetDesignCancelled("the electrode-set design was cancelled")


def statistics_msg(d):
    """ErrorStats.to_dict() -> RoughingStatistics message."""
    return RoughingStatistics(point_count=int(d["count"]), mean_absolute_error=float(d["mean_abs"]),
                              standard_deviation=float(d["std_abs"]), min_error=float(d["min"]),
                              max_error=float(d["max"]), range=float(d["range"]),
                              max_absolute_error=float(d["max_abs"]))


def fill_roughing_response(response, stored, frame_id):
    """A PlanRoughing response from a stored roughing plan (fresh or from the store alike)."""
    m, a = stored.meta, stored.arrays
    response.success = True
    response.error_code = error_code(ErrorCode.SUCCESS)
    response.message = m["message"]
    response.plan_id = stored.plan_id
    response.tool_radius, response.min_blade_gap = float(m["tool_radius"]), float(m["l_min"])
    response.max_tool_radius, response.line_count = float(m["r_max"]), int(m["line_count"])
    response.labels = list(m["labels"])
    response.tool_poses = pose_array_msg(a["tool_poses"], frame_id)
    response.initial_tool_poses = pose_array_msg(a["initial_tool_poses"], frame_id)
    response.hausdorff_initial = [float(v) for v in a["hausdorff_initial"]]
    response.hausdorff = [float(v) for v in a["hausdorff"]]
    response.initial, response.optimised = statistics_msg(m["stats_initial"]), statistics_msg(m["stats"])
    response.mae_reduction_percent = float(m["mae_reduction_percent"])
    response.axis_path = axis_path_msg(stored.axis_names, stored.samples)
    response.planning_time = float(m["planning_time"])


def channel_plan_msg(stored, poses, axis_path, metrics):
    """The ChannelPlan message the bridge takes, of a stored plan of any kind (with its cycle, if it has one).

    ``metrics`` gets the record's machining figures (cycle margin, removal proof; NaN without).
    """
    cycle = cycle_from_record(stored.meta, stored.arrays) if stored.kind == "channel" else None
    for key, value in machining_figures(cycle, stored.meta.get("removal")).items():
        setattr(metrics, key, value)
    return ChannelPlan(plan_id=stored.plan_id, geometry_id=stored.geometry_id, channel=int(stored.channel),
                       electrode_id=stored.electrode_id, method=stored.method,
                       final_pose=[float(v) for v in stored.poses[-1].reshape(-1)],
                       reference_pose=[float(v) for v in np.asarray(stored.final_pose).reshape(-1)],
                       poses=poses, axis_path=axis_path, metrics=metrics,
                       certificate_sha256=stored.meta.get(META_KEY, ""),
                       **cycle_fields(cycle, stored.meta.get("set_id", "")))


class _Prepared:
    """A geometry being (or done being) prepared for planning.

    ``parsed`` is set as soon as the blisk and the electrode design are read from the message (all a
    plan-store lookup needs), ``ready`` once the electrodes are designed and the distance field is loaded.
    """

    def __init__(self, gid):
        self.geometry_id = gid
        self.parsed = threading.Event()
        self.ready = threading.Event()
        self.blisk = None
        self.design = None
        self.geometry = None
        self.field = None
        self.error = None


class TrajectoryPlannerNode(Node):
    """Serves PlanChannel for every geometry published on ``geometry``."""

    def __init__(self, **kwargs):
        super().__init__("trajectory_planner", **kwargs)
        self.declare_parameter("cache_dir", "")
        self.declare_parameter("fast_spacing", 0.1)
        self.declare_parameter("time_budget", 60.0)
        self.declare_parameter("export_dir", "")
        self.declare_parameter("geometry_wait", 120.0)
        self.declare_parameter("unknown_geometry_wait", 5.0)
        self.declare_parameter("frame_id", "blisk")
        self.declare_parameter("set_wait", 600.0)
        self.declare_parameter("machine_file", "")
        self.declare_parameter("volume_resolution", 0.5)
        self.declare_parameter("stock_mesh", "")
        self.declare_parameter("ray_address", "")
        # the process section (regimes, wear) electrode sets are planned with: the machine file the axis bridge
        # times them on (the same default); a bad file stops the node at start, with the key named
        self.process = load_machine(self.get_parameter("machine_file").value or default_machine_file()).process
        # a pre-machined stock the electrodes start from ('' : the solid channel); a bad file stops the node
        stock = self.get_parameter("stock_mesh").value
        self.stock_mesh = load_stock_mesh(stock) if stock else None
        self.store, self.store_error = declare_plan_store(self)
        self._lock = threading.Lock()
        self.received = ReceivedGeometries(self._lock)       # geometry id -> _Prepared
        self.create_subscription(BliskGeometry, "geometry", self.on_geometry, LATCHED,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.plan_pub = self.create_publisher(ChannelPlan, "plan", LATCHED)
        self.progress_pub = self.create_publisher(PlanProgress, "plan_progress", 10)
        self.service = self.create_service(PlanChannel, "plan_channel", self.on_plan,
                                           callback_group=MutuallyExclusiveCallbackGroup())
        self.roughing_service = self.create_service(PlanRoughing, "plan_roughing", self.on_roughing,
                                                    callback_group=MutuallyExclusiveCallbackGroup())
        self.set_service = self.create_service(PlanElectrodeSet, "plan_electrode_set", self.on_plan_set,
                                               callback_group=MutuallyExclusiveCallbackGroup())
        # the same work as an action (feedback, cancel); one set design at a time, by either
        self._set_lock = threading.Lock()
        self._set_job = None
        self.set_action = ActionServer(self, PlanElectrodeSetAction, "plan_electrode_set", self.execute_plan_set,
                                       goal_callback=self.on_set_goal, cancel_callback=self.on_set_cancel,
                                       callback_group=ReentrantCallbackGroup())

    # -- geometry ---------------------------------------------------------------------------
    def on_geometry(self, msg):
        gid = msg.summary.geometry_id
        if self.received.again(gid):            # loaded again after another: the latest once more
            return
        prepared = _Prepared(gid)
        self.received.add(gid, prepared)
        threading.Thread(target=self._prepare, args=(gid, msg.model_json, prepared), daemon=True).start()

    def _prepare(self, gid, model_json, prepared):
        try:
            model = json.loads(model_json)
            blisk = Blisk.from_dict(model)
            design = ElectrodeDesign.from_dict(model.get("electrode_design") or {})
            prepared.blisk, prepared.design = blisk, design
            prepared.parsed.set()          # stored plans are answered from here on
            cache = self.get_parameter("cache_dir").value or CACHE_ROOT
            electrodes = cached_design(blisk, design, cache_dir=cache)
            measured = MeasuredBlades.from_dict(model.get("as_measured"))
            prepared.geometry = LoadedGeometry(gid, blisk, design, electrodes, source=model.get("source", ""),
                                               measured=measured)
            # a blisk as measured: this is its nominal channels' field, the nominal file's
            key = measured.nominal_field_key if measured is not None and measured.nominal_field_key else gid
            prepared.field = FastChannelField(blisk, spacing=float(self.get_parameter("fast_spacing").value),
                                              cache_dir=cache, cache_key=key)
            self.get_logger().info(f"geometry {gid[:12]} ready for planning: electrodes "
                                   f"{[e.electrode_id for e in electrodes]}, field bound "
                                   f"{prepared.field.error_bound * 1e3:.2f} um")
        except Exception as exc:  # a geometry we cannot use must not take the node down
            prepared.error = exc
            self.get_logger().error(f"geometry {gid[:12]} not usable for planning: {exc!r}")
        finally:
            prepared.ready.set()
            prepared.parsed.set()

    def _geometry(self, gid, parsed_only=False):
        """The prepared geometry of a request; with ``parsed_only`` without waiting for electrodes and field."""
        # a geometry loaded just before the request may still be on its way on the latched topic
        gid, prepared = self.received.require(gid, float(self.get_parameter("unknown_geometry_wait").value))
        event = prepared.parsed if parsed_only else prepared.ready
        if not event.wait(float(self.get_parameter("geometry_wait").value)):
            raise EdmError(ErrorCode.TIMEOUT, f"geometry {gid[:12]} is still being prepared")
        if prepared.error is not None:
            raise EdmError(ErrorCode.INVALID_GEOMETRY, f"geometry {gid[:12]} not usable: {prepared.error}")
        return prepared

    # -- planning ---------------------------------------------------------------------------
    def on_plan(self, request, response):
        return answer(self, "PlanChannel", self._plan, request, response)

    def _plan(self, request, response):
        # a plan in the store is answered at once: its key needs the geometry id and the design only
        prepared = self._geometry(request.geometry_id, parsed_only=True)
        gid = prepared.geometry_id
        options = plan_options(request.settings, float(self.get_parameter("time_budget").value))
        design = design_override(request.electrode, prepared.design)
        request_id = f"{gid[:8]}/{request.channel}/{request.electrode_id or 'first'}"

        def progress(stage, fraction, nodes, reference, message):
            self.progress_pub.publish(PlanProgress(request_id=request_id, stage=stage, fraction=float(fraction),
                                                   nodes=int(nodes), reference=float(reference),
                                                   message=message))

        key = request_key(gid, request.channel, request.electrode_id, options, design)
        plan, note = self._stored(key), ""
        if plan is None:
            prepared = self._geometry(gid)
            plan = plan_channel(prepared.geometry, int(request.channel), request.electrode_id, options,
                                field=prepared.field, progress=progress, design=design,
                                cache_dir=self.get_parameter("cache_dir").value or CACHE_ROOT)
            note = self._store(plan, key)
        else:
            progress("stored", 1.0, plan.metrics.node_count, 0.0, f"plan {plan.plan_id} from the plan store")
        response.success = plan.success
        response.error_code = error_code(plan.error_code)
        response.message = plan.message + note
        response.plan_id = plan.plan_id
        response.metrics = metrics_to_msg(plan.metrics, plan.cycle, plan.removal)
        response.furthest_node = int(plan.furthest_node)
        response.furthest_reference = float(plan.furthest_reference)
        response.blocking_surface = plan.blocking_surface
        response.blocking_clearance_lower_bound = float(plan.blocking_clearance_lower_bound)
        if not plan.success:
            self.get_logger().warning(f"plan {plan.plan_id}: {plan.error_code.name}: {plan.message}")
            return
        frame = self.get_parameter("frame_id").value
        response.poses = pose_array_msg(plan.poses, frame)
        response.axis_path = axis_path_msg(plan.axis_names, plan.samples)
        if request.write_export:
            root = self.get_parameter("export_dir").value or os.path.join(
                os.path.expanduser("~"), ".local", "share", "edm_planner", "plans")
            path = export_path(root, plan.plan_id, "plan id")        # never outside export_dir, never via a link
            write_plan(plan, path, prepared.blisk, cache_dir=self.get_parameter("cache_dir").value or CACHE_ROOT)
            response.export_path = str(path)
        self.plan_pub.publish(channel_plan_msg(plan_to_stored(plan), response.poses, response.axis_path,
                                               response.metrics))
        self.get_logger().info(f"plan {plan.plan_id}: {response.message}")

    # -- electrode sets ---------------------------------------------------------------------
    def on_plan_set(self, request, response):
        # one set design at a time: a call waits for the design under way, but not for ever
        wait = float(self.get_parameter("set_wait").value)
        if not self._set_lock.acquire(timeout=max(wait, 0.0)):
            response.success = False
            response.error_code = error_code(ErrorCode.TIMEOUT)
            response.message = (f"another electrode set is still being designed after {wait:g} s (one at a time, "
                                f"parameter set_wait): call again later, or use the plan_electrode_set action")
            self.get_logger().warning(f"PlanElectrodeSet refused (TIMEOUT): {response.message}")
            return response
        try:
            return answer(self, "PlanElectrodeSet", self._plan_set, request, response)
        finally:
            self._set_lock.release()

    def on_set_goal(self, goal):
        """Accept a PlanElectrodeSet goal unless a set is being designed (its lock is held until the goal ends)."""
        if not self._set_lock.acquire(blocking=False):
            self.get_logger().warning(f"PlanElectrodeSet goal (channel {goal.channel}) rejected: another electrode "
                                      f"set is being designed (one at a time; try again when it is done)")
            return GoalResponse.REJECT
        self._set_job = _SetJob()
        return GoalResponse.ACCEPT

    def on_set_cancel(self, goal_handle):
        job = self._set_job
        if job is not None:
            job.cancel()
            self.get_logger().info("PlanElectrodeSet goal: cancel requested, stopping the design")
        return CancelResponse.ACCEPT

    def execute_plan_set(self, goal_handle):
        """The action's body: ``_plan_set`` with feedback and cancel; SUCCEEDED iff the result's ``success``."""
        job = self._set_job
        result = PlanElectrodeSetAction.Result()
        throttle = _FeedbackThrottle(goal_handle)
        t0 = time.monotonic()

        def fill(goal, res):
            try:
                self._plan_set(goal, res, job=job,
                              detail=lambda r, stage="electrode set": throttle(set_feedback_msg(r, stage)))
            except SetDesignCancelled:
                job.cancelled = True

        try:
            answer(self, "PlanElectrodeSet", fill, goal_handle.request, result)
            if job.cancelled and not result.plan_ids and not result.candidates:
                result.success, result.error_code = False, error_code(ErrorCode.SUCCESS)
                result.message = (f"cancelled after {time.monotonic() - t0:.1f} s: nothing delivered, nothing "
                                  f"written to the plan store")
                end_canceled(goal_handle)
                self.get_logger().info(f"PlanElectrodeSet goal {result.message}")
            elif result.success:
                goal_handle.succeed()
            else:
                goal_handle.abort()
            return result
        finally:
            self._set_job = None
            self._set_lock.release()

    def _plan_set(self, request, response, detail=None, job=None):
        """PlanElectrodeSet, for the service and the action alike (request: a Request or a Goal, response: a
        Response or a Result); ``detail(SetProgress)`` gets the design's steps, ``job`` (_SetJob) cancels it."""

        prepared = self._geometry(request.geometry_id, parsed_only=True)
        gid = prepared.geometry_id
        options = plan_options(request.settings, float(self.get_parameter("time_budget").value))
        set_options = electrode_set_options(request, prepared.design)
        cycle_options = CycleOptions(tolerance=set_options.tolerance)
        if not 0 <= request.channel < prepared.blisk.blade_count:
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"channel must be in 0 .. {prepared.blisk.blade_count - 1}, got {request.channel}")
        designer = None
        process = self.process
        if request.single_regime:
            process = replace(process, rough_and_finish=False)
        resolution = float(self.get_parameter("volume_resolution").value)
        set_id, program_id = set_id_for(gid, request.channel, SetDesigner.machining_plan_options(
            options, prepared.design, set_options), set_options, cycle_options, process, resolution,
            self.stock_mesh[1] if self.stock_mesh else "")
        found = self._stored_set(set_id)
        if found is not None:
            plans, meta = found
            message = f"from the plan store: {meta.get('message', '')}"
            candidates, planning_time = meta.get("candidates", []), float(meta.get("planning_time_s", 0.0))
            if detail is not None:
                detail(SetProgress(message=f"set {set_id} from the plan store").timed(1.0, 0.0), "stored")
        else:
            prepared = self._geometry(gid)
            if job is not None:
                job.check()                 # cancelled while the geometry was being prepared
            request_id = f"{gid[:8]}/{request.channel}/set"

            def progress(stage, fraction, message):
                self.progress_pub.publish(PlanProgress(request_id=request_id, stage=stage,
                                                       fraction=float(fraction), message=message))

            cache = self.get_parameter("cache_dir").value or CACHE_ROOT
            # a blisk as measured: the channel's set is designed on its own two blades, with their field
            geometry, field = prepared.geometry.for_channel(int(request.channel)), prepared.field
            if geometry.field_key != prepared.geometry.field_key:
                progress("field", 0.0, f"distance field of channel {request.channel} as measured")
                field = FastChannelField(geometry.blisk, spacing=field.spacing, cache_dir=cache,
                                         cache_key=geometry.field_key)
            designer = SetDesigner(geometry, field, options, set_options, cycle_options,
                                   progress=progress, field_cache=(cache, geometry.field_key), detail=detail,
                                   process=process,
                                   process_resolution=resolution, stock_mesh=self.stock_mesh,
                                   process_step=add_process,
                                   ray_address=str(self.get_parameter("ray_address").value or ""))
            if job is not None:
                job.attach(designer)
            # a cancelled design raises SetDesignCancelled here, before anything is stored (the plans, the set
            # and the program are kept only below, once the design is complete)
            result = designer.design(int(request.channel))
            meta = result.to_dict()
            meta["labels"] = [p.label for p in result.delivered.pieces] if result.delivered else []
            message, candidates, planning_time = result.message, meta["candidates"], result.planning_time
            plans = result.plans
            if plans:
                message += self._keep_set(result, blisk_program_steps(
                    [p.plan_id for p in plans], prepared.blisk.blade_count), meta)
        response.set_id, response.program_id = set_id, program_id
        response.candidates = [candidate_msg(c) for c in candidates]
        response.planning_time = float(planning_time)
        # success only for a set that machines the channel to the tolerance; the closest certified set is
        # still delivered (plan ids, store, topic) with INFEASIBLE and the stock named in the message
        response.success = bool(plans) and bool(meta.get("meets_tolerance"))
        response.error_code = error_code(ErrorCode.SUCCESS if response.success else ErrorCode.INFEASIBLE)
        response.message = message
        if not plans:
            self.get_logger().warning(f"electrode set {set_id}: {message}")
            return
        frame = self.get_parameter("frame_id").value
        labels = meta.get("labels") or [p.electrode_id for p in plans]
        response.plan_ids = [p.plan_id for p in plans]
        response.electrode_labels = list(labels)
        response.metrics = [metrics_to_msg(p.metrics, p.cycle, p.removal) for p in plans]
        fill_process(response, meta)
        if request.write_export:
            root = self.get_parameter("export_dir").value or os.path.join(
                os.path.expanduser("~"), ".local", "share", "edm_planner", "plans")
            path = export_path(root, set_id, "set id")
            cache = self.get_parameter("cache_dir").value or CACHE_ROOT
            if designer is not None:
                write_set(result, path, prepared.blisk, cache_dir=cache)
            else:
                write_stored_set(plans, labels, meta, path, prepared.blisk, cache_dir=cache)
            response.export_path = str(path)
        for plan, metrics in zip(plans, response.metrics):
            self.plan_pub.publish(channel_plan_msg(plan_to_stored(plan), pose_array_msg(plan.poses, frame),
                                                   axis_path_msg(plan.axis_names, plan.samples), metrics))
        self.get_logger().info(f"electrode set {set_id}: {message}")

    def _stored_set(self, set_id):
        """(plans in order, meta) of a stored set, or None."""
        if self.store is None:
            return None
        try:
            seq = self.store.get_sequence(set_id)
            if seq is None:
                return None
            return [stored_to_plan(self.store.get(pid), str(self.store.path)) for pid, _ in seq.steps], seq.meta
        except (PlanStoreError, NotCertifiedError) as exc:
            self.get_logger().error(f"plan store: {exc.message}; designing the set anew")
            return None

    def _keep_set(self, result, program_steps, meta):
        """Keep the set's plans, the set and the whole-blisk program; a note when they could not be kept."""
        if self.store is None:
            return f"; not kept in the plan store: {self.store_error}" if self.store_error else ""
        try:
            for plan in result.plans:
                self.store.put(plan_to_stored(plan))
            self.store.put_sequence(result.set_id, "electrode_set",
                                    [(p.plan_id, p.channel) for p in result.plans], meta)
            self.store.put_sequence(result.program_id, "blisk_program", program_steps,
                                    {"set_id": result.set_id, "message": result.message})
        except PlanStoreError as exc:
            self.get_logger().error(exc.message)
            return f"; not kept in the plan store: {exc.message}"
        return ""

    # -- roughing ---------------------------------------------------------------------------
    def on_roughing(self, request, response):
        return answer(self, "PlanRoughing", self._roughing, request, response)

    def _roughing(self, request, response):
        prepared = self._geometry(request.geometry_id, parsed_only=True)
        gid = prepared.geometry_id
        options = roughing_options(request)
        plan_id = roughing_plan_id(gid, request.channel, options)
        stored, note = self._lookup(plan_id), ""
        if stored is None:
            prepared = self._geometry(gid)
            def progress(stage, fraction, nodes, reference, message):
                self.progress_pub.publish(PlanProgress(
                    request_id=f"{gid[:8]}/{request.channel}/roughing", stage=stage, fraction=float(fraction),
                    nodes=int(nodes), reference=float(reference), message=message))

            # a blisk as measured: the channel's own walls (its channel k is the part's)
            result = plan_roughing(prepared.geometry.for_channel(int(request.channel)).blisk, int(request.channel),
                                   options, progress=progress)
            stored = roughing_to_stored(result, plan_id, gid)
            note = self._keep(stored, plan_id)
        else:
            note = f"; from the plan store (planned {stored.created})"
        fill_roughing_response(response, stored, self.get_parameter("frame_id").value)
        response.message += note
        metrics = PlanMetrics(node_count=len(response.labels), planning_time=response.planning_time,
                              axis_names=list(stored.axis_names),
                              **{f"{name}_{s}": float("nan") for name in CorePlanMetrics.CLEARANCES for s in SURFACES})
        self.plan_pub.publish(channel_plan_msg(stored, pose_array_msg(stored.poses, response.tool_poses.header.frame_id),
                                               response.axis_path, metrics))
        self.get_logger().info(f"roughing plan {plan_id}: {response.message}")

    # -- the plan store ---------------------------------------------------------------------
    def _lookup(self, key):
        """The record stored for a request key, or None (also when the store cannot be read)."""
        if self.store is None:
            return None
        try:
            stored = self.store.find(key)
            if stored is not None:      # never re-serve a record that is not what was certified (or has no digest)
                verify_record(stored, str(self.store.path))
            return stored
        except (PlanStoreError, NotCertifiedError) as exc:
            self.get_logger().error(f"plan store: {exc.message}; planning anew")
            return None

    def _stored(self, key):
        """The stored plan of an equal earlier request, or None."""
        stored = self._lookup(key)
        if stored is None:
            return None
        plan = stored_to_plan(stored, str(self.store.path))
        plan.message = f"from the plan store (planned {stored.created}): {plan.message}"
        return plan

    def _store(self, plan, key):
        """Keep a certified plan; returns a note for the answer when it could not be kept."""
        return self._keep(plan_to_stored(plan), key) if plan.success else ""

    def _keep(self, stored, key):
        if self.store is None:
            return f"; not kept in the plan store: {self.store_error}" if self.store_error else ""
        try:
            self.store.put(stored, key)
        except PlanStoreError as exc:
            self.get_logger().error(exc.message)
            return f"; not kept in the plan store: {exc.message}"
        return ""


def main(args=None):
    """Console entry point ``trajectory_planner``."""
    return spin_node(TrajectoryPlannerNode, args)
