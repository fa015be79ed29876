"""axis_bridge node: times certified plans and sends them to the EDM controller.

Subscribes to the trajectory_planner's latched ``plan`` topic
(edm_planner_msgs/ChannelPlan) and keeps the plans it has seen by id. The
``execute_plan`` service (edm_planner_msgs/ExecutePlan) times a plan on the
configured machine (toppra, ``edm_planner.cnc.timing``) and, unless
``dry_run``, publishes it as ``trajectory_msgs/JointTrajectory``.

Machines of 4 (X, Y, Z, C), 5 (X, Y, Z, A, C) and 6 axes (X, Y, Z, A, C, B):
``config/machine_4axis.yaml``, ``machine.yaml``, ``machine_6axis.yaml``. The
plan's axes must be exactly the machine's (matched by planner axis name; the
trajectory's joints are in the machine file's order).

Cycles and sequences: a plan with a machining cycle (ChannelPlan ``leg_phases``
non-empty, or a plan-store record with a cycle) is sent as its whole cycle
(approach, feed, process, return, retract): each leg timed on its own, rest
to rest, brought to full rest at its ends (velocity and acceleration zero, so
a rest point shared by two legs is one trajectory point), every limit checked
on every leg, and the legs concatenated into ONE JointTrajectory; the
response lists the phases and their start times. A plan without a cycle is
timed and sent as its feed, exactly as before cycles existed. A sequence id
of the plan store (an electrode set, a whole-blisk program) is sent one
electrode at a time: ``electrode`` k of the request selects the k-th run of
consecutive steps with the same plan (the electrode in each of its channels,
index legs turning A at the home point between channels); the trajectory ends
at the home point before the next tool change, which the response names
(``next_electrode``, phase ``tool_change`` at the end). Change the electrode,
then ask for electrode k + 1.

Refusals before anything is timed: NOT_CERTIFIED (the plan's certificate
digest, ChannelPlan ``certificate_sha256`` or the store record's, is missing
or does not match what the bridge holds: altered after certification, in the
store or in transit; ``edm_planner.records.certificate``), INVALID_REQUEST
(the request's channel, ``expected_geometry_id`` or ``expected_reference_pose``
disagrees with the plan), INFEASIBLE (a sample of a leg outside the travel,
named with leg, sample, axis, value and travel).

Error codes: UNKNOWN_ID (plan or sequence never seen), NOT_CERTIFIED (above),
INVALID_REQUEST (channel does not match the plan or the electrode's first
step, geometry or reference pose not the expected one, plan axes not the
machine's, electrode index out of range, a sequence's plan without a cycle, a
four-axis plan in another channel; a plan or sequence id that cannot name an
export file), INFEASIBLE (travel or velocity/acceleration limit violated,
named with axis and time; or the machine's ``/joint_states`` is further from
the plan's start than the tolerance), FILE_ERROR (an export path that is a
symbolic link or cannot be written). Nothing that violates a limit is ever
published.

Units: the trajectory is in the machine config's units, millimetres and
radians (mm/s, mm/s^2 ...), like every message of this project; joint values
are ``direction * planner axis + offset`` per ``config/machine.yaml``.

Parameters
----------
machine_file : str
    Machine YAML ('' : share/edm_planner/config/machine.yaml).
trajectory_topic : str
    Where JointTrajectory goes (default /edm_controller/joint_trajectory).
joint_states_topic : str
    sensor_msgs/JointState of the machine (default /joint_states); '' : no start-state check.
start_tolerance_linear : float
    Largest start-state error of a linear joint [mm].
start_tolerance_rotary : float
    Largest start-state error of a rotary joint [rad].
joint_state_max_age : float
    A JointState older than this is not used for the start check [s].
max_plans : int
    Plans kept (oldest dropped first).
plan_wait : float
    How long a request for an unknown plan id waits for it to arrive on ``plan`` [s]
    (a plan published just before the request may still be on its way).
export_dir : str
    When set, every timed plan (dry runs included: the way to get a program without moving
    the machine) is also written there as ``<plan_id>.nc`` (ISO, G93 inverse time; a cycle's
    phases marked) and ``<plan_id>.csv`` (timed axis samples; a cycle's with phase columns),
    a sequence's electrode k as ``<sequence_id>.e<k>.nc`` / ``.csv``; the response message names
    the files. Plain names only, never written through a symbolic link (``edm_planner.paths``).
reference_tolerance_linear : float
    How far the plan's reference pose may be from a request's ``expected_reference_pose`` [mm].
reference_tolerance_rotary : float
    The largest rotation angle between the two [rad].
plan_store : str
    Directory of the persistent plan store the planner writes ('' : ~/.local/share/edm_planner/plan_store,
    'none' : off). A plan id not seen on ``plan`` is looked up there first, so plans can be executed by id
    after a restart of the bridge or the planner.
"""

import math
import threading
import time
from collections import OrderedDict

import numpy as np
from builtin_interfaces.msg import Duration
from edm_planner_msgs.action import ExecutePlan as ExecutePlanAction
from edm_planner_msgs.msg import ChannelPlan
from edm_planner_msgs.srv import ExecutePlan
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from ..ros.startup import prepare_process

#: this entry point's set-up, before the core's kernel modules load (numba reads its cache directory then) and
#: before rclpy.init (Fast DDS on loopback): :func:`edm_planner.ros.startup.prepare_process`
DDS_SETUP = prepare_process()

from ..errors import EdmError, ErrorCode
from ..geometry.frames import is_rigid, pose_difference, rotation_about_x
from ..cnc.config import LINEAR, load_machine
from ..cnc.nc import trajectory_csv
from ..cnc.post import ProgramRun, write_program
from ..cnc.timing import load_solver
from ..cnc.trajectory import check_samples_travel, plan_trajectory, time_run
from ..machining.program import PlanCycle, program_runs
from ..paths import export_path, open_for_export
from ..records.certificate import certificate_digest, check_digest
from ..records.store import PlanStoreError, plan_cycle_of_stored
from ..ros.conversions import error_code, msg_to_cycle
from ..ros.shared import LATCHED
from ..ros.runtime import answer, declare_plan_store, default_machine_file, end_canceled, spin_node


def duration_msg(seconds):
    """Seconds -> builtin_interfaces/Duration (nanosecond rounding carried into sec)."""
    sec = int(math.floor(seconds))
    nanosec = int(round((seconds - sec) * 1e9))
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return Duration(sec=sec, nanosec=nanosec)


def joint_trajectory_msg(arrays, frame_id=""):
    """JointTrajectoryArrays -> trajectory_msgs/JointTrajectory (positions, velocities, accelerations every point).

    Header stamp zero: the controller starts it on receipt (joint_trajectory_controller convention).
    """
    msg = JointTrajectory()
    msg.header.frame_id = frame_id
    msg.joint_names = list(arrays.joint_names)
    stamps = [duration_msg(t) for t in arrays.times]
    ns = [d.sec * 1_000_000_000 + d.nanosec for d in stamps]
    if any(b <= a for a, b in zip(ns, ns[1:])):
        raise EdmError(ErrorCode.INTERNAL, "time_from_start not strictly increasing at nanosecond resolution")
    msg.points = [JointTrajectoryPoint(positions=p, velocities=v, accelerations=a, time_from_start=d)
                  for p, v, a, d in zip(arrays.positions.tolist(), arrays.velocities.tolist(),
                                        arrays.accelerations.tolist(), stamps)]
    return msg


class _KnownPlan:
    __slots__ = ("plan_id", "channel", "geometry_id", "electrode_id", "axis_names", "samples", "final_pose", "cycle",
                 "certificate", "digest")

    def __init__(self, msg):
        self.cycle = msg_to_cycle(msg)
        self.plan_id = msg.plan_id
        self.channel = int(msg.channel)
        self.geometry_id = msg.geometry_id
        self.electrode_id = msg.electrode_id
        self.axis_names = tuple(msg.axis_path.axis_names)
        self.samples = np.array([p.positions for p in msg.axis_path.points], dtype=np.float64).reshape(
            -1, len(self.axis_names))
        # the certificate digest as published, and that of what arrived (checked before anything is timed)
        self.certificate = msg.certificate_sha256
        self.digest = certificate_digest(msg.plan_id, msg.geometry_id, msg.channel, msg.electrode_id, msg.method,
                                         self.axis_names, self.samples, np.array(msg.reference_pose).reshape(4, 4),
                                         self.cycle)
        # the message's final pose is in the plan's channel; the kinematics want channel 0's,
        # which A's last value (channel * pitch in the planner's convention) turns back to
        final = np.array(msg.final_pose, dtype=np.float64).reshape(4, 4)
        reference = np.array(msg.reference_pose, dtype=np.float64).reshape(4, 4)
        if reference.any():                 # the publisher says what the axis values are measured from
            final = reference
        elif "A" in self.axis_names and len(self.samples):
            final = rotation_about_x(-self.samples[-1, self.axis_names.index("A")]) @ final
        elif len(self.samples) and len(msg.poses.poses) == len(self.samples):
            # no A (4 axes): X, Y, Z, C are channel 0's and the blisk is indexed to the channel outside the
            # path, so the poses are those of channel 0 turned about X by the index angle
            final = rotation_about_x(-index_angle(self.samples[:, :3], msg.poses.poses)) @ final
        self.final_pose = final

    def check_certified(self):
        """NOT_CERTIFIED unless what arrived on ``plan`` is what was certified (digest recomputed on receipt)."""
        check_digest(self.plan_id, self.certificate, self.digest, "the 'plan' topic")

    def as_plan_cycle(self):
        self.check_certified()
        return PlanCycle(self.plan_id, self.geometry_id, self.electrode_id, self.channel, self.axis_names,
                         self.final_pose, self.samples, self.cycle)


def index_angle(xyz, poses):
    """Angle about X turning a 4-axis plan's channel-0 X, Y, Z into its published positions [rad].

    The positions are ``R_x(angle) (XYZ + t_final)``: least squares over the centred samples.
    """
    p = np.array([[q.position.x, q.position.y, q.position.z] for q in poses])
    u, v = xyz - xyz.mean(axis=0), p - p.mean(axis=0)
    return float(np.arctan2(np.sum(u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]),
                            np.sum(u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2])))


class AxisBridgeNode(Node):
    """Serves ExecutePlan for every plan seen on ``plan``."""

    def __init__(self, **kwargs):
        super().__init__("axis_bridge", **kwargs)
        self.declare_parameter("machine_file", "")
        self.declare_parameter("trajectory_topic", "/edm_controller/joint_trajectory")
        self.declare_parameter("joint_states_topic", "/joint_states")
        self.declare_parameter("start_tolerance_linear", 0.05)
        self.declare_parameter("start_tolerance_rotary", 0.001)
        self.declare_parameter("joint_state_max_age", 5.0)
        self.declare_parameter("max_plans", 50)
        self.declare_parameter("plan_wait", 10.0)
        self.declare_parameter("export_dir", "")
        self.declare_parameter("reference_tolerance_linear", 0.001)
        self.declare_parameter("reference_tolerance_rotary", 1e-6)
        self.store, self.store_error = declare_plan_store(self)
        path = self.get_parameter("machine_file").value or default_machine_file()
        self.machine = load_machine(path)   # a bad machine file stops the node at start, with the key named
        self.get_logger().info(f"machine {self.machine.name!r} from {path}: joints "
                               f"{[a.joint for a in self.machine.axes.values()]}")
        self.plans = OrderedDict()
        self._joint_state = None            # (monotonic receipt time, {name: position})
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)     # notified when a plan is stored
        self.create_subscription(ChannelPlan, "plan", self.on_plan, LATCHED,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        topic = self.get_parameter("joint_states_topic").value
        if topic:
            self.create_subscription(JointState, topic, self.on_joint_state, 10,
                                     callback_group=MutuallyExclusiveCallbackGroup())
        self.trajectory_pub = self.create_publisher(JointTrajectory,
                                                    self.get_parameter("trajectory_topic").value, 10)
        self.service = self.create_service(ExecutePlan, "execute_plan", self.on_execute,
                                           callback_group=MutuallyExclusiveCallbackGroup())
        # the same as an action that follows the trajectory (feedback, cancel = stop); one followed at a time
        self._following = None              # threading.Event of the goal being followed (set: cancel)
        self._follow_lock = threading.Lock()
        self.action = ActionServer(self, ExecutePlanAction, "execute_plan", self.execute_goal,
                                   goal_callback=self.on_goal, cancel_callback=self.on_cancel,
                                   callback_group=ReentrantCallbackGroup())
        # every ExecutePlan times its trajectory with toppra (0.8 s to import, matplotlib with it): imported
        # while the node waits for its first request, not in it (a request meanwhile waits for the import)
        self.solver_loaded = threading.Event()
        threading.Thread(target=self._load_solver, name="load_solver", daemon=True).start()

    def _load_solver(self):
        try:
            load_solver()
        except Exception as exc:  # reported again, with its code, by the first request that times
            self.get_logger().error(f"the timing solver (toppra) did not load: {exc!r}")
        finally:
            self.solver_loaded.set()

    def on_plan(self, msg):
        try:
            plan = _KnownPlan(msg)
        except Exception as exc:  # a malformed message must not stop the bridge; ExecutePlan will not know it
            self.get_logger().error(f"plan {msg.plan_id!r} on 'plan' not taken: {exc}")
            return
        with self._arrived:
            self.plans[plan.plan_id] = plan
            self.plans.move_to_end(plan.plan_id)
            while len(self.plans) > int(self.get_parameter("max_plans").value):
                self.plans.popitem(last=False)
            self._arrived.notify_all()
        self.get_logger().info(f"plan {plan.plan_id}: channel {plan.channel}, {len(plan.samples)} samples")

    def on_joint_state(self, msg):
        with self._lock:
            self._joint_state = (time.monotonic(), dict(zip(msg.name, msg.position)))

    def on_execute(self, request, response):
        return answer(self, "ExecutePlan", self._execute, request, response)

    def on_goal(self, goal):
        """Accept an ExecutePlan goal unless another goal's trajectory is being followed."""
        with self._follow_lock:
            if self._following is not None:
                self.get_logger().warning(f"ExecutePlan goal ({goal.plan_id}) rejected: another goal's trajectory "
                                          f"is being followed (cancel it first)")
                return GoalResponse.REJECT
            self._following = threading.Event()
        return GoalResponse.ACCEPT

    def on_cancel(self, goal_handle):
        stop = self._following
        if stop is not None:
            stop.set()
        return CancelResponse.ACCEPT

    def execute_goal(self, goal_handle):
        """The action's body: ``_execute`` (the service's), then, with ``follow``, the trajectory followed by the
        clock (feedback about every 0.5 s); cancel while following publishes the stop trajectory."""
        goal, stop = goal_handle.request, self._following
        result = ExecutePlanAction.Result()
        sent = {}

        def fill(g, r):
            sent["arrays"], sent["start"] = self._execute(g, r)

        try:
            answer(self, "ExecutePlan", fill, goal, result)
            if not result.success:
                goal_handle.abort()
                return result
            start = sent.get("start")
            if start is None or not goal.follow:            # dry run, or not asked to follow
                goal_handle.succeed()
                return result
            return self._follow(goal_handle, result, sent["arrays"], start, stop)
        finally:
            with self._follow_lock:
                self._following = None

    def _follow(self, goal_handle, result, arrays, start, stop, period=0.5):
        """Feedback along a published trajectory until its duration has passed, or stop it on cancel."""
        duration = float(arrays.duration)
        times = [float(m.time) for m in arrays.phases]
        while True:
            executed = time.monotonic() - start
            if stop.is_set() or goal_handle.is_cancel_requested:
                self.trajectory_pub.publish(JointTrajectory(joint_names=list(arrays.joint_names)))
                result.message += (f"; CANCELED at {executed:.2f} s of {duration:.2f} s: stop sent on "
                                   f"{self.trajectory_pub.topic_name} (an empty JointTrajectory)")
                self.get_logger().info(result.message)
                end_canceled(goal_handle)
                return result
            k = max(0, int(np.searchsorted(times, min(executed, duration), side="right")) - 1)
            mark = arrays.phases[k] if arrays.phases else None
            goal_handle.publish_feedback(ExecutePlanAction.Feedback(
                executed_time=float(min(executed, duration)), duration=duration,
                phase=mark.phase if mark else "feed", channel=int(mark.channel) if mark else 0,
                regime=mark.regime if mark else "",
                fraction=float(min(executed / duration, 1.0)) if duration > 0 else 1.0,
                message=f"{min(executed, duration):.1f} of {duration:.1f} s"))
            if executed >= duration:
                break
            stop.wait(min(period, duration - executed))
        result.message += f"; followed for {duration:.2f} s (by the bridge's clock)"
        goal_handle.succeed()
        return result

    def _execute(self, request, response):
        """ExecutePlan, for the service and the action (a Request or a Goal; a Response or a Result).

        Returns
        -------
        (JointTrajectoryArrays, float or None)
            What was timed, and when it was published (``time.monotonic()``; None for a dry run).
        """
        # a plan published just before the request may still be on its way (or being read): wait a little
        with self._lock:
            plan = self.plans.get(request.plan_id)
        store_note, sequence = "", None
        if plan is None:       # made before this bridge started? the plan store has every certified plan
            plan, store_note = self._from_store(request.plan_id)
        if plan is None and not store_note:       # not a plan: a sequence of the store?
            sequence, store_note = self._sequence_from_store(request.plan_id)
        if plan is None and sequence is None:     # published just before the request: may still be on its way
            with self._arrived:
                self._arrived.wait_for(lambda: request.plan_id in self.plans,
                                       timeout=float(self.get_parameter("plan_wait").value))
                plan = self.plans.get(request.plan_id)
        if plan is None and sequence is None:
            raise EdmError(ErrorCode.UNKNOWN_ID, f"unknown plan id {request.plan_id!r}: neither a plan nor a "
                                                 f"sequence in the plan store{store_note} and not seen on 'plan' "
                                                 f"(latest {list(self.plans)[-5:]})")
        response.electrode_count = 1
        if sequence is not None:
            arrays, what, export_name = self._sequence_trajectory(sequence, request, response)
        else:
            # the refusals, all before anything is timed: not what was certified, not what the request names,
            # not what the cell expects, outside the machine's travel
            if not isinstance(plan, PlanCycle):         # from the topic (a store record was verified on reading)
                plan.check_certified()
            if int(request.channel) != plan.channel:
                raise EdmError(ErrorCode.INVALID_REQUEST, f"plan {plan.plan_id} is for channel {plan.channel}, "
                                                          f"the request names channel {request.channel}")
            if int(request.electrode):
                raise EdmError(ErrorCode.INVALID_REQUEST, f"{plan.plan_id} is a plan (one electrode), not a "
                                                          f"sequence: electrode must be 0, got {request.electrode}")
            self._check_expected(request, f"plan {plan.plan_id}", plan.geometry_id, plan.final_pose)
            what, export_name = f"plan {plan.plan_id} channel {plan.channel}", plan.plan_id
            if plan.cycle is None:
                check_samples_travel(plan.samples, plan.axis_names, self.machine, plan.final_pose,
                                     f"plan {plan.plan_id} (feed)")
                arrays = plan_trajectory(plan.samples, plan.axis_names, self.machine, final_pose=plan.final_pose)
            else:
                pc = plan if isinstance(plan, PlanCycle) else plan.as_plan_cycle()
                legs = program_runs([(pc.plan_id, pc.channel)], {pc.plan_id: pc})[0].legs
                self._check_legs_travel(legs)
                arrays = time_run(legs, self.machine)
                what += f" whole cycle ({len(plan.cycle.legs)} legs)"
        self._check_start_state(arrays)
        _fill_phases(response, arrays)
        if sequence is not None and response.next_electrode:
            response.phase_names.append("tool_change")
            response.phase_start_times.append(float(arrays.duration))
            response.phase_channels.append(int(response.phase_channels[-1]))
        timed = arrays.timed
        response.duration = float(arrays.duration)
        response.point_count = len(arrays.times)
        response.axis_names = list(arrays.axis_names)         # the machine's joint order, as the peaks
        response.peak_velocity = [float(v) for v in timed.peak_velocity]
        response.peak_acceleration = [float(v) for v in timed.peak_acceleration]
        dev = timed.deviation_between_samples
        linear = np.array([a in LINEAR for a in arrays.axis_names])
        summary = (f"{what}: {response.point_count} points, "
                   f"{response.duration:.3f} s (uniform time stretch {timed.time_scale:.4f} to meet the "
                   f"velocity, acceleration and jerk limits), "
                   f"deviation from the certified chords <= {dev[linear].max() * 1e3:.3f} um "
                   f"/ {dev[~linear].max() if (~linear).any() else 0.0:.2e} rad")
        export_dir = self.get_parameter("export_dir").value
        if export_dir:
            summary += "; " + self._export(export_name, arrays, export_dir, sequence or plan)
        if response.next_electrode:
            summary += f"; then change the electrode: next {response.next_electrode} (electrode {request.electrode + 1})"
        started = None
        if not request.dry_run:
            self.trajectory_pub.publish(joint_trajectory_msg(arrays))
            started = time.monotonic()
            summary += f"; sent on {self.trajectory_pub.topic_name} as joints {arrays.joint_names}"
        else:
            summary += "; dry run, nothing sent"
        response.success = True
        response.error_code = error_code(ErrorCode.SUCCESS)
        response.message = summary
        self.get_logger().info(summary)
        return arrays, started

    def _from_store(self, plan_id):
        """(plan, '') from the plan store (a PlanCycle, with the record's cycle), or (None, why not) ."""
        if self.store is None:
            return None, f" ({self.store_error})" if self.store_error else " (no plan store configured)"
        try:
            stored = self.store.get(plan_id)
        except PlanStoreError as exc:
            self.get_logger().error(exc.message)
            return None, f" ({exc.message})"
        if stored is None:
            return None, ""
        self.get_logger().info(f"plan {plan_id} read from the plan store {self.store.path}")
        return plan_cycle_of_stored(stored, f"the plan store {self.store.path}"), ""   # NOT_CERTIFIED if altered

    def _sequence_from_store(self, sequence_id):
        """(StoredSequence, '') or (None, why not)."""
        if self.store is None:
            return None, ""
        try:
            return self.store.get_sequence(sequence_id), ""
        except PlanStoreError as exc:
            self.get_logger().error(exc.message)
            return None, f" ({exc.message})"

    def _plan_of_sequence(self, plan_id, sequence_id):
        # the store's record first: it keeps the whole cycle, wear compensation included, which a ChannelPlan
        # message does not carry (a program from the message would run every channel uncompensated)
        plan, note = self._from_store(plan_id)
        if plan is not None:
            return plan
        with self._lock:
            known = self.plans.get(plan_id)
        if known is not None and known.cycle is not None:
            return known.as_plan_cycle()
        raise EdmError(ErrorCode.UNKNOWN_ID, f"sequence {sequence_id}: its plan {plan_id} is not in the plan "
                                             f"store{note}")

    def _sequence_trajectory(self, sequence, request, response):
        """The trajectory of electrode ``request.electrode`` of a sequence; (arrays, summary head, export name)."""
        plans = {p: self._plan_of_sequence(p, sequence.sequence_id) for p in sequence.plan_ids}
        blade_count = sequence.meta.get("blade_count")
        pitch = 2 * math.pi / int(blade_count) if blade_count else None
        runs = program_runs(sequence.steps, plans, pitch)
        k = int(request.electrode)
        if k >= len(runs):
            raise EdmError(ErrorCode.INVALID_REQUEST, f"{sequence.kind} {sequence.sequence_id} has {len(runs)} "
                                                      f"electrode(s) (0 .. {len(runs) - 1}); electrode {k} asked for")
        run = runs[k]
        if int(request.channel) != run.channels[0]:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"electrode {k} ({run.label}) of {sequence.kind} "
                                                      f"{sequence.sequence_id} starts in channel {run.channels[0]}, "
                                                      f"the request names channel {request.channel}")
        self._check_expected(request, f"{sequence.kind} {sequence.sequence_id} electrode {k} (plan "
                                      f"{run.plan.plan_id})", sequence.geometry_id, run.plan.final_pose)
        self._check_legs_travel(run.legs)
        arrays = time_run(run.legs, self.machine)
        response.electrode_count = len(runs)
        if k + 1 < len(runs):
            nxt = runs[k + 1]
            response.next_electrode = f"{nxt.label} (plan {nxt.plan.plan_id})"
        channels = run.channels
        span = f"channels {channels[0]}..{channels[-1]}" if len(channels) > 1 else f"channel {channels[0]}"
        what = (f"{sequence.kind} {sequence.sequence_id} electrode {k + 1} of {len(runs)} ({run.label}, plan "
                f"{run.plan.plan_id}, {span})")
        return arrays, what, f"{sequence.sequence_id}.e{k}"

    def _export(self, name, arrays, directory, source):
        # the name is a plan or sequence id, which a message or the store chose: a plain name inside the
        # directory, never written through a symbolic link
        base = str(export_path(directory, name, "plan or sequence id", (".nc", ".csv")))
        if hasattr(source, "steps"):                   # one electrode of a sequence
            marks = arrays.phases or []
            run = ProgramRun(arrays, marks[0].electrode_id if marks else "", marks[0].plan_id if marks else name)
            kind = source.kind
        else:
            run, kind = ProgramRun(arrays, source.electrode_id, source.plan_id), "plan"
        # the machine's dialect and structure; the final check refuses a program breaking them (INTERNAL)
        text, _ = write_program([run], name, source.geometry_id, kind, self.machine)
        try:
            with open_for_export(base + ".nc") as f:
                f.write(text)
            with open_for_export(base + ".csv") as f:
                f.write(trajectory_csv(arrays))
        except OSError as exc:
            raise EdmError(ErrorCode.FILE_ERROR, f"cannot write the NC/CSV export to {directory}: {exc}") from None
        return f"written {base}.nc and {base}.csv"

    def _check_legs_travel(self, legs):
        """Every sample of every leg inside the machine's travel, before any timing (INFEASIBLE naming the leg)."""
        for i, leg in enumerate(legs):
            check_samples_travel(leg.samples, leg.plan.axis_names, self.machine, leg.plan.final_pose,
                                 f"plan {leg.plan.plan_id} channel {leg.channel} leg {i} ({leg.phase}: {leg.label})")

    def _check_expected(self, request, what, geometry_id, reference_pose):
        """INVALID_REQUEST when the plan is not for the geometry or reference pose the request expects."""
        expected = request.expected_geometry_id
        if expected and expected != geometry_id:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"{what} is for geometry {geometry_id}, the request expects "
                                                      f"geometry {expected}: nothing sent")
        values = np.asarray(request.expected_reference_pose, dtype=np.float64)
        if not values.size:
            return
        if values.size != 16 or not np.isfinite(values).all():
            raise EdmError(ErrorCode.INVALID_REQUEST, f"expected_reference_pose must be empty or 16 finite values "
                                                      f"(4x4 row-major, mm), got {values.size}")
        want, have = values.reshape(4, 4), np.asarray(reference_pose, dtype=np.float64)
        if not is_rigid(want):
            raise EdmError(ErrorCode.INVALID_REQUEST, "expected_reference_pose is not a rigid transform (rotation "
                                                      "orthonormal to 1e-6, last row 0 0 0 1)")
        linear, angle = pose_difference(have, want)
        tol_linear = float(self.get_parameter("reference_tolerance_linear").value)
        tol_rotary = float(self.get_parameter("reference_tolerance_rotary").value)
        if not (linear <= tol_linear and angle <= tol_rotary):
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"{what}: its reference pose (what the axis values are measured from) differs from the "
                           f"one the request expects by {linear:.6g} mm and {angle:.6g} rad (tolerances "
                           f"{tol_linear:g} mm, {tol_rotary:g} rad; expected translation "
                           f"{np.round(want[:3, 3], 6).tolist()} mm, the plan's {np.round(have[:3, 3], 6).tolist()} mm): "
                           f"nothing sent")

    def _check_start_state(self, arrays):
        with self._lock:
            state = self._joint_state
        if state is None or time.monotonic() - state[0] > float(self.get_parameter("joint_state_max_age").value):
            return                          # no live joint states: nothing to check against
        received, positions = state
        for j, (joint, axis) in enumerate(zip(arrays.joint_names, arrays.axis_names)):
            if joint not in positions:
                raise EdmError(ErrorCode.INVALID_REQUEST, f"joint {joint} (axis {axis}) is not in the machine's "
                                                          f"joint states {sorted(positions)}")
            linear = axis in LINEAR
            tol = float(self.get_parameter("start_tolerance_linear" if linear else "start_tolerance_rotary").value)
            error = abs(positions[joint] - arrays.positions[0, j])
            if not error <= tol:
                unit = "mm" if linear else "rad"
                raise EdmError(ErrorCode.INFEASIBLE,
                               f"start state: joint {joint} (axis {axis}) is at {positions[joint]:.6g} {unit}, the "
                               f"plan starts at {arrays.positions[0, j]:.6g} {unit} (tolerance {tol:g} {unit}); "
                               f"move the machine to the plan's start first")


def _fill_phases(response, arrays):
    """Phase names, start times and channels of a timed cycle (consecutive legs of one phase merged)."""
    for mark in arrays.phases:
        if response.phase_names and response.phase_names[-1] == mark.phase and \
                response.phase_channels[-1] == mark.channel:
            continue
        response.phase_names.append(mark.phase)
        response.phase_start_times.append(float(mark.time))
        response.phase_channels.append(int(mark.channel))
    fill_regimes(response, arrays)


def fill_regimes(response, arrays):
    """The generator's regime along a timed trajectory (one entry per change), its eroding time and volume."""
    marks = arrays.phases
    for mark in marks:
        if response.regime_names and response.regime_names[-1] == mark.regime:
            continue
        response.regime_names.append(mark.regime)
        response.regime_start_times.append(float(mark.time))
        response.regime_condition_codes.append(mark.condition_code)
    ends = [m.time for m in marks[1:]] + [arrays.duration]
    response.eroding_time = float(sum(e - m.time for m, e in zip(marks, ends) if m.generator_on))
    volumes = [m.removed_volume for m in marks if np.isfinite(m.removed_volume)]
    response.removed_volume = float(sum(volumes)) if volumes else float("nan")




def main(args=None):
    """Console entry point ``axis_bridge``."""
    return spin_node(AxisBridgeNode, args)
