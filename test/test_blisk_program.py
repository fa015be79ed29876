"""Cycles and sequences in the plan store, the whole-blisk program's steps, its timing and its NC program.

One real plan with its certified cycle (the rear electrode of the front/rear split, as in
test_machining_cycle) is planned once per module; a second "electrode" for the programs is the same
plan stored under another id and electrode name (the program logic does not care what the electrode is).
"""

import copy
import json
import math
import sqlite3
import zlib
from dataclasses import replace

import numpy as np
import pytest

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.geometry.electrode import ElectrodeDesign
from edm_planner.cnc.config import default_machine_path, load_machine
from edm_planner.cnc.kinematics import axis_poses
from edm_planner.cnc.nc import PHASE_COLUMNS, program_csv
from edm_planner.cnc.post import ProgramRun, parse_nc, write_program
from edm_planner.cnc.trajectory import time_run
from edm_planner.machining.cycle import PHASES
from edm_planner.machining.program import (INDEX, PlanCycle, blisk_program_steps, program_runs, sequence_id_for,
                                           shift_to_channel)
from edm_planner.records.store import PlanStore, PlanStoreError, plan_to_stored, stored_to_plan


GAP, TOLERANCE = 0.1, 0.02
MARGIN = GAP - TOLERANCE
DESIGN = ElectrodeDesign(circumferential_reduction=0.03, radial_reduction=3.0, split="front_rear", split_overlap=1.0)
#: a removal proof as RemovalReport.to_dict() writes it (figures made up; the store keeps them as they are)
REMOVAL = {"every_sample_within_tolerance": True, "tolerance_mm": 0.02, "discharge_gap_mm": [0.1], "stock_max_mm": 0.04,
           "overcut_max_mm": 0.0,
           "surfaces": {s: {"area_mm2": 100.0 + i, "stock_max_mm": 0.01 * (i + 1), "stock_mean_mm": 0.001 * (i + 1),
                            "area_fraction_above_tolerance": 0.001 * i, "overcut_max_mm": 0.0005 * i}
                        for i, s in enumerate(("suction", "pressure", "hub", "shroud"))},
           "accuracy": {"sample_spacing_mm": 0.25, "exact": "at the wall samples", "continuous_bound_mm": 0.011},
           "pose_count": 4633, "distance_queries": 123, "elapsed_s": 8.0}


@pytest.fixture(scope="module")
def rear(rear_cycle):
    g, field, electrode, design, plan, builder = rear_cycle
    assert design == DESIGN
    plan = copy.deepcopy(plan)
    plan.removal, plan.set_id = REMOVAL, "set-of-test"
    return g, electrode, plan


@pytest.fixture(scope="module")
def machine():
    return load_machine(default_machine_path())


def _second(plan):
    """The same plan as a second electrode ("front") under another id."""
    other = replace(plan, plan_id="f" * 16, electrode_id="front")
    return other


# -- the store -----------------------------------------------------------------------------------

def test_a_plan_with_its_cycle_round_trips_bit_for_bit(rear, tmp_path):
    g, electrode, plan = rear
    store = PlanStore(tmp_path)
    store.put(plan_to_stored(plan), "key")
    back = stored_to_plan(store.get(plan.plan_id))
    c0, c1 = plan.cycle, back.cycle
    assert c1 is not None and c1.axis_names == c0.axis_names
    assert [(leg.phase, leg.label) for leg in c1.legs] == [(leg.phase, leg.label) for leg in c0.legs]
    for a, b in zip(c0.legs, c1.legs):
        assert a.samples.tobytes() == b.samples.tobytes()
        np.testing.assert_array_equal(a.clearance_lower_bound, b.clearance_lower_bound)
    assert c1.reach.to_dict() == c0.reach.to_dict() and c1.clear_zone == c0.clear_zone is not None
    assert (c1.margin, c1.certified, c1.message) == (c0.margin, c0.certified, c0.message)
    assert c1.samples.tobytes() == c0.samples.tobytes() and c1.leg_ranges == c0.leg_ranges
    assert c1.phase_ranges == c0.phase_ranges and [p for p, _, _ in c1.phase_ranges] == list(PHASES)
    assert back.removal == REMOVAL and back.set_id == "set-of-test"
    assert back.samples.tobytes() == plan.samples.tobytes()


def test_records_without_a_cycle_still_load(rear, tmp_path):
    """A record as written before cycles existed (no cycle, removal or set id in it) loads with cycle None."""
    g, electrode, plan = rear
    old = replace(plan, cycle=None, removal=None, set_id="")
    stored = plan_to_stored(old)
    for key in ("removal", "set_id", "cycle"):
        stored.meta.pop(key, None)
    store = PlanStore(tmp_path)
    store.put(stored)
    back = stored_to_plan(store.get(plan.plan_id))
    assert back.cycle is None and back.removal is None and back.set_id == ""


def test_sequences_round_trip_and_are_checked(rear, tmp_path):
    g, electrode, plan = rear
    store = PlanStore(tmp_path)
    other = _second(plan)
    store.put(plan_to_stored(plan))
    store.put(plan_to_stored(other))
    steps = blisk_program_steps([plan.plan_id, other.plan_id], 3)
    sid = sequence_id_for("blisk_program", steps, plan.geometry_id)
    assert len(sid) == 16 and sid == sequence_id_for("blisk_program", steps, plan.geometry_id)
    store.put_sequence(sid, "blisk_program", steps, {"blade_count": 3, "labels": ["rear", "front"]})
    store.put_sequence("set1", "electrode_set", [(plan.plan_id, 0), (other.plan_id, 0)], {"channel": 0})
    seq = PlanStore(tmp_path).get_sequence(sid)                  # another opener of the same file
    assert seq.kind == "blisk_program" and seq.geometry_id == plan.geometry_id
    assert seq.steps == steps and seq.meta == {"blade_count": 3, "labels": ["rear", "front"]}
    assert seq.plan_ids == [plan.plan_id, other.plan_id]
    assert store.get_sequence("nope") is None
    assert {r["sequence_id"]: r["kind"] for r in store.list_sequences()} == {sid: "blisk_program",
                                                                          "set1": "electrode_set"}
    assert store.list_sequences(limit=1)[0]["sequence_id"] in (sid, "set1")
    # bad input, named
    with pytest.raises(EdmError) as e:
        store.put_sequence("x", "whole_blisk", steps)
    assert e.value.code == ErrorCode.INVALID_REQUEST and "electrode_set" in e.value.message
    with pytest.raises(EdmError) as e:
        store.put_sequence("x", "electrode_set", [("0000000000000000", 0)])
    assert e.value.code == ErrorCode.UNKNOWN_ID and "0000000000000000" in e.value.message
    with pytest.raises(EdmError) as e:
        store.put_sequence("x", "electrode_set", [])
    assert e.value.code == ErrorCode.INVALID_REQUEST
    # a complete program gives its blade count; a partial one must name it (the index turns depend on it)
    assert store.put_sequence("p", "blisk_program", steps).meta["blade_count"] == 3
    with pytest.raises(EdmError) as e:
        store.put_sequence("x", "blisk_program", steps[:3] + steps[3:5])        # the second electrode stops
    assert e.value.code == ErrorCode.INVALID_REQUEST and "blade_count" in e.value.message
    assert store.put_sequence("x", "blisk_program", steps[:2], {"blade_count": 60}).meta["blade_count"] == 60
    with pytest.raises(EdmError) as e:
        store.put_sequence("x", "blisk_program", steps, {"blade_count": 2})
    assert e.value.code == ErrorCode.INVALID_REQUEST
    # a damaged sequence record is refused, not guessed at
    con = sqlite3.connect(tmp_path / "plans.sqlite")
    with con:
        con.execute("UPDATE sequences SET record = ? WHERE sequence_id = 'set1'",
                    (zlib.compress(json.dumps({"sequence_id": "set1"}).encode()),))
    con.close()
    with pytest.raises(PlanStoreError) as e:
        store.get_sequence("set1")
    assert "corrupt" in e.value.message and e.value.code == ErrorCode.FILE_ERROR


def test_a_store_of_the_first_schema_gains_the_sequences_table(tmp_path):
    """A store written before sequences existed (no sequences table) opens and takes sequences."""
    PlanStore(tmp_path)
    con = sqlite3.connect(tmp_path / "plans.sqlite")
    with con:
        con.execute("DROP TABLE sequences")
    con.close()
    store = PlanStore(tmp_path)
    assert store.list_sequences() == []


# -- program steps and axis values ---------------------------------------------------------------

def test_blisk_program_steps_each_electrode_through_every_channel():
    assert blisk_program_steps(["a", "b"], 3) == [("a", 0), ("a", 1), ("a", 2), ("b", 0), ("b", 1), ("b", 2)]
    assert len(blisk_program_steps(["a", "b", "c"], 60)) == 180
    for bad in (([], 3), (["a", "a"], 3), (["a"], 0), (["a"], 2.5)):
        with pytest.raises(EdmError) as e:
            blisk_program_steps(*bad)
        assert e.value.code == ErrorCode.INVALID_REQUEST


def test_shift_to_channel_and_the_four_axis_refusal():
    q = np.array([[1.0, 2.0, 3.0, 0.1, 0.2]])
    out = shift_to_channel(q, ("X", "Y", "Z", "A", "C"), 2, 5, 0.25)
    np.testing.assert_array_equal(out, [[1.0, 2.0, 3.0, 0.1 + 3 * 0.25, 0.2]])
    four = np.array([[1.0, 2.0, 3.0, 0.2]])
    np.testing.assert_array_equal(shift_to_channel(four, ("X", "Y", "Z", "C"), 4, 4, 0.25), four)
    with pytest.raises(EdmError) as e:
        shift_to_channel(four, ("X", "Y", "Z", "C"), 0, 1, 0.25)
    assert e.value.code == ErrorCode.INVALID_REQUEST and "no A axis" in e.value.message


def test_program_runs_index_at_the_clear_position_and_change_tools(rear):
    g, electrode, plan = rear
    pitch = g.blisk.pitch
    a, b = PlanCycle.of_plan(plan), PlanCycle.of_plan(_second(plan))
    steps = blisk_program_steps([a.plan_id, b.plan_id], 3)
    runs = program_runs(steps, {a.plan_id: a, b.plan_id: b}, pitch)
    assert [r.plan.plan_id for r in runs] == [a.plan_id, b.plan_id] and [r.channels for r in runs] == [[0, 1, 2]] * 2
    ia, ix = plan.axis_names.index("A"), plan.axis_names.index("X")
    cycle_phases = [leg.phase for leg in plan.cycle.legs]
    assert cycle_phases[-2:] == ["retract", "clear"]
    per_channel = len(cycle_phases) + 1                         # the clear leg reversed first
    zone = plan.cycle.clear_zone
    for run in runs:
        phases = [leg.phase for leg in run.legs]
        one = ["clear"] + cycle_phases
        assert phases == one + [INDEX] + one + [INDEX] + one
        for x, y in zip(run.legs[:-1], run.legs[1:]):           # rest to rest, consecutive legs meet
            assert np.array_equal(x.samples[-1], y.samples[0])
        clear = plan.cycle.legs[-1].samples[-1]
        assert clear[ix] == zone.clear_x and run.legs[0].samples[0][ix] == zone.clear_x
        for k, idx in zip((1, 2), (per_channel, 2 * per_channel + 1)):
            leg = run.legs[idx]
            assert leg.channel == k and len(leg.samples) == 2
            # the index turns A only, by one pitch, at the clear position, certified by the clear zone
            np.testing.assert_array_equal(np.delete(leg.samples, ia, axis=1),
                                          np.repeat(np.delete(clear, ia)[None], 2, axis=0))
            assert leg.samples[-1, ia] - leg.samples[0, ia] == pytest.approx(pitch, abs=1e-15)
            np.testing.assert_array_equal(leg.clearance_lower_bound, zone.separation(zone.clear_x))
        # channel k's cycle is channel 0's with A + k pitch: the feed of channel 2 ends at its machining pose
        feed2 = run.legs[2 * per_channel + 2 + 2].samples
        assert run.legs[2 * per_channel + 2 + 2].phase == "feed"
        assert feed2[-1, ia] == pytest.approx(plan.samples[-1, ia] + 2 * pitch, abs=1e-12)
    # at the clear position the electrode is beyond the part's axial envelope by the clearance: every vertex
    pose = axis_poses(plan.final_pose, plan.axis_names, clear[None])[0]
    x = electrode.mesh.vertices @ pose[:3, 0] + pose[0, 3]
    lo, hi = zone.envelope
    assert (x.min() - hi if zone.side > 0 else lo - x.max()) >= zone.separation(zone.clear_x) >= 2.0 - 1e-9
    assert lo <= min(g.blisk.hub.x_range[0], g.blisk.axial_range[0]) and hi >= g.blisk.axial_range[1]
    # a cycle without a clear zone (stored before clear legs) cannot index: refused, not run uncertified
    bare = replace(a, cycle=replace(plan.cycle, clear_zone=None))
    with pytest.raises(EdmError) as e:
        program_runs(blisk_program_steps([a.plan_id], 2), {a.plan_id: bare}, pitch)
    assert e.value.code == ErrorCode.INVALID_REQUEST and "no clear position" in e.value.message
    # a plan without a cycle cannot be part of a program
    with pytest.raises(EdmError) as e:
        program_runs([(a.plan_id, 0)], {a.plan_id: replace(a, cycle=None)}, pitch)
    assert e.value.code == ErrorCode.INVALID_REQUEST and "no machining cycle" in e.value.message
    # nor one whose cycle is not certified (it might overcut): refused with the cycle's reason
    with pytest.raises(EdmError) as e:
        program_runs([(a.plan_id, 0)], {a.plan_id: replace(a, cycle=replace(plan.cycle, certified=False,
                                                                             message="the approach is not certified"))})
    assert e.value.code == ErrorCode.INFEASIBLE and "the approach is not certified" in e.value.message
    with pytest.raises(EdmError) as e:
        program_runs([(a.plan_id, 1)], {a.plan_id: a})
    assert e.value.code == ErrorCode.INVALID_REQUEST and "blade count" in e.value.message
    with pytest.raises(EdmError) as e:
        program_runs([("missing", 0)], {})
    assert e.value.code == ErrorCode.UNKNOWN_ID


def test_the_program_nc_marks_phases_and_tool_changes_and_parses_back(rear, machine, tmp_path):
    g, electrode, plan = rear
    a, b = PlanCycle.of_plan(plan), PlanCycle.of_plan(_second(plan))
    steps = blisk_program_steps([a.plan_id, b.plan_id], 3)
    runs = program_runs(steps, {a.plan_id: a, b.plan_id: b}, g.blisk.pitch)
    cache = {}
    timed = [time_run(r.legs, machine, cache=cache) for r in runs]
    # the cycle legs are timed once: channels 1 and 2 (and the second electrode, same samples) reuse channel 0's
    arrays = timed[0]
    single = time_run(program_runs([(a.plan_id, 0)], {a.plan_id: a})[0].legs, machine)
    n = len(single.times)
    np.testing.assert_array_equal(arrays.times[:n], single.times)
    ia = list(arrays.axis_names).index("A")
    text, stats = write_program([ProgramRun(t, r.label, r.plan.plan_id) for t, r in zip(timed, runs)], "prog",
                                plan.geometry_id, "blisk_program", machine, structure="flat")
    back = parse_nc(text)
    assert back["plan_id"] == "prog" and back["geometry_id"] == plan.geometry_id.lower()
    # one trajectory per electrode, a tool change before each naming the electrode and its plan
    assert [t for t, _, _ in back["tool_changes"]] == [1, 2]
    assert "ELECTRODE 1 OF 2 REAR" in back["tool_changes"][0][2] and "FRONT" in back["tool_changes"][1][2]
    assert len(back["trajectories"]) == 2
    # every leg start is marked, in order, with its channel: 3 cycles and 2 indexes per electrode
    names = [p for p, _, _ in back["phases"]]
    one = ["clear"] + [leg.phase for leg in plan.cycle.legs]
    per_electrode = one + [INDEX] + one + [INDEX] + one
    assert names == per_electrode * 2
    assert [(p, c) for p, c, _ in back["phases"][:len(arrays.phases)]] == [(m.phase, m.channel) for m in arrays.phases]
    # the program's points are timed points (straight legs merged), within the rounding (0.1 um, 1e-4 deg),
    # at their times
    for t, (first, last) in zip(timed, back["trajectories"]):
        p, tt = back["positions"][first:last + 1], back["times"][first:last + 1]
        j = np.searchsorted(t.times, tt - 1e-3)
        j = np.array([k + int(np.argmin(np.abs(t.times[k:k + 3] - x))) for k, x in zip(j, tt)])
        assert j[0] == 0 and j[-1] == len(t.times) - 1 and np.all(np.diff(j) > 0)
        assert np.abs(p[:, :3] - t.positions[j, :3]).max() <= 0.5e-4 + 1e-12
        assert np.abs(p[:, 3:] - t.positions[j, 3:]).max() <= math.radians(0.5e-4) + 1e-15
        np.testing.assert_allclose(tt, t.times[j], rtol=1e-5, atol=1e-4)
    assert stats.blocks < stats.points / 4                       # straight legs are one block each
    # each channel's machining pose (where its process starts): A one pitch further than the channel before
    assert [m.channel for m in arrays.phases if m.phase == "feed"] == [0, 1, 2]
    a_pose = [arrays.positions[m.index, ia] for m in arrays.phases if m.phase == "process"][::len(
        [leg for leg in plan.cycle.legs if leg.phase == "process"])]
    np.testing.assert_allclose(np.diff(a_pose), g.blisk.pitch, atol=1e-12)
    # the CSV: one row per point, phase columns after the numbers
    csv = program_csv(timed)
    rows = csv.splitlines()
    assert rows[0].split(",")[-len(PHASE_COLUMNS):] == PHASE_COLUMNS
    assert len(rows) - 1 == sum(len(t.times) for t in timed)
    import csv as csv_module
    last = next(csv_module.reader([rows[-1]]))
    assert last[-6:-1] == ["clear", "2", "1", "front", "f" * 16]
    # the single plan's NC: its phases, one tool
    text, _ = write_program([ProgramRun(single, "rear", plan.plan_id)], plan.plan_id, plan.geometry_id, "plan",
                            machine)
    one_back = parse_nc(text)
    assert [p for p, _, _ in one_back["phases"]] == one and len(one_back["tool_changes"]) == 1


def test_a_program_leaving_the_a_travel_is_refused(rear, machine, tmp_path):
    """60 channels run A to 2 pi 59/60 = 6.18 rad (the travel is +-7 rad); a machine with less A travel refuses."""
    g, electrode, plan = rear
    text = default_machine_path().read_text().replace("min_rad: -7.0", "min_rad: -2.0").replace(
        "max_rad: 7.0", "max_rad: 2.0")
    short = tmp_path / "short_a.yaml"
    short.write_text(text)
    m = load_machine(short)
    a = PlanCycle.of_plan(plan)
    runs = program_runs(blisk_program_steps([a.plan_id], g.blisk.blade_count), {a.plan_id: a}, g.blisk.pitch)
    with pytest.raises(EdmError) as e:
        time_run(runs[0].legs, m)
    assert e.value.code == ErrorCode.INFEASIBLE and "axis A" in e.value.message and "travel" in e.value.message
    # on the default machine the whole blisk fits: every channel's machining pose at A + k pitch
    arrays = time_run(runs[0].legs, machine)
    ia = list(arrays.axis_names).index("A")
    assert arrays.positions[:, ia].max() > 6.0 and sum(m.phase == INDEX for m in arrays.phases) == 59


# -- edm-plan export -----------------------------------------------------------------------------

def _run(argv):
    import io

    from edm_planner.cli import main

    out, err = io.StringIO(), io.StringIO()
    rc = main(argv, out=out, err=err)
    return rc, out.getvalue(), err.getvalue()


def _set_dir(rear, root):
    """An electrode-set directory as `edm-plan plan` writes it (write_set): two electrode exports and set.json."""
    from edm_planner.records.plan_export import write_plan

    g, electrode, plan = rear
    front = _second(plan)
    write_plan(front, root / "front", g.blisk)
    write_plan(plan, root / "rear", g.blisk)
    (root / "set.json").write_text(json.dumps({
        "format": "edm_planner.electrode_set/1", "set_id": "5" * 16, "program_id": "9" * 16,
        "electrodes": [{"order": 1, "label": "rear", "plan_id": plan.plan_id, "export": "rear"},
                       {"order": 0, "label": "front", "plan_id": front.plan_id, "export": "front"}]}))
    return front


def test_export_a_plan_with_its_cycle_and_an_electrode_set(rear, tmp_path):
    g, electrode, plan = rear
    _set_dir(rear, tmp_path / "set")
    # one plan export: the whole cycle, phases marked, the CSV with its phase columns
    rc, out, err = _run(["export", str(tmp_path / "set" / "rear"), "--out", str(tmp_path / "one"), "--store", "none"])
    assert rc == 0, err
    assert f"whole cycle, {len(plan.cycle.legs)} legs" in out and "dialect iso_fanuc" in out
    back = parse_nc((tmp_path / "one" / f"{plan.plan_id}.nc").read_text())
    one = ["clear"] + [leg.phase for leg in plan.cycle.legs]
    assert [p for p, _, _ in back["phases"]] == one
    rows = (tmp_path / "one" / f"{plan.plan_id}.csv").read_text().splitlines()
    assert len(rows) - 1 > len(back["positions"]) and rows[1].split(",")[-6] == "clear"
    # the set directory: one program in the set's channel, front first (set.json's order), a tool call each
    rc, out, err = _run(["export", str(tmp_path / "set"), "--out", str(tmp_path / "two"), "--store", "none"])
    assert rc == 0, err
    assert "electrode set: 2 electrode(s) (front, rear) in 1 channel(s)" in out
    back = parse_nc((tmp_path / "two" / ("5" * 16 + ".nc")).read_text())
    assert [(t, "FRONT" in c) for t, _, c in back["tool_changes"]] == [(1, True), (2, False)]
    assert [p for p, _, _ in back["phases"]] == one * 2
    assert len(back["trajectories"]) == 2
    # a plan from the store that belongs to a set: --all-channels names the set to export instead
    store = tmp_path / "store"
    s = PlanStore(store)
    s.put(plan_to_stored(plan))
    rc, out, err = _run(["export", plan.plan_id, "--all-channels", "--store", str(store)])
    assert rc == ErrorCode.INVALID_REQUEST and "set-of-test" in err
    rc, out, err = _run(["export", "nothing-of-that-name", "--store", str(store)])
    assert rc == ErrorCode.UNKNOWN_ID and "electrode-set directory" in err
    # a plan without a cycle in a program: refused with the reason
    s.put(plan_to_stored(replace(plan, plan_id="e" * 16, cycle=None)))
    s.put_sequence("bare-set", "electrode_set", [("e" * 16, 0)])
    rc, out, err = _run(["export", "bare-set", "--store", str(store)])
    assert rc == ErrorCode.INVALID_REQUEST and "no machining cycle" in err


def test_export_all_channels_writes_one_program_for_the_whole_blisk(rear, tmp_path):
    """A set id of the store (one electrode here, for time): every channel, A indexed between them."""
    g, electrode, plan = rear
    store = tmp_path / "store"
    s = PlanStore(store)
    s.put(plan_to_stored(plan))
    n = g.blisk.blade_count
    s.put_sequence("9" * 16, "blisk_program", blisk_program_steps([plan.plan_id], n))
    s.put_sequence("5" * 16, "electrode_set", [(plan.plan_id, 0)], {"program_id": "9" * 16})
    rc, out, err = _run(["export", "5" * 16, "--all-channels", "--store", str(store), "--out", str(tmp_path / "nc"),
                         "--format", "nc"])
    assert rc == 0, err
    assert f"blisk program: 1 electrode(s) (rear) in {n} channel(s)" in out
    text = (tmp_path / "nc" / ("9" * 16 + ".nc")).read_text()
    assert not (tmp_path / "nc" / ("9" * 16 + ".csv")).exists()
    back = parse_nc(text)
    assert back["plan_id"] == "9" * 16 and len(back["tool_changes"]) == 1
    feeds = [(c, i) for p, c, i in back["phases"] if p == "feed"]
    assert [c for c, _ in feeds] == list(range(n))
    assert [c for p, c, _ in back["phases"] if p == INDEX] == list(range(1, n))
    # each channel's feed starts one pitch further in A (joint A in the NC: degrees, read back in rad)
    ia = back["axis_names"].index("A")
    a = back["positions"][[i for _, i in feeds], ia]
    np.testing.assert_allclose(np.diff(a), g.blisk.pitch, atol=2 * math.radians(0.5e-4))
    assert back["times"][-1] > n * 30.0
    # one subprogram, called in every channel after a G52 shift of A: the size does not grow with the channels
    assert text.count("M98 P1001") == n and text.count("\nO1001") == 1 and "1 subprogram(s) called" in out
    assert len(text.encode()) < 200_000
