"""axis_bridge over real DDS: a real plan from a real trajectory_planner, timed and sent as JointTrajectory."""

import math
import threading
import time

import numpy as np
import pytest
from edm_planner_msgs.msg import BliskGeometry, ChannelPlan, ErrorCode, PlannerSettings
from edm_planner_msgs.srv import ExecutePlan, PlanChannel
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from edm_planner.geometry.frames import rotation_about_x
from edm_planner.cnc.config import default_machine_path, load_machine
from edm_planner.cnc.kinematics import FiveAxisKinematics
from edm_planner.nodes.axis_bridge import AxisBridgeNode
from edm_planner.ros.conversions import pose_to_matrix
from edm_planner.nodes.geometry_loader import GeometryLoaderNode
from edm_planner.ros.shared import LATCHED
from edm_planner.nodes.trajectory_planner import TrajectoryPlannerNode

from test_timing import quintic_peaks
from test_trajectory_planner_node import rear_design

pytestmark = pytest.mark.slow          # nodes over DDS that plan, or the whole product: not in make test-fast

PITCH = 2 * np.pi / 60
TOPIC = "/edm_controller/joint_trajectory"
JOINTS = ["edm_x", "edm_y", "edm_z", "edm_a", "edm_c"]
SIX_AXIS = default_machine_path().parent / "machine_6axis.yaml"


class Inbox:
    """Messages of one topic, with waiting."""

    def __init__(self):
        self.items, self.cond = [], threading.Condition()

    def __call__(self, msg):
        with self.cond:
            self.items.append(msg)
            self.cond.notify_all()

    def wait(self, count, timeout):
        with self.cond:
            return self.cond.wait_for(lambda: len(self.items) >= count, timeout)


@pytest.fixture(scope="module")
def system(tmp_path_factory, field_cache):
    from ros_harness import InProcessRos

    ros = InProcessRos()
    machine_text = default_machine_path().read_text()
    tight = tmp_path_factory.mktemp("machine") / "tight.yaml"
    tight.write_text(machine_text.replace("min_mm: -250.0\n    max_mm: 250.0", "min_mm: -250.0\n    max_mm: 15.0"))
    ros.add(GeometryLoaderNode(context=ros.context))
    ros.add(TrajectoryPlannerNode(context=ros.context, parameter_overrides=[Parameter("cache_dir", value=field_cache)]))
    exports = tmp_path_factory.mktemp("nc")
    ros.add(AxisBridgeNode(context=ros.context, parameter_overrides=[
        Parameter("joint_states_topic", value="/test_joint_states"), Parameter("export_dir", value=str(exports)),
        Parameter("plan_wait", value=1.0)]))
    # the same bridge on a machine whose X travel ends at 15 mm, serving under another name
    ros.add(AxisBridgeNode(context=ros.context, cli_args=["--ros-args", "-r", "execute_plan:=tight/execute_plan",
                                                          "-r", "__node:=axis_bridge_tight"],
                           parameter_overrides=[Parameter("machine_file", value=str(tight)),
                                                Parameter("trajectory_topic", value="/tight/joint_trajectory")]))
    # and on a machine with channel 0 at A = 0.5 rad and the C axis 4.5 mm off the electrode origin
    pivot = tmp_path_factory.mktemp("machine") / "pivot.yaml"
    pivot.write_text(machine_text.replace("a_zero_rad: 0.0", "a_zero_rad: 0.5").replace(
        "c_pivot_mm: [0.0, 0.0, 0.0]", "c_pivot_mm: [4.0, -2.0, 30.0]"))
    ros.add(AxisBridgeNode(context=ros.context, cli_args=["--ros-args", "-r", "execute_plan:=pivot/execute_plan",
                                                          "-r", "__node:=axis_bridge_pivot"],
                           parameter_overrides=[Parameter("machine_file", value=str(pivot)),
                                                Parameter("trajectory_topic", value="/pivot/joint_trajectory")]))
    # and on the six-axis machine of config/machine_6axis.yaml
    ros.add(AxisBridgeNode(context=ros.context, cli_args=["--ros-args", "-r", "execute_plan:=six/execute_plan",
                                                          "-r", "__node:=axis_bridge_six"],
                           parameter_overrides=[Parameter("machine_file", value=str(SIX_AXIS)),
                                                Parameter("joint_states_topic", value=""),
                                                Parameter("trajectory_topic", value="/six/joint_trajectory")]))
    client = ros.add(Node("bridge_client", context=ros.context))
    trajectories, tight_trajectories, pivot_trajectories, plans = Inbox(), Inbox(), Inbox(), Inbox()
    six_trajectories = Inbox()
    client.create_subscription(JointTrajectory, "/six/joint_trajectory", six_trajectories, 10)
    geometry = threading.Event()
    client.create_subscription(BliskGeometry, "geometry", lambda m: geometry.set(), LATCHED)
    client.create_subscription(JointTrajectory, TOPIC, trajectories, 10)
    client.create_subscription(JointTrajectory, "/tight/joint_trajectory", tight_trajectories, 10)
    client.create_subscription(JointTrajectory, "/pivot/joint_trajectory", pivot_trajectories, 10)
    client.create_subscription(ChannelPlan, "plan", plans, LATCHED)
    joint_states = client.create_publisher(JointState, "/test_joint_states", 10)
    assert geometry.wait(60)
    res = ros.call(client, PlanChannel, "plan_channel",
                   PlanChannel.Request(channel=3, electrode_id="rear", electrode=rear_design()), timeout=300)
    assert res.success, res.message
    assert plans.wait(1, 10)
    samples = np.array([p.positions for p in res.axis_path.points])
    yield dict(ros=ros, client=client, plan=res, samples=samples, exports=exports, plans=plans, trajectories=trajectories,
               tight_trajectories=tight_trajectories, pivot_trajectories=pivot_trajectories,
               six_trajectories=six_trajectories,
               joint_states=joint_states)
    ros.close()


def execute(system, service="execute_plan", **fields):
    req = ExecutePlan.Request(plan_id=fields.pop("plan_id", system["plan"].plan_id), channel=fields.pop("channel", 3),
                              **fields)
    deadline = time.monotonic() + 10
    while True:   # the bridge may not have taken the latched plan yet
        res = system["ros"].call(system["client"], ExecutePlan, service, req, timeout=60)
        if res.error_code.val != ErrorCode.UNKNOWN_ID or req.plan_id != system["plan"].plan_id \
                or time.monotonic() > deadline:
            return res
        time.sleep(0.2)


def seconds(d):
    return d.sec + d.nanosec * 1e-9


def test_dry_run_times_and_sends_nothing(system):
    m = load_machine(default_machine_path())
    res = execute(system, dry_run=True)
    assert res.success, res.message
    assert res.error_code.val == ErrorCode.SUCCESS and "dry run" in res.message
    assert res.point_count == len(system["samples"]) > 1000
    assert list(res.axis_names) == ["X", "Y", "Z", "A", "C"]
    lim = m.limits_for(res.axis_names)
    v = np.array(res.peak_velocity) / [a.velocity_max for a in lim]
    a = np.array(res.peak_acceleration) / [a.acceleration_max for a in lim]
    assert np.all(v <= 1 + 1e-6) and np.all(a <= 1 + 1e-6) and max(v.max(), a.max()) > 0.1
    assert 2.0 < res.duration < 60.0
    time.sleep(1.0)
    assert not system["trajectories"].items


def test_execute_publishes_the_joint_trajectory(system):
    inbox = system["trajectories"]
    res = execute(system)
    assert res.success, res.message
    assert inbox.wait(1, 10), "no JointTrajectory received"
    msg = inbox.items[-1]
    m = load_machine(default_machine_path())
    lim = m.limits_for(("X", "Y", "Z", "A", "C"))
    assert list(msg.joint_names) == JOINTS
    assert len(msg.points) == res.point_count == len(system["samples"])
    t = np.array([seconds(p.time_from_start) for p in msg.points])
    p = np.array([pt.positions for pt in msg.points])
    v = np.array([pt.velocities for pt in msg.points])
    a = np.array([pt.accelerations for pt in msg.points])
    assert p.shape == v.shape == a.shape == (len(t), 5)
    assert t[0] == 0.0 and np.all(np.diff(t) > 0) and t[-1] == pytest.approx(res.duration, abs=1e-9)
    # the certified samples, start pose first, machining pose of channel 3 last, at rest at both ends
    np.testing.assert_allclose(p, system["samples"], atol=1e-9)
    np.testing.assert_allclose(p[-1], [0, 0, 0, 3 * PITCH, 0], atol=1e-9)
    assert p[0, 0] > 10.0
    np.testing.assert_array_equal(v[[0, -1]], 0.0)
    vmax = np.array([x.velocity_max for x in lim])
    amax = np.array([x.acceleration_max for x in lim])
    assert np.all(np.abs(v) <= vmax * (1 + 1e-6)) and np.all(np.abs(a) <= amax * (1 + 1e-6))
    np.testing.assert_allclose(np.abs(v).max(axis=0), res.peak_velocity, rtol=1e-3, atol=1e-9)
    # and between the points, as the controller interpolates quintics through (p, v, a)
    qv, qa, qj = quintic_peaks(t, p, v, a)
    jmax = np.array([x.jerk_max for x in lim])
    assert np.all(qv <= vmax * (1 + 1e-6)) and np.all(qa <= amax * (1 + 1e-6)) and np.all(qj <= jmax * (1 + 1e-6))
    # consistent with finite differences of the positions (see test_timing for the bounds)
    span = (t[2:] - t[:-2])[:, None]
    assert np.all(np.abs((p[2:] - p[:-2]) / span - v[1:-1]) <= 0.5 * amax * span)
    err = np.abs((v[2:] - v[:-2]) / span - a[1:-1]) / amax
    assert np.all(err < 0.5) and np.all(np.median(err, axis=0) < 1e-3)


def test_nc_and_csv_export_match_the_published_trajectory(system):
    from types import SimpleNamespace

    from edm_planner.cnc.post import check_program, parse_nc

    inbox = system["trajectories"]
    count = len(inbox.items)
    res = execute(system)
    assert res.success, res.message
    plan_id = system["plan"].plan_id
    nc, csv = system["exports"] / f"{plan_id}.nc", system["exports"] / f"{plan_id}.csv"
    assert str(nc) in res.message and nc.exists() and csv.exists()
    assert inbox.wait(count + 1, 10)
    msg = inbox.items[-1]
    back = parse_nc(nc.read_text())
    assert back["plan_id"] == plan_id and back["axis_names"] == ("X", "Y", "Z", "A", "C")
    assert back["geometry_id"] == system["plans"].items[-1].geometry_id and len(back["geometry_id"]) == 64
    p = np.array([pt.positions for pt in msg.points])
    t = np.array([seconds(pt.time_from_start) for pt in msg.points])
    # every NC point a published point (0.1 um, 1e-4 deg), every one left out within 1 um of its block
    check_program(nc.read_text(), "iso_fanuc", [SimpleNamespace(positions=p)])
    assert back["times"][-1] == pytest.approx(t[-1], rel=1e-5)
    table = np.loadtxt(csv, delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 1::3], p, atol=1e-12)


def test_bad_requests(system):
    res = execute(system, plan_id="no-such-plan", dry_run=True)
    assert not res.success and res.error_code.val == ErrorCode.UNKNOWN_ID and "no-such-plan" in res.message
    res = execute(system, channel=4, dry_run=True)
    assert not res.success and res.error_code.val == ErrorCode.INVALID_REQUEST
    assert "channel 3" in res.message and "channel 4" in res.message


def test_travel_violation_is_rejected_and_nothing_sent(system):
    res = execute(system, service="tight/execute_plan")
    assert not res.success and res.error_code.val == ErrorCode.INFEASIBLE
    assert "axis X (joint edm_x)" in res.message and "[-250, 15] mm" in res.message
    # the plan starts at X > 15 mm outside the blisk: rejected at its first sample, before any timing
    assert "sample 0 of" in res.message and "before timing" in res.message
    time.sleep(1.0)
    assert not system["tight_trajectories"].items


def test_machine_a_zero_and_c_pivot_keep_the_published_poses(system):
    res = execute(system, service="pivot/execute_plan")
    assert res.success, res.message
    assert system["pivot_trajectories"].wait(1, 10)
    msg = system["pivot_trajectories"].items[-1]
    q = np.array([pt.positions for pt in msg.points])
    plan = system["plan"]
    poses = np.array([pose_to_matrix(p) for p in plan.poses.poses])
    final0 = pose_to_matrix(plan.poses.poses[-1])
    kin = FiveAxisKinematics(rotation_about_x(-3 * PITCH) @ final0, PITCH, c_pivot=(4.0, -2.0, 30.0), a_zero=0.5)
    # the sent joints reach the planner's published electrode poses (to the poses' message precision)
    np.testing.assert_allclose(kin.forward(q), poses, atol=1e-6)
    assert abs(q[-1, 3] - (0.5 + 3 * PITCH)) < 1e-9
    assert np.abs(q[:, :3] - system["samples"][:, :3]).max() > 2.0


def test_six_axis_machine_executes_a_six_axis_plan(system):
    """machine_file = config/machine_6axis.yaml: a 6-axis plan is sent as six joints; a 5-axis plan is refused."""
    from edm_planner.cnc.kinematics import axis_poses

    res = execute(system, service="six/execute_plan", dry_run=True)       # the 5-axis plan: B left undefined
    assert not res.success and res.error_code.val == ErrorCode.INVALID_REQUEST
    assert "machine axes ['B'] not in the plan" in res.message and "edm6_reference" in res.message
    ros, client = system["ros"], system["client"]
    count = len(system["plans"].items)
    plan = ros.call(client, PlanChannel, "plan_channel",
                    PlanChannel.Request(channel=3, electrode_id="rear", electrode=rear_design(),
                                        settings=PlannerSettings(axes=6)), timeout=300)
    assert plan.success, plan.message
    assert list(plan.axis_path.axis_names) == ["X", "Y", "Z", "A", "C", "B"]
    assert system["plans"].wait(count + 1, 10)
    res = execute(system, service="six/execute_plan", plan_id=plan.plan_id)
    assert res.success, res.message
    assert list(res.axis_names) == ["X", "Y", "Z", "A", "C", "B"]
    assert system["six_trajectories"].wait(1, 10)
    msg = system["six_trajectories"].items[-1]
    assert list(msg.joint_names) == ["edm_x", "edm_y", "edm_z", "edm_a", "edm_c", "edm_b"]
    samples = np.array([p.positions for p in plan.axis_path.points])
    t = np.array([seconds(p.time_from_start) for p in msg.points])
    p = np.array([pt.positions for pt in msg.points])
    v = np.array([pt.velocities for pt in msg.points])
    a = np.array([pt.accelerations for pt in msg.points])
    assert p.shape == v.shape == a.shape == (len(samples), 6) and res.point_count == len(samples)
    assert t[0] == 0.0 and np.all(np.diff(t) > 0) and t[-1] == pytest.approx(res.duration, abs=1e-9)
    np.testing.assert_allclose(p, samples, atol=1e-9)
    np.testing.assert_allclose(p[-1], [0, 0, 0, 3 * PITCH, 0, 0], atol=1e-9)
    np.testing.assert_array_equal(v[[0, -1]], 0.0)
    lim = load_machine(SIX_AXIS).limits_for(("X", "Y", "Z", "A", "C", "B"))
    vmax, amax = np.array([x.velocity_max for x in lim]), np.array([x.acceleration_max for x in lim])
    assert np.all(np.abs(v) <= vmax * (1 + 1e-6)) and np.all(np.abs(a) <= amax * (1 + 1e-6))
    assert np.ptp(p[:, 5]) > 0.1 and np.all((p[:, 5] > lim[5].position_min) & (p[:, 5] < lim[5].position_max))
    # the reported peaks are the spline's exact ones, between points too: at least the points' and within the limits
    peak = np.array(res.peak_velocity)
    assert np.all(peak >= np.abs(v).max(axis=0) - 1e-12) and np.all(peak <= vmax * (1 + 1e-6))
    np.testing.assert_allclose(peak, np.abs(v).max(axis=0), rtol=1e-2, atol=1e-9)
    # the sent joints reach the published electrode poses (to the poses' message precision)
    poses = np.array([pose_to_matrix(q) for q in plan.poses.poses])
    final0 = rotation_about_x(-3 * PITCH) @ poses[-1]
    np.testing.assert_allclose(axis_poses(final0, ("X", "Y", "Z", "A", "C", "B"), p), poses, atol=1e-6)


def test_start_state_checked_against_joint_states(system):
    pub, start = system["joint_states"], system["samples"][0]
    count = len(system["trajectories"].items)

    def send(positions):
        pub.publish(JointState(name=JOINTS, position=[float(x) for x in positions]))
        time.sleep(0.5)

    far = start.copy()
    far[2] += 1.0                                   # Z one millimetre off
    send(far)
    res = execute(system)
    assert not res.success and res.error_code.val == ErrorCode.INFEASIBLE
    assert "start state: joint edm_z (axis Z)" in res.message and "tolerance 0.05 mm" in res.message
    assert len(system["trajectories"].items) == count
    near = start.copy()
    near[3] += 0.0005                               # A within 0.001 rad
    send(near)
    res = execute(system)
    assert res.success, res.message
    assert system["trajectories"].wait(count + 1, 10)
    send([0.0] * 4)                                  # edm_c missing
    pub.publish(JointState(name=JOINTS[:4], position=[float(x) for x in start[:4]]))
    time.sleep(0.5)
    res = execute(system, dry_run=True)
    assert not res.success and res.error_code.val == ErrorCode.INVALID_REQUEST and "edm_c" in res.message
    assert not math.isnan(res.duration)


def test_console_entry_point(ros, node_processes, tmp_path):
    """``axis_bridge`` as its own process answers over DDS; a bad machine file stops it naming the key."""
    import os
    import sys

    assert os.access(os.path.join(sys.prefix, "lib", "edm_planner", "axis_bridge"), os.X_OK)
    node_processes.start("axis_bridge", "--ros-args", "-r", "execute_plan:=proc/execute_plan")
    client = ros.add(Node("process_client", context=ros.context))
    res = ros.call(client, ExecutePlan, "proc/execute_plan", ExecutePlan.Request(plan_id="nothing", dry_run=True),
                   timeout=60)
    assert res.error_code.val == ErrorCode.UNKNOWN_ID, node_processes.log("axis_bridge")
    assert node_processes.stop()["axis_bridge"] in (0, -2), node_processes.log("axis_bridge")
    bad = tmp_path / "bad.yaml"
    bad.write_text(default_machine_path().read_text().replace("velocity_max_rad_s: 0.5", "velocity_max_rad_s: -1", 1))
    proc = node_processes.start("axis_bridge", params={"machine_file": str(bad)})
    assert proc.wait(timeout=60) != 0
    assert "axes.A.velocity_max_rad_s: must be positive" in node_processes.log("axis_bridge")
