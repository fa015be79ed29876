"""Wear compensation by feed depth (issue 25 point 4): the tool offset along the front, its schedule, the
compensated program, and a set designed with it. Real geometry, real certifier; numbers measured."""

import copy
import math

import numpy as np
import pytest

from edm_planner.cnc.kinematics import axis_poses, offset_axes
from edm_planner.machining.program import PlanCycle, blisk_program_steps, program_runs
from edm_planner.process.report import ElectrodeProcess, compensation_schedule


def _electrode(front_wear, side_wear=0.0, per_channel=1, per_blisk=60):
    faces = {"front": front_wear}
    if side_wear:
        faces["face +y"] = side_wear
    return ElectrodeProcess("front", "finish", "C120", 100.0, 99.0, 101.0, 1500.0, 15.0, 300.0, front_wear, faces,
                            0.02, per_channel, per_blisk)


def test_an_offset_in_the_electrode_frame_moves_the_pose_and_nothing_else(rear_cycle):
    """offset_axes over the rear electrode's whole cycle (A and C turning): the poses are the nominal ones
    moved by the offset in their own frame, exactly."""
    g, field, electrode, design, plan, builder = rear_cycle
    q = plan.cycle.samples
    q = q[:: max(1, len(q) // 400)].copy()
    q[:, plan.axis_names.index("C")] += np.linspace(-0.2, 0.2, len(q))       # C turning too
    offset = np.array([0.03, -0.02, 0.05])
    moved = offset_axes(plan.final_pose, plan.axis_names, q, offset)
    shift = np.eye(4)
    shift[:3, 3] = offset
    assert np.allclose(axis_poses(plan.final_pose, plan.axis_names, moved),
                       axis_poses(plan.final_pose, plan.axis_names, q) @ shift, atol=1e-12)
    xyz = [plan.axis_names.index(n) for n in "XYZ"]
    others = [i for i in range(len(plan.axis_names)) if i not in xyz]
    assert np.array_equal(moved[:, others], q[:, others])


def test_the_schedule_offsets_only_wear_already_done_and_replaces_the_electrode_in_time():
    e = _electrode(0.015, side_wear=0.004)
    depths = compensation_schedule(e, 0.3, 60)
    # the front may take 0.3 mm: 20 channels; a side 0.02 mm at 0.004 per channel: 5. The fewest: 5
    assert depths == pytest.approx([0.0, 0.015, 0.030, 0.045, 0.060])
    assert e.compensation["channels_per_electrode"] == 5 and e.electrodes_per_blisk == 12
    assert "side face" in e.compensation["note"]
    e = _electrode(0.015)
    assert len(compensation_schedule(e, 0.3, 60)) == 20 and e.electrodes_per_blisk == 3
    assert "max_compensated_wear" in e.compensation["note"]
    e = _electrode(0.015)
    assert len(compensation_schedule(e, 0.3, 8)) == 8 and e.electrodes_per_blisk == 1
    # a face beyond its limit within one channel: redressed inside the channel, counts unchanged
    e = _electrode(0.05, per_channel=3, per_blisk=150)
    assert compensation_schedule(e, 0.3, 60) == [] and e.electrodes_per_blisk == 150
    assert "within the channel" in e.compensation["note"]
    e = _electrode(0.0)
    assert compensation_schedule(e, 0.3, 60, has_front=False) == [] and "no front wear" in e.compensation["note"]


def _compensated(plan, depths, front=(0.0, 0.0, -1.0)):
    plan = copy.deepcopy(plan)
    plan.cycle.reach.compensation_front = tuple(front)
    plan.cycle.reach.compensation_depths = tuple(depths)
    return plan


def test_the_blisk_program_runs_each_channel_moved_by_its_depth_and_changes_the_worn_electrode(rear_cycle):
    g, field, electrode, design, plan, builder = rear_cycle
    depths = [0.0, 0.01, 0.02]
    plan = _compensated(plan, depths)
    pitch = 2 * math.pi / 8
    runs = program_runs(blisk_program_steps([plan.plan_id], 8), {plan.plan_id: PlanCycle.of_plan(plan)}, pitch)
    # 8 channels, 3 per electrode: 3 electrodes, a tool change after channels 2 and 5
    assert [r.channels for r in runs] == [[0, 1, 2], [3, 4, 5], [6, 7]]
    assert [r.replacement for r in runs] == [0, 1, 2] and runs[1].label.endswith("(replacement 1)")
    # every channel's feed end is the machining pose of that channel, moved by its depth along the front
    ia = plan.axis_names.index("A")
    k = 0
    for run in runs:
        for leg in run.legs:
            if leg.phase != "feed":
                continue
            q_end = leg.samples[-1].copy()
            q_end[ia] -= leg.channel * pitch                     # back to channel 0's A
            pose = axis_poses(plan.final_pose, plan.axis_names, q_end[None])[0]
            local = np.linalg.inv(plan.final_pose) @ pose
            assert np.allclose(local[:3, :3], np.eye(3), atol=1e-12)
            assert np.allclose(local[:3, 3], [0.0, 0.0, -depths[k % 3]], atol=1e-12), (k, local[:3, 3])
            k += 1
    assert k == 8
    # between channels of one electrode the index also moves X, Y, Z by the change of the compensation
    index = [leg for leg in runs[0].legs if leg.phase == "index"]
    assert [leg.label.split(", ")[-1] for leg in index] == ["wear compensation +0.0100 mm"] * 2
    for leg in index:                  # one straight leg at the clear position, certified by its separation
        step = leg.samples[1] - leg.samples[0]
        assert len(leg.samples) == 2 and abs(np.linalg.norm(step[:3]) - 0.01) < 1e-12
        assert np.all(leg.clearance_lower_bound >= plan.cycle.margin)
        assert leg.clearance_lower_bound[0] == pytest.approx(plan.cycle.clear_zone.separation(
            min(leg.samples[:, 0], key=lambda x: plan.cycle.clear_zone.separation(x))), abs=1e-12)
    # a roughing twin (its legs erode in the rough regime) is named as one, not by the id it shares
    rough = copy.deepcopy(plan)
    rough.plan_id = "twin"
    next(leg for leg in rough.cycle.legs if leg.phase == "feed").regime = "rough"
    runs = program_runs(blisk_program_steps([rough.plan_id], 4), {rough.plan_id: PlanCycle.of_plan(rough)}, pitch)
    assert [r.label for r in runs] == [f"rough-{rough.electrode_id}", f"rough-{rough.electrode_id} (replacement 1)"]
    # the stored plan is the fresh electrode's: depth 0, the certified samples bit for bit
    (single,) = program_runs([(plan.plan_id, 0)], {plan.plan_id: PlanCycle.of_plan(plan)})
    assert single.legs[0].phase == "clear"                        # the clear leg reversed, then the cycle
    assert all(np.array_equal(a.samples, b.samples) for a, b in zip(single.legs[1:], plan.cycle.legs))
    with pytest.raises(ValueError, match="finite and >= 0"):
        plan.cycle.with_compensation_depth(-0.01, plan.final_pose)


def test_a_set_with_compensation_schedules_the_front_and_counts_the_electrodes(rear_cycle):
    """add_process on the rear piece with a low-wear finish regime: the report's schedule, the cycle's
    compensation (stored at depth 0: a fresh electrode), and the electrode count the program runs."""
    from conftest import REAR_TOLERANCE
    from edm_planner.machining.cycle import CycleOptions
    from edm_planner.machining.electrode_set import Candidate, Piece, SetDesigner
    from edm_planner.process.set_process import add_process
    from edm_planner.process.model import DEFAULT_PROCESS

    g, field, electrode, design, plan, builder = rear_cycle
    finish = DEFAULT_PROCESS.regimes["finish"]
    low = {**DEFAULT_PROCESS.regimes, "finish": type(finish)(**{**finish.__dict__, "wear_ratio": 0.1})}
    process = type(DEFAULT_PROCESS)(**{**DEFAULT_PROCESS.__dict__, "regimes": low, "rough_and_finish": False,
                                       "wear_compensation": True, "max_compensated_wear": 0.1})
    steps = []
    designer = SetDesigner(g, field, cycle_options=CycleOptions(tolerance=REAR_TOLERANCE), process=process,
                           process_step=add_process, detail=steps.append)
    plan = copy.deepcopy(plan)
    before = [leg.samples.copy() for leg in plan.cycle.legs]
    piece = Piece("rear", "rear", design, plan, plan.cycle)
    report = add_process(designer, Candidate("front/rear", [piece]))
    # the process step reports its steps in the last PROCESS_SHARE of the design's progress, rising
    from edm_planner.machining.electrode_set import PROCESS_SHARE
    assert [s.message.split(": ", 1)[1].split(" ")[0] for s in steps] == ["removed", "wear"]
    assert all(s.message.startswith("front/rear: ") for s in steps)
    assert all(1 - PROCESS_SHARE <= s.fraction <= 0.99 for s in steps)
    assert [s.fraction for s in steps] == sorted(s.fraction for s in steps) and steps[0].fraction < steps[1].fraction
    (e,) = report.electrodes
    c = e.compensation
    assert c["depths_mm"], c
    front = e.face_wear["front"]
    life = c["channels_per_electrode"]
    assert c["depths_mm"] == pytest.approx([j * front for j in range(life)], abs=1e-5)
    sides = max([v for k, v in e.face_wear.items() if k != "front"], default=0.0)
    n = g.blisk.blade_count
    assert life == min(math.floor(0.1 / front + 1e-9), math.floor(e.wear_limit / sides + 1e-9) if sides else n, n)
    assert e.electrodes_per_channel == 1 and e.electrodes_per_blisk == math.ceil(n / life)
    r = piece.cycle.reach
    assert r.compensation_depths == pytest.approx(c["depths_mm"], abs=1e-5)
    assert np.linalg.norm(r.compensation_front) == pytest.approx(1.0) and c["front_direction"] == pytest.approx(
        r.compensation_front, abs=1e-6)
    # the stored cycle is unchanged (depth 0), and certified as it was
    assert all(np.array_equal(a, b.samples) for a, b in zip(before, piece.cycle.legs)) and piece.cycle.certified
    d = report.to_dict()["electrodes"][0]["wear_compensation"]
    assert d["channels_per_electrode"] == life and "replaced after" in d["note"]
    plan.plan_id = "compensated"
    runs = program_runs(blisk_program_steps([plan.plan_id], n), {plan.plan_id: PlanCycle.of_plan(plan)}, 2 * math.pi / n)
    assert len(runs) == e.electrodes_per_blisk and all(len(run.channels) <= life for run in runs)
