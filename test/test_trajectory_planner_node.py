"""trajectory_planner over real DDS, fed by a real geometry_loader (default blisk)."""

import threading
import time

import numpy as np
import pytest
from edm_planner_msgs.msg import BliskGeometry, ChannelPlan, ElectrodeDesign, ErrorCode, PlanProgress
from edm_planner_msgs.srv import PlanChannel
from rclpy.node import Node
from rclpy.parameter import Parameter

from edm_planner.geometry.frames import rotation_about_x
from edm_planner.interference.exact_points import ExactChannelDistance, transform_points
from edm_planner.ros.conversions import pose_to_matrix
from edm_planner.nodes.geometry_loader import LATCHED, GeometryLoaderNode
from edm_planner.interference import SURFACES
from edm_planner.nodes.trajectory_planner import TrajectoryPlannerNode

pytestmark = pytest.mark.slow          # nodes over DDS that plan, or the whole product: not in make test-fast


PITCH = 2 * np.pi / 60
NAN = float("nan")


def rear_design(**changes):
    """The rear electrode of a front/rear split, thin enough to leave the curved channel downstream."""
    d = dict(discharge_gap=NAN, circumferential_reduction=0.03, reduction_side="", radial_reduction=3.0,
             axial_start=NAN, axial_end=NAN, split="front_rear", split_fraction=NAN, split_overlap=1.0)
    d.update(changes)
    return ElectrodeDesign(**d)


@pytest.fixture(scope="module")
def system(tmp_path_factory, field_cache):
    from ros_harness import InProcessRos

    ros = InProcessRos()
    cache = field_cache
    exports = tmp_path_factory.mktemp("plans")
    ros.add(GeometryLoaderNode(context=ros.context))
    ros.add(TrajectoryPlannerNode(context=ros.context, parameter_overrides=[
        Parameter("cache_dir", value=str(cache)), Parameter("export_dir", value=str(exports)),
        Parameter("unknown_geometry_wait", value=20.0),
        # a store of this module's own: the first request must plan (other modules plan the same channel)
        Parameter("plan_store", value=str(tmp_path_factory.mktemp("planner_store")))]))
    client = ros.add(Node("planner_client", context=ros.context))
    geometries, plans, progress = [], [], []
    ready = threading.Event()
    client.create_subscription(BliskGeometry, "geometry", lambda m: (geometries.append(m), ready.set()), LATCHED)
    client.create_subscription(ChannelPlan, "plan", plans.append, LATCHED)
    client.create_subscription(PlanProgress, "plan_progress", progress.append, 50)
    assert ready.wait(60)
    yield ros, client, geometries[0].summary.geometry_id, plans, progress
    ros.close()


def call(system, **fields):
    ros, client, gid = system[:3]
    req = PlanChannel.Request(geometry_id=fields.pop("geometry_id", gid), **fields)
    return ros.call(client, PlanChannel, "plan_channel", req, timeout=300)


@pytest.fixture(scope="module")
def rear_plan(system):
    res = call(system, channel=3, electrode_id="rear", electrode=rear_design(), write_export=True)
    return res


def test_plan_of_the_rear_electrode_is_certified_and_complete(system, rear_plan, default_geometry):
    res = rear_plan
    assert res.success, res.message
    assert res.error_code.val == ErrorCode.SUCCESS and res.plan_id
    m = res.metrics
    assert m.certified and m.node_count > 50 and m.path_length > 10.0
    assert list(m.axis_names) == ["X", "Y", "Z", "A", "C"] and list(res.axis_path.axis_names) == list(m.axis_names)
    assert len(m.smoothness) == 5 and len(m.sharp_points) == 5
    assert m.circumferential_reduction == pytest.approx(0.03)
    # the margins (0.02 mm default) hold along the whole certified path
    lower = [getattr(m, f"clearance_lower_bound_{s}") for s in SURFACES]
    exact = [getattr(m, f"clearance_exact_{s}") for s in SURFACES]
    assert min(lower) >= 0.02
    # the exact minimum over the samples can only lie above the certified lower bound over the path
    assert all(np.isfinite(exact)) and all(lo <= ex for lo, ex in zip(lower, exact)), (lower, exact)
    q = np.array([p.positions for p in res.axis_path.points])
    assert len(q) == len(res.poses.poses) > 100
    # feed order: ends at the machining pose of channel 3 (A = 3 pitches, the rest zero)
    np.testing.assert_allclose(q[-1], [0, 0, 0, 3 * PITCH, 0], atol=1e-9)
    assert q[0, 0] > 10.0                                   # starts downstream, outside the blisk
    last = pose_to_matrix(res.poses.poses[-1])
    g = default_geometry
    assert res.export_path
    from edm_planner.geometry.electrode import design_electrodes
    from edm_planner.geometry.electrode import ElectrodeDesign as Design
    rear = design_electrodes(g.blisk, Design(circumferential_reduction=0.03, radial_reduction=3.0,
                                             split="front_rear", split_overlap=1.0))[1]
    np.testing.assert_allclose(last, rotation_about_x(3 * PITCH) @ rear.final_pose, atol=1e-6)
    # independent exact re-check of a few published poses (all vertices, channel 3)
    exact = ExactChannelDistance(g.blisk)
    poses = np.array([pose_to_matrix(p) for p in res.poses.poses])
    for pose in poses[:: max(1, len(poses) // 6)]:
        world = transform_points(pose[None], rear.mesh.vertices)[0]
        assert exact.clearances(world, 3).min() >= 0.02 - 0.004


def test_plan_is_latched_and_progress_is_published(system, rear_plan):
    plans, progress = system[3], system[4]
    deadline = time.monotonic() + 10
    while not plans and time.monotonic() < deadline:
        time.sleep(0.1)
    assert plans and plans[-1].plan_id == rear_plan.plan_id and plans[-1].channel == 3
    assert len(plans[-1].axis_path.points) == len(rear_plan.axis_path.points)
    stages = {p.stage for p in progress}
    assert {"search", "certify"} <= stages
    assert progress[-1].fraction == pytest.approx(1.0)


def test_same_request_same_plan(system, rear_plan):
    again = call(system, channel=3, electrode_id="rear", electrode=rear_design())
    assert again.plan_id == rear_plan.plan_id
    a = np.array([p.positions for p in again.axis_path.points])
    b = np.array([p.positions for p in rear_plan.axis_path.points])
    np.testing.assert_array_equal(a, b)


def test_infeasible_channel_reports_where_it_stopped(system):
    # the primitive full-size electrode cannot leave the 104-degree channel
    res = call(system, channel=0)
    assert not res.success and res.error_code.val == ErrorCode.INFEASIBLE
    assert res.blocking_surface in ("suction", "pressure", "hub", "shroud")
    assert res.furthest_node >= 1 and 0.0 < res.furthest_reference < 5.0
    assert "blocked by the" in res.message


def test_bad_requests_get_clear_errors(system):
    res = call(system, geometry_id="0" * 64)
    assert res.error_code.val == ErrorCode.UNKNOWN_ID and "geometry" in res.message
    res = call(system, electrode_id="nope", electrode=rear_design())
    assert res.error_code.val == ErrorCode.UNKNOWN_ID and "nope" in res.message
    res = call(system, channel=60)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "channel" in res.message
    req = PlanChannel.Request()
    req.settings.method = "simplex"
    res = call(system, settings=req.settings)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "method" in res.message
    req.settings.method = ""
    req.settings.step = NAN
    req.settings.margin_blade = -1.0
    res = call(system, settings=req.settings)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "margin_blade" in res.message
    res = call(system, electrode=rear_design(discharge_gap=2.0))
    assert res.error_code.val in (ErrorCode.INVALID_REQUEST, ErrorCode.INVALID_GEOMETRY)
    assert "discharge_gap" in res.message


def test_electrode_in_collision_at_its_final_pose(system):
    req = PlanChannel.Request()
    req.settings.margin_blade = 0.2          # more than the 0.1 mm discharge gap
    res = call(system, electrode_id="rear", electrode=rear_design(circumferential_reduction=0.0),
               settings=req.settings)
    assert res.error_code.val == ErrorCode.ELECTRODE_IN_COLLISION
    assert res.blocking_surface in ("suction", "pressure") and "margin" in res.message


def test_a_geometry_loaded_again_after_another_is_the_latest_again(system):
    """Load A (the default blisk, 60 blades), then B (Rotor 37, 36 blades), then A again: a request naming
    no geometry is answered for A again (the channel check says which blisk answered)."""
    from edm_planner_msgs.srv import LoadGeometry, PlanElectrodeSet

    from edm_planner.nodes.geometry_loader import config_directory

    ros, client, gid_a = system[:3]

    def load(name):
        res = ros.call(client, LoadGeometry, "load_geometry",
                       LoadGeometry.Request(path=str(config_directory() / name)), timeout=300)
        assert res.success, res.message
        return res.geometry_id

    def channels_of_the_latest():
        res = ros.call(client, PlanElectrodeSet, "plan_electrode_set",
                       PlanElectrodeSet.Request(geometry_id="", channel=70), timeout=300)
        assert res.error_code.val == ErrorCode.INVALID_REQUEST, res.message
        return res.message

    def wait_for(text):
        deadline = time.monotonic() + 120
        while text not in (said := channels_of_the_latest()):
            assert time.monotonic() < deadline, f"still answered as: {said}"
            time.sleep(0.2)

    assert "0 .. 59" in channels_of_the_latest()
    assert load("rotor37.yaml") != gid_a
    wait_for("0 .. 35")
    assert load("default_blisk.yaml") == gid_a
    wait_for("0 .. 59")
