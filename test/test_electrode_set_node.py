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

from edm_planner.records.store import PlanStore

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
        assert load.success, f"the default blisk loads: {load.message}"
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
    assert not res.success and res.error_code.val == ErrorCode.INFEASIBLE, \
        f"with one electrode allowed the default blisk's channel cannot be machined: {res.message}"
    assert [c.name for c in res.candidates] == ["one electrode"], "only the one-electrode candidate is tried"
    (c,) = res.candidates
    assert c.status == "infeasible" and "no certified path" in c.reason, \
        f"the single electrode has no certified path, and the answer says so: {c.status}: {c.reason}"
    assert "one electrode: infeasible" in res.message, f"the message names the candidate and why: {res.message}"
    assert not res.plan_ids and res.set_id, "no plans are delivered, the request still has its set id"


def test_bad_requests(nodes):
    res = plan_set(nodes, channel=60)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "channel" in res.message, \
        f"channel 60 of a 60-blade blisk is refused, naming the channel: {res.message}"
    res = plan_set(nodes, channel=0, geometry_id="f" * 64, timeout=300)
    assert res.error_code.val == ErrorCode.UNKNOWN_ID, f"an unknown geometry id is UNKNOWN_ID: {res.message}"
    res = plan_set(nodes, channel=0, tolerance=0.2)            # not below the 0.1 mm gap
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "tolerance" in res.message, \
        f"a tolerance not below the discharge gap is refused, naming the tolerance: {res.message}"


#: the default blisk's set as measured (issue 23, with the corner rounding computed from the walls): front/rear
#: chosen; share beyond the rounding suction 0.83 %, pressure 0.30 %, hub 0.01 %, shroud 0.49 % (at most 1 %
#: allowed); overcut at most 0.0133 mm (pressure); the strict shares 1.16 / 0.57 / 1.23 / 1.39 %
SURFACES = ("suction", "pressure", "hub", "shroud")


@pytest.mark.slow
def test_the_set_is_designed_stored_and_answered_again_from_the_store(nodes, default_geometry):
    t0 = time.monotonic()
    first = plan_set(nodes, channel=2)
    # the default blisk's set machines the channel to the tolerance: front/rear, accepted on the share beyond
    # the corner rounding (measured: the largest, the suction wall's, is 0.83 % of 1 % allowed)
    assert first.success and first.error_code.val == ErrorCode.SUCCESS, \
        f"the default blisk's set machines the channel to the tolerance: {first.message}"
    assert [(c.name, c.status) for c in first.candidates] == [
        ("one electrode", "infeasible"), ("front/rear", "chosen"), ("left/right", "infeasible"),
        ("three axial pieces", "not tried"), ("front/rear x left/right", "not tried"),
        ("four axial pieces", "not tried"), ("five axial pieces", "not tried")], \
        f"one electrode and left/right have no certified path, front/rear is chosen, three pieces are not needed: " \
        f"{[(c.name, c.status, c.reason[:100]) for c in first.candidates]}"
    (chosen,) = [c for c in first.candidates if c.status == "chosen"]
    labels, regimes = list(first.electrode_labels), list(first.electrode_regimes)
    finishing = [lab for lab, r in zip(labels, regimes) if r == "finish"]
    twins = [lab for lab, r in zip(labels, regimes) if r == "rough"]
    assert finishing == ["front", "rear"] and len(first.plan_ids) == len(labels) == len(regimes), \
        f"the front electrode first, then the rear: {labels}"
    assert regimes == sorted(regimes, key=lambda r: r != "rough"), f"roughing twins are machined first: {regimes}"
    # the front electrode is too thin at the hub (h 0.055 rad) for a twin 0.25 mm smaller per side; the rear has one
    assert twins == ["rough-rear"], f"the rear electrode's roughing twin: {labels}"
    assert "machines the channel to 0.02 mm" in chosen.reason, chosen.reason
    assert all(c.status != "not tried" or "machines the channel" in c.reason for c in first.candidates), \
        "a candidate is left untried only because a smaller set machines the channel"

    # the acceptance figure as stored with the set (set.json's content): the chosen candidate's share beyond
    # the corner rounding, per wall, within the 1 % allowed, the corner rounding from the walls' geometry
    store = PlanStore(str(nodes[3]))
    seq = store.get_sequence(first.set_id)
    assert seq is not None, f"the set is kept in the plan store: {first.message[-400:]}"
    meta = seq.meta
    assert meta["meets_tolerance"] is True and meta["chosen"] == "front/rear", \
        "set.json's meets_tolerance is the acceptance (the share beyond the corner rounding), and it holds"
    (stored,) = [c for c in meta["candidates"] if c["name"] == "front/rear"]
    proof = stored["removal"]
    beyond = {s: proof["surfaces"][s]["area_fraction_beyond_inherent"] for s in SURFACES}
    strict = {s: proof["surfaces"][s]["area_fraction_above_tolerance"] for s in SURFACES}
    assert max(beyond.values()) <= 0.01, f"every wall within 1 % beyond the corner rounding: {beyond}"
    assert 0.006 < beyond["suction"] < 0.01, \
        f"the suction wall's share is the measured 0.83 % (its axial end strips and the front/rear seam): {beyond}"
    assert proof["every_sample_within_tolerance"] is False and max(strict.values()) > 0.01, \
        f"the strict figure (sharp corners) is not met: the corner rounding alone exceeds the tolerance: {strict}"
    assert "corner rounding of the walls' own geometry" in proof["accuracy"]["inherent_reference"], \
        "the inherent stock is computed from the walls, not by the electrode design code"
    inherent = {s: proof["surfaces"][s]["inherent_stock_max_mm"] for s in SURFACES}
    assert all(0.041 < v < 0.07 for v in inherent.values()), \
        f"the rounding g (1/sin(phi/2) - 1) of corners of 70 to 90 deg (0.062 / 0.065 mm measured): {inherent}"

    # overcut: within the tolerance, and as the certified cycles bound it independently of the proof: every
    # electrode vertex stays at least the machining margin from the final walls over the whole cycle, so the
    # eroded surface reaches at most gap - margin inside them (mesh faces between vertices: 2 um more at most)
    gap = default_geometry.design.discharge_gap
    assert len(chosen.overcut_max) == 4
    overcut = max(chosen.overcut_max)
    metrics = [m for m, r in zip(first.metrics, regimes) if r == "finish"]
    for m in metrics:
        assert m.certified and m.cycle_certified and len(m.stock_max_exact) == 4, \
            "every delivered plan and its whole cycle are certified, with the set's proof"
        assert m.machining_margin == pytest.approx(gap - 0.02), "the cycles are certified with gap - tolerance"
    for m in [m for m, r in zip(first.metrics, regimes) if r == "rough"]:
        # the twin: offset 0.25 + 0.1 mm from the walls, its process legs certified with that less the tolerance
        assert m.certified and m.cycle_certified and m.machining_margin == pytest.approx(0.35 - 0.02)
        assert min(m.clearance_lower_bound_suction, m.clearance_lower_bound_pressure, m.clearance_lower_bound_hub,
                   m.clearance_lower_bound_shroud) >= 0.25 - 0.02, "its feed never erodes into a final surface"
    bound = gap - min(m.machining_margin for m in metrics) + 0.002
    assert overcut <= bound, f"overcut {overcut:.4f} mm beyond what the certified cycles allow ({bound:.4f} mm)"
    assert overcut <= 0.02, f"overcut {overcut:.4f} mm within the 0.02 mm tolerance"
    assert overcut > 0.005, \
        f"the proof sees the cycles use the margin (measured 0.0133 mm; 0 would mean it sees no approach): {overcut}"
    assert [list(m.overcut_max) for m in metrics] == [list(chosen.overcut_max)] * 2, \
        "each finishing electrode's metrics carry the whole set's proof"

    # the process (issue 25): model estimates per electrode, channel and blisk, from config/machine.yaml
    proc = list(first.process)
    assert [e.label for e in proc] == labels and [e.regime for e in proc] == regimes
    assert all(e.condition_code == ("C180" if e.regime == "rough" else "C120") for e in proc)
    for e in proc:
        assert e.removed_volume_lower <= e.removed_volume <= e.removed_volume_upper, e
        rate = 40.0 if e.regime == "rough" else 4.0
        assert e.eroding_time == pytest.approx(60 * e.removed_volume / rate, rel=1e-3, abs=1.0), e
        assert e.wear_volume == pytest.approx(e.removed_volume * (0.03 if e.regime == "rough" else 0.15), rel=1e-3)
        assert e.electrodes_per_channel >= 1 and e.electrodes_per_blisk >= e.electrodes_per_channel
        assert e.electrodes_per_channel >= e.worst_face_wear / e.wear_limit - 1e-9
    assert first.channel_eroding_time == pytest.approx(sum(e.eroding_time for e in proc), abs=5.0)
    assert first.blisk_eroding_time == pytest.approx(60 * first.channel_eroding_time, rel=1e-3)
    # the channel's removed volume against its cavity between the final walls (4 503 mm^3 by quadrature;
    # the estimate also counts the strips ahead of and behind the walls' common extent): within 10 %
    assert 4503 <= first.channel_removed_volume <= 1.1 * 4503, first.channel_removed_volume
    assert stored["process"]["channel"]["cavity_volume_mm3"] == pytest.approx(4503, abs=5)
    allowance = stored["roughing_allowance"]
    assert allowance["uniform"], f"the twin leaves the allowance uniform within its band: {allowance}"
    assert allowance["twin_inset_mm"]["rough-rear"] >= 0.25 - 0.005, "the twin lies 0.25 mm inside, measured"
    assert all(v["smallest_stock_mm"] >= 0.1 - 0.03 for v in allowance["surfaces"].values()), \
        "no overcut by the roughing twin, and never less than the allowance less the band"
    assert stored["roughing_removal"]["discharge_gap_mm"] == [0.25], "the roughing proof erodes with the rough gap"

    assert [pid for pid, _ in seq.steps] == list(first.plan_ids), "the stored set lists the plans in order"
    assert all(ch == 2 for _, ch in seq.steps), "the stored set is for channel 2"
    program = store.get_sequence(first.program_id)
    assert len(program.steps) == 60 * len(first.plan_ids), "the program runs every electrode through 60 channels"
    assert [pid for pid, ch in program.steps[:2]] == [first.plan_ids[0]] * 2, "the first electrode (a twin) first"
    elapsed = time.monotonic() - t0
    again = plan_set(nodes, channel=2)
    assert again.success == first.success and list(again.plan_ids) == list(first.plan_ids), \
        "the same request gets the same set"
    assert again.message.startswith("from the plan store"), f"answered from the store: {again.message[:100]}"
    assert time.monotonic() - t0 - elapsed < 30, "the stored answer takes under 30 s"
