"""PlanElectrodeSet over DDS against node processes (geometry_loader, trajectory_planner).

The default blisk has no `electrode:` section: the planner designs its set.
With one electrode allowed the only candidate (the primitive electrode) is
infeasible and the answer says why, candidate by candidate; the whole set is
designed once per module and then answered from the plan store, bit for bit.
"""

import time

import pytest
from edm_planner_msgs.msg import ErrorCode
from edm_planner_msgs.srv import LoadGeometry, PlanElectrodeSet

from edm_planner.planning.store import PlanStore

from conftest import CONFIG


@pytest.fixture(scope="module")
def nodes(tmp_path_factory, field_cache):
    from ros_harness import InProcessRos, NodeProcesses

    store = tmp_path_factory.mktemp("set_store")
    procs = NodeProcesses(tmp_path_factory.mktemp("set_logs"))
    ros = None
    try:
        # the loader reads only its allowed directories: the repository's config is made one of them
        procs.start("geometry_loader", params={"geometry_file": str(CONFIG / "default_blisk.yaml"),
                                               "allowed_directories": f"['{CONFIG}']"})
        procs.start("trajectory_planner", params={"cache_dir": field_cache, "plan_store": str(store),
                                                  "unknown_geometry_wait": 30.0})
        ros = InProcessRos()
        from rclpy.node import Node
        client = ros.add(Node("set_client", context=ros.context))
        load = ros.call(client, LoadGeometry, "load_geometry",
                        LoadGeometry.Request(path=str(CONFIG / "default_blisk.yaml")), timeout=300)
        assert load.success, load.message
        yield ros, client, load.geometry_id, store, procs
    finally:
        if ros is not None:
            ros.close()
        procs.stop()


def plan_set(nodes, timeout=1800, **fields):
    ros, client, gid = nodes[:3]
    req = PlanElectrodeSet.Request(geometry_id=fields.pop("geometry_id", gid), **fields)
    return ros.call(client, PlanElectrodeSet, "plan_electrode_set", req, timeout=timeout)


def test_one_electrode_is_not_enough_and_the_answer_says_why(nodes):
    res = plan_set(nodes, channel=0, max_electrodes=1)
    assert not res.success
    assert res.error_code.val == ErrorCode.INFEASIBLE
    assert [c.name for c in res.candidates] == ["one electrode"]
    (c,) = res.candidates
    assert c.status == "infeasible" and "no certified path" in c.reason
    assert "one electrode: infeasible" in res.message
    assert not res.plan_ids and res.set_id


def test_bad_requests(nodes):
    res = plan_set(nodes, channel=60)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "channel" in res.message
    res = plan_set(nodes, channel=0, geometry_id="f" * 64, timeout=300)
    assert res.error_code.val == ErrorCode.UNKNOWN_ID
    res = plan_set(nodes, channel=0, tolerance=0.2)            # not below the 0.1 mm gap
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "tolerance" in res.message


@pytest.mark.slow
def test_the_set_is_designed_stored_and_answered_again_from_the_store(nodes):
    t0 = time.monotonic()
    first = plan_set(nodes, channel=2)
    # the set machines the channel to the tolerance (SUCCESS), or the closest certified set is delivered flagged
    assert first.plan_ids, first.message
    assert len(first.plan_ids) == len(first.electrode_labels) >= 2
    chosen = [c for c in first.candidates if c.status == "chosen"]
    if first.success:
        assert first.error_code.val == ErrorCode.SUCCESS
        assert len(chosen) == 1 and chosen[0].electrode_count == len(first.plan_ids)
    else:
        assert first.error_code.val == ErrorCode.INFEASIBLE and not chosen
        assert "leaves the least stock" in first.message
    assert all(c.status != "not tried" or "machines the channel" in c.reason for c in first.candidates)
    proven = [c for c in first.candidates if c.stock_max_exact]
    assert proven and all(len(c.stock_max_exact) == 4 and max(c.overcut_max) >= 0 for c in proven)
    for m in first.metrics:
        assert m.certified and m.cycle_certified and len(m.stock_max_exact) == 4
    store = PlanStore(str(nodes[3]))
    seq = store.get_sequence(first.set_id)
    assert [pid for pid, _ in seq.steps] == list(first.plan_ids)
    assert all(ch == 2 for _, ch in seq.steps)
    program = store.get_sequence(first.program_id)
    assert len(program.steps) == 60 * len(first.plan_ids)
    elapsed = time.monotonic() - t0
    again = plan_set(nodes, channel=2)
    assert again.success == first.success and list(again.plan_ids) == list(first.plan_ids)
    assert again.message.startswith("from the plan store")
    assert time.monotonic() - t0 - elapsed < 30
