"""The persistent plan store: round trips bit for bit, keys, bad files, and plans surviving node restarts."""

import contextlib
import os
import sqlite3
import subprocess
import sys
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from edm_planner_msgs.msg import ErrorCode as ErrorCodeMsg
from edm_planner_msgs.srv import ExecutePlan, PlanChannel
from rclpy.node import Node

from edm_planner.errors import ErrorCode
from edm_planner.planning.plan import PlanOptions
from edm_planner.planning.planner import plan_channel
from edm_planner.planning.search import SearchOptions
from edm_planner.records.store import (FILE_NAME, PlanStore, PlanStoreError, open_store, plan_to_stored,
                                        request_key, stored_to_plan)

from test_trajectory_planner_node import rear_design


@pytest.fixture(scope="module")
def geometry(default_geometry):
    return default_geometry


@pytest.fixture(scope="module")
def plan(geometry, field_cache):
    design = replace(geometry.design, split="front_rear", circumferential_reduction=0.03, radial_reduction=3.0,
                     split_overlap=1.0)
    p = plan_channel(geometry, 1, "rear", PlanOptions(), design=design, cache_dir=field_cache)
    assert p.success, p.message
    return p


def test_round_trip_is_bit_for_bit(plan, tmp_path):
    store = PlanStore(tmp_path)
    key = request_key(plan.geometry_id, 1, "rear", plan.options)
    store.put(plan_to_stored(plan), key)
    again = stored_to_plan(PlanStore(tmp_path).find(key))      # a second opener: another process, later
    for name in ("samples", "poses", "nodes", "final_pose"):
        np.testing.assert_array_equal(getattr(again, name), getattr(plan, name), err_msg=name)
    np.testing.assert_array_equal(again.electrode_mesh.vertices, plan.electrode_mesh.vertices)
    np.testing.assert_array_equal(again.electrode_mesh.faces, plan.electrode_mesh.faces)
    assert again.options == plan.options and again.metrics == plan.metrics
    assert (again.plan_id, again.channel, again.electrode_id, again.axis_names, again.error_code) == (
        plan.plan_id, 1, "rear", plan.axis_names, ErrorCode.SUCCESS)
    assert store.get(plan.plan_id).created and store.get("no such id") is None
    rows = store.list()
    assert [r["plan_id"] for r in rows] == [plan.plan_id] and rows[0]["kind"] == "channel"


def test_request_keys_tell_settings_and_geometry_apart(plan):
    base = request_key("g" * 64, 1, "rear", plan.options)
    assert base == request_key("g" * 64, 1, "rear", replace(plan.options))
    other = replace(plan.options, search=SearchOptions(step=0.2))
    assert len({base, request_key("g" * 64, 1, "rear", other), request_key("h" * 64, 1, "rear", plan.options),
                request_key("g" * 64, 2, "rear", plan.options), request_key("g" * 64, 1, "front", plan.options),
                request_key("g" * 64, 1, "rear", plan.options, design={"split": "none"})}) == 6


def _refused(directory, *words):
    before = (directory / FILE_NAME).read_bytes()
    with pytest.raises(PlanStoreError) as err:
        PlanStore(directory)
    assert err.value.code == ErrorCode.FILE_ERROR
    for word in (str(directory / FILE_NAME), "left untouched", *words):
        assert word in err.value.message
    assert (directory / FILE_NAME).read_bytes() == before          # nothing lost, nothing rewritten


def test_a_file_that_is_not_sqlite_is_refused_and_left_alone(tmp_path):
    (tmp_path / FILE_NAME).write_bytes(b"these are somebody's notes, not a database\n" * 40)
    _refused(tmp_path, "not a usable SQLite database")


def test_another_applications_database_is_refused(tmp_path):
    con = sqlite3.connect(tmp_path / FILE_NAME)
    con.execute("CREATE TABLE invoices (id INTEGER PRIMARY KEY, total REAL)")
    con.execute("INSERT INTO invoices VALUES (1, 99.5)")
    con.commit()
    con.close()
    _refused(tmp_path, "another application", "invoices")


def test_a_newer_schema_is_refused(tmp_path):
    PlanStore(tmp_path)
    con = sqlite3.connect(tmp_path / FILE_NAME)
    con.execute("UPDATE meta SET value = '7' WHERE key = 'schema'")
    con.commit()
    con.close()
    _refused(tmp_path, "schema '7'")


def test_a_truncated_file_is_refused(plan, tmp_path):
    store = PlanStore(tmp_path)
    store.put(plan_to_stored(plan), "k")
    data = (tmp_path / FILE_NAME).read_bytes()
    assert len(data) > 8192
    (tmp_path / FILE_NAME).write_bytes(data[: len(data) // 2])
    for extra in ("-wal", "-shm"):
        (tmp_path / (FILE_NAME + extra)).unlink(missing_ok=True)
    _refused(tmp_path)


def test_a_damaged_record_is_reported_and_the_others_still_read(plan, tmp_path):
    store = PlanStore(tmp_path)
    store.put(plan_to_stored(plan), "a")
    other = plan_to_stored(plan)
    other.plan_id = "another0plan0id0"
    store.put(other, "b")
    con = sqlite3.connect(tmp_path / FILE_NAME)
    blob = bytearray(con.execute("SELECT record FROM plans WHERE plan_id = ?", (plan.plan_id,)).fetchone()[0])
    blob[len(blob) // 2] ^= 0xFF
    con.execute("UPDATE plans SET record = ? WHERE plan_id = ?", (bytes(blob), plan.plan_id))
    con.commit()
    con.close()
    with pytest.raises(PlanStoreError, match=f"plan {plan.plan_id} .* is corrupt"):
        store.find("a")
    assert store.get("another0plan0id0").plan_id == "another0plan0id0"


def test_a_directory_that_cannot_be_made_is_a_clear_error(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(PlanStoreError, match="plan store directory"):
        PlanStore(tmp_path / "file" / "store")
    assert open_store("none") is None


def test_writers_in_parallel_lose_nothing(plan, tmp_path):
    stores = [PlanStore(tmp_path) for _ in range(4)]
    errors = []

    def write(i):
        try:
            for j in range(5):
                s = plan_to_stored(plan)
                s.plan_id = f"p{i}-{j}"
                stores[i].put(s, f"k{i}-{j}")
        except Exception as exc:  # collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(PlanStore(tmp_path).list()) == 20
    assert stores[0].find("k3-4").plan_id == "p3-4"


# -- nodes ------------------------------------------------------------------------------------

@contextlib.contextmanager
def busy_cores():
    """A busy loop on every core of the machine while the block runs (processes of the test's own)."""
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 2)]
    try:
        yield
    finally:
        for p in loops:
            p.kill()
            p.wait()


def _pose_array(msg):
    return np.array([[p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
                      p.orientation.w] for p in msg.poses])


def _wait_for_service(ros, client, srv_type, name, timeout=90.0):
    c = client.create_client(srv_type, name)
    try:
        assert c.wait_for_service(timeout_sec=timeout), f"{name} not up"
    finally:
        client.destroy_client(c)


@pytest.mark.slow
def test_plans_survive_restarts_of_the_planner_and_the_bridge(ros, node_processes, tmp_path, field_cache):
    store = tmp_path / "store"
    node_processes.start("geometry_loader")
    planner_params = {"plan_store": str(store), "cache_dir": field_cache, "unknown_geometry_wait": 90.0}
    node_processes.start("trajectory_planner", params=planner_params)
    client = ros.add(Node("store_client", context=ros.context))
    request = PlanChannel.Request(channel=2, electrode_id="rear", electrode=rear_design())
    first = ros.call(client, PlanChannel, "plan_channel", request, timeout=300)
    assert first.success, first.message + node_processes.log("trajectory_planner")
    assert "from the plan store" not in first.message

    # the planner is gone (nothing latched on 'plan' any more); a bridge started now finds the plan by id
    node_processes.stop("trajectory_planner")
    node_processes.start("axis_bridge", params={"plan_store": str(store), "joint_states_topic": "''",
                                                "plan_wait": 1.0})
    _wait_for_service(ros, client, ExecutePlan, "execute_plan")
    done = ros.call(client, ExecutePlan, "execute_plan",
                    ExecutePlan.Request(plan_id=first.plan_id, channel=2, dry_run=True), timeout=120)
    assert done.success, done.message + node_processes.log("axis_bridge")
    assert done.duration > 1.0 and done.point_count > 100
    assert "read from the plan store" in node_processes.log("axis_bridge")
    unknown = ros.call(client, ExecutePlan, "execute_plan",
                       ExecutePlan.Request(plan_id="0123456789abcdef", channel=2, dry_run=True), timeout=60)
    assert unknown.error_code.val == ErrorCodeMsg.UNKNOWN_ID and "in the plan store" in unknown.message

    # the planner restarted under CPU load (a busy loop on every core) answers the same request from the
    # store: same plan, bit for bit, within 5 s of its service coming up. A stored plan waits neither for
    # the electrode design nor for the distance field, which the restarted node prepares meanwhile.
    with busy_cores():
        node_processes.start("trajectory_planner", params=planner_params)
        _wait_for_service(ros, client, PlanChannel, "plan_channel", timeout=300)
        t = time.monotonic()
        again = ros.call(client, PlanChannel, "plan_channel", request, timeout=60)
        elapsed = time.monotonic() - t
        log = node_processes.log("trajectory_planner")
    assert again.success, again.message
    assert again.message.startswith("from the plan store") and again.plan_id == first.plan_id
    np.testing.assert_array_equal([p.positions for p in again.axis_path.points],
                                  [p.positions for p in first.axis_path.points])
    np.testing.assert_array_equal(_pose_array(again.poses), _pose_array(first.poses))
    assert again.metrics.planning_time == first.metrics.planning_time
    assert elapsed < 5.0, f"stored plan answered after {elapsed:.1f} s\n{log}"


@pytest.mark.slow
def test_nodes_with_a_foreign_store_keep_working_and_say_why_plans_are_not_kept(ros, tmp_path, field_cache):
    from rclpy.parameter import Parameter

    from edm_planner.nodes.axis_bridge import AxisBridgeNode
    from edm_planner.nodes.geometry_loader import GeometryLoaderNode
    from edm_planner.nodes.trajectory_planner import TrajectoryPlannerNode

    con = sqlite3.connect(tmp_path / FILE_NAME)
    con.execute("CREATE TABLE cutting_data (tool TEXT, feed REAL)")
    con.commit()
    con.close()
    before = (tmp_path / FILE_NAME).read_bytes()
    store = Parameter("plan_store", value=str(tmp_path))
    ros.add(GeometryLoaderNode(context=ros.context))
    ros.add(TrajectoryPlannerNode(context=ros.context, cli_args=["--ros-args", "-r", "plan_channel:=foreign/plan",
                                                                 "-r", "plan:=foreign/plan_topic"],
                                  parameter_overrides=[store, Parameter("cache_dir", value=field_cache),
                                                       Parameter("unknown_geometry_wait", value=30.0)]))
    ros.add(AxisBridgeNode(context=ros.context, cli_args=["--ros-args", "-r", "execute_plan:=foreign/execute",
                                                          "-r", "plan:=foreign/nothing"],
                           parameter_overrides=[store, Parameter("plan_wait", value=0.2),
                                                Parameter("joint_states_topic", value="")]))
    client = ros.add(Node("foreign_client", context=ros.context))
    res = ros.call(client, PlanChannel, "foreign/plan",
                   PlanChannel.Request(channel=4, electrode_id="rear", electrode=rear_design()), timeout=300)
    assert res.success and res.plan_id, res.message
    assert "not kept in the plan store" in res.message and "another application" in res.message
    done = ros.call(client, ExecutePlan, "foreign/execute",
                    ExecutePlan.Request(plan_id=res.plan_id, channel=4, dry_run=True), timeout=60)
    assert done.error_code.val == ErrorCodeMsg.UNKNOWN_ID and "another application" in done.message
    assert (tmp_path / FILE_NAME).read_bytes() == before
