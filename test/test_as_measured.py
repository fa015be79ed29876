"""Every channel as measured (issue 28, part 2): each channel designed, planned and proven on its own blades.

The test blisk is the default blisk with every blade's faces off nominal by up to +-0.05 mm at random
(``measured_blisk.py``, seeded). Its channel 43 narrows most on both walls (about 0.05 mm each):
the nominal plan's machining cycle is shown not to hold there, and the channel's own plan does.
"""

import numpy as np
import pytest

from edm_planner.errors import EdmError, GeometryError
from edm_planner.geometry.as_measured import wall_deviation
from edm_planner.geometry.blisk import Blisk
from edm_planner.geometry.loader import load_geometry
from measured_blisk import narrowing, write_measured_blisk

SEED, CHANNEL = 59, 43


@pytest.fixture(scope="module")
def measured(tmp_path_factory, default_geometry):
    """(the blisk with all 60 blades as measured, the faces' offsets [mm])."""
    path, offsets = write_measured_blisk(tmp_path_factory.mktemp("measured"), default_geometry.blisk, seed=SEED)
    return load_geometry(path), offsets


@pytest.fixture(scope="module")
def one_channel(tmp_path_factory, default_geometry):
    """The same blisk with only channel 43's two walls as measured: one channel of its own, the rest nominal."""
    path, _ = write_measured_blisk(tmp_path_factory.mktemp("one_channel"), default_geometry.blisk, seed=SEED,
                                   only_channel=CHANNEL)
    return load_geometry(path)


def test_the_test_channel_narrows_on_both_walls(measured):
    _, offsets = measured
    both = np.minimum(offsets[:, 1], -np.roll(offsets[:, 0], -1))
    assert int(np.argmax(both)) == CHANNEL and both[CHANNEL] > 0.048
    assert narrowing(offsets)[CHANNEL] > 0.048


def test_a_channel_of_its_own_is_the_parts_channel(measured, default_geometry):
    """Channel k's geometry has blade k's suction face and blade k+1's pressure face where the files put them."""
    g, offsets = measured
    own = g.for_channel(CHANNEL)
    assert own is not g and own.channel == CHANNEL and own.for_channel(5) is own
    assert own.geometry_id == g.geometry_id and own.field_key not in (g.field_key, g.geometry_id)
    assert g.for_channel(CHANNEL) is own                      # kept
    # at the measured stations (mid chord, mid span) the walls of channel k are the measured faces, in place
    n = g.blisk.blade_count
    for blade, face, column in ((CHANNEL, "plus", 0), (CHANNEL + 1, "minus", 1)):
        rows = np.loadtxt(g.source.rsplit("/", 1)[0] + f"/blade{blade:02d}.csv", delimiter=",", skiprows=1)
        sec = rows[rows[:, 0] == 10]
        x, r = sec[:, 1][40:60], sec[:, 2][40:60]
        th = (sec[:, 4] if face == "plus" else sec[:, 3])[40:60]
        walls = own.blisk.wall_angles(x, r, channel=CHANNEL)
        assert walls[2].all()
        assert np.max(np.abs(walls[column] - th) * r) < 1e-6
        nominal = default_geometry.blisk.wall_angles(x, r, channel=CHANNEL)
        moved = (walls[column] - nominal[column]) * r                 # arc [mm], + towards +theta
        sign = 1 if face == "plus" else -1                            # into the channel
        assert np.all(sign * moved > 0.5 * abs(offsets[blade % n, 1 if face == "plus" else 0]))


def test_channels_of_nominal_blades_share_the_nominal_files_field(one_channel, default_geometry):
    """The test file is the default blisk's YAML with an as_measured section: its nominal channels' field is
    the default blisk's (one field built, not two), its own channels' are their own."""
    assert one_channel.geometry_id != default_geometry.geometry_id
    assert one_channel.for_channel(0).field_key == default_geometry.geometry_id
    assert one_channel.for_channel(CHANNEL).field_key not in (default_geometry.geometry_id, one_channel.geometry_id)
    from edm_planner.geometry.as_measured import MeasuredBlades

    assert MeasuredBlades.from_dict(one_channel.measured.to_dict()).nominal_field_key == default_geometry.geometry_id


def test_channels_of_nominal_blades_share_the_nominal_geometry(one_channel):
    g = one_channel
    nominal = g.for_channel(0)
    assert nominal.blisk is g.blisk and nominal.measured is None and nominal.field_key == g.measured.nominal_field_key
    assert nominal.geometry_id == g.geometry_id                  # plans name the part
    assert g.for_channel(CHANNEL + 2) is nominal and g.for_channel(CHANNEL).measured is None
    # channels CHANNEL - 1 and CHANNEL + 1 each have one measured blade, but their walls are nominal
    for k in (CHANNEL - 1, CHANNEL + 1):
        assert g.for_channel(k).blisk is not g.blisk
        assert wall_deviation(g.blisk, g.for_channel(k).blisk) < 1e-9
    groups = g.channel_groups()
    assert [(rep, len(members)) for rep, members, _ in groups] == [(0, 59), (CHANNEL, 1)]
    assert CHANNEL not in groups[0][1]
    dev = wall_deviation(g.blisk, g.for_channel(CHANNEL).blisk)
    assert 0.04 < dev < 0.15                                   # the arc of a ~0.05 mm normal offset
    info = g.info()
    assert info["measured_blades"] == [CHANNEL, CHANNEL + 1] and info["channel_groups"] == 2
    assert info["channels_own_geometry"] == 3 and info["largest_wall_deviation"] < 1e-9


def test_all_blades_measured_make_a_group_per_channel_unless_within_the_tolerance(measured, one_channel):
    g, _ = measured
    groups = g.channel_groups()
    assert sum(len(m) for _, m, _ in groups) == 60 and len(groups) >= 50
    # channel 43 of the fully measured blisk has exactly the walls of the one-channel blisk's
    assert wall_deviation(g.for_channel(CHANNEL).blisk, one_channel.for_channel(CHANNEL).blisk) < 1e-9


def test_model_round_trip_keeps_the_pressure_blade(one_channel):
    own = one_channel.for_channel(CHANNEL).blisk
    back = Blisk.from_dict(own.to_dict())
    assert back.pressure_blade is not None
    x, r = np.array([12.0, 15.0]), np.array([105.0, 112.0])
    assert np.allclose(np.column_stack(back.wall_angles(x, r)[:2]), np.column_stack(own.wall_angles(x, r)[:2]),
                       atol=1e-12)


@pytest.mark.parametrize("entry, words", [
    ("{blade: 60, sections: {file: blade43.csv}}", ["as_measured.blades[0].blade", "0 .. 59"]),
    ("{blade: -1, sections: {file: blade43.csv}}", ["as_measured.blades[0].blade"]),
    ("{sections: {file: blade43.csv}}", ["as_measured.blades[0]", "'blade'"]),
    ("{blade: 43, sections: {file: missing.csv}}", ["blade 43", "missing.csv"]),
    ("{blade: 43}", ["blade 43", "exactly one of"]),
])
def test_bad_measured_blades_are_refused_with_their_place(one_channel, entry, words):
    folder = one_channel.source.rsplit("/", 1)[0]
    text = (open(f"{folder}/blisk.yaml").read().split("as_measured:")[0]
            + f"as_measured:\n  blades:\n    - {entry}\n")
    with pytest.raises(EdmError) as err:
        load_geometry(text=text, base_dir=folder)
    for w in words:
        assert w in err.value.message


def test_twice_given_blade_and_bad_tolerance_are_refused(one_channel):
    folder = one_channel.source.rsplit("/", 1)[0]
    head = open(f"{folder}/blisk.yaml").read().split("as_measured:")[0]
    twice = head + "as_measured:\n  blades:\n    - {blade: 43, sections: {file: blade43.csv}}\n" \
                   "    - {blade: 43, sections: {file: blade44.csv}}\n"
    with pytest.raises(GeometryError, match="blade 43 is given twice"):
        load_geometry(text=twice, base_dir=folder)
    for tol in ("-0.01", "0.5", "yes"):
        bad = head + f"as_measured:\n  tolerance: {tol}\n  blades:\n    - {{blade: 43, sections: {{file: blade43.csv}}}}\n"
        with pytest.raises(GeometryError, match="as_measured.tolerance"):
            load_geometry(text=bad, base_dir=folder)


def test_a_measured_blade_that_runs_into_its_neighbour_is_refused(tmp_path, default_geometry):
    b = default_geometry.blisk
    fat = b.blade.rotated(5 * b.pitch)          # blade 5's place ...
    th_p = fat.theta_plus + 0.6 * b.pitch       # ... with its suction face pushed most of a pitch out
    rows = ["section,x,r,theta_1,theta_2"] + [
        f"{i},{float(fat.x[i, j])!r},{float(fat.r[i, j])!r},{float(fat.theta_minus[i, j])!r},{float(th_p[i, j])!r}"
        for i in range(fat.shape[0]) for j in range(fat.shape[1])]
    (tmp_path / "blade05.csv").write_text("\n".join(rows) + "\n")
    text = (open(default_geometry.source).read()
            + "\nas_measured:\n  blades:\n    - {blade: 5, sections: {file: blade05.csv}}\n")
    with pytest.raises(GeometryError, match=r"channel 5 as measured \(blades 5 and 6\).*intersects"):
        load_geometry(text=text, base_dir=tmp_path)



# -- the plan of the nominal channel against the channel's own -----------------------------------------------
@pytest.fixture(scope="module")
def own_channel(one_channel, rear_cycle, field_cache):
    """Channel 43 of the blisk as measured: its field, and its own electrode's plan with the machining cycle."""
    from edm_planner.geometry.electrode import design_electrodes
    from edm_planner.interference.fast import FastChannelField
    from edm_planner.machining.cycle import CycleBuilder, CycleOptions, shift_channel
    from edm_planner.planning.planner import plan_channel

    _, _, _, design, nominal_plan, _ = rear_cycle
    own = one_channel.for_channel(CHANNEL)
    field = FastChannelField(own.blisk, spacing=0.1, cache_dir=field_cache, cache_key=own.field_key)
    plan = plan_channel(one_channel, CHANNEL, "rear", nominal_plan.options, design=design, cache_dir=field_cache)
    electrode = design_electrodes(own.blisk, design, only="rear")[0]
    margin = REAR_GAP - REAR_TOLERANCE
    if plan.success:
        builder = CycleBuilder(field, electrode, design, plan.axis_names, CycleOptions(tolerance=REAR_TOLERANCE))
        cycle0 = builder.build(shift_channel(plan.samples, plan.axis_names, -CHANNEL, own.blisk.pitch), margin,
                               plan.metrics.clearance_lower_bound)
        # the cycle's axis values in the plan's channel (as the set designer's, whose plans are channel 0's)
        for leg in cycle0.legs:
            leg.samples = shift_channel(leg.samples, plan.axis_names, CHANNEL, own.blisk.pitch)
        plan.cycle = cycle0
    return own, field, electrode, plan


REAR_GAP, REAR_TOLERANCE = 0.1, 0.02


@pytest.mark.slow
def test_the_nominal_plan_is_not_certified_on_the_measured_channel(rear_cycle, own_channel):
    """The nominal channel's electrode and feed, certified there (cycle and all), do not hold in channel 43
    as measured: copy processing would bring the electrode closer to its walls than the machining margin."""
    from edm_planner.machining.cycle import CycleBuilder, CycleOptions

    _, _, electrode, design, plan, _ = rear_cycle
    assert plan.cycle.certified
    own, field, _, _ = own_channel
    # the same feed and electrode, in the channel's own walls (its field's channel 0 is the part's channel 43)
    on_part = CycleBuilder(field, electrode, design, plan.axis_names, CycleOptions(tolerance=REAR_TOLERANCE)).build(
        plan.samples, REAR_GAP - REAR_TOLERANCE, plan.metrics.clearance_lower_bound)
    assert not on_part.certified
    assert "machining margin 0.080 mm" in on_part.message, on_part.message


@pytest.mark.slow
def test_the_channels_own_plan_is_certified_on_its_own_blades(rear_cycle, own_channel, one_channel):
    own, field, electrode, plan = own_channel
    nominal_plan = rear_cycle[4]
    assert plan.success, plan.message
    assert plan.channel == CHANNEL and plan.geometry_id == one_channel.geometry_id
    assert plan.plan_id != nominal_plan.plan_id
    # designed on its own walls: a narrower channel, a smaller electrode
    assert electrode.mesh.volume < rear_cycle[2].mesh.volume
    m = plan.metrics
    assert min(m.clearance_lower_bound) >= REAR_GAP - REAR_TOLERANCE - 1e-9          # certified at the margin
    assert min(m.clearance_exact) >= min(m.clearance_lower_bound) - 1e-6              # one truth
    assert plan.cycle.certified, plan.cycle.message


@pytest.mark.slow
def test_the_blisk_program_uses_each_channels_own_plan(rear_cycle, own_channel, one_channel):
    from edm_planner.machining.program import PlanCycle, channel_program_steps, program_runs

    nominal_plan, plan = rear_cycle[4], own_channel[3]
    groups = one_channel.channel_groups()
    steps = channel_program_steps(groups, {0: [nominal_plan.plan_id], CHANNEL: [plan.plan_id]}, 60)
    assert len(steps) == 60 and sorted(k for _, k in steps) == list(range(60))
    assert dict((k, p) for p, k in steps)[CHANNEL] == plan.plan_id
    plans = {p.plan_id: PlanCycle.of_plan(p) for p in (nominal_plan, plan)}
    runs = program_runs(steps, plans, pitch=one_channel.blisk.pitch)
    assert [r.plan.plan_id for r in runs] == [nominal_plan.plan_id, plan.plan_id]
    assert runs[1].channels == [CHANNEL] and CHANNEL not in runs[0].channels and len(runs[0].channels) == 59
    feed = [leg for leg in runs[1].legs if leg.phase == "feed"][0]
    assert np.array_equal(feed.samples, plan.samples)                 # the channel's own feed, not the nominal's
    with pytest.raises(EdmError, match="every group needs its own electrode set"):
        channel_program_steps(groups, {0: [nominal_plan.plan_id]}, 60)


def test_the_set_designer_wants_the_channels_own_geometry(one_channel, default_field):
    from edm_planner.machining.electrode_set import SetDesigner

    with pytest.raises(EdmError, match=r"design the set of channel 43 on its own geometry, geometry.for_channel\(43\)"):
        SetDesigner(one_channel, default_field, workers=1).design(CHANNEL)


def test_measured_blades_travel_in_the_geometry_model(one_channel):
    from edm_planner.geometry.as_measured import MeasuredBlades, channel_blisk

    back = MeasuredBlades.from_dict(one_channel.measured.to_dict())
    assert sorted(back.blades) == [CHANNEL, CHANNEL + 1] and back.tolerance == one_channel.measured.tolerance
    view = channel_blisk(one_channel.blisk, back, CHANNEL)
    assert wall_deviation(view, one_channel.for_channel(CHANNEL).blisk) == 0.0


@pytest.mark.slow
def test_check_interference_over_dds_measures_a_measured_channel_against_its_own_walls(one_channel, rear_cycle,
                                                                                      field_cache):
    """geometry_loader publishes the blisk as measured; interference_checker answers channel 43 on its own walls
    (the same pose in a nominal channel keeps the discharge gap, in channel 43 it comes closer)."""
    import threading
    import time

    from edm_planner_msgs.msg import BliskGeometry
    from edm_planner_msgs.msg import ErrorCode as ErrorCodeMsg
    from edm_planner_msgs.srv import CheckInterference
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from edm_planner.geometry.frames import rotation_about_x
    from edm_planner.interference.pose_check import verify_poses
    from edm_planner.nodes.geometry_loader import LATCHED, GeometryLoaderNode
    from edm_planner.nodes.interference_checker import InterferenceCheckerNode
    from edm_planner.ros.conversions import matrix_to_pose
    from ros_harness import InProcessRos

    _, _, electrode, _, _, _ = rear_cycle
    folder = one_channel.source.rsplit("/", 1)[0]
    with InProcessRos() as ros:
        ros.add(GeometryLoaderNode(context=ros.context, parameter_overrides=[
            Parameter("geometry_file", value=one_channel.source), Parameter("allowed_directories", value=[folder])]))
        ros.add(InterferenceCheckerNode(context=ros.context, parameter_overrides=[
            Parameter("cache_dir", value=str(field_cache))]))
        client = ros.add(Node("measured_client", context=ros.context))
        got, ready = [], threading.Event()
        client.create_subscription(BliskGeometry, "geometry", lambda m: (got.append(m), ready.set()), LATCHED)
        assert ready.wait(120), "no geometry published"
        gid = got[-1].summary.geometry_id
        assert gid == one_channel.geometry_id and "as_measured" in got[-1].model_json
        eid = got[-1].electrode_ids[0]
        design_electrode = one_channel.electrode(eid)
        answers = {}
        for k in (0, CHANNEL):
            pose = rotation_about_x(k * one_channel.blisk.pitch) @ design_electrode.final_pose
            req = CheckInterference.Request(geometry_id=gid, channel=k, electrode_id=eid,
                                            method=CheckInterference.Request.METHOD_EXACT)
            req.poses = [matrix_to_pose(pose)]
            deadline = time.monotonic() + 120
            while True:                  # the checker may still be receiving the latched geometry
                res = ros.call(client, CheckInterference, "check_interference", req, timeout=300)
                if res.error_code.val != ErrorCodeMsg.UNKNOWN_ID or time.monotonic() > deadline:
                    break
                time.sleep(0.5)
            assert res.error_code.val == ErrorCodeMsg.SUCCESS, res.message
            c = res.clearances[0]
            answers[k] = np.array([c.suction, c.pressure, c.hub, c.shroud])
    np.testing.assert_allclose(answers[0], 0.1, atol=3e-6)            # a nominal channel: the gap everywhere
    own = one_channel.for_channel(CHANNEL)
    pose = rotation_about_x(CHANNEL * own.blisk.pitch) @ design_electrode.final_pose
    expected = verify_poses(pose[None], design_electrode.mesh.vertices, CHANNEL, own.blisk, None,
                            cache_dir=field_cache, cache_key=own.field_key).clearance_exact
    np.testing.assert_allclose(answers[CHANNEL], [expected[s] for s in ("suction", "pressure", "hub", "shroud")],
                               atol=1e-6)
    assert answers[CHANNEL][:2].max() < 0.1 - 0.03                    # both walls came in by ~0.05 mm


@pytest.mark.slow
def test_edm_plan_plans_and_checks_a_measured_channel_on_its_own_walls(one_channel, own_channel, field_cache,
                                                                     tmp_path):
    """``edm-plan plan --channel 43`` on the blisk as measured gives the channel's own plan (the same as the
    library's), ``edm-plan check`` re-checks it against the channel's own walls, ``geometry info`` names
    the groups."""
    import io

    from edm_planner.cli import main
    from edm_planner.records.plan_export import read_plan

    def run(argv):
        out, err = io.StringIO(), io.StringIO()
        return main(argv, out, err), out.getvalue(), err.getvalue()

    yaml = one_channel.source
    rc, out, err = run(["plan", "--geometry", yaml, "--channel", str(CHANNEL), "--out", str(tmp_path / "plan"),
                        "--cache-dir", str(field_cache), "--electrode", "rear", "--split", "front_rear",
                        "--circumferential-reduction", "0.03", "--radial-reduction", "3", "--split-overlap", "1",
                        "--exit-side", "downstream", "--margin-blade", "0.08", "--margin-hub-shroud", "0.08",
                        "--store", "none", "--progress", "none"])
    assert rc == 0, err
    plan = read_plan(tmp_path / "plan")
    assert plan.channel == CHANNEL and plan.doc["plan_id"] == own_channel[3].plan_id
    np.testing.assert_allclose(plan.axes, own_channel[3].samples, atol=1e-9)
    rc, out, err = run(["check", str(tmp_path / "plan"), "--geometry", yaml, "--threshold", "0.079",
                        "--cache-dir", str(field_cache)])
    assert rc == 0 and "passed" in out, out + err
    rc, out, err = run(["geometry", "info", "--geometry", yaml])
    assert rc == 0, err
    assert "channel_groups: 2" in out and f"measured_blades: [{CHANNEL}, {CHANNEL + 1}]" in out, out


def test_program_steps_of_groups_cover_each_channel_once():
    from edm_planner.machining.program import channel_program_steps

    groups = [(0, [0, 1, 3]), (2, [2])]
    steps = channel_program_steps(groups, {0: ["a", "b"], 2: ["c"]}, 4)
    assert steps == [("a", 0), ("a", 1), ("a", 3), ("b", 0), ("b", 1), ("b", 3), ("c", 2)]
    with pytest.raises(EdmError, match="cover channels 0 .. 3 once each"):
        channel_program_steps([(0, [0, 1])], {0: ["a"]}, 4)
    with pytest.raises(EdmError, match="cover channels 0 .. 3 once each"):
        channel_program_steps([(0, [0, 1, 2, 3]), (1, [1])], {0: ["a"], 1: ["b"]}, 4)
    # one group's set alone: a program of its channels only (edm-plan export --all-channels of such a set)
    assert channel_program_steps([(2, [2, 3])], {2: ["c"]}, 4, partial=True) == [("c", 2), ("c", 3)]
