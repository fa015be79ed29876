"""Plunge roughing (issue 7, Chen & Dong): formulas, mapping points, optimiser, statistics, axis path."""

import dataclasses
import json
import math

import numpy as np
import pytest

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.geometry.profiles import RevolutionProfile
from edm_planner.cnc.config import load_machine
from edm_planner.cnc.kinematics import axis_poses
from edm_planner.cnc.trajectory import plan_trajectory
from edm_planner.roughing import (RoughingOptions, RoughingOptionsError, error_stats, plan_roughing,
                                  reduction_percent)
from edm_planner.roughing.distance import RevolutionDistance
from edm_planner.roughing.hausdorff import (ToolPoseModel, bottom_points, brute_force_optimum, optimise_pose,
                                            parameter_bounds, paper_iteration)
from edm_planner.roughing.path import TOOL_IN_CARRIER
from edm_planner.roughing.planner import check_travel, target_surface
from edm_planner.roughing.positions import (blade_root_data, groove_step, line_count, line_spacing,
                                            max_tool_radius, minimum_gap, triangular_order)

from conftest import CONFIG

OPTS = RoughingOptions()
UM = 1e-3          # one micrometre [mm]


@pytest.fixture(scope="module")
def blisk(default_geometry):
    return default_geometry.blisk


@pytest.fixture(scope="module")
def plan(blisk):
    stages = []
    res = plan_roughing(blisk, 0, OPTS, progress=lambda *a: stages.append(a))
    return res, stages


# -- eq. 10-13 and the travel order, by hand ------------------------------------------------
def test_minimum_gap_eq10_by_hand():
    # N = 10; interior points k = 2, 3 (1-based): (2 pi 110 - 10 * 2) / 20 = 11 pi - 1, (2 pi 120 - 30) / 20
    # the end points (a tiny radius) are left out (1 < k < n)
    assert minimum_gap([5.0, 110.0, 120.0, 5.0], [4.0, 2.0, 3.0, 4.0], 10) == pytest.approx(11 * math.pi - 1, abs=1e-12)
    assert minimum_gap([130.0, 120.0, 110.0], [0.0, 3.0, 0.0], 10) == pytest.approx(12 * math.pi - 1.5, abs=1e-12)


def test_max_tool_radius_eq11_by_hand():
    assert max_tool_radius(10.0, 0.5, 1.25) == pytest.approx(3.6, abs=1e-12)      # (10 - 1) / 2.5
    assert max_tool_radius(4.0, 0.3, 1.3) == pytest.approx(3.4 / 2.6, abs=1e-12)


def test_groove_step_eq12_by_hand():
    # radius of curvature 10, eps 0.1: 2 sqrt(100 - 9.9^2) = 2 sqrt(1.99)
    assert groove_step(0.1, 0.1, 100.0) == pytest.approx(2 * math.sqrt(1.99), abs=1e-12)
    # radius 1, eps 0.5: 2 sqrt(1 - 0.25) = sqrt(3)
    assert groove_step(1.0, 0.5, 100.0) == pytest.approx(math.sqrt(3.0), abs=1e-12)
    # straight: the cap; capped; radius below eps: the diameter
    np.testing.assert_allclose(groove_step([0.0, 0.1, 10.0], 0.1, 1.5), [1.5, 1.5, 0.2])


def test_line_count_eq13_by_hand():
    # r = 2, h = 0.5: spacing 2 sqrt(2) mm; S = 20: 7.07 lines -> 8
    assert line_spacing(2.0, 0.5) == pytest.approx(2 * math.sqrt(2.0))
    n, value = line_count(20.0, 2.0, 0.5)
    assert value == pytest.approx(20 / (2 * math.sqrt(2.0))) and n == 8
    assert line_count(4 * 2 * math.sqrt(2.0), 2.0, 0.5)[0] == 4            # exact multiple: no extra line
    assert line_count(0.1, 2.0, 0.5)[0] == 1


def test_triangular_travel_order_small_case():
    order, labels = triangular_order(2, [3, 1, 5])
    assert labels == ["O1", "O2", "A1", "B1", "C1", "B2", "A3", "L3.1", "B3", "L3.3", "C3"]
    # grooving inlet -> outlet, then the lines from the outlet back, each A_i -> B_i -> C_i
    assert [labels[i] for i in order] == ["O1", "O2", "A3", "L3.1", "B3", "L3.3", "C3", "B2", "A1", "B1", "C1"]
    with pytest.raises(ValueError):
        triangular_order(1, [4])


def test_blade_gap_on_the_default_blisk(blisk):
    x, radii, thickness = blade_root_data(blisk, 101)
    # eq. 10 is half the circumferential gap between the walls at the shroud, r (theta_p - theta_s) / 2
    th_s, th_p, inside = blisk.wall_angles(x, radii, 0)
    assert inside.all()
    half_gap = radii * (th_p - th_s) / 2
    assert minimum_gap(radii, thickness, blisk.blade_count) == pytest.approx(half_gap[1:-1].min(), abs=1e-9)


# -- eq. 4-8: mapping points ---------------------------------------------------------------------
def _brute_distance(profile, xp, rp, lo, hi):
    """min over a 2-level grid of the profile of the (x, r) distance (eq. 7)."""
    xs = np.linspace(lo, hi, 20001)
    d = np.hypot(xs - xp, profile.radius_at(xs) - rp)
    k = int(np.argmin(d))
    xs = np.linspace(xs[max(k - 1, 0)], xs[min(k + 1, len(xs) - 1)], 20001)
    return float(np.min(np.hypot(xs - xp, profile.radius_at(xs) - rp)))


@pytest.mark.parametrize("name", ["shroud", "cone"])
def test_distance_to_revolution_against_brute_force(blisk, name):
    profile = blisk.shroud if name == "shroud" else RevolutionProfile([[-20.0, 90.0], [40.0, 102.0]], "cone")
    dist = RevolutionDistance(profile)
    rng = np.random.default_rng(7)
    n = 40
    x = rng.uniform(-2.0, 28.0, n)
    th = rng.uniform(-0.5, 0.5, n)
    r = profile.radius_at(x) + rng.uniform(-6.0, 2.0, n)
    pts = np.column_stack([x, r * np.cos(th), r * np.sin(th)])
    signed, grad, foot = dist.closest(pts)
    lo, hi = profile.x_range
    brute = np.array([_brute_distance(profile, a, b, lo - 10, hi + 10) for a, b in zip(x, r)])
    np.testing.assert_allclose(np.abs(signed), brute, atol=1e-9)
    # sign: positive towards the axis (short of the surface)
    assert np.all(np.sign(signed) == np.sign(profile.radius_at(x) - r))
    # the mapping point lies on the surface, at the point's own angle (eq. 6), at the distance found
    np.testing.assert_allclose(np.hypot(foot[:, 1], foot[:, 2]), profile.radius_at(foot[:, 0]), atol=1e-12)
    np.testing.assert_allclose(np.arctan2(foot[:, 2], foot[:, 1]), th, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pts - foot, axis=1), np.abs(signed), atol=1e-12)
    # eq. 6 in 3-D: no other angle is closer (a theta grid around the mapping point's x)
    for i in range(0, n, 8):
        tt = th[i] + np.linspace(-0.2, 0.2, 2001)
        xs = foot[i, 0] + np.linspace(-0.5, 0.5, 201)
        rs = profile.radius_at(xs)
        grid = np.stack(np.broadcast_arrays(xs[:, None], rs[:, None] * np.cos(tt), rs[:, None] * np.sin(tt)), -1)
        assert np.linalg.norm(grid - pts[i], axis=-1).min() >= abs(signed[i]) - 1e-12
    # the gradient is the derivative of the signed distance
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (dist.signed_distance(pts + e) - dist.signed_distance(pts - e)) / (2 * h)
        np.testing.assert_allclose(fd, grad[:, k], atol=1e-6)


# -- the optimiser -------------------------------------------------------------------------------------
def _pose(profile, x, theta, tilt=(0.0, 0.0), offset=0.0):
    """Radial-plunge tool frame on the surface at (x, theta), tilted about its x then y axis, shifted along z."""
    r = float(profile.radius_at(x))
    er = np.array([0.0, math.cos(theta), math.sin(theta)])
    T = np.eye(4)
    T[:3, 0] = [0.0, -math.sin(theta), math.cos(theta)]
    T[:3, 2] = -er
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = [x, r * math.cos(theta), r * math.sin(theta)]
    a, b = tilt
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    rot = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    T[:3, :3] = T[:3, :3] @ rot
    T[:3, 3] += offset * T[:3, 2]
    return T


def _optimise(model, rot=OPTS.rotation_range, trans=OPTS.translation_range, **kw):
    return optimise_pose(model, rot, trans, OPTS.secondary_rotation_range, OPTS.eta, OPTS.increment_tolerance,
                         OPTS.objective_tolerance, OPTS.max_iterations, **kw)


@pytest.mark.parametrize("tilt, offset", [((0.05, 0.0), 0.4), ((0.0, -0.08), -0.3), ((0.0, 0.0), 1.0)])
def test_optimum_on_a_cylinder_is_the_closed_form(tilt, offset):
    # a flat disc of radius rho in a cylinder of radius R: axis radial, the centre rho^2/(4R) short of the
    # surface and the rim points on the circumferential diameter as far beyond: h* = rho^2 / (4 R) exactly
    # (one tilt at a time: the optimum then turns the discretised rim back onto that diameter)
    R, rho = 120.0, 2.0
    cyl = RevolutionProfile([[-50.0, R], [50.0, R]], "cylinder")
    model = ToolPoseModel(RevolutionDistance(cyl), _pose(cyl, 10.0, 0.3, tilt, offset), bottom_points(rho), rho)
    opt = _optimise(model)
    assert opt.h == pytest.approx(rho ** 2 / (4 * R), abs=1e-12)
    assert opt.h < opt.h_initial
    axis, centre = opt.pose[:3, 2], opt.pose[:3, 3]
    er = np.array([0.0, centre[1], centre[2]]) / np.hypot(centre[1], centre[2])
    assert np.dot(axis, -er) == pytest.approx(1.0, abs=1e-12)
    assert R - np.hypot(centre[1], centre[2]) == pytest.approx(rho ** 2 / (4 * R), abs=1e-12)


def test_paper_iteration_alone_is_eq9():
    R, rho = 120.0, 2.0
    h_star = rho ** 2 / (4 * R)
    cyl = RevolutionProfile([[-50.0, R], [50.0, R]], "cylinder")
    lower, upper = parameter_bounds(OPTS.rotation_range, OPTS.translation_range)
    # eta = 1 from the optimal pose: the increment is zero, the iteration stops after one LP
    model = ToolPoseModel(RevolutionDistance(cyl), _pose(cyl, 10.0, 0.3, offset=h_star), bottom_points(rho), rho)
    res = paper_iteration(model, np.zeros(3), lower, upper, eta=1.0)
    assert res.iterations == 1 and res.h == pytest.approx(h_star, abs=1e-12)
    # eta = 0.5 from a tilted pose: h falls monotonically; the stopping rule ends it before N_max a
    # little short of the optimum (which the polish then reaches, test above)
    model = ToolPoseModel(RevolutionDistance(cyl), _pose(cyl, 10.0, 0.3, tilt=(0.1, 0.0)), bottom_points(rho), rho)
    res = paper_iteration(model, np.zeros(3), lower, upper, eta=0.5, max_iterations=200)
    assert np.all(np.diff(res.history) <= 1e-15) and res.iterations < 200
    assert 1e-8 < res.h - h_star < UM


def test_optimiser_matches_brute_force_on_a_cone():
    cone = RevolutionProfile([[-30.0, 95.0], [60.0, 113.0]], "cone")          # slope 0.2 (11.3 degrees)
    for x, tilt, rho in ((5.0, (0.0, 0.0), 4.0), (20.0, (0.1, -0.12), 6.0)):
        model = ToolPoseModel(RevolutionDistance(cone), _pose(cone, x, 0.1, tilt), bottom_points(rho), rho)
        opt = _optimise(model)
        _, h_brute = brute_force_optimum(model, OPTS.rotation_range, OPTS.translation_range)
        assert opt.h <= h_brute + 1e-9
        assert abs(opt.h - h_brute) < UM
        assert opt.h < 0.5 * opt.h_initial


def test_secondary_optimisation_where_the_first_round_got_worse():
    """Section 3.2 on a model made for it: e = +-f(alpha), f = 0.1 + alpha + 15 alpha^2 (no root).

    One full LP step (eta = 1) jumps to alpha = -0.1, f = 0.15: worse than f(0) = 0.1. The secondary round
    (range 0.05) stops at alpha = -0.05, f = 0.0875; the polish finds the minimum f(-1/30) = 1/12.
    """
    class Model:
        scale = 1.0
        bottom = np.zeros((2, 3))

        def f(self, x):
            return 0.1 + x[0] + 15 * x[0] ** 2

        def errors(self, x):
            return np.array([self.f(x), -self.f(x)])

        def evaluate(self, x):
            d = 1 + 30 * x[0]
            return self.errors(x), np.array([[d, 0.0, 0.0], [-d, 0.0, 0.0]])

        def objective(self, x):
            return abs(self.f(x))

        def pose(self, x):
            return np.eye(4)

        def norm(self, dx):
            return float(np.linalg.norm(dx))

    opt = optimise_pose(Model(), 0.1, (-1.0, 1.0), 0.05, eta=1.0, max_iterations=1)
    assert opt.secondary and opt.h_initial == pytest.approx(0.1)
    assert opt.h_paper == pytest.approx(0.0875, abs=1e-12)
    assert opt.h == pytest.approx(1 / 12, abs=1e-12) and opt.x[0] == pytest.approx(-1 / 30, abs=1e-6)


# -- eq. 14-15 ----------------------------------------------------------------------------------------
def test_statistics_eq14_15_by_hand():
    st = error_stats([-1.0, 2.0, -3.0, 2.0])
    # |e| = 1, 2, 3, 2: mu = 2, sigma = sqrt((1 + 0 + 1 + 0) / 4)
    assert st.count == 4 and st.mean_abs == pytest.approx(2.0) and st.std_abs == pytest.approx(math.sqrt(0.5))
    assert (st.min, st.max, st.range, st.max_abs) == (-3.0, 2.0, 5.0, 3.0)
    assert st.to_dict()["range"] == 5.0
    # the paper's figures: 1.30 mm -> 0.5487 mm is a 57.79 % reduction
    assert reduction_percent(1.30, 0.5487) == pytest.approx(57.79, abs=0.005)
    with pytest.raises(ValueError):
        error_stats([])


# -- errors ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [
    {"tool_radius": -1.0}, {"tool_radius": float("nan")}, {"mu": 0.9}, {"allowance": 0.0},
    {"allowance": float("inf")}, {"residual_height": -0.1}, {"step_tolerance": 0}, {"root_points": 2},
    {"bottom_points": 10}, {"bottom_rings": 0}, {"rotation_range": 2.0}, {"secondary_rotation_range": 0.5},
    {"translation_range": (1.0, -1.0)}, {"translation_range": (0.0,)}, {"eta": 0.0}, {"eta": 1.5},
    {"max_iterations": 0}, {"max_iterations": 2.5}, {"polish": "yes"}, {"path_spacing": 0.0},
    {"retract_clearance": -1.0}, {"mu": True}, {"max_step": "1"}])
def test_bad_options_are_rejected(bad):
    with pytest.raises(RoughingOptionsError) as info:
        RoughingOptions(**bad)
    assert isinstance(info.value, ValueError) and info.value.code == ErrorCode.INVALID_REQUEST


def test_bad_requests_are_errors(blisk):
    for channel in (-1, 60, 1.5, True, "0"):
        with pytest.raises(EdmError) as info:
            plan_roughing(blisk, channel)
        assert info.value.code == ErrorCode.INVALID_REQUEST
    with pytest.raises(EdmError) as info:
        plan_roughing(blisk, 0, options={"tool_radius": 1.0})
    assert info.value.code == ErrorCode.INVALID_REQUEST
    with pytest.raises(EdmError) as info:
        plan_roughing(blisk, 0, RoughingOptions(tool_radius=2.0))           # r_max is 1.64 mm
    assert info.value.code == ErrorCode.INFEASIBLE and "r_max" in info.value.message
    with pytest.raises(EdmError) as info:
        plan_roughing(blisk, 0, RoughingOptions(allowance=3.0))             # (L_min - 6) / 2.6 < 0
    assert info.value.code == ErrorCode.INFEASIBLE and "no tool fits" in info.value.message
    with pytest.raises(EdmError) as info:                                   # best h ~ 6 um > 1 um allowance
        plan_roughing(blisk, 0, RoughingOptions(allowance=0.001))
    assert info.value.code == ErrorCode.INFEASIBLE and "cut into the finished shroud" in info.value.message


# -- the plan on the default blisk -----------------------------------------------------------------------
def test_plan_on_the_default_blisk(blisk, plan):
    res, stages = plan
    n = res.position_count
    assert res.tool_radius == res.r_max and 1.5 < res.r_max < 1.8
    assert res.groove_count + sum(1 for lb in res.labels if lb[0] in "ABCL") == n
    assert sorted(res.order) == list(range(n))
    assert np.all(res.groove_steps <= res.tool_radius + 1e-12) and np.all(res.groove_steps > 0)
    assert res.line_count == math.ceil(res.machining_length / res.line_spacing - 1e-9)
    # every bottom centre on the target surface, between the walls by at least tool radius + allowance
    target = target_surface(blisk, OPTS.allowance)
    c = res.initial_poses[:, :3, 3]
    r = np.hypot(c[:, 1], c[:, 2])
    np.testing.assert_allclose(r, target.radius_at(c[:, 0]), atol=1e-9)
    th_s, th_p, inside = blisk.wall_angles(c[:, 0], r, 0)
    th = np.arctan2(c[:, 2], c[:, 1])
    assert inside.all()
    clearance = res.tool_radius + OPTS.allowance
    assert np.all(r * (th - th_s) >= clearance - 1e-3) and np.all(r * (th_p - th) >= clearance - 1e-3)
    # never worse than the initial pose or the paper's iteration; the statistics improve
    assert np.all(res.hausdorff <= res.hausdorff_initial + 1e-12)
    assert np.all(res.hausdorff <= res.hausdorff_paper + 1e-12)
    assert res.stats.mean_abs < 0.2 * res.stats_initial.mean_abs and res.stats.std_abs < res.stats_initial.std_abs
    assert res.stats.max_abs == pytest.approx(res.hausdorff.max()) and res.stats.count == n * 49
    assert res.mae_reduction_percent == pytest.approx(
        100 * (1 - np.abs(res.errors).mean() / np.abs(res.errors_initial).mean()))
    summary = json.loads(json.dumps(res.summary()))                       # plain data
    assert summary["paper_mae_reduction_percent"] == 57.79 and summary["positions"] == n
    # progress as the planner's: (stage, fraction, nodes, reference_mm, message)
    assert {s[0] for s in stages} == {"positions", "optimise", "path"}
    assert stages[-1][:3] == ("path", 1.0, n)


def test_optimum_on_the_default_blisk_matches_brute_force(blisk, plan):
    res, _ = plan
    dist = RevolutionDistance(target_surface(blisk, OPTS.allowance))
    bottom = bottom_points(res.tool_radius, OPTS.bottom_rings, OPTS.bottom_points)
    for label in ("O1", "C8"):
        i = res.labels.index(label)
        model = ToolPoseModel(dist, res.initial_poses[i], bottom, res.tool_radius)
        _, h_brute = brute_force_optimum(model, OPTS.rotation_range, OPTS.translation_range)
        assert res.hausdorff[i] <= h_brute + 1e-9
        assert abs(res.hausdorff[i] - h_brute) < UM


def test_axis_path_round_trip_and_spacing(plan):
    res, _ = plan
    carrier = axis_poses(res.reference_pose, res.axis_names, res.samples)
    tool = carrier @ TOOL_IN_CARRIER
    # the path visits the optimised poses, in travel order, exactly
    np.testing.assert_allclose(tool[res.bottom_index], res.poses[res.order], atol=1e-9)
    # ... from and back to a retract point on the same tool axis
    for k in (0, len(res.order) // 2, len(res.order) - 1):
        b = res.bottom_index[k]
        pose = res.poses[res.order[k]]
        for j in (b - 1, b + 1):
            np.testing.assert_allclose(tool[j, :3, :3], pose[:3, :3], atol=1e-9)
            off = tool[j, :3, 3] - pose[:3, 3]
            np.testing.assert_allclose(off, np.dot(off, pose[:3, 2]) * pose[:3, 2], atol=1e-9)
            assert np.dot(off, pose[:3, 2]) > 0
        up = res.path.retract_index[k]
        np.testing.assert_allclose(tool[up, :3, 3], pose[:3, 3] + res.retract_distances[k] * pose[:3, 2], atol=1e-9)
    # retracted below the hub radius (clear of the blades), and A near channel 0
    assert np.all(res.retract_distances > 15.0)
    assert np.all(np.abs(res.samples[:, 3]) < 0.2)
    # no point of the tool bottom moves more than the spacing between samples
    rim = bottom_points(res.tool_radius, 1, 16)
    pts = np.einsum("nij,mj->nmi", tool[:, :3, :3], rim) + tool[:, None, :3, 3]
    assert np.linalg.norm(np.diff(pts, axis=0), axis=2).max() <= OPTS.path_spacing + 1e-9


def test_bridge_times_the_roughing_path(plan):
    res, _ = plan
    machine = load_machine(CONFIG / "machine.yaml")
    for name, lim in machine.axes.items():
        j = res.axis_names.index(name)
        joint = lim.to_joint(res.samples[:, j])
        assert joint.min() > lim.position_min and joint.max() < lim.position_max
    check_travel(res.samples, res.axis_names, machine)
    narrow = dataclasses.replace(machine, axes={**machine.axes, "Y": dataclasses.replace(machine.axes["Y"],
                                                                                         position_min=-5.0)})
    with pytest.raises(EdmError) as info:
        check_travel(res.samples, res.axis_names, narrow)
    assert info.value.code == ErrorCode.INFEASIBLE and "axis Y" in info.value.message
    traj = plan_trajectory(res.samples, res.axis_names, machine, final_pose=res.reference_pose)
    assert traj.duration > 0 and len(traj.times) == len(res.samples)
    # the executed spline does not plunge past an optimised pose: sampled densely around each bottom
    from scipy.interpolate import CubicSpline
    spline = CubicSpline(traj.times, traj.positions, bc_type=((1, np.zeros(5)), (1, np.zeros(5))))
    worst = 0.0
    for k in range(0, len(res.order), 7):
        b = res.bottom_index[k]
        q = spline(np.linspace(traj.times[b - 3], traj.times[b + 3], 200))
        tool = axis_poses(res.reference_pose, res.axis_names, q) @ TOOL_IN_CARRIER
        pose = res.poses[res.order[k]]
        worst = min(worst, float(((tool[:, :3, 3] - pose[:3, 3]) @ pose[:3, 2]).min()))
    assert worst > -1e-6


def test_other_channel_is_the_same_plan_rotated(blisk, plan):
    res0, _ = plan
    coarse = dataclasses.replace(OPTS, bottom_rings=1, bottom_points=8, residual_height=2.0)
    r0 = plan_roughing(blisk, 0, coarse)
    r5 = plan_roughing(blisk, 5, coarse)
    rot = blisk.channel_transform(5)
    np.testing.assert_allclose(rot @ r0.poses, r5.poses, atol=1e-9)
    np.testing.assert_allclose(r5.hausdorff, r0.hausdorff, atol=1e-9)
    # channel k on the A axis: k pitches on from channel 0, the other axes the same
    np.testing.assert_allclose(r5.samples[:, 3], r0.samples[:, 3] + 5 * blisk.pitch, atol=1e-9)
    np.testing.assert_allclose(r5.samples[:, [0, 1, 2, 4]], r0.samples[:, [0, 1, 2, 4]], atol=1e-9)
    np.testing.assert_allclose(r5.reference_pose, res0.reference_pose, atol=1e-12)


def test_paper_iteration_only(blisk):
    res = plan_roughing(blisk, 0, RoughingOptions(polish=False, bottom_rings=1, bottom_points=8,
                                                  residual_height=2.0))
    assert np.all(res.polish_iterations == 0)
    np.testing.assert_allclose(res.hausdorff, res.hausdorff_paper, atol=1e-12)
