"""The machining cycle (copy processing) and the automatic electrode set on the default blisk.

One certified feed of the rear electrode of a front/rear split is planned
once per module with the machining margin (gap less the tolerance); the
cycle around it is built, certified, checked against closed forms (the A
rotation of copy processing lands each side face exactly on its wall's gap
offset) and made to overcut on purpose.
"""

import copy
from dataclasses import replace

import numpy as np
import pytest

from edm_planner.geometry.electrode import ElectrodeDesign, design_electrodes
from edm_planner.geometry.frames import rotation_about_x
from edm_planner.geometry.loader import load_geometry
from edm_planner.cnc.kinematics import axis_poses
from edm_planner.machining.cycle import PHASES, CycleOptions, comb_shares, side_rotations
from edm_planner.machining.electrode_set import Piece, SetDesigner, SetOptions, candidate_sets
from edm_planner.machining.removal import simulate_removal
from edm_planner.records.set_files import write_set

from conftest import CONFIG

GAP, TOLERANCE = 0.1, 0.02
MARGIN = GAP - TOLERANCE
DESIGN = ElectrodeDesign(circumferential_reduction=0.03, radial_reduction=3.0, split="front_rear", split_overlap=1.0)


@pytest.fixture(scope="module")
def rear(rear_cycle):
    g, field, electrode, design, plan, builder = rear_cycle
    assert design == DESIGN
    plan = copy.deepcopy(plan)
    return g, field, electrode, plan, builder, plan.cycle


def test_the_cycle_runs_every_phase_in_order_and_is_certified(rear):
    g, field, electrode, plan, builder, cycle = rear
    assert cycle.certified, cycle.message
    assert [p for p, _, _ in cycle.phase_ranges] == list(PHASES)
    samples = cycle.samples
    # legs meet at rest samples: consecutive legs share their end and start
    for a, b in zip(cycle.legs[:-1], cycle.legs[1:]):
        assert np.array_equal(a.samples[-1], b.samples[0])
    feed = dict((p, (a, b)) for p, a, b in cycle.phase_ranges)["feed"]
    assert np.array_equal(samples[feed[0]:feed[1] + 1], plan.samples)
    # the process starts and ends at the machining pose; the return is the feed backwards
    proc = dict((p, (a, b)) for p, a, b in cycle.phase_ranges)["process"]
    assert np.allclose(samples[proc[0]], plan.samples[-1]) and np.allclose(samples[proc[1]], plan.samples[-1])
    ret = dict((p, (a, b)) for p, a, b in cycle.phase_ranges)["return"]
    assert np.array_equal(samples[ret[0]:ret[1] + 1], plan.samples[::-1])
    # approach and retract: the same straight leg both ways, starting and ending at one point further out
    assert np.array_equal(samples[0], cycle.legs[-2].samples[-1]) and cycle.legs[-1].phase == "clear"
    assert np.linalg.norm(samples[0][:3] - plan.samples[0][:3]) <= CycleOptions().approach_distance + 1e-9
    assert np.linalg.norm(samples[0][:3] - plan.samples[0][:3]) >= 0.5 * CycleOptions().approach_distance
    outwards = np.sign(plan.samples[0][0] - plan.samples[-1][0])
    assert outwards * (samples[0][0] - plan.samples[0][0]) > 0
    # every process leg keeps the machining margin (certified lower bound)
    assert np.all(cycle.clearance_lower_bound("process") >= MARGIN)


def test_copy_processing_rotates_each_side_face_onto_its_wall_gap(rear):
    """Closed form: the reduction is a rotation about X by h/2 per side, the process rotation undoes it."""
    g, field, electrode, plan, builder, cycle = rear
    rot = side_rotations(DESIGN, "rear")
    assert rot == {"suction": pytest.approx(-0.015), "pressure": pytest.approx(0.015)}
    assert cycle.reach.rotation_suction == pytest.approx(-0.015)
    assert cycle.reach.rotation_pressure == pytest.approx(0.015)
    unreduced = {e.electrode_id: e for e in design_electrodes(g.blisk, replace(DESIGN, circumferential_reduction=0.0))}
    for wall, angle in rot.items():
        side = "left" if wall == "suction" else "right"
        pts = electrode.samples[side] @ electrode.final_pose[:3, :3].T + electrode.final_pose[:3, 3]
        turned = pts @ rotation_about_x(angle)[:3, :3].T
        ref = unreduced["rear"]
        ref_pts = ref.samples[side] @ ref.final_pose[:3, :3].T + ref.final_pose[:3, 3]
        # same lattice stations: the turned reduced face is the unreduced face (the gap offset of the wall)
        assert len(turned) == len(ref_pts)
        assert np.abs(turned - ref_pts).max() < 1e-9
        # and the field agrees: the wall's clearance is the gap there (within the electrode's chord tolerance)
        clear = field.exact_blade_distances(turned, 0)[:, 0 if wall == "suction" else 1]
        assert clear.min() == pytest.approx(GAP, abs=DESIGN.chord_tolerance + 2e-3)


def test_the_radial_move_reaches_the_shroud_gap_where_the_blades_allow(rear):
    g, field, electrode, plan, builder, cycle = rear
    reach = cycle.reach.radial_reach
    steps = len(comb_shares(CycleOptions().wall_steps))
    assert len(reach) == 1 + 2 * steps                                    # A = 0, then a comb towards each wall
    assert reach[0] == pytest.approx(DESIGN.radial_reduction)            # at A = 0 the whole reduction
    assert all(0 <= r <= DESIGN.radial_reduction + 1e-12 for r in reach)
    # the lean stops the plunge only near a wall: the comb's first steps reach further than its last
    for comb in (reach[1:1 + steps], reach[1 + steps:]):
        assert max(comb) >= comb[-1]
    # the radial direction is the electrode frame's Z: after the move the top face is at the shroud gap
    q = plan.samples[-1].copy()
    q[:3] += reach[0] * electrode.final_pose[:3, 2]
    pose = axis_poses(electrode.final_pose, plan.axis_names, q[None])[0]
    top = electrode.samples["upper"] @ pose[:3, :3].T + pose[:3, 3]
    shroud = field.exact_profile_distances(top)[:, 1]
    assert shroud.min() >= MARGIN
    assert shroud.min() == pytest.approx(GAP, abs=0.01)


def test_a_process_motion_that_overcuts_is_caught(rear):
    """A rotation beyond the reduction pushes the side face into its wall: not certified."""
    g, field, electrode, plan, builder, cycle = rear
    q0 = plan.samples[-1]
    ia = plan.axis_names.index("A")
    q1 = q0.copy()
    q1[ia] -= 0.015 + 0.0005                           # 0.05 mm too far at r = 100 mm
    leg, cert = builder.leg("process", "too far", q0, q1)
    assert not cert.certified
    assert cert.failure_surface == "suction"
    q1[ia] = q0[ia] - 0.015                            # exactly the reduction: certified
    leg, cert = builder.leg("process", "exact", q0, q1)
    assert cert.certified
    # a radial move past the reduction cuts into the shroud
    q2 = q0.copy()
    q2[:3] += (DESIGN.radial_reduction + 0.05) * electrode.final_pose[:3, 2]
    leg, cert = builder.leg("process", "radial too far", q0, q2)
    assert not cert.certified and cert.failure_surface in ("shroud", "suction", "pressure")


def test_the_removal_proof_of_the_rear_cycle(rear):
    """The rear electrode machines its half of the channel; the front half keeps the stock for the front one."""
    g, field, electrode, plan, builder, cycle = rear
    poses = axis_poses(electrode.final_pose, plan.axis_names, cycle.samples)
    report = simulate_removal(g.blisk, [(electrode.mesh.vertices, electrode.mesh.faces, poses)], GAP,
                              tolerance=TOLERANCE, spacing=0.5)
    assert report.overcut_max <= TOLERANCE                           # the machining margin holds
    for name, s in report.surfaces.items():
        u = s.u[np.isfinite(s.stock)]
        stock = s.stock[np.isfinite(s.stock)]
        x_mid = electrode.final_pose[0, 3]
        # behind the rear electrode's front end nothing is machined; in the middle of its range the walls are done
        lo, hi = g.blisk.full_span_axial_range
        front_part = u < lo + 0.25 * (hi - lo)
        assert stock[front_part].min() > TOLERANCE, name
        assert np.median(stock[np.abs(u - x_mid) < 2.0]) <= TOLERANCE, name


def test_the_proof_leaves_out_only_moves_that_retrace_others(rear):
    """Return, retract and every move back of copy processing retrace earlier moves: the proof of the rest
    finds the same stock, to the sampling of the moves (their samples differ, their segments do not)."""
    from edm_planner.machining.proof_path import proof_legs, proof_samples, retraces
    from edm_planner.machining.removal import Sweep, stock_at_points, wall_samples

    g, field, electrode, plan, builder, cycle = rear
    kept = proof_legs(cycle)
    labels = [leg.label for leg in kept]
    assert labels[:2] == ["approach", "feed"] and all(leg.phase == "process" for leg in kept[2:])
    assert not any("back" in lab for lab in labels)
    dropped = [leg for leg in cycle.legs if leg not in kept]
    assert {leg.phase for leg in dropped} == {"process", "return", "retract", "clear"}
    # every one retraces a kept leg, but the clear leg: out along X from the home point, beyond the part
    assert all(retraces(leg.samples, [k.samples for k in kept]) for leg in dropped if leg.phase != "clear")
    assert dropped[-1].phase == "clear" and dropped[-1].samples[0].tolist() == cycle.legs[0].samples[0].tolist()
    assert not retraces(cycle.legs[1].samples[:-5], [k.samples for k in kept if k.phase != "feed"])
    samples, breaks = proof_samples(cycle)
    assert len(samples) < 0.6 * len(cycle.samples)
    # where a kept move does not start where the one before ended, and only there, the sweep records a break
    apart = sum(not np.array_equal(a.samples[-1], b.samples[0]) for a, b in zip(kept, kept[1:]))
    assert len(breaks) == apart >= 1
    assert all(not np.array_equal(samples[i], samples[i + 1]) for i in breaks)
    # the stock at wall points near the electrode's range, from every leg and from the kept ones
    walls = wall_samples(g.blisk, 0.5)
    pts = np.vstack([w.points[w.valid] for w in walls.values()])
    pts = pts[np.abs(pts[:, 0] - electrode.final_pose[0, 3]) < 3.0][::7]
    every = axis_poses(electrode.final_pose, plan.axis_names, cycle.samples)
    fewer = axis_poses(electrode.final_pose, plan.axis_names, samples)
    a, _ = stock_at_points(pts, [(electrode.mesh.vertices, electrode.mesh.faces, every)], GAP)
    b, _ = stock_at_points(pts, [Sweep(electrode.mesh.vertices, electrode.mesh.faces, fewer, breaks)], GAP)
    assert np.all(b >= a - 1e-12)                                  # a subset of the poses never removes more
    assert np.abs(b - a).max() <= 0.5 * 0.05 + 1e-9                # half the 0.05 mm vertex step of a move


def test_candidates_in_order_of_electrode_count():
    g = load_geometry(CONFIG / "default_blisk.yaml")
    cands = candidate_sets(g.blisk, g.design, SetOptions())
    assert [n for n, _ in cands] == ["one electrode", "front/rear", "left/right", "three axial pieces",
                                     "front/rear x left/right", "four axial pieces", "five axial pieces"]
    assert [len(p) for _, p in cands] == [1, 2, 2, 3, 4, 4, 5]
    for name, pieces in cands[3:]:
        ranges = sorted({d.axial_range for _, _, d in pieces})
        assert all(a[1] > b[0] for a, b in zip(ranges, ranges[1:])), name                 # overlapping
        assert ranges[0][0] == pytest.approx(cands[3][1][0][2].axial_range[0]), name       # the same span
        assert ranges[-1][1] == pytest.approx(cands[3][1][-1][2].axial_range[1]), name
        assert len({lab for lab, _, _ in pieces}) == len(pieces), name                       # export dirs
    quarters = dict((lab, (eid, d)) for lab, eid, d in cands[4][1])
    assert sorted(quarters) == ["front-left", "front-right", "rear-left", "rear-right"]
    assert {(eid, d.split) for eid, d in quarters.values()} == {("left", "left_right"), ("right", "left_right")}
    assert len(candidate_sets(g.blisk, g.design, SetOptions(max_electrodes=2))) == 3
    assert len(candidate_sets(g.blisk, g.design, SetOptions(max_electrodes=3))) == 4


def test_the_pieces_sized_ahead_are_those_of_candidates_certain_to_be_tried():
    """While a candidate's pieces are sized, an idle worker sizes ahead only pieces of later candidates with as
    many electrodes: those are tried whatever the current one gives (only an accepted set with fewer electrodes
    passes a candidate over); a candidate with more electrodes may never be tried and is not started."""
    from edm_planner.machining.electrode_set import Candidate

    g = load_geometry(CONFIG / "default_blisk.yaml")
    designer = SetDesigner(g, None, workers=1)
    designer._cands = [Candidate(name, [Piece(lab, eid, d) for lab, eid, d in pieces])
                       for name, pieces in candidate_sets(g.blisk, g.design, SetOptions())]
    names = [c.name for c in designer._cands]
    at = names.index
    ahead = designer._certain_after
    assert ahead(designer._cands[0], 0) == []                              # one electrode: none has one
    assert ahead(designer._cands[1], at("front/rear")) == [(at("left/right"), 0), (at("left/right"), 1)]
    assert ahead(designer._cands[2], at("left/right")) == []
    assert ahead(designer._cands[3], at("three axial pieces")) == []       # the next ones have 4 and 5
    four = at("front/rear x left/right")
    assert ahead(designer._cands[four], four) == [(at("four axial pieces"), j) for j in range(4)]
    designer._ahead[(at("four axial pieces"), 0)] = None                   # submitted already: not twice
    assert ahead(designer._cands[four], four) == [(at("four axial pieces"), j) for j in range(1, 4)]
    # a candidate evaluated on its own, not the design's: nothing ahead
    assert ahead(Candidate("front/rear", designer._cands[1].pieces), at("front/rear")) == []


def test_the_set_designer_reports_why_a_candidate_fails(rear):
    """The primitive electrode (one piece) is infeasible on the default blisk: rejected with the planner's reason."""
    g, field, electrode, plan, builder, cycle = rear
    designer = SetDesigner(g, field, options=SetOptions(max_electrodes=1, time_budget=120.0))
    result = designer.design(0)
    assert not result.success
    (only,) = result.candidates
    assert only.status == "infeasible"
    assert "no certified path" in only.reason and "INFEASIBLE" in only.reason
    assert len(only.pieces[0].tried) == 4                # the four start designs, none certified
    assert "one electrode: infeasible" in result.message


def test_a_thin_electrode_reports_its_stock(rear, tmp_path):
    """A deliberately thin electrode (large h, no process rotation) leaves stock on both walls, and says so."""
    g, field, electrode, plan, builder, cycle = rear
    thin = replace(DESIGN, circumferential_reduction=0.05)
    e = {x.electrode_id: x for x in design_electrodes(g.blisk, thin)}["rear"]
    report = simulate_removal(g.blisk, [(e.mesh.vertices, e.mesh.faces, e.final_pose[None])], GAP,
                              tolerance=TOLERANCE, spacing=0.5)
    # each side face stands h/2 off its wall at the final pose: about 0.025 * r (r ~ 100 .. 120 mm)
    for wall in ("suction", "pressure"):
        s = report.surfaces[wall]
        assert s.area_fraction_above_tolerance > 0.4
        assert s.stock_max > 2.0
    assert not report.every_sample_within_tolerance, "a too thin electrode leaves stock beyond the tolerance"
    # written out with its picture
    from edm_planner.records.stock_maps import plot_stock_maps
    plot_stock_maps(report, tmp_path / "thin.png")
    assert (tmp_path / "thin.png").stat().st_size > 20_000


def test_write_set_of_a_one_piece_result(rear, tmp_path):
    """set.json, stock.png and the export with the cycle (cycle.csv, phases in plan.json)."""
    import json

    from edm_planner.machining.electrode_set import Candidate, ElectrodeSet

    g, field, electrode, plan, builder, cycle = rear
    plan.cycle = cycle
    poses = axis_poses(electrode.final_pose, plan.axis_names, cycle.samples)
    piece = Piece("rear", "rear", DESIGN, plan=plan, cycle=cycle, volume=float(electrode.mesh.volume))
    cand = Candidate("rear only", [piece], status="chosen", reason="test")
    cand.removal = simulate_removal(g.blisk, [(electrode.mesh.vertices, electrode.mesh.faces, poses)], GAP,
                                    tolerance=TOLERANCE, spacing=0.5)
    path = write_set(ElectrodeSet(g.geometry_id, 0, [cand], chosen=cand, message="test"), tmp_path, g.blisk)
    doc = json.loads(path.read_text())
    assert doc["format"] == "edm_planner.electrode_set/1"
    assert doc["electrodes"][0]["plan_id"] == plan.plan_id
    assert doc["candidates"][0]["removal"]["surfaces"]["suction"]["overcut_max_mm"] <= TOLERANCE
    assert (tmp_path / "stock.png").exists() and doc["stock_map"]["candidate"] == "rear only"
    import trimesh
    scene = trimesh.load(tmp_path / "stock.glb")
    assert len(scene.geometry) == 4
    colours = np.vstack([g.visual.vertex_colors for g in scene.geometry.values()])
    assert len(np.unique(colours[:, :3], axis=0)) > 10          # the stock coloured, not one flat colour
    pj = json.loads((tmp_path / "rear" / "plan.json").read_text())
    assert [p["phase"] for p in pj["cycle"]["phases"]] == list(PHASES)
    assert pj["cycle"]["clear_zone"]["clear_x_mm"] == cycle.clear_zone.clear_x
    rows = (tmp_path / "rear" / "cycle.csv").read_text().splitlines()
    assert rows[0].startswith("phase,leg,X_mm,Y_mm,Z_mm,A_rad,C_rad")
    assert len(rows) - 1 == len(cycle.samples)
    assert rows[1].split(",")[0] == "approach" and rows[-1].split(",")[0] == "clear"


def test_the_cycle_ends_at_a_clear_position_beyond_the_part(rear):
    """The clear leg: X alone, away from the blisk, to where no A, C, Y or Z move can reach the part."""
    from edm_planner.cnc.kinematics import axis_poses

    g, field, electrode, plan, builder, cycle = rear
    zone, leg = cycle.clear_zone, cycle.legs[-1]
    names = list(plan.axis_names)
    ix, ic = names.index("X"), names.index("C")
    assert leg.phase == "clear" and len(leg.samples) == 2
    assert np.array_equal(leg.samples[0], cycle.legs[-2].samples[-1])            # from the home point
    step = leg.samples[1] - leg.samples[0]
    assert np.count_nonzero(step) == 1 and np.sign(step[ix]) == zone.side       # X alone, outwards
    assert leg.samples[1][ix] == zone.clear_x and np.all(leg.clearance_lower_bound >= cycle.margin)
    # the envelope holds the model's hub, shroud and blades (and the cycle's 5 mm beyond them)
    lo, hi = zone.envelope
    b = g.blisk
    assert lo == pytest.approx(min(b.hub.x_range[0], b.shroud.x_range[0], b.axial_range[0]) - 5.0)
    assert hi == pytest.approx(max(b.hub.x_range[1], b.shroud.x_range[1], b.axial_range[1]) + 5.0)
    # independently: at the clear position, whatever C, A, Y, Z do, every vertex lies beyond the envelope by
    # at least the stated separation (>= the 2 mm clearance)
    rng = np.random.default_rng(7)
    q = np.repeat(leg.samples[1][None], 200, axis=0)
    q[:, ic] = rng.uniform(-np.pi, np.pi, 200)
    for name, span in (("A", np.pi), ("Y", 50.0), ("Z", 50.0)):
        q[:, names.index(name)] += rng.uniform(-span, span, 200)
    poses = axis_poses(plan.final_pose, plan.axis_names, q)
    x = np.einsum("nij,vj->nvi", poses[:, :3, :3], electrode.mesh.vertices)[..., 0] + poses[:, None, 0, 3]
    gap = (x - hi).min() if zone.side > 0 else (lo - x).max() * -1
    assert gap >= zone.separation(zone.clear_x) >= 2.0 - 1e-9
    # and every blade is further than the blade gap from the home point on (the electrode is past them)
    assert zone.blade_gap > 0


def test_the_sizing_bisection_finds_the_smallest_certified_value():
    """The bracket narrows to the resolution around the threshold; below it nothing is taken."""
    import time as _time

    designer = SetDesigner.__new__(SetDesigner)          # only the bisection: no geometry needed
    designer.options, designer.t0 = SetOptions(), _time.perf_counter()
    tried = []

    def attempt(v):
        tried.append(v)
        return ("plan", f"design {v:.4f}") if v >= 0.3 else (None, None)

    value, best = designer._bisect(0.0, 2.0, 0.01, attempt, ("plan", "design 2"))
    assert 0.3 <= value <= 0.31 and best == ("plan", f"design {value:.4f}")
    assert len(tried) == 8                               # log2(2 / 0.01) halvings
    value, best = designer._bisect(0.0, 0.2, 0.01, attempt, ("plan", "start"))
    assert value == 0.2 and best == ("plan", "start")    # nothing below the start is certified
