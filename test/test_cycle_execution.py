"""The whole machining cycle timed and sent: JointTrajectory checks as for the feed, then over DDS.

A real plan with its certified cycle (rear electrode of the front/rear split, machining margin, as in
test_machining_cycle) is planned once per module. The core part times it leg by leg and checks the
trajectory as test_timing checks the feed's; the DDS part runs an axis_bridge in-process that takes the
plan from the ``plan`` topic (the ChannelPlan of the trajectory_planner's channel_plan_msg, with
its cycle) and from the plan store (sequences: an electrode set and a short blisk program).
"""

import copy
import math
import time
from dataclasses import replace

import numpy as np
import pytest

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.geometry.electrode import ElectrodeDesign
from edm_planner.cnc.config import default_machine_path, load_machine
from edm_planner.cnc.trajectory import plan_trajectory, time_leg, time_run
from edm_planner.machining.cycle import PHASES, CycleOptions
from edm_planner.machining.program import PlanCycle, program_runs

from test_axis_bridge_node import Inbox
from test_timing import quintic_peaks

GAP, TOLERANCE = 0.1, 0.02
MARGIN = GAP - TOLERANCE
DESIGN = ElectrodeDesign(circumferential_reduction=0.03, radial_reduction=3.0, split="front_rear", split_overlap=1.0)
JOINTS = ["edm_x", "edm_y", "edm_z", "edm_a", "edm_c"]
REMOVAL = {"tolerance_mm": 0.02, "surfaces": {s: {"stock_max_mm": 0.015, "stock_mean_mm": 0.002,
                                                  "area_fraction_above_tolerance": 0.0, "overcut_max_mm": 0.0}
                                              for s in ("suction", "pressure", "hub", "shroud")},
           "accuracy": {"sample_spacing_mm": 0.25, "continuous_bound_mm": 0.012}}


@pytest.fixture(scope="module")
def rear(rear_cycle):
    g, field, electrode, design, plan, builder = rear_cycle
    assert design == DESIGN
    plan = copy.deepcopy(plan)
    return g, plan


@pytest.fixture(scope="module")
def machine():
    return load_machine(default_machine_path())


def limits(machine):
    lim = machine.limits_for(("X", "Y", "Z", "A", "C"))
    return (np.array([x.velocity_max for x in lim]), np.array([x.acceleration_max for x in lim]),
            np.array([x.jerk_max for x in lim]))


def check_cycle_trajectory(t, p, v, a, machine, expected, phases=None, atol=1e-9):
    """What every sent cycle must satisfy: the feed's checks (test_timing), at rest at every leg joint.

    ``expected``: the points, or NaN rows where any point of the timed profile will do (points added between
    the knots, test_trajectory_consistency checks them); ``atol``: how close [mm, rad].
    """
    vmax, amax, jmax = limits(machine)
    assert p.shape == v.shape == a.shape == (len(t), 5)
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    assert np.all(np.abs(v) <= vmax * (1 + 1e-6)) and np.all(np.abs(a) <= amax * (1 + 1e-6))
    # between the points, as the controller interpolates quintics through (p, v, a): within every limit (to
    # 1e-5 for the jerk: a knot, where the jerk switches, lies up to 0.5 ns from the point on a whole
    # nanosecond that stands for it; test_trajectory_consistency measures 1.4e-6)
    qv, qa, qj = quintic_peaks(t, p, v, a, n=33)
    assert np.all(qv <= vmax * (1 + 1e-6)) and np.all(qa <= amax * (1 + 1e-6)) and np.all(qj <= jmax * (1 + 1e-5))
    assert len(p) == len(expected)
    known = ~np.isnan(expected).any(axis=1)
    np.testing.assert_allclose(p[known], expected[known], atol=atol)
    np.testing.assert_array_equal(v[[0, -1]], 0.0)
    np.testing.assert_array_equal(a[[0, -1]], 0.0)
    if phases is not None:
        for i in phases:                       # every leg joint is a full rest: a reversal, not rounded off
            np.testing.assert_array_equal(v[i], 0.0)
            np.testing.assert_array_equal(a[i], 0.0)
    # finite differences of positions agree with the velocities (bound as in test_timing)
    span = (t[2:] - t[:-2])[:, None]
    assert np.all(np.abs((p[2:] - p[:-2]) / span - v[1:-1]) <= 0.5 * amax * span)


# -- core ------------------------------------------------------------------------------------------

def test_the_cycle_is_timed_leg_by_leg_within_every_limit(rear, machine):
    g, plan = rear
    cycle = plan.cycle
    pc = PlanCycle.of_plan(plan)
    legs = program_runs([(plan.plan_id, 0)], {plan.plan_id: pc})[0].legs
    # a program runs the cycle from its clear position: the clear leg reversed, then the cycle's legs
    assert legs[0].phase == "clear" and np.array_equal(legs[0].samples, cycle.legs[-1].samples[::-1])
    arrays = time_run(legs[1:], machine)
    assert [m.phase for m in arrays.phases] == [leg.phase for leg in cycle.legs]
    # the points are the cycle's samples in order, the rest sample shared by two legs once; a two-sample
    # leg (a short straight move) has its chord's middle between them
    # (points of the timed profile between them, sample_index -1, where the trapezoid rule needs them)
    si = arrays.timed.sample_index
    np.testing.assert_array_equal(si[si >= 0], np.arange(len(cycle.samples)))
    expected = np.full_like(arrays.positions, np.nan)
    expected[si >= 0] = cycle.samples
    starts = np.flatnonzero(si >= 0)[[a for _, _, a, _ in cycle.leg_ranges]]
    assert [m.index for m in arrays.phases] == list(starts)
    # the samples to 1e-8: on whole nanoseconds, a sample's point is the profile's within its speed x 0.5 ns
    check_cycle_trajectory(arrays.times, arrays.positions, arrays.velocities, arrays.accelerations, machine,
                           expected, [m.index for m in arrays.phases], atol=1e-8)
    # a two-sample leg (a short straight move): its chord's middle, the knot between its two quintics, is
    # a point too, and the points between stay on the chord
    for (_, _, first, last), leg in zip(cycle.leg_ranges, cycle.legs):
        if len(leg.samples) == 2:
            i, j = np.flatnonzero(si == first)[0], np.flatnonzero(si == last)[0]
            q0, q1 = leg.samples
            d = (q1 - q0) / np.linalg.norm(q1 - q0)
            rel = arrays.positions[i:j + 1] - q0
            assert np.abs(rel - (rel @ d)[:, None] * d).max() <= 1e-12
            assert np.abs(arrays.positions[i:j + 1] - 0.5 * (q0 + q1)).sum(axis=1).min() <= 1e-8
            assert j - i + 1 >= 20
    # the home point first (further out than the feed's start, by up to the approach distance), the
    # machining pose reached
    np.testing.assert_allclose(arrays.positions[0], cycle.legs[0].samples[0], atol=1e-9)
    out = np.linalg.norm(arrays.positions[0, :3] - plan.samples[0, :3])
    assert 0.0 < out <= CycleOptions().approach_distance + 1e-9
    assert abs(arrays.positions[0, 0]) > abs(plan.samples[0, 0])
    process = [m for m in arrays.phases if m.phase == "process"][0]
    assert si[process.index] == dict((p, a) for p, a, _ in cycle.phase_ranges)["process"]
    np.testing.assert_allclose(arrays.positions[process.index], plan.samples[-1], atol=1e-9)
    # the feed leg is the certified feed: the same samples as the feed-only trajectory (which needs no point
    # between them: its segments agree by the trapezoid rule as they are), slower only where it comes to full
    # rest at its ends, where the rest quintics get points between the samples
    feed = [m for m in arrays.phases if m.phase == "feed"][0]
    only = plan_trajectory(plan.samples, plan.axis_names, machine, final_pose=plan.final_pose)
    n = len(only.times)
    assert np.all(only.timed.sample_index >= 0)
    first = dict((p, a) for p, a, _ in cycle.phase_ranges)["feed"]
    in_feed = np.flatnonzero((si >= first) & (si < first + n))
    assert in_feed[0] == feed.index and len(in_feed) == n
    np.testing.assert_allclose(arrays.positions[in_feed], only.positions, atol=1e-8)
    feed_time = arrays.times[in_feed[-1]] - arrays.times[feed.index]
    assert only.duration <= feed_time <= 1.2 * only.duration
    # the phase times: in order, the cycle takes the sum of its legs
    times = [m.time for m in arrays.phases]
    assert times[0] == 0.0 and np.all(np.diff(times) > 0)
    assert 30.0 < arrays.duration < 120.0
    # deviation from the certified chords stays sub-micrometre (the end quintics included)
    dev = arrays.timed.deviation_between_samples
    assert dev[:3].max() < 1e-3 and dev[3:].max() < 1e-4


def test_a_leg_comes_to_full_rest_and_the_controller_quintics_are_verified(rear, machine):
    """time_leg: velocity and acceleration zero at both ends; the stretch it needs for the end quintics."""
    g, plan = rear
    leg = plan.cycle.legs[0]                                     # the approach, a straight line in axis space
    arrays = time_leg(leg.samples, plan.axis_names, machine, final_pose=plan.final_pose)
    plain = plan_trajectory(leg.samples, plan.axis_names, machine, final_pose=plan.final_pose)
    assert np.any(plain.accelerations[[0, -1]] != 0)             # the spline alone does not rest in acceleration
    np.testing.assert_array_equal(arrays.accelerations[[0, -1]], 0.0)
    assert arrays.timed.time_scale >= plain.timed.time_scale
    vmax, amax, jmax = limits(machine)
    qv, qa, qj = quintic_peaks(arrays.times, arrays.positions, arrays.velocities, arrays.accelerations, n=257)
    # the exact peaks (roots of the quintics' derivatives) bound the densely sampled ones and meet the limits
    # (to the float error of quintic coefficients over pieces of a few ms, measured 3e-9 of the jerk)
    assert np.all(qv <= arrays.timed.peak_velocity * (1 + 1e-8) + 1e-12)
    assert np.all(qa <= arrays.timed.peak_acceleration * (1 + 1e-8) + 1e-12)
    assert np.all(qj <= arrays.timed.peak_jerk * (1 + 1e-8) + 1e-12)
    assert np.all(arrays.timed.peak_jerk <= jmax * (1 + 1e-9))
    # a straight leg stays on its line (the controller's quintics too: every point's velocity and
    # acceleration lie along it)
    q0, q1 = leg.samples[0], leg.samples[-1]
    d = (q1 - q0) / np.linalg.norm(q1 - q0)
    for x in (arrays.positions - q0, arrays.velocities, arrays.accelerations):
        off = x - (x @ d)[:, None] * d
        assert np.abs(off).max() <= 1e-9 * max(1.0, np.abs(x).max())


def test_a_leg_beyond_the_travel_is_refused(rear, machine, tmp_path):
    g, plan = rear
    home_x = plan.cycle.legs[0].samples[0, 0]
    text = default_machine_path().read_text().replace("min_mm: -250.0\n    max_mm: 250.0",
                                                      f"min_mm: -250.0\n    max_mm: {home_x - 1.0}")
    tight = tmp_path / "tight.yaml"
    tight.write_text(text)
    pc = PlanCycle.of_plan(plan)
    with pytest.raises(EdmError) as e:
        time_run(program_runs([(plan.plan_id, 0)], {plan.plan_id: pc})[0].legs, load_machine(tight))
    assert e.value.code == ErrorCode.INFEASIBLE and "axis X" in e.value.message and "travel" in e.value.message


# -- over DDS ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bridge(rear, tmp_path_factory):
    from edm_planner_msgs.msg import ChannelPlan
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from trajectory_msgs.msg import JointTrajectory

    from edm_planner.machining.program import blisk_program_steps
    from edm_planner.nodes.axis_bridge import AxisBridgeNode
    from edm_planner.nodes.geometry_loader import LATCHED
    from edm_planner.nodes.trajectory_planner import channel_plan_msg, metrics_to_msg, pose_array_msg, axis_path_msg
    from edm_planner.records.store import PlanStore, plan_to_stored
    from ros_harness import InProcessRos

    g, plan = rear
    store_dir = tmp_path_factory.mktemp("cycle_store")
    store = PlanStore(store_dir)
    published = replace(plan, removal=REMOVAL, set_id="set-a")
    front = replace(plan, plan_id="f" * 16, electrode_id="front", set_id="set-a")   # a second "electrode"
    for p in (published, front):
        store.put(plan_to_stored(p))
    store.put_sequence("set-a", "electrode_set", [(front.plan_id, 0), (plan.plan_id, 0)], {"channel": 0})
    short = [s for s in blisk_program_steps([front.plan_id, plan.plan_id], 60) if s[1] < 3]
    store.put_sequence("prog-a", "blisk_program", short, {"blade_count": 60})
    store.put_sequence("prog-all", "blisk_program", blisk_program_steps([front.plan_id], 60), {"blade_count": 60})
    store.put_sequence("set-elsewhere", "electrode_set", [(plan.plan_id, 5)], {})     # no blade count
    exports = tmp_path_factory.mktemp("cycle_nc")
    ros = InProcessRos()
    ros.add(AxisBridgeNode(context=ros.context, parameter_overrides=[
        Parameter("joint_states_topic", value=""), Parameter("export_dir", value=str(exports)),
        Parameter("plan_store", value=str(store_dir)), Parameter("plan_wait", value=0.5),
        Parameter("trajectory_topic", value="/cycle/joint_trajectory")]))
    client = ros.add(Node("cycle_client", context=ros.context))
    trajectories = Inbox()
    client.create_subscription(JointTrajectory, "/cycle/joint_trajectory", trajectories, 10)
    # the plan as the trajectory_planner publishes it, under an id the store does not have
    on_topic = replace(published, plan_id="c" * 16)
    metrics = metrics_to_msg(on_topic.metrics)
    msg = channel_plan_msg(plan_to_stored(on_topic), pose_array_msg(on_topic.poses, "blisk"),
                           axis_path_msg(on_topic.axis_names, on_topic.samples), metrics)
    pub = client.create_publisher(ChannelPlan, "plan", LATCHED)
    pub.publish(msg)
    yield dict(ros=ros, client=client, plan=plan, msg=msg, trajectories=trajectories, exports=exports, g=g)
    ros.close()


def execute(bridge, plan_id, channel=0, dry_run=False, electrode=0, timeout=120):
    from edm_planner_msgs.srv import ExecutePlan

    req = ExecutePlan.Request(plan_id=plan_id, channel=channel, dry_run=dry_run, electrode=electrode)
    deadline = time.monotonic() + 10
    while True:   # the bridge may not have taken the latched plan yet
        res = bridge["ros"].call(bridge["client"], ExecutePlan, "execute_plan", req, timeout=timeout)
        if res.error_code.val != ErrorCode.UNKNOWN_ID or time.monotonic() > deadline or plan_id != "c" * 16:
            return res
        time.sleep(0.2)


def _local(bridge, steps, pitch=None, plans=None):
    """The trajectory the bridge must send, timed here."""
    plan = bridge["plan"]
    plans = plans or {plan.plan_id: PlanCycle.of_plan(plan)}
    return [time_run(r.legs, load_machine(default_machine_path())) for r in program_runs(steps, plans, pitch)]


def _arrays(msg):
    t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
    return (t, np.array([p.positions for p in msg.points]), np.array([p.velocities for p in msg.points]),
            np.array([p.accelerations for p in msg.points]))


def test_channel_plan_message_carries_the_cycle_and_the_machining_figures(bridge):
    from edm_planner.ros.conversions import msg_to_cycle

    msg, plan = bridge["msg"], bridge["plan"]
    cycle = msg_to_cycle(msg)
    assert [leg.phase for leg in cycle.legs] == [leg.phase for leg in plan.cycle.legs]
    assert [leg.label for leg in cycle.legs] == list(msg.leg_labels)
    assert list(msg.leg_last) == [b for _, _, _, b in plan.cycle.leg_ranges]
    for a, b in zip(cycle.legs, plan.cycle.legs):
        assert a.samples.tobytes() == b.samples.tobytes()
        np.testing.assert_array_equal(a.clearance_lower_bound, b.clearance_lower_bound)
    assert list(msg.cycle_path.axis_names) == list(plan.axis_names)
    assert msg.cycle_certified and msg.cycle_margin == pytest.approx(MARGIN) and msg.set_id == "set-a"
    m = msg.metrics
    assert m.machining_margin == pytest.approx(MARGIN) and m.cycle_certified
    assert m.stock_tolerance == 0.02 and list(m.stock_max_exact) == [0.015] * 4
    assert list(m.stock_mean) == [0.002] * 4 and list(m.overcut_max) == [0.0] * 4
    assert list(m.stock_area_fraction_above) == [0.0] * 4
    assert m.stock_sample_spacing == 0.25 and m.stock_continuous_bound == 0.012
    # a plan without a cycle or proof: NaN and empty
    from edm_planner.nodes.trajectory_planner import metrics_to_msg
    bare = metrics_to_msg(plan.metrics)
    assert math.isnan(bare.machining_margin) and not bare.cycle_certified and len(bare.stock_max_exact) == 0
    assert math.isnan(bare.stock_continuous_bound)


def test_execute_a_plan_with_its_cycle_from_the_topic(bridge):
    from types import SimpleNamespace

    from edm_planner.cnc.post import check_program, parse_nc

    inbox, plan = bridge["trajectories"], bridge["plan"]
    count = len(inbox.items)
    res = execute(bridge, "c" * 16)
    assert res.success, res.message
    assert "whole cycle" in res.message
    assert list(res.phase_names) == ["clear"] + list(PHASES) and res.electrode_count == 1
    assert res.next_electrode == "" and list(res.phase_channels) == [0] * 7
    assert inbox.wait(count + 1, 30)
    msg = inbox.items[-1]
    assert list(msg.joint_names) == JOINTS
    t, p, v, a = _arrays(msg)
    (local,) = _local(bridge, [(plan.plan_id, 0)])
    assert res.point_count == len(t) == len(local.times)
    assert t[-1] == pytest.approx(res.duration, abs=1e-9)
    np.testing.assert_allclose(t, local.times, atol=1e-9)
    firsts = [m for i, m in enumerate(local.phases) if not i or m.phase != local.phases[i - 1].phase]
    np.testing.assert_allclose(res.phase_start_times, [m.time for m in firsts], atol=1e-9)
    check_cycle_trajectory(t, p, v, a, load_machine(default_machine_path()), local.positions,
                           [m.index for m in local.phases])
    # the NC program written beside it: each phase marked, parse_nc reads the same points back
    nc = bridge["exports"] / ("c" * 16 + ".nc")
    back = parse_nc(nc.read_text())
    assert [ph for ph, _, _ in back["phases"]] == ["clear"] + [leg.phase for leg in plan.cycle.legs]
    check_program(nc.read_text(), "iso_fanuc", [SimpleNamespace(positions=p)])
    assert back["times"][-1] == pytest.approx(t[-1], rel=1e-5)
    header = (bridge["exports"] / ("c" * 16 + ".csv")).read_text().splitlines()[0]
    assert header.endswith("phase,channel,trajectory,electrode,plan_id,leg")


def test_execute_an_electrode_set_one_trajectory_per_electrode(bridge):
    inbox, plan = bridge["trajectories"], bridge["plan"]
    count = len(inbox.items)
    first = execute(bridge, "set-a")
    assert first.success, first.message
    assert first.electrode_count == 2 and first.next_electrode == f"rear (plan {plan.plan_id})"
    assert list(first.phase_names) == ["clear"] + list(PHASES) + ["tool_change"]
    assert first.phase_start_times[-1] == pytest.approx(first.duration)
    assert "then change the electrode" in first.message and "electrode 1 of 2 (front" in first.message
    second = execute(bridge, "set-a", electrode=1)
    assert second.success, second.message
    assert second.next_electrode == "" and list(second.phase_names) == ["clear"] + list(PHASES)
    assert inbox.wait(count + 2, 30)
    (local,) = _local(bridge, [(plan.plan_id, 0)])
    for msg in inbox.items[-2:]:
        t, p, v, a = _arrays(msg)
        check_cycle_trajectory(t, p, v, a, load_machine(default_machine_path()), local.positions,
                               [m.index for m in local.phases])
    # bad requests, named
    res = execute(bridge, "set-a", electrode=2, dry_run=True)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "has 2 electrode(s)" in res.message
    res = execute(bridge, "set-a", channel=4, dry_run=True)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "starts in channel 0" in res.message
    res = execute(bridge, "no-such-sequence", dry_run=True)
    assert res.error_code.val == ErrorCode.UNKNOWN_ID and "neither a plan nor a sequence" in res.message
    res = execute(bridge, "set-elsewhere", channel=5, dry_run=True)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "blade count" in res.message
    res = execute(bridge, plan.plan_id, electrode=1, dry_run=True)
    assert res.error_code.val == ErrorCode.INVALID_REQUEST and "not a sequence" in res.message


def test_execute_a_blisk_program_electrode_through_its_channels(bridge):
    inbox, plan, g = bridge["trajectories"], bridge["plan"], bridge["g"]
    count = len(inbox.items)
    res = execute(bridge, "prog-a")
    assert res.success, res.message
    cyc = ["clear"] + list(PHASES)
    assert list(res.phase_names) == cyc + ["index"] + cyc + ["index"] + cyc + ["tool_change"]
    assert list(res.phase_channels) == [0] * 7 + [1] * 8 + [2] * 8 + [2]
    assert inbox.wait(count + 1, 30)
    t, p, v, a = _arrays(inbox.items[-1])
    (single,) = _local(bridge, [(plan.plan_id, 0)])
    n = len(single.times)
    ia = 3
    # three cycles and two index turns (A only, one pitch each, at the clear position); channel k's points
    # are channel 0's with A + k pitch, timed alike
    idx = [i for i, name in enumerate(res.phase_names) if name == "index"]
    starts = [int(np.searchsorted(t, res.phase_start_times[i] - 1e-9)) for i in idx]
    assert starts[0] == n - 1
    index_len = starts[1] - starts[0] - (n - 1)
    # one straight leg (certified by the clear zone), with points of its profile where it leaves and reaches
    # its rests
    assert 3 <= index_len <= 64
    expected = [single.positions]
    others = [j for j in range(5) if j != ia]
    for k in (1, 2):
        a0 = single.positions[-1, ia] + (k - 1) * g.blisk.pitch
        turn = p[starts[k - 1] + 1:starts[k - 1] + 1 + index_len]
        np.testing.assert_allclose(turn[:, others], np.repeat(single.positions[-1:, others], index_len, axis=0),
                                   atol=1e-12)
        assert np.all(np.diff(turn[:, ia]) > 0) and turn[-1, ia] == pytest.approx(a0 + g.blisk.pitch, abs=1e-12)
        turn = np.full((index_len, 5), np.nan)            # (checked here)
        shifted = single.positions[1:].copy()
        shifted[:, ia] += k * g.blisk.pitch
        expected += [turn, shifted]
    rests = [m.index for m in single.phases]
    rests += [n - 1 + index_len + i for i in rests] + [2 * (n - 1 + index_len) + i for i in rests]
    check_cycle_trajectory(t, p, v, a, load_machine(default_machine_path()), np.vstack(expected), rests)
    cycle2 = slice(2 * (n - 1 + index_len), None)
    np.testing.assert_allclose(t[cycle2] - t[cycle2][0], single.times, atol=1e-9)
    # the NC program the bridge wrote: the three channels' passes are one motion, one subprogram called thrice
    nc = (bridge["exports"] / "prog-a.e0.nc").read_text()
    assert nc.count("M98 P1001") == 3 and nc.count("\nO1001") == 1 and "O1002" not in nc, nc[:2000]
    # the whole-blisk electrode (60 channels, 59 index turns), timed only
    res = execute(bridge, "prog-all", dry_run=True, timeout=300)
    assert res.success, res.message
    assert res.phase_names.count("index") == 59 and res.phase_channels[-1] == 59
    assert res.point_count == 60 * (n - 1) + 1 + 59 * index_len
    assert res.duration == pytest.approx(60 * single.duration + 59 * (t[starts[0] + index_len] - t[starts[0]]),
                                         rel=1e-9)
