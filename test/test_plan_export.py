"""Plan export: write/read round trip, the exported files re-checked exactly, malformed files rejected."""

import dataclasses
import json
import shutil
import zlib

import numpy as np
import pytest
import trimesh

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.geometry.frames import rotation_about_x
from edm_planner.geometry.electrode import ElectrodeDesign, design_electrodes
from edm_planner.interference import SURFACES
from edm_planner.interference.exact_points import ExactChannelDistance, transform_points
from edm_planner.cnc.kinematics import state_axes, state_poses
from edm_planner.interference.pose_check import verify_poses
from edm_planner.cnc.kinematics import axes_to_poses
from edm_planner.records.plan_check import verify_exported_plan
from edm_planner.records.plan_export import FORMAT, PlanFileError, read_plan, write_plan
from edm_planner.planning.plan import AXIS_NAMES, Plan, PlanMetrics, PlanOptions
from edm_planner.planning.search import ExitSearch, SearchOptions, SearchStatus



def _dense(electrode, states, spacing):
    """States interpolated linearly between nodes so that no vertex moves more than ``spacing``."""
    V = electrode.mesh.vertices
    poses = state_poses(electrode.final_pose, states[:, :3], states[:, 3], states[:, 4])
    W = transform_points(poses, V)
    moves = np.linalg.norm(np.diff(W, axis=0), axis=2).max(axis=1)
    out = [states[:1]]
    for i, move in enumerate(moves):
        n = int(np.ceil(move / (0.8 * spacing)))      # linear in the states is not uniform in the vertices
        t = np.linspace(0, 1, n + 1)[1:, None]
        out.append(states[i] + t * (states[i + 1] - states[i]))
    return np.vstack(out)


@pytest.fixture(scope="module")
def planned(tmp_path_factory, default_geometry, default_field):
    """A plan from a real exit search: the reduced rear electrode of a front/rear split, channel 0."""
    g, field = default_geometry, default_field
    rear = design_electrodes(g.blisk, ElectrodeDesign(circumferential_reduction=0.045, radial_reduction=1.5,
                                                      split="front_rear", split_overlap=1.0))[1]
    opts = PlanOptions(search=SearchOptions(method="max_min_distance", exit_side="downstream", step=0.2))
    res = ExitSearch(g.blisk, rear, field, opts.search).run()
    assert res.status == SearchStatus.SUCCESS, res.message
    feed = res.states[::-1]                         # feed order: outside the blisk first
    dense = _dense(rear, feed, opts.sample_spacing)
    pos, a, c = dense[:, :3], dense[:, 3], dense[:, 4]
    metrics = PlanMetrics(node_count=len(feed), path_length=float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum()),
                          clearance_lower_bound=tuple(res.clearances.min(axis=0)), objfun1=res.objfun1,
                          objfun2=res.objfun2, axis_names=AXIS_NAMES[5], solver_evaluations=res.evaluations,
                          planning_time=res.elapsed, certified=True, circumferential_reduction=0.045)
    plan = Plan(plan_id="test-plan-1", error_code=ErrorCode.SUCCESS, message="ok", geometry_id=g.geometry_id,
                channel=0, electrode_id=rear.electrode_id, electrode_mesh=rear.mesh, final_pose=rear.final_pose,
                options=opts, axis_names=AXIS_NAMES[5], samples=state_axes(rear.final_pose, pos, a, c),
                poses=state_poses(rear.final_pose, pos, a, c),
                nodes=state_axes(rear.final_pose, feed[:, :3], feed[:, 3], feed[:, 4]), metrics=metrics)
    out = tmp_path_factory.mktemp("plan") / "channel0"
    write_plan(plan, out, g.blisk)
    return g, plan, out


@pytest.fixture(scope="module")
def field(default_field):
    """The planner's distance field (loaded from the cache): the verification uses its exact solvers."""
    return default_field


def brute_force(field, poses, vertices, channel=0):
    """Exact distances of every vertex at every pose by the numba solvers: (poses, vertices, 4)."""
    world = transform_points(poses, vertices).reshape(-1, 3)
    d = np.concatenate([field.exact_blade_distances(world, channel), field.exact_profile_distances(world)], axis=1)
    return d.reshape(len(poses), len(vertices), 4)


def test_round_trip_keeps_every_number(planned):
    g, plan, out = planned
    doc = json.loads((out / "plan.json").read_text())
    assert doc["format"] == FORMAT and doc["units"] == {"length": "mm", "angle": "rad"}
    assert doc["geometry_id"] == g.geometry_id and doc["channel"] == 0 and doc["method"] == "max_min_distance"
    assert doc["electrode_id"] == "rear" and doc["axis_names"] == ["X", "Y", "Z", "A", "C"]
    s = doc["settings"]
    assert s["search"]["step"] == 0.2 and s["search"]["exit_side"] == "downstream"
    assert s["search"]["weights"]["margin"] == [0.5, 0.25, 0.25] and s["sample_spacing"] == 0.05
    assert doc["metrics"]["node_count"] == len(plan.nodes) > 20
    assert set(doc["metrics"]["clearance_lower_bound"]) == set(SURFACES)

    r = read_plan(out)
    assert r.success and r.axis_names == AXIS_NAMES[5] and len(r.axes) == len(plan.samples) > 100
    # bit-exact: shortest round-trip digits in JSON and CSV, ASCII STL for the electrode
    np.testing.assert_array_equal(r.axes, plan.samples)
    np.testing.assert_array_equal(r.poses, plan.poses)
    np.testing.assert_array_equal(r.final_pose, plan.final_pose)
    np.testing.assert_array_equal(r.nodes, plan.nodes)
    m = plan.electrode_mesh
    np.testing.assert_array_equal(r.electrode_mesh.vertices, np.unique(m.vertices, axis=0))
    assert len(r.electrode_mesh.faces) == len(m.faces) and r.electrode_mesh.is_watertight
    assert r.electrode_mesh.volume == pytest.approx(m.volume, rel=1e-12)
    # feed order: starts outside the blisk downstream, ends at the final pose (axes zero but A = 0 in channel 0)
    np.testing.assert_allclose(r.axes[-1], 0.0, atol=1e-9)
    assert r.axes[0, 0] > 10.0
    # the axis values reproduce the poses under the documented convention
    np.testing.assert_allclose(axes_to_poses(r.axis_names, r.axes, r.final_pose, 0, g.blisk.pitch), r.poses,
                               atol=1e-9)


def test_electrode_stl_is_kept_by_content_and_written_the_same(planned, tmp_path, caplog):
    """With a cache directory electrode.stl's text is formatted once per mesh: later exports read it back,
    byte for byte trimesh's ASCII STL; a damaged cache file is formatted and written again."""
    g, plan, out = planned
    reference = (out / "electrode.stl").read_bytes()         # written without a cache
    assert reference == trimesh.exchange.stl.export_stl_ascii(plan.electrode_mesh).encode()
    cache = tmp_path / "cache"
    write_plan(plan, tmp_path / "first", g.blisk, cache_dir=cache)
    kept = list((cache / "electrode_stl").glob("*.stl.z"))
    assert len(kept) == 1
    stamp = kept[0].stat().st_mtime_ns
    write_plan(plan, tmp_path / "second", g.blisk, cache_dir=cache)
    assert kept[0].stat().st_mtime_ns >= stamp and list((cache / "electrode_stl").glob("*.stl.z")) == kept
    for name in ("first", "second"):
        assert (tmp_path / name / "electrode.stl").read_bytes() == reference
    kept[0].write_bytes(b"not zlib")
    with caplog.at_level("WARNING"):
        write_plan(plan, tmp_path / "third", g.blisk, cache_dir=cache)
    assert "unreadable" in caplog.text
    assert (tmp_path / "third" / "electrode.stl").read_bytes() == reference
    assert zlib.decompress(kept[0].read_bytes()) == reference
    other = plan.electrode_mesh.copy()
    other.vertices[0, 0] += 1e-9                               # another mesh: another entry
    write_plan(dataclasses.replace(plan, electrode_mesh=other), tmp_path / "fourth", g.blisk, cache_dir=cache)
    assert len(list((cache / "electrode_stl").glob("*.stl.z"))) == 2


def test_workpiece_surfaces_are_recoverable(planned):
    g, plan, out = planned
    parts = read_plan(out).workpiece_meshes()
    ref = g.blisk.channel_meshes(0, 0.5)
    for s in SURFACES:
        assert len(parts[s].faces) == len(ref[s].faces)
        np.testing.assert_allclose(parts[s].triangles_center.mean(axis=0), ref[s].triangles_center.mean(axis=0),
                                   atol=1e-4)      # float32 binary STL
    # the labels are right: the exact clearance of each surface's own vertices to it is ~0
    ex = ExactChannelDistance(g.blisk)
    for i, s in enumerate(SURFACES):
        v = parts[s].vertices[::50]
        inside = (v[:, 0] > g.blisk.axial_range[0] + 1) & (v[:, 0] < g.blisk.axial_range[1] - 1)
        assert np.abs(ex.clearances(v[inside])[:, i]).max() < 0.01


def test_exported_files_pass_the_exact_recheck(planned, field):
    g, plan, out = planned
    check = verify_exported_plan(out, g.blisk, threshold=0.0, geometry_id=g.geometry_id, field=field)
    assert check.passed, check.message
    assert check.samples == len(plan.samples) and check.vertices == len(np.unique(plan.electrode_mesh.vertices,
                                                                                     axis=0))
    assert check.max_vertex_step <= 0.05 and check.axes_pose_error < 1e-9 and check.start_outside
    # the search keeps 0.02 mm margins at its nodes (less the field bound on sampled points); between nodes
    # the linear interpolation of this test keeps them to within a few hundredths
    mins = check.clearance_exact
    assert min(mins["suction"], mins["pressure"]) > 0.0
    # at the final pose the electrode is the channel shrunk by the 0.1 mm discharge gap: hub 0.1 mm
    assert mins["hub"] == pytest.approx(0.1, abs=2e-3)
    assert check.argmin["hub"][0] == len(plan.samples) - 1
    # the bounding evaluated a small share of all points, and the minima it found are those of the exact
    # method (ExactChannelDistance, scipy): every vertex at the samples where they were attained and their
    # neighbours
    assert check.exact_evaluations < 0.1 * check.samples * check.vertices
    ex = ExactChannelDistance(g.blisk)
    V = np.unique(plan.electrode_mesh.vertices, axis=0)
    near = sorted({min(max(check.argmin[s][0] + d, 0), len(plan.poses) - 1) for s in SURFACES for d in (-1, 0, 1)})
    scipy = ex.clearances(transform_points(plan.poses[near], V).reshape(-1, 3)).reshape(len(near), len(V), 4)
    for i, s in enumerate(SURFACES):
        j, k = check.argmin[s]
        assert scipy[:, :, i].min() >= mins[s] - 1e-6
        assert scipy[near.index(j), :, i].min() == pytest.approx(mins[s], abs=1e-6)
        assert scipy[near.index(j), k, i] == pytest.approx(mins[s], abs=1e-6)


def test_minima_equal_a_brute_force_over_every_sample_and_vertex(planned, field):
    g, plan, _ = planned
    V = np.unique(plan.electrode_mesh.vertices, axis=0)[::29]
    # where the walls come closest, and the last samples into the machining pose (hub at the gap)
    walls = verify_poses(plan.poses, V, 0, g.blisk, field)
    j = walls.argmin["suction"][0]
    for part in (plan.poses[max(j - 40, 0):j + 40], plan.poses[-60:]):
        check = verify_poses(part, V, 0, g.blisk, field)
        every = brute_force(field, part, V)
        np.testing.assert_allclose([check.clearance_exact[s] for s in SURFACES], every.min(axis=(0, 1)), rtol=0,
                                   atol=1e-12)
        for i, s in enumerate(SURFACES):
            assert every[check.argmin[s] + (i,)] == pytest.approx(check.clearance_exact[s], abs=1e-12)
        assert check.exact_evaluations < every.shape[0] * every.shape[1] and check.behind_pairs == 0


def test_a_path_sliding_into_a_blade_is_caught_exactly(planned, field):
    g, plan, _ = planned
    V = np.unique(plan.electrode_mesh.vertices, axis=0)[::29]
    # turned half a pitch towards the suction wall and fed axially from 6 mm downstream: the vertices on that
    # side enter blade 0 and the channel beyond it across the blade's footprint (from its trailing edge),
    # where the signed distance jumps from + to -, not through the face
    poses = np.repeat((rotation_about_x(-0.5 * g.blisk.pitch) @ plan.poses[-1])[None], 121, axis=0)
    poses[:, 0, 3] += np.linspace(6.0, 0.0, 121)
    every = brute_force(field, poses, V)
    suction = every[..., 0]
    jumps = (np.signbit(suction[1:]) != np.signbit(suction[:-1])) & (np.abs(np.diff(suction, axis=0)) > 0.1)
    assert suction.min() < -1.0 and jumps.sum() > 10
    for few in (False, True):                    # anchors every 0.5 mm of travel / the first and last only
        check = verify_poses(poses, V, 0, g.blisk, field, anchor_travel=100.0 if few else 0.5)
        np.testing.assert_allclose([check.clearance_exact[s] for s in SURFACES], every.min(axis=(0, 1)), rtol=0,
                                   atol=1e-12)
        assert not check.passed and "suction clearance" in check.message
    # the side tests found every position behind a wall, as the exact distances have them
    assert check.behind_pairs == (every[..., :2] < 0).sum()


def test_verify_poses_loads_its_field_and_refuses_bad_input(planned, field, field_cache):
    g, plan, _ = planned
    V = plan.electrode_mesh.vertices[::50]
    a = verify_poses(plan.poses[-30:], V, 0, g.blisk, field)
    b = verify_poses(plan.poses[-30:], V, 0, g.blisk, cache_dir=field_cache, cache_key=g.geometry_id, threads=1,
                     anchor_stride=1)
    assert a.clearance_exact == b.clearance_exact and a.argmin == b.argmin and b.anchor_samples == 30
    # another channel: the same plan turned by k pitches
    k = 4
    c = verify_poses(rotation_about_x(k * g.blisk.pitch)[None] @ plan.poses[-30:], V, k, g.blisk, field)
    for s in SURFACES:
        assert c.clearance_exact[s] == pytest.approx(a.clearance_exact[s], abs=1e-9)
    bad = plan.poses[-3:].copy()
    bad[1, :3, :3] *= 1.001
    with pytest.raises(ValueError, match="rigid"):
        verify_poses(bad, V, 0, g.blisk, field)
    with pytest.raises(ValueError):
        verify_poses(plan.poses[-3:], np.zeros((0, 3)), 0, g.blisk, field)


def test_recheck_catches_a_path_that_cuts_a_blade(planned, field, tmp_path):
    g, plan, out = planned
    # the last 160 samples (inside the channel) keep the exact re-check short
    plan = dataclasses.replace(plan, samples=plan.samples[-160:], poses=plan.poses[-160:])
    bad = tmp_path / "bad"
    write_plan(plan, bad, g.blisk)
    doc = json.loads((bad / "plan.json").read_text())
    # turn five samples in the middle about X towards the suction wall by their clearance + 0.3 mm: into the blade
    j = len(doc["samples"]) // 2
    V = plan.electrode_mesh.vertices
    world = transform_points(plan.poses[j], V)[0]
    gap = ExactChannelDistance(g.blisk).clearances(world)[:, 0].min()
    turn = rotation_about_x(-(gap + 0.3) / np.hypot(world[:, 1], world[:, 2]).min())
    for k in range(j - 2, j + 3):
        doc["samples"][k]["pose"] = (turn @ plan.poses[k]).reshape(-1).tolist()
    (bad / "plan.json").write_text(json.dumps(doc))
    check = verify_exported_plan(bad, g.blisk, threshold=0.0, field=field)
    assert not check.passed
    assert check.clearance_exact["suction"] < 0 and check.argmin["suction"][0] in range(j - 2, j + 3)
    assert "suction clearance" in check.message and "disagree" in check.message and "moves" in check.message
    assert not check.start_outside and "not outside" in check.message


def _tampered(out, tmp_path, edit):
    bad = shutil.copytree(out, tmp_path / "bad")
    doc = json.loads((bad / "plan.json").read_text())
    edit(doc)
    (bad / "plan.json").write_text(json.dumps(doc))
    return bad


def _non_rigid(doc):
    p = np.array(doc["samples"][3]["pose"]).reshape(4, 4)
    p[:3, :3] *= 1.001                   # a scaling, not a rotation
    doc["samples"][3]["pose"] = p.reshape(-1).tolist()


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(format="edm_planner.plan/2"), "format is 'edm_planner.plan/2'"),
    (lambda d: d["samples"][5]["axes"].__setitem__(2, float("nan")), "samples[5].axes: contains NaN"),
    (lambda d: d["samples"][7].pop("pose"), "samples[7] needs 'axes' and 'pose'"),
    (lambda d: d["samples"][7].update(pose=d["samples"][7]["pose"][:12]), "samples[7].pose: expected 16 numbers"),
    (_non_rigid, "pose 3 is not a rigid motion"),
    (lambda d: d.update(units={"length": "m", "angle": "rad"}), "units are"),
    (lambda d: d.update(axis_names=["X", "Y", "Z", "A"]), "axis_names"),
    (lambda d: d.pop("geometry_id"), "missing key 'geometry_id'"),
    (lambda d: d.update(samples=d["samples"][:1]), "at least 2 samples"),
])
def test_malformed_plan_json_is_rejected(planned, tmp_path, edit, words):
    _, _, out = planned
    with pytest.raises(PlanFileError) as err:
        read_plan(_tampered(out, tmp_path, edit))
    assert err.value.code == ErrorCode.FILE_ERROR and words in str(err.value)


def test_broken_or_missing_companion_files_are_rejected(planned, tmp_path):
    _, _, out = planned
    with pytest.raises(PlanFileError, match="no such file"):
        read_plan(tmp_path / "nowhere")
    bad = shutil.copytree(out, tmp_path / "a")
    (bad / "plan.json").write_text("{ not json")
    with pytest.raises(PlanFileError, match="not valid JSON"):
        read_plan(bad)
    bad = shutil.copytree(out, tmp_path / "b")
    trimesh.creation.box().export(bad / "electrode.stl")
    with pytest.raises(PlanFileError, match="sha256 differs"):
        read_plan(bad)
    bad = shutil.copytree(out, tmp_path / "c")
    lines = (bad / "axes.csv").read_text().splitlines()
    lines[4] = lines[4].rsplit(",", 1)[0] + ",0.5"
    (bad / "axes.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(PlanFileError, match="axes.csv: axis values differ"):
        read_plan(bad)
    bad = shutil.copytree(out, tmp_path / "d")
    (bad / "workpiece.stl").unlink()
    with pytest.raises(PlanFileError, match="workpiece.stl: no such file"):
        read_plan(bad)


def test_failed_plan_is_written_but_refused_by_default(planned, tmp_path):
    g, plan, _ = planned
    failed = Plan(plan_id="f", error_code=ErrorCode.INFEASIBLE, message="blocked by the suction wall",
                  geometry_id=g.geometry_id, channel=2, electrode_id="main", electrode_mesh=plan.electrode_mesh,
                  final_pose=plan.final_pose, options=plan.options, axis_names=AXIS_NAMES[5],
                  samples=np.zeros((0, 5)), poses=np.zeros((0, 4, 4)), nodes=np.zeros((0, 5)),
                  metrics=PlanMetrics(), furthest_node=4, furthest_reference=0.8, blocking_surface="suction",
                  blocking_clearance_lower_bound=-0.01)
    write_plan(failed, tmp_path / "f", g.blisk)
    doc = json.loads((tmp_path / "f" / "plan.json").read_text())      # strict JSON: NaN written as null
    assert doc["metrics"]["clearance_lower_bound"]["hub"] is None and doc["failure"]["blocking_surface"] == "suction"
    with pytest.raises(EdmError) as err:
        read_plan(tmp_path / "f")
    assert err.value.code == ErrorCode.INFEASIBLE and "blocked by the suction wall" in str(err.value)
    r = read_plan(tmp_path / "f", require_success=False)
    assert not r.success and r.channel == 2 and r.axes.shape == (0, 5)
