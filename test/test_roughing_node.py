"""PlanRoughing over real DDS: the trajectory_planner plans, the axis bridge executes the plan by id."""

import threading
import time

import numpy as np
import pytest
from edm_planner_msgs.msg import BliskGeometry, ChannelPlan, ErrorCode
from edm_planner_msgs.srv import ExecutePlan, PlanRoughing
from rclpy.node import Node
from rclpy.parameter import Parameter

from edm_planner.cnc.kinematics import axis_poses
from edm_planner.nodes.axis_bridge import AxisBridgeNode
from edm_planner.ros.conversions import pose_to_matrix
from edm_planner.nodes.geometry_loader import LATCHED, GeometryLoaderNode
from edm_planner.nodes.trajectory_planner import TrajectoryPlannerNode
from edm_planner.roughing.distance import RevolutionDistance
from edm_planner.roughing.path import TOOL_IN_CARRIER
from edm_planner.roughing.planner import target_surface

pytestmark = pytest.mark.slow          # nodes over DDS that plan, or the whole product: not in make test-fast



@pytest.fixture(scope="module")
def system(tmp_path_factory, field_cache):
    from ros_harness import InProcessRos

    ros = InProcessRos()
    store = Parameter("plan_store", value=str(tmp_path_factory.mktemp("roughing_store")))
    ros.add(GeometryLoaderNode(context=ros.context))
    ros.add(TrajectoryPlannerNode(context=ros.context, parameter_overrides=[
        Parameter("cache_dir", value=field_cache), Parameter("unknown_geometry_wait", value=20.0), store]))
    ros.add(AxisBridgeNode(context=ros.context, parameter_overrides=[
        Parameter("joint_states_topic", value=""), Parameter("plan_wait", value=5.0), store]))
    client = ros.add(Node("roughing_client", context=ros.context))
    plans, ready = [], threading.Event()
    client.create_subscription(BliskGeometry, "geometry", lambda m: ready.set(), LATCHED)
    client.create_subscription(ChannelPlan, "plan", plans.append, LATCHED)
    assert ready.wait(60)
    yield ros, client, plans
    ros.close()


def rough(system, **fields):
    ros, client = system[:2]
    return ros.call(client, PlanRoughing, "plan_roughing", PlanRoughing.Request(**fields), timeout=300)


@pytest.fixture(scope="module")
def channel_2(system):
    return rough(system, channel=2)


def test_roughing_plan_over_dds(system, channel_2, default_geometry):
    res = channel_2
    assert res.success and res.error_code.val == ErrorCode.SUCCESS, res.message
    n = len(res.labels)
    assert n > 20 and len(res.tool_poses.poses) == len(res.initial_tool_poses.poses) == len(res.hausdorff) == n
    assert res.tool_radius == pytest.approx(res.max_tool_radius) and 0 < res.max_tool_radius < res.min_blade_gap / 2
    assert res.line_count >= 1 and res.planning_time > 0
    # optimised: every position closer to the target than at its initial pose, statistics consistent
    h0, h = np.array(res.hausdorff_initial), np.array(res.hausdorff)
    assert (h <= h0 + 1e-9).all() and h.max() < 0.3                   # within the default allowance
    assert res.optimised.mean_absolute_error < 0.5 * res.initial.mean_absolute_error
    assert res.mae_reduction_percent == pytest.approx(
        100 * (1 - res.optimised.mean_absolute_error / res.initial.mean_absolute_error))
    assert res.optimised.range == pytest.approx(res.optimised.max_error - res.optimised.min_error)
    assert res.optimised.max_absolute_error == pytest.approx(h.max())
    # independent check of the published poses: the bottom centre of each tool lies at most h from the
    # target surface (the shroud offset by 0.3 mm), in channel 2's angular sector
    g = default_geometry
    target = RevolutionDistance(target_surface(g.blisk, 0.3))
    poses = np.array([pose_to_matrix(p) for p in res.tool_poses.poses])
    centre_error = np.abs(target.signed_distance(poses[:, :3, 3]))
    assert (centre_error <= h + 1e-9).all()
    # ... between the two blades of channel 2, the bottom's rim keeping the allowance to each wall
    x, r = poses[:, 0, 3], np.hypot(poses[:, 1, 3], poses[:, 2, 3])
    suction, pressure, inside = g.blisk.wall_angles(x, r, 2)
    theta = suction + np.mod(np.arctan2(poses[:, 2, 3], poses[:, 1, 3]) - suction, 2 * np.pi)
    assert inside.all()
    assert ((theta - suction) * r).min() >= res.tool_radius + 0.3 - 2e-3
    assert ((pressure - theta) * r).min() >= res.tool_radius + 0.3 - 2e-3


def test_the_published_roughing_plan_reproduces_its_poses_and_executes(system, channel_2):
    ros, client, plans = system
    deadline = time.monotonic() + 10
    while not any(p.plan_id == channel_2.plan_id for p in plans) and time.monotonic() < deadline:
        time.sleep(0.1)
    msg = [p for p in plans if p.plan_id == channel_2.plan_id][-1]
    assert msg.method == "plunge_roughing" and msg.channel == 2
    names = tuple(msg.axis_path.axis_names)
    q = np.array([p.positions for p in msg.axis_path.points])
    reference = np.array(msg.reference_pose).reshape(4, 4)
    tools = axis_poses(reference, names, q) @ TOOL_IN_CARRIER
    published = np.array([pose_to_matrix(p) for p in msg.poses.poses])
    np.testing.assert_allclose(tools, published, atol=1e-6)
    # every optimised tool pose is visited by the axis path (the bottom of its plunge)
    for p in channel_2.tool_poses.poses[::7]:
        target = pose_to_matrix(p)
        assert np.abs(tools - target).reshape(len(tools), -1).max(axis=1).min() < 1e-6
    res = ros.call(client, ExecutePlan, "execute_plan",
                   ExecutePlan.Request(plan_id=channel_2.plan_id, channel=2, dry_run=True), timeout=120)
    assert res.success, res.message
    assert res.duration > 60.0 and res.point_count == len(q)


def test_repeated_request_comes_from_the_store(system, channel_2):
    again = rough(system, channel=2, tool_radius=float("nan"), allowance=0.0)     # NaN / 0: the defaults
    assert again.success and again.plan_id == channel_2.plan_id
    assert "from the plan store" in again.message
    assert list(again.hausdorff) == list(channel_2.hausdorff)


def test_bad_roughing_requests(system, channel_2):
    too_big = rough(system, channel=2, tool_radius=channel_2.max_tool_radius * 1.5)
    assert too_big.error_code.val == ErrorCode.INFEASIBLE and "exceeds r_max" in too_big.message
    assert rough(system, channel=60).error_code.val == ErrorCode.INVALID_REQUEST
    assert rough(system, channel=0, allowance=-0.1).error_code.val == ErrorCode.INVALID_REQUEST
    assert rough(system, channel=0, safeguard_factor=0.5).error_code.val == ErrorCode.INVALID_REQUEST
    unknown = rough(system, geometry_id="f" * 64, channel=0)
    assert unknown.error_code.val == ErrorCode.UNKNOWN_ID and not unknown.success
