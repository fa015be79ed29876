"""DDS that survives crashes and concurrent starts (issue 23): loopback UDP, never shared memory.

The drill (edm_planner/nodes/programs/crash_drill.py) starts four sets of the four nodes at once, kills one
node of each set with SIGKILL while it is busy, starts the killed ones again, twice, then starts a new set:
every node alive at the end must answer over DDS within the deadline, and a node that does not is reported
with its stacks. The decision table of the DDS set-up is tested on its own, without processes.
"""

import logging
import os
import pathlib

import pytest

from edm_planner.ros import dds
from edm_planner.nodes.programs.crash_drill import NODES, run, udp_local_addresses

OURS = str(dds.profile_path())


def shm_segments():
    """Fast DDS's shared-memory files (ports, their locks, data sharing) in /dev/shm."""
    return {p.name for p in pathlib.Path("/dev/shm").iterdir() if "fastrtps" in p.name or "fast_datasharing" in p.name}


# -- the set-up's decision, per environment ------------------------------------------------------------

def test_localhost_discovery_becomes_the_loopback_udp_profile():
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    assert dds.use_loopback_udp(env) == "loopback-udp"
    # Fast DDS reads the profile (2.x and 3.x names); rmw_fastrtps must not replace its transports
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == env["FASTDDS_DEFAULT_PROFILES_FILE"] == OURS
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    # a child inherits the switched environment and keeps it as it is
    child = dict(env)
    assert dds.use_loopback_udp(child) == "loopback-udp" and child == env
    # the older switch means the same
    old = {"ROS_LOCALHOST_ONLY": "1"}
    assert dds.use_loopback_udp(old) == "loopback-udp" and "ROS_LOCALHOST_ONLY" not in old


def test_a_child_told_localhost_again_is_switched_again():
    # what the test harness and the demo do: they set LOCALHOST in the child's environment on top of ours
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": OURS}
    assert dds.use_loopback_udp(env) == "loopback-udp" and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"


def test_the_same_profile_of_another_install_is_ours(tmp_path):
    # a colcon workspace's node started from a process of the source tree inherits the source tree's path
    other = tmp_path / "install" / dds.PROFILE_NAME
    other.parent.mkdir()
    other.write_bytes(pathlib.Path(OURS).read_bytes())
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": str(other)}
    assert dds.use_loopback_udp(env) == "loopback-udp", "our own profile at another path taken for the user's"
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    # a file of that name with other content is the user's
    other.write_text("<dds/>")
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": str(other)}
    assert dds.use_loopback_udp(env).startswith("stock:")


@pytest.mark.parametrize("env, why", [
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, "beyond this machine"),
    ({}, "beyond this machine"),                                      # Jazzy's default range is SUBNET
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, "middleware"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "EDM_PLANNER_DDS": "stock"}, "EDM_PLANNER_DDS"),
])
def test_other_choices_of_the_user_are_left_alone(env, why):
    before = dict(env)
    result = dds.use_loopback_udp(env)
    assert result.startswith("stock:") and why in result, result
    assert env == before, "the environment was changed although the user chose otherwise"


def test_a_profile_of_the_users_own_is_kept_with_a_warning(tmp_path, caplog):
    own = tmp_path / "own.xml"
    own.write_text("<dds/>")
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": str(own)}
    with caplog.at_level(logging.WARNING):
        assert dds.use_loopback_udp(env) == "stock: the user's own Fast DDS profile"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(own) and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert "shared memory" in caplog.text


def test_this_test_process_runs_dds_on_loopback_udp():
    """conftest switched the test process itself (its in-process nodes and clients) before any rclpy.init."""
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    assert os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == OURS


def test_in_process_nodes_bind_udp_to_loopback_only_and_create_no_shared_memory(ros):
    from rclpy.node import Node
    from std_srvs.srv import Trigger

    before = shm_segments()
    server = ros.add(Node("loopback_probe_server", context=ros.context))
    server.create_service(Trigger, "loopback_probe", lambda req, res: (setattr(res, "success", True), res)[1])
    client = ros.add(Node("loopback_probe_client", context=ros.context))
    res = ros.call(client, Trigger, "loopback_probe", Trigger.Request(), timeout=60)
    assert res.success, "a service call over the loopback profile was not answered"
    addresses = udp_local_addresses(os.getpid())
    assert addresses == {"127.0.0.1"}, f"DDS sockets bound beyond loopback: {addresses}"
    assert shm_segments() <= before, f"shared-memory segments created: {shm_segments() - before}"


# -- the drill: crashes and concurrent starts -----------------------------------------------------------

@pytest.mark.slow
def test_every_node_answers_after_concurrent_starts_and_kills_while_busy(tmp_path, field_cache):
    before = shm_segments()
    report = run(sets=4, rounds=2, deadline=180.0, log_dir=tmp_path / "drill", field_cache=field_cache,
                 progress=lambda m: None)
    # the claim: no node hangs, whatever was killed around it
    assert not report["hung"], "nodes that did not answer within 180 s:\n" + "\n".join(
        f"--- {name} ---\n{stacks}" for name, stacks in report["hung"].items())
    assert not report["dead"], f"nodes that exited by themselves: {report['dead']}"
    # every node alive at the end answered: 4 sets and the new one, four nodes each
    assert len(report["answer_s"]) == 5 * len(NODES), report["answer_s"]
    # the kills happened while the nodes worked, 4 per round: CPU time seen rising, and a loader before the answer
    # to the load it was killed in came back
    assert len(report["kills"]) == 8 and all(k["busy_seen"] for k in report["kills"]), report["kills"]
    assert {k["node"].split("/")[1] for k in report["kills"]} == set(NODES)
    # on loopback, and no Fast DDS shared memory anywhere in it
    assert report["udp_bound_to"] == ["127.0.0.1"], report["udp_bound_to"]
    assert shm_segments() <= before, f"shared-memory segments created: {shm_segments() - before}"
