"""Test configuration: loopback DDS and a ROS domain of this run's own."""

import os
import pathlib
import sys

import pytest

# Before anything initialises rclpy: keep DDS on this machine and away from
# other test runs (a domain from the process id, unless the caller set one).
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
REPO = pathlib.Path(__file__).resolve().parent.parent
CONFIG = REPO / "config"


@pytest.fixture
def ros():
    """Nodes in-process on a private context; see ros_harness.InProcessRos."""
    from ros_harness import InProcessRos

    harness = InProcessRos()
    try:
        yield harness
    finally:
        harness.close()


@pytest.fixture
def node_processes(tmp_path):
    """Nodes as OS processes; stopped (SIGINT, then SIGKILL) at teardown."""
    from ros_harness import NodeProcesses

    procs = NodeProcesses(tmp_path / "logs")
    try:
        yield procs
    finally:
        procs.stop()


@pytest.fixture(scope="session")
def field_cache(tmp_path_factory):
    """One distance-field cache directory for the whole run: each geometry's field is built once."""
    return str(tmp_path_factory.mktemp("field_cache"))


@pytest.fixture(scope="session", autouse=True)
def plan_store_of_this_run(tmp_path_factory):
    """Nodes and the CLI keep plans in a store of this run, not in the user's (EDM_PLANNER_PLAN_STORE)."""
    path = str(tmp_path_factory.mktemp("plan_store"))
    os.environ["EDM_PLANNER_PLAN_STORE"] = path
    return path
