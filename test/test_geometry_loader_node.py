"""geometry_loader over real DDS: in-process on a private context, and as a process."""

import json
import os
import shutil
import sys
import threading
import time

import numpy as np
import pytest
from edm_planner_msgs.msg import BliskGeometry, ErrorCode
from edm_planner_msgs.srv import LoadGeometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from visualization_msgs.msg import MarkerArray

from conftest import CONFIG
from edm_planner.errors import ErrorCode as CoreErrorCode
from edm_planner.geometry.blisk import Blisk
from edm_planner.ros.conversions import msg_to_mesh, pose_to_matrix
from edm_planner.nodes.geometry_loader import LATCHED, GeometryLoaderNode


def test_error_codes_mirror_the_message_constants():
    consts = {name: getattr(ErrorCode, name) for name in dir(ErrorCode)
              if name.isupper() and isinstance(getattr(ErrorCode, name), int)}
    assert consts == {c.name: c.value for c in CoreErrorCode}


def _loader(ros, allowed, namespace=""):
    node = ros.add(GeometryLoaderNode(context=ros.context, namespace=namespace, parameter_overrides=[
        Parameter("allowed_directories", value=[str(CONFIG), str(allowed)])]))
    client = ros.add(Node("test_client", context=ros.context, namespace=namespace))
    return node, client


@pytest.fixture
def fresh_loader(ros, tmp_path):
    """A loader node started for this test (it publishes the default geometry at start)."""
    return _loader(ros, tmp_path)


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """One loader node for the requests of this module (its start loads the default blisk, ~10 s)."""
    from ros_harness import InProcessRos

    allowed = tmp_path_factory.mktemp("allowed")
    with InProcessRos() as ros:
        yield ros, _loader(ros, allowed), allowed


@pytest.fixture
def loader(shared):
    return shared[1]


@pytest.fixture
def shared_ros(shared):
    return shared[0]


def _load(ros, client, **fields):
    return ros.call(client, LoadGeometry, "load_geometry", LoadGeometry.Request(**fields), timeout=60)


def test_late_joiner_receives_the_default_geometry_and_rebuilds_the_model(ros, fresh_loader):
    node, client = fresh_loader
    got, markers = [], []
    done = threading.Event()
    client.create_subscription(BliskGeometry, "geometry", lambda m: (got.append(m), done.set()), LATCHED)
    client.create_subscription(MarkerArray, "geometry_markers", markers.append, LATCHED)
    assert done.wait(30), "no geometry received on the TRANSIENT_LOCAL topic"
    msg = got[0]
    assert msg.header.frame_id == "workpiece"
    assert msg.summary.blade_count == 60 and msg.summary.blade_source == "parametric"
    assert 95 < msg.summary.hub_radius_min < 105 and 115 < msg.summary.shroud_radius_max < 125
    model = json.loads(msg.model_json)
    blisk = Blisk.from_dict(model)
    assert model["geometry_id"] == msg.summary.geometry_id
    assert list(msg.surface_labels) == ["suction", "pressure", "hub", "shroud"]
    assert all(len(msg_to_mesh(m).faces) > 100 for m in msg.surfaces)
    electrode = msg_to_mesh(msg.electrodes[0])
    assert electrode.is_watertight and electrode.volume > 1000          # mm^3
    # flat arrays, received as such: the loader's electrode to the bit
    loaded = node.geometries[msg.summary.geometry_id].electrodes[0].mesh
    np.testing.assert_array_equal(electrode.vertices, loaded.vertices)
    np.testing.assert_array_equal(electrode.faces, loaded.faces)
    pose = pose_to_matrix(msg.electrode_final_poses[0])
    assert 100 < (pose[1, 3] ** 2 + pose[2, 3] ** 2) ** 0.5 < 120       # electrode centre inside the channel
    assert blisk.blade_count == 60
    deadline = time.monotonic() + 30
    while not markers and time.monotonic() < deadline:      # latched too: arrives without a new publish
        time.sleep(0.05)
    assert markers and len(markers[0].markers) == 5


@pytest.mark.parametrize("name, blades, source", [
    ("default_blisk.yaml", 60, "parametric"),
    ("rotor37.yaml", 36, "sections"),
    ("mesh_blisk.yaml", 60, "mesh"),
])
def test_load_each_blade_source(shared_ros, loader, name, blades, source):
    ros = shared_ros
    _, client = loader
    res = _load(ros, client, path=name)
    assert res.success, res.message
    assert res.error_code.val == ErrorCode.SUCCESS
    assert res.summary.blade_count == blades and res.summary.blade_source == source
    assert len(res.geometry_id) == 64 and res.summary.geometry_id == res.geometry_id
    assert res.summary.min_channel_width > 3.0
    assert res.summary.electrode_count == 1 and res.summary.electrode_volume[0] > 0


def test_inline_yaml_and_same_content_same_id(shared_ros, loader):
    ros = shared_ros
    _, client = loader
    by_path = _load(ros, client, path=str(CONFIG / "default_blisk.yaml"))
    inline = _load(ros, client, yaml_text=(CONFIG / "default_blisk.yaml").read_text())
    assert by_path.success and inline.success
    assert by_path.geometry_id == inline.geometry_id


def test_a_geometry_the_topic_already_holds_is_not_published_again(shared_ros, loader):
    """LoadGeometry of what the latched topic holds answers without a new message; another geometry does."""
    ros = shared_ros
    _, client = loader
    first = _load(ros, client, path="rotor37.yaml")
    got, arrived = [], threading.Condition()

    def on_geometry(msg):
        with arrived:
            got.append(msg.summary.geometry_id)
            arrived.notify_all()

    def wait_for(count):
        with arrived:
            assert arrived.wait_for(lambda: len(got) >= count, timeout=60), got

    client.create_subscription(BliskGeometry, "geometry", on_geometry, LATCHED)
    wait_for(1)                                                       # the latched message: rotor 37
    again = _load(ros, client, path="rotor37.yaml")                   # already on the topic
    default = _load(ros, client, path="default_blisk.yaml")           # another geometry: published
    wait_for(2)
    _load(ros, client, path="default_blisk.yaml")
    _load(ros, client, path="rotor37.yaml")
    wait_for(3)
    assert again.success and again.geometry_id == first.geometry_id
    # messages of one publisher arrive in order: no repeat between the changes
    assert got == [first.geometry_id, default.geometry_id, first.geometry_id]


def test_markers_are_built_only_for_a_viewer_the_latest_when_it_comes_then_on_each_load(ros, tmp_path):
    """Markers cost about 2 s of CPU per load: none are built while no viewer subscribes; a viewer that comes
    later (RViz started later) gets the latest geometry's, and while it listens each load's follow in order."""
    # a namespace of its own: this module's shared loader publishes its markers on the same domain
    node, client = _loader(ros, tmp_path, namespace="markers_in_order")
    for name in ("rotor37.yaml", "mesh_blisk.yaml", "default_blisk.yaml", "rotor37.yaml"):
        assert _load(ros, client, path=name).success
    last = node.geometries[_load(ros, client, path="rotor37.yaml").geometry_id]
    node._marker_work.submit(lambda: None).result(timeout=120)       # every marker job before it is done
    assert node.marker_builds == 0
    late = ros.add(Node("late_viewer", context=ros.context, namespace="markers_in_order"))
    markers = []
    late.create_subscription(MarkerArray, "geometry_markers", markers.append, LATCHED)

    def wait_for(count):
        deadline = time.monotonic() + 60
        while len(markers) < count and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(markers) == count, len(markers)

    def assert_markers_of(geometry, got):
        meshes = geometry.blisk.channel_meshes(resolution=node.get_parameter("mesh_resolution").value)
        channel = [m for m in got.markers if m.ns == "channel"]
        assert [len(m.points) for m in channel] == [3 * len(meshes[s].faces)
                                                     for s in ("suction", "pressure", "hub", "shroud")]
        [electrode] = [m for m in got.markers if m.ns == "electrode"]
        assert len(electrode.points) == 3 * len(geometry.electrodes[0].mesh.faces)

    wait_for(1)
    assert_markers_of(last, markers[0])
    assert node.marker_builds == 1
    # with the viewer listening: the next load's markers follow it
    default = node.geometries[_load(ros, client, path="default_blisk.yaml").geometry_id]
    wait_for(2)
    assert_markers_of(default, markers[1])
    node._marker_work.submit(lambda: None).result(timeout=120)
    assert node.marker_builds == 2


@pytest.mark.parametrize("fields, code, words", [
    ({}, ErrorCode.INVALID_REQUEST, "exactly one"),
    ({"path": "x.yaml", "yaml_text": "blade_count: 2"}, ErrorCode.INVALID_REQUEST, "exactly one"),
    ({"path": "no_such_file.yaml"}, ErrorCode.FILE_ERROR, "not found"),
    ({"path": "/etc/hostname"}, ErrorCode.FILE_ERROR, "outside the allowed"),
    ({"path": "../../../etc/passwd"}, ErrorCode.FILE_ERROR, "outside the allowed"),
    ({"yaml_text": "blade_count: [1, 2\nhub: {"}, ErrorCode.FILE_ERROR, "malformed YAML at line"),
    ({"yaml_text": "blade_count: 1\nhub_profile: [[0, 100], [10, 100]]\n"
                   "shroud_profile: [[0, 120], [10, 120]]\nblade: {parametric: {}}"},
     ErrorCode.INVALID_GEOMETRY, "blade"),
])
def test_bad_requests_get_clear_errors(shared_ros, loader, fields, code, words):
    ros = shared_ros
    _, client = loader
    res = _load(ros, client, **fields)
    assert not res.success
    assert res.error_code.val == code, res.message
    assert words in res.message


def test_symlink_out_of_the_allowed_directory_is_refused(shared, loader):
    ros, _, tmp_path = shared
    _, client = loader
    outside = tmp_path.parent / f"outside_{os.getpid()}.yaml"
    shutil.copy(CONFIG / "default_blisk.yaml", outside)
    (tmp_path / "link.yaml").symlink_to(outside)
    res = _load(ros, client, path=str(tmp_path / "link.yaml"))
    assert res.error_code.val == ErrorCode.FILE_ERROR and "outside the allowed" in res.message
    # a copy inside the allowed directory loads
    shutil.copy(CONFIG / "default_blisk.yaml", tmp_path / "inside.yaml")
    assert _load(ros, client, path=str(tmp_path / "inside.yaml")).success


@pytest.mark.slow
def test_geometry_loader_process_answers_over_dds(ros, node_processes):
    """The console entry point as its own OS process, called from this process."""
    exe = os.path.join(sys.prefix, "lib", "edm_planner", "geometry_loader")
    assert os.access(exe, os.X_OK), "ament layout executable missing"
    # a namespace of its own: this module's in-process loader serves load_geometry on the same domain, and
    # answered this test's calls while the process was still starting (the SIGINT below then came mid-start)
    node_processes.start("geometry_loader", "--ros-args", "-r", "__ns:=/process_answers")
    client = ros.add(Node("process_client", context=ros.context, namespace="process_answers"))
    for name, blades in (("default_blisk.yaml", 60), ("mesh_blisk.yaml", 60), ("rotor37.yaml", 36)):
        res = _load(ros, client, path=name)
        assert res.success, f"{res.message}\n{node_processes.log('geometry_loader')}"
        assert res.summary.blade_count == blades
    assert "rotor37.yaml: 36 blades" in node_processes.log("geometry_loader"), "answered by another loader"
    rc = node_processes.stop()
    assert rc["geometry_loader"] in (0, -2), node_processes.log("geometry_loader")
