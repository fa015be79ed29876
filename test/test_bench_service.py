"""make bench's service round trips: the bench (no ROS) runs the ROS shell's timing program as a child process
with a deadline and reads its JSON; a hang fails with a message and the child's stacks."""

import os
import sys

import numpy as np
import pytest

from edm_planner.bench.common import poses_near
from edm_planner.bench.service import child_environment, run_json, service_round_trips


def test_a_hung_child_fails_with_its_stacks_and_stderr():
    code = ("import faulthandler, signal, sys, time\n"
            "faulthandler.register(signal.SIGUSR1, all_threads=True)\n"
            "print('bringing the nodes up', file=sys.stderr, flush=True)\n"
            "def waiting_for_dds():\n"
            "    time.sleep(60)\n"
            "waiting_for_dds()\n")
    with pytest.raises(RuntimeError) as info:
        run_json([sys.executable, "-c", code], deadline_s=2)
    message = str(info.value)
    assert "did not finish within 2 s (hung?); killed" in message
    assert "bringing the nodes up" in message                    # its stderr
    assert "in waiting_for_dds" in message                       # its stack, asked for with SIGUSR1


def test_a_failed_child_fails_with_its_stderr_and_the_last_json_line_is_read():
    with pytest.raises(RuntimeError, match=r"exited 3\. Its stderr:\nno geometry"):
        run_json([sys.executable, "-c", "import sys; sys.stderr.write('no geometry'); sys.exit(3)"], deadline_s=60)
    with pytest.raises(RuntimeError, match="printed no JSON object last"):
        run_json([sys.executable, "-c", "print('[1, 2]')"], deadline_s=60)
    code = "print('a log line'); print('{\"check_interference_ms\": 1.5}')"
    assert run_json([sys.executable, "-c", code], deadline_s=60) == {"check_interference_ms": 1.5}


def test_the_child_keeps_dds_local_on_the_bench_domain_unless_told():
    env = child_environment({"PATH": "/bin"})
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert env["ROS_DOMAIN_ID"] == str(101 - os.getpid() % 50)
    told = child_environment({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_DOMAIN_ID": "7"})
    assert (told["ROS_AUTOMATIC_DISCOVERY_RANGE"], told["ROS_DOMAIN_ID"]) == ("SUBNET", "7")


def test_the_offsets_give_the_benchs_poses_bit_for_bit():
    from edm_planner.nodes.programs.service_bench import poses_about

    final = poses_near(np.eye(4), 1, seed=5, spread=3.0)[0]       # any rigid pose
    final[:3, 3] += (120.0, -40.0, 15.0)
    assert np.array_equal(poses_about(final, poses_near(np.eye(4), 50)), poses_near(final, 50))


@pytest.mark.slow
def test_the_round_trips_are_timed_over_dds_in_a_child():
    trips = service_round_trips(offsets=poses_near(np.eye(4), 20), load_geometry="default_blisk.yaml", repeat=2,
                                deadline_s=300)
    assert set(trips) == {"check_interference_ms", "check_interference_poses", "load_geometry_ms"}
    assert trips["check_interference_poses"] == 20
    assert 0 < trips["check_interference_ms"] < 60e3 and 0 < trips["load_geometry_ms"] < 60e3
