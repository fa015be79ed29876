"""interference_checker over real DDS, fed by a real geometry_loader."""

import json
import threading
import time

import numpy as np
import pytest
from edm_planner_msgs.msg import AxisPoint, BliskGeometry, ErrorCode
from edm_planner_msgs.srv import CheckInterference
from geometry_msgs.msg import Pose
from rclpy.node import Node
from rclpy.parameter import Parameter

from edm_planner.geometry.frames import rotation_about_x
from edm_planner.ros.conversions import matrix_to_pose, pose_to_matrix
from edm_planner.nodes.geometry_loader import LATCHED, GeometryLoaderNode
from edm_planner.nodes.interference_checker import InterferenceCheckerNode

GAP = 0.1
PITCH = 2 * np.pi / 60


@pytest.fixture(scope="module")
def system(tmp_path_factory, field_cache):
    """geometry_loader (default blisk) + interference_checker + a client, for the whole module."""
    from ros_harness import InProcessRos

    ros = InProcessRos()
    cache = field_cache
    ros.add(GeometryLoaderNode(context=ros.context))
    ros.add(InterferenceCheckerNode(context=ros.context, parameter_overrides=[
        Parameter("cache_dir", value=str(cache)), Parameter("max_poses", value=2000),
        Parameter("max_designs", value=2)]))
    client = ros.add(Node("checker_client", context=ros.context))
    got = []
    ready = threading.Event()
    client.create_subscription(BliskGeometry, "geometry", lambda m: (got.append(m), ready.set()), LATCHED)
    assert ready.wait(60)
    geo = got[0]
    final = pose_to_matrix(geo.electrode_final_poses[0])
    yield ros, client, geo.summary.geometry_id, final
    ros.close()


def call(system, poses=(), method=CheckInterference.Request.METHOD_EXACT, **fields):
    ros, client, gid, _ = system
    req = CheckInterference.Request(geometry_id=fields.pop("geometry_id", gid), method=method, **fields)
    req.poses = [p if isinstance(p, Pose) else matrix_to_pose(p) for p in poses]
    deadline = time.monotonic() + 120
    while True:                     # the checker may still be receiving the latched geometry
        res = ros.call(client, CheckInterference, "check_interference", req, timeout=120)
        if (res.error_code.val != ErrorCode.UNKNOWN_ID or "geometry" not in res.message
                or req.geometry_id != gid or time.monotonic() > deadline):     # an unknown id stays unknown
            return res
        time.sleep(0.5)


def clearances(res):
    return np.array([[c.suction, c.pressure, c.hub, c.shroud] for c in res.clearances])


def test_final_pose_keeps_the_discharge_gap_exact_and_fast(system):
    final = system[3]
    exact = call(system, [final], closest_points=True)
    assert exact.error_code.val == ErrorCode.SUCCESS, exact.message
    c = clearances(exact)[0]
    # every electrode vertex sits at the gap from the blade faces (exactly) and the hub/shroud (to 3 um)
    np.testing.assert_allclose(c, GAP, atol=3e-6)
    assert not exact.clearances[0].colliding and exact.error_bound == 0.0
    assert exact.clearance_kind == CheckInterference.Response.CLEARANCE_EXACT and "clearances exact" in exact.message
    pairs = exact.clearances[0]
    for e, s, d in zip(pairs.electrode_points, pairs.surface_points, c):
        assert np.hypot(np.hypot(e.x - s.x, e.y - s.y), e.z - s.z) == pytest.approx(d, abs=1e-6)
    fast = call(system, [final], method=CheckInterference.Request.METHOD_FAST)
    assert fast.error_code.val == ErrorCode.SUCCESS, fast.message
    assert 0 < fast.error_bound <= 0.005
    assert fast.clearance_kind == CheckInterference.Response.CLEARANCE_WITHIN_ERROR_BOUND
    assert f"exact within +-{fast.error_bound * 1e3:.1f} um" in fast.message
    np.testing.assert_allclose(clearances(fast)[0], c, atol=fast.error_bound)


def test_mesh_and_paper_methods(system):
    final = system[3]
    mesh = call(system, [final], method=CheckInterference.Request.METHOD_MESH)
    assert mesh.error_code.val == ErrorCode.SUCCESS, mesh.message
    c = clearances(mesh)[0]
    # the triangles stay within the electrode's chord tolerance (5 um) of the gap, plus the wall faceting
    assert np.all(c > GAP - 0.005 - mesh.error_bound) and np.all(c <= GAP + 1e-6)
    assert mesh.clearance_kind == CheckInterference.Response.CLEARANCE_WITHIN_ERROR_BOUND
    paper = call(system, [final], method=CheckInterference.Request.METHOD_PAPER_CRITERIA)
    assert paper.error_code.val == ErrorCode.SUCCESS and not paper.clearances[0].colliding
    assert paper.clearance_kind == CheckInterference.Response.CLEARANCE_NONE and np.isnan(clearances(paper)).all()
    pushed = final.copy()
    pushed[:3, 3] = rotation_about_x(-0.012)[:3, :3] @ pushed[:3, 3]      # ~1.3 mm into the suction blade
    assert call(system, [pushed], method=CheckInterference.Request.METHOD_PAPER_CRITERIA).clearances[0].colliding
    exact = clearances(call(system, [pushed]))[0]
    assert exact[0] < -1.0 and exact[1] > GAP


def test_channels_and_axis_values(system):
    final = system[3]
    base = clearances(call(system, [final]))[0]
    k = 7
    in_k = rotation_about_x(k * PITCH) @ final
    np.testing.assert_allclose(clearances(call(system, [in_k], channel=k))[0], base, atol=1e-9)
    # the same pose as machine axis values: all zero = final pose; A = k * pitch selects channel k
    res = call(system, axis_names=["X", "Y", "Z", "A", "C"], channel=k,
               axis_values=[AxisPoint(positions=[0.0, 0.0, 0.0, k * PITCH, 0.0])])
    assert res.error_code.val == ErrorCode.SUCCESS, res.message
    np.testing.assert_allclose(clearances(res)[0], base, atol=1e-9)


def test_segment_check_catches_a_collision_between_clear_waypoints(system):
    final = system[3]
    out = final.copy()
    out[0, 3] += 40.0                       # straight out along X, well beyond the trailing edge
    ends = call(system, [out], method=CheckInterference.Request.METHOD_FAST)
    assert clearances(ends)[0].min() > 0.3  # clear outside the blisk (hub and shroud continue as cylinders)
    res = call(system, [final, out], method=CheckInterference.Request.METHOD_FAST, segments=True, threshold=0.0)
    assert res.error_code.val == ErrorCode.SUCCESS, res.message
    (seg,) = res.segment_checks
    # a full-size electrode cannot leave the curved channel straight along X
    assert not seg.certified and 0.0 <= seg.first_contact < 0.5 and seg.penetration_bound > 0
    # while a short move inside the channel is certified
    nudge = final.copy()
    nudge[0, 3] += 0.01
    res = call(system, [final, nudge], method=CheckInterference.Request.METHOD_FAST, segments=True,
               threshold=0.05)
    assert res.segment_checks[0].certified, res.segment_checks[0]


@pytest.mark.parametrize("fields, code, words", [
    ({"geometry_id": "f" * 64}, ErrorCode.UNKNOWN_ID, "unknown geometry"),
    ({"electrode_id": "nope"}, ErrorCode.UNKNOWN_ID, "unknown electrode"),
    ({"method": 9}, ErrorCode.INVALID_REQUEST, "unknown method"),
    ({"channel": 60}, ErrorCode.INVALID_REQUEST, "channel 60"),
    ({"threshold": float("nan")}, ErrorCode.INVALID_REQUEST, "threshold"),
    ({"axis_names": ["X", "Y", "Z", "A", "C"], "axis_values": [AxisPoint(positions=[0.0] * 5)]},
     ErrorCode.INVALID_REQUEST, "not both"),
])
def test_bad_requests(system, fields, code, words):
    res = call(system, [system[3]], **fields)
    assert res.error_code.val == code and words in res.message, res.message


@pytest.mark.parametrize("names, values, words", [
    (["X", "Y"], [[0.0, 0.0]], "axis_names"),
    (["X", "Y", "Z", "A", "C"], [[0.0] * 4], "5 positions"),
    (["X", "Y", "Z", "A", "C"], [[0.0, float("nan"), 0.0, 0.0, 0.0]], "NaN"),
])
def test_bad_axis_values(system, names, values, words):
    res = call(system, [], axis_names=names, axis_values=[AxisPoint(positions=v) for v in values])
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and words in res.message, res.message


def test_bad_poses(system):
    assert call(system, []).error_code.val == ErrorCode.INVALID_REQUEST
    p = matrix_to_pose(system[3])
    p.orientation.w = 0.5
    res = call(system, [p])
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "not unit" in res.message
    p = matrix_to_pose(system[3])
    p.position.x = float("nan")
    assert call(system, [p]).error_code.val == ErrorCode.INVALID_REQUEST
    res = call(system, [system[3]] * 2001, method=CheckInterference.Request.METHOD_FAST)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "at most 2000" in res.message


def test_a_re_designed_electrode_is_checked_as_requested(system, default_geometry):
    """ElectrodeDesign overrides: the rear electrode of a front/rear split, checked exactly at its final pose."""
    from edm_planner_msgs.msg import ElectrodeDesign

    from edm_planner.geometry.electrode import ElectrodeDesign as Design
    from edm_planner.geometry.electrode import design_electrodes


    nan = float("nan")
    msg = ElectrodeDesign(discharge_gap=0.2, circumferential_reduction=0.03, reduction_side="", radial_reduction=3.0,
                          axial_start=nan, axial_end=nan, split="front_rear", split_fraction=nan, split_overlap=1.0)
    g = default_geometry
    rear = design_electrodes(g.blisk, Design(discharge_gap=0.2, circumferential_reduction=0.03,
                                             radial_reduction=3.0, split="front_rear", split_overlap=1.0))[1]
    assert rear.electrode_id == "rear"
    res = call(system, [rear.final_pose], electrode_id="rear", electrode=msg)
    assert res.error_code.val == ErrorCode.SUCCESS, res.message
    c = clearances(res)[0]
    # the hub keeps the 0.2 mm gap; the blades more (h = 0.03 rad); the shroud 3 mm more
    assert c[2] == pytest.approx(0.2, abs=3e-6) and min(c[0], c[1]) > 0.2 and c[3] > 3.0
    again = call(system, [rear.final_pose], electrode_id="rear", electrode=msg,
                 method=CheckInterference.Request.METHOD_FAST)                     # the design is kept
    np.testing.assert_allclose(clearances(again)[0], c, atol=again.error_bound)
    # the geometry file's electrodes are untouched; a bad design is refused
    assert call(system, [rear.final_pose], electrode_id="rear").error_code.val == ErrorCode.UNKNOWN_ID
    msg.split = "diagonal"
    bad = call(system, [rear.final_pose], electrode_id="rear", electrode=msg)
    assert bad.error_code.val in (ErrorCode.INVALID_REQUEST, ErrorCode.INVALID_GEOMETRY) and "split" in bad.message



def test_re_designed_electrodes_kept_are_the_most_recently_used(system):
    """With max_designs 2, a third design drops the least recently used one; asked for again, it is made
    again and answered as before (the node's memory stays bounded however many designs clients send)."""
    from edm_planner_msgs.msg import ElectrodeDesign

    ros, _, gid, final = system
    checker = next(n for n in ros.nodes if n.get_name() == "interference_checker")
    nan = float("nan")

    def design(gap):
        return ElectrodeDesign(discharge_gap=gap, circumferential_reduction=nan, reduction_side="",
                               radial_reduction=nan, axial_start=nan, axial_end=nan, split="",
                               split_fraction=nan, split_overlap=nan)

    def hub(gap):
        res = call(system, [final], electrode=design(gap), method=CheckInterference.Request.METHOD_FAST)
        assert res.error_code.val == ErrorCode.SUCCESS, res.message
        return clearances(res)[0, 2]

    def kept():
        return [json.loads(key[1])["discharge_gap"] for key in checker.redesigned]

    first = {gap: hub(gap) for gap in (0.15, 0.2)}
    assert kept() == [0.15, 0.2]
    hub(0.15)                                    # used again: now the most recent
    assert kept() == [0.2, 0.15]
    hub(0.25)
    assert kept() == [0.15, 0.25]                # 0.2 dropped
    assert hub(0.2) == first[0.2] and kept() == [0.25, 0.2]
    # at the geometry's own final pose (gap 0.1 mm) a larger gap leaves a thinner electrode, farther off
    assert 0.1 < first[0.15] < first[0.2]

def test_a_geometry_loaded_again_after_another_is_the_latest_again(system):
    """Load A (the default), then B (the same blisk, a 0.2 mm gap), then A again: a request naming no
    geometry is answered for A, whose electrode sits 0.1 mm from the walls at its final pose."""
    from edm_planner_msgs.srv import LoadGeometry

    from conftest import CONFIG

    ros, client, gid_a, final = system
    text = (CONFIG / "default_blisk.yaml").read_text() + "\nelectrode: {discharge_gap: 0.2}\n"

    def load(**fields):
        res = ros.call(client, LoadGeometry, "load_geometry", LoadGeometry.Request(**fields), timeout=300)
        assert res.success, res.message
        return res.geometry_id

    def latest():
        return clearances(call(system, [final], geometry_id=""))[0]

    gid_b = load(yaml_text=text)
    assert gid_b != gid_a
    assert call(system, [final], geometry_id=gid_b).error_code.val == ErrorCode.SUCCESS   # the checker has B
    deadline = time.monotonic() + 120
    while np.allclose(latest(), GAP, atol=3e-6):        # B's thinner electrode: more room than A's 0.1 mm
        assert time.monotonic() < deadline, "a request naming no geometry is not answered for B"
        time.sleep(0.2)
    assert latest().min() > 0.15
    from edm_planner.nodes.geometry_loader import config_directory
    assert load(path=str(config_directory() / "default_blisk.yaml")) == gid_a
    deadline = time.monotonic() + 120
    while not np.allclose(latest(), GAP, atol=3e-6):
        assert time.monotonic() < deadline, "a request naming no geometry is still answered for B"
        time.sleep(0.2)


def test_a_request_for_a_geometry_still_on_its_way_waits_for_it(system, field_cache):
    """A checker that has received no geometry yet is asked for one: the request waits for it on the
    latched topic (``unknown_geometry_wait``) and is answered for it once it arrives, as when a cell
    controller calls right after LoadGeometry's answer; a geometry that never comes is UNKNOWN_ID after the
    wait, and the message says how long it waited."""
    ros, client, gid, final = system
    got, ready = [], threading.Event()
    client.create_subscription(BliskGeometry, "geometry", lambda m: (got.append(m), ready.set()), LATCHED)
    assert ready.wait(60), "the loader's latched geometry not received"
    # a checker of its own namespace: the loader's topic does not reach it, this test publishes its geometry
    checker = ros.add(InterferenceCheckerNode(context=ros.context, namespace="on_its_way", parameter_overrides=[
        Parameter("cache_dir", value=str(field_cache)), Parameter("unknown_geometry_wait", value=300.0)]))
    service = client.create_client(CheckInterference, "/on_its_way/check_interference")
    assert service.wait_for_service(timeout_sec=60)
    done = threading.Event()
    future = service.call_async(CheckInterference.Request(geometry_id=gid, poses=[matrix_to_pose(final)],
                                                          method=CheckInterference.Request.METHOD_EXACT))
    future.add_done_callback(lambda _: done.set())
    deadline = time.monotonic() + 120
    while checker.received.waiting == 0:           # the request is in the checker, waiting for its geometry
        assert not done.is_set(), future.result().message
        assert time.monotonic() < deadline, "the request never waited for its geometry"
        time.sleep(0.01)
    client.create_publisher(BliskGeometry, "/on_its_way/geometry", LATCHED).publish(got[-1])
    assert done.wait(300), "not answered after its geometry arrived"
    res = future.result()
    assert res.error_code.val == ErrorCode.SUCCESS, res.message
    np.testing.assert_allclose(clearances(res)[0], GAP, atol=3e-6)
    assert checker.received.waiting == 0
    # an id that never comes: UNKNOWN_ID once the wait is over
    checker.set_parameters([Parameter("unknown_geometry_wait", value=0.5)])
    res = ros.call(client, CheckInterference, "/on_its_way/check_interference", CheckInterference.Request(
        geometry_id="f" * 64, poses=[matrix_to_pose(final)]), timeout=120)
    assert res.error_code.val == ErrorCode.UNKNOWN_ID and "waited 0.5 s" in res.message, res.message
    # a geometry the checker cannot use: its requests are told so, a request naming none too (it is the
    # latest), not answered for the geometry before it
    checker.set_parameters([Parameter("unknown_geometry_wait", value=300.0)])
    broken = BliskGeometry(model_json="{not json")
    broken.summary.geometry_id = "e" * 64
    client.create_publisher(BliskGeometry, "/on_its_way/geometry", LATCHED).publish(broken)
    for named in ("e" * 64, ""):                    # the first waits for it to arrive
        res = ros.call(client, CheckInterference, "/on_its_way/check_interference", CheckInterference.Request(
            geometry_id=named, poses=[matrix_to_pose(final)]), timeout=300)
        assert res.error_code.val == ErrorCode.INVALID_GEOMETRY and "not usable" in res.message, res.message
