"""Faults (issue 15): each node killed with SIGKILL while busy, and command lines and a node writing one store.

What is shown, each time: no stored plan lost or changed (the store's rows compared bit for bit before
and after), the survivors and the restarted node recover (the latched geometry is received again), and
a client waiting on a service whose server died finds out instead of waiting for ever. Killed writers and
a full disk: ``test_faults_store.py``.
"""

import os
import pathlib
import shutil
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from edm_planner_msgs.msg import PlanProgress
from edm_planner_msgs.srv import CheckInterference, ExecutePlan, LoadGeometry, PlanChannel
from rclpy.node import Node

from edm_planner.nodes.geometry_loader import config_directory
from edm_planner.nodes.programs.crash_drill import cpu_seconds

from test_faults_records import store_rows
from test_trajectory_planner_node import rear_design


# -- helpers -----------------------------------------------------------------------------------

def send(client, request):
    """Send a request; (future, event set when it completes)."""
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    return future, done


def wait_busy(pid, done, cpu, timeout=300.0):
    """Wait until the server process has worked ``cpu`` seconds on the request sent just before.

    The readiness signal that it is busy with it; fails if the answer came first.
    """
    start, deadline = cpu_seconds(pid), time.monotonic() + timeout
    while True:
        now = cpu_seconds(pid)
        assert start is not None and now is not None, f"process {pid} ended before it was seen busy"
        if now - start >= cpu:
            break
        assert not done.is_set(), "the request was answered before the node was seen busy with it"
        assert time.monotonic() < deadline, f"process {pid} not busy after {timeout} s"
        time.sleep(0.01)
    assert not done.is_set()


def kill9(procs, name):
    """SIGKILL a node process (its whole process group) and reap it."""
    proc, log = procs.procs[name]
    os.killpg(proc.pid, signal.SIGKILL)
    assert proc.wait(timeout=30) == -signal.SIGKILL
    log.close()


def wait_service_gone(client, done, timeout=120.0):
    """A client's view of a server that died: the service leaves the ROS graph, the request stays unanswered.

    Returns the seconds it took (DDS notices a killed participant when its lease runs out).
    """
    t, deadline = time.monotonic(), time.monotonic() + timeout
    while client.service_is_ready():
        assert time.monotonic() < deadline, f"{client.srv_name} still in the graph {timeout} s after its server died"
        time.sleep(0.1)
    assert not done.is_set()
    return time.monotonic() - t


def wait_service(client, timeout=120.0):
    assert client.wait_for_service(timeout_sec=timeout), f"{client.srv_name} not up after {timeout} s"


def answered(client, request, timeout=300.0):
    future, done = send(client, request)
    assert done.wait(timeout), f"{client.srv_name} did not answer within {timeout} s"
    return future.result()


def axis_path(res):
    return np.array([p.positions for p in res.axis_path.points])


# -- one cell: the four nodes as processes, one plan store ---------------------------------------

class Cell:
    def __init__(self, procs, ros, store, field_cache):
        self.procs, self.ros, self.store = procs, ros, str(store)
        self.copy_dir = pathlib.Path(store).parent / "geometries"
        self.copy_dir.mkdir()
        shutil.copy(config_directory() / "default_blisk.yaml", self.copy_dir)
        self.params = {
            "geometry_loader": {"allowed_directories": f"[{config_directory()},{self.copy_dir}]"},
            "interference_checker": {"cache_dir": field_cache},
            "trajectory_planner": {"plan_store": self.store, "cache_dir": field_cache,
                                   "unknown_geometry_wait": 120.0, "geometry_wait": 600.0},   # a field built first
            "axis_bridge": {"plan_store": self.store, "joint_states_topic": "''", "plan_wait": 1.0},
        }
        self.node = ros.add(Node("fault_client", context=ros.context))
        self.clients = {"plan_channel": self.node.create_client(PlanChannel, "plan_channel"),
                        "execute_plan": self.node.create_client(ExecutePlan, "execute_plan"),
                        "check_interference": self.node.create_client(CheckInterference, "check_interference"),
                        "load_geometry": self.node.create_client(LoadGeometry, "load_geometry")}
        self.progress = []
        self.node.create_subscription(PlanProgress, "plan_progress", self.progress.append, 100)

    def start(self, name):
        self.procs.start(name, params=self.params[name])
        return self.procs.procs[name][0].pid

    def restart(self, name, service):
        """Start ``name`` again and wait until this test's client is matched with its new server alone.

        A killed server stays in the graph until DDS notices (its lease, 5 s), and a request sent meanwhile
        reaches only the dead one: so wait for one more server than the fewest seen since the start (the dead
        one may leave before or after the new one comes). A server in the graph is not yet matched with the
        client's request writer, and a request written before that is lost (services are volatile; seen once
        on a fresh clone, the planner's request): so wait until the dead one has left too, and the client sees a server.
        """
        fewest = self.node.count_services(service)
        self.start(name)
        deadline = time.monotonic() + 120
        while (n := self.node.count_services(service)) <= fewest:
            fewest = min(fewest, n)
            assert time.monotonic() < deadline, f"{name} not in the graph again after 120 s"
            time.sleep(0.01)
        client = self.clients.get(service.lstrip("/"))
        while self.node.count_services(service) > 1 or (client is not None and not client.service_is_ready()):
            assert time.monotonic() < deadline, f"{name}: the killed server still in the graph after 120 s"
            time.sleep(0.01)

    def pid(self, name):
        return self.procs.procs[name][0].pid

    def log(self, name):
        return self.procs.log(name)


@pytest.fixture(scope="module")
def cell(tmp_path_factory, field_cache):
    from ros_harness import InProcessRos, NodeProcesses

    base = tmp_path_factory.mktemp("faults")
    procs = NodeProcesses(base / "logs")
    ros = InProcessRos()
    try:
        c = Cell(procs, ros, base / "store", field_cache)
        for name in ("geometry_loader", "interference_checker", "trajectory_planner", "axis_bridge"):
            c.start(name)
        for client in c.clients.values():
            wait_service(client)
        c.first_request = PlanChannel.Request(channel=0, electrode_id="rear", electrode=rear_design())
        loaded = answered(c.clients["load_geometry"], LoadGeometry.Request(path="default_blisk.yaml"))
        assert loaded.success, loaded.message
        c.geometry_id = loaded.geometry_id
        c.first = answered(c.clients["plan_channel"], c.first_request, timeout=900.0)   # may wait for the field
        assert c.first.success, c.first.message + c.log("trajectory_planner")
        c.other_request = PlanChannel.Request(channel=3, electrode_id="rear", electrode=rear_design())
        other = answered(c.clients["plan_channel"], c.other_request)
        assert other.success, other.message
        yield c
        procs.stop()
        # no dead server of this module left in the graph for the next test file of this worker's domain
        deadline = time.monotonic() + 60
        while any(c.node.count_services(s) for s in ("/plan_channel", "/execute_plan", "/check_interference",
                                                       "/load_geometry")) and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        procs.stop()
        ros.close()


# -- kill -9 of each node while it is busy ---------------------------------------------------------

@pytest.mark.slow
def test_the_loader_killed_while_loading_comes_back_and_the_others_keep_serving(cell):
    before = store_rows(cell.store)
    # killed while loading a geometry whose electrode it must design (0.9-1.2 s of CPU on a Zen 3; the
    # default blisk again takes 0.3 s at most, its electrode from the cache, and was once answered first):
    # a discharge gap of its own, so neither the loader's memory nor the electrode cache holds it (it is
    # never finished, so never kept)
    text = (config_directory() / "default_blisk.yaml").read_text() + "\nelectrode:\n  discharge_gap: 0.0617\n"
    future, done = send(cell.clients["load_geometry"], LoadGeometry.Request(yaml_text=text))
    wait_busy(cell.pid("geometry_loader"), done, cpu=0.3)
    kill9(cell.procs, "geometry_loader")
    # the others keep their geometry while the loader is gone
    stored = answered(cell.clients["plan_channel"], cell.first_request)
    assert stored.message.startswith("from the plan store") and stored.plan_id == cell.first.plan_id
    cell.restart("geometry_loader", "/load_geometry")
    # the default blisk from a second directory: loaded anew (the loader's memory is per directory), the same
    # geometry id (its content), so the others have nothing new to prepare
    request = LoadGeometry.Request(path=str(cell.copy_dir / "default_blisk.yaml"))
    res = answered(cell.clients["load_geometry"], request)
    assert res.success, res.message
    assert res.geometry_id == cell.geometry_id
    assert store_rows(cell.store) == before
    assert not future.done()


@pytest.mark.slow
def test_two_cli_processes_and_the_planner_write_one_store_at_once(cell, field_cache, tmp_path):
    from edm_planner.records.store import PlanStore

    before = store_rows(cell.store)
    rear = ["--electrode", "rear", "--split", "front_rear", "--circumferential-reduction", "0.03",
            "--radial-reduction", "3.0", "--split-overlap", "1.0"]
    logs = [tmp_path / f"cli{k}.log" for k in (7, 8)]
    clis = [subprocess.Popen([os.path.join(sys.prefix, "bin", "edm-plan"), "plan", "--geometry",
                              str(config_directory() / "default_blisk.yaml"), "--channel", str(k), "--cache-dir",
                              field_cache, "--store", cell.store, "--progress", "lines", "--out",
                              str(tmp_path / f"cli{k}"), *rear], stdout=open(log, "w"), stderr=subprocess.STDOUT)
            for k, log in zip((7, 8), logs)]
    # all three plan at once: the node's request goes out when both command lines are searching
    deadline = time.monotonic() + 300
    while not all(" search " in log.read_text() for log in logs):
        assert time.monotonic() < deadline and all(p.poll() is None for p in clis), [x.read_text() for x in logs]
        time.sleep(0.01)
    node = answered(cell.clients["plan_channel"],
                    PlanChannel.Request(channel=9, electrode_id="rear", electrode=rear_design()))
    for p in clis:
        p.wait(timeout=300)
    outputs = [log.read_text() for log in logs]
    assert [p.returncode for p in clis] == [0, 0], outputs
    assert all("kept in the plan store" in out for out in outputs), outputs
    assert node.success, node.message
    after = store_rows(cell.store)
    assert {k: after[0][k] for k in before[0]} == before[0]                   # the earlier rows, bit for bit
    new = set(after[0]) - set(before[0])
    store = PlanStore(cell.store)
    assert len(new) == 3 and sorted(store.get(p).channel for p in new) == [7, 8, 9]
    assert node.plan_id in new
    np.testing.assert_array_equal(store.get(node.plan_id).samples, axis_path(node))


@pytest.mark.slow
def test_the_planner_killed_while_planning_loses_no_plan_and_plans_again_after_a_restart(cell):
    before = store_rows(cell.store)
    assert cell.first.plan_id in before[0]
    request = PlanChannel.Request(channel=5, electrode_id="rear", electrode=rear_design())
    future, done = send(cell.clients["plan_channel"], request)
    # busy: its progress reports of this request's search
    deadline = time.monotonic() + 300
    while not any(p.request_id.endswith("/5/rear") and p.stage == "search" for p in list(cell.progress)):
        assert not done.is_set() and time.monotonic() < deadline, "no search progress seen"
        time.sleep(0.01)
    kill9(cell.procs, "trajectory_planner")
    assert not done.is_set()

    cell.restart("trajectory_planner", "/plan_channel")
    assert store_rows(cell.store) == before                         # nothing lost, nothing changed
    # the restarted planner receives the latched geometry again: a request naming no geometry is planned
    again = answered(cell.clients["plan_channel"], request)
    assert again.success, again.message + cell.log("trajectory_planner")
    assert not again.message.startswith("from the plan store")     # the killed request had stored nothing
    first = answered(cell.clients["plan_channel"], cell.first_request)
    assert first.message.startswith("from the plan store") and first.plan_id == cell.first.plan_id
    np.testing.assert_array_equal(axis_path(first), axis_path(cell.first))
    after = store_rows(cell.store)
    assert {k: after[0][k] for k in before[0]} == before[0] and set(after[0]) - set(before[0]) == {again.plan_id}
    assert not future.done()                     # the request sent to the killed planner: never answered


@pytest.mark.slow
def test_the_checker_killed_while_checking_recovers_with_the_latched_geometry(cell):
    poses = list(cell.first.poses.poses)
    exact = CheckInterference.Request(channel=0, electrode_id="rear", electrode=rear_design(),
                                      method=CheckInterference.Request.METHOD_EXACT, poses=poses * 4)
    future, done = send(cell.clients["check_interference"], exact)
    wait_busy(cell.pid("interference_checker"), done, cpu=1.0)
    kill9(cell.procs, "interference_checker")
    cell.restart("interference_checker", "/check_interference")
    fast = CheckInterference.Request(channel=0, electrode_id="rear", electrode=rear_design(),
                                     method=CheckInterference.Request.METHOD_FAST, poses=poses)
    deadline = time.monotonic() + 300
    while True:                           # until the restarted checker has received the latched geometry
        res = answered(cell.clients["check_interference"], fast)
        if res.error_code.val == 0 or "unknown geometry" not in res.message or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert res.error_code.val == 0, res.message
    assert len(res.clearances) == len(poses) and min(c.minimum for c in res.clearances) > 0
    assert not future.done()


@pytest.mark.slow
def test_a_pending_execute_plan_of_a_killed_bridge_is_detected_and_a_restarted_bridge_answers_it(cell):
    from edm_planner.nodes.programs.bringup import Bringup
    from edm_planner.nodes.programs.demo_steps import _call

    # the latched plan is another one (answered from the store, published again); a bridge of its own (a
    # cell controller's bring-up, as make demo's) reads the first plan from the store, then times it: killed
    # while it times
    other = answered(cell.clients["plan_channel"], cell.other_request)
    assert other.success and other.plan_id != cell.first.plan_id
    before = store_rows(cell.store)
    cell.procs.stop("axis_bridge")
    request = ExecutePlan.Request(plan_id=cell.first.plan_id, channel=0, dry_run=True)
    # the kill must come while the bridge times the plan; on a loaded machine this thread may see the log line
    # only after the answer went out (seen once on a new clone): that attempt tests nothing, so another is made
    for attempt in range(1, 4):
        gone_by = time.monotonic() + 120
        while cell.node.count_services("/execute_plan"):  # the last one stopped or killed has left the graph
            assert time.monotonic() < gone_by, "the stopped bridge's service is still in the graph"
            time.sleep(0.01)
        bringup = Bringup(cell.procs.log_dir / f"demo_bridge_{attempt}", {"axis_bridge": cell.params["axis_bridge"]})
        bringup.start(("axis_bridge",))
        try:
            wait_service(cell.clients["execute_plan"])
            outcome = {}

            def demo_call():
                try:
                    outcome["response"] = _call(cell.node, ExecutePlan, "execute_plan", request, 300, bringup)
                except Exception as exc:  # what make demo would report
                    outcome["error"] = exc

            caller = threading.Thread(target=demo_call)
            caller.start()
            future, done = send(cell.clients["execute_plan"], request)
            log = bringup.log_dir / "axis_bridge.log"
            deadline = time.monotonic() + 300
            while "read from the plan store" not in log.read_text() and not done.is_set():
                assert time.monotonic() < deadline, log.read_text()
                time.sleep(0.005)
            proc = bringup.procs["axis_bridge"][0]
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
            caller.join(timeout=60)
            if "response" in outcome or done.is_set():
                answer = future.result() if done.is_set() else outcome["response"]
                assert answer.success, answer.message        # answered first, then rightly
                print(f"attempt {attempt}: the bridge answered before it was killed; again")
                continue
            # make demo's client names the dead node at once
            assert "node axis_bridge exited with -9" in str(outcome.get("error")), outcome
            # a plain client (one that did not start the node) sees the service leave the graph, unanswered
            gone_after = wait_service_gone(cell.clients["execute_plan"], done)
            print(f"ExecutePlan's server left the graph {gone_after:.1f} s after kill -9")
            # within our DDS profile's lease (5 s; Fast DDS's own is 20 s), with room for a loaded machine
            assert gone_after < 15.0, f"the dead server stayed {gone_after:.1f} s in the graph: the profile's lease?"
            break
        finally:
            bringup.stop()
    else:
        pytest.fail("in all three attempts the bridge answered before it was killed: the pending call was never tested")
    assert store_rows(cell.store) == before
    cell.restart("axis_bridge", "/execute_plan")
    res = answered(cell.clients["execute_plan"], request)
    assert res.success, res.message
    assert res.duration > 1.0 and res.point_count > 100
