"""The core's suites: geometry, interference (field, checker, plan re-check, services), planning, roughing."""

import logging
import tempfile
import time

import numba
import numpy as np
import trimesh

from ..cli import DEFAULT_CACHE
from ..geometry.electrode import design_electrodes
from ..geometry.frames import cylindrical_to_cartesian
from ..geometry.loader import load_geometry
from ..interference.checker import ChannelChecker, CheckerOptions, Method
from ..interference.exact_points import transform_points
from ..interference.fast import FastChannelField
from ..planning.plan import PlanOptions
from ..planning.planner import plan_channel
from ..planning.search import SearchOptions
from ..roughing import PAPER_MAE_REDUCTION_PERCENT, RoughingOptions, plan_roughing
from ..roughing.distance import RevolutionDistance
from ..roughing.hausdorff import ToolPoseModel, bottom_points, brute_force_optimum, optimise_pose
from ..roughing.planner import target_surface
from ..roughing.stats import reduction_percent
from .common import CONFIG, best_of, poses_near, rear_design
from .interference import bench_verify_plan
from .service import service_round_trip

_log = logging.getLogger(__name__)


def bench_geometry():
    """Loading the three example geometries and the face queries the planner makes."""
    out = {}
    for name in ("default_blisk", "rotor37", "mesh_blisk"):
        t = time.perf_counter()
        g = load_geometry(CONFIG / f"{name}.yaml")
        load_s = time.perf_counter() - t
        t = time.perf_counter()
        s = g.summary()
        out[name] = {"load_s": round(load_s, 3), "summary_s": round(time.perf_counter() - t, 3),
                     "blade_sections": list(g.blisk.blade.shape),
                     "electrode_triangles": s["electrode_mesh_triangles"],
                     "min_channel_width_mm": round(s["min_channel_width"], 4)}
    g = load_geometry(CONFIG / "default_blisk.yaml")
    b = g.blisk
    rng = np.random.default_rng(0)
    x0, x1 = b.full_span_axial_range
    n = 20000
    x = rng.uniform(x0, x1, n)
    r = b.hub.radius_at(x) + rng.uniform(0.05, 0.95, n) * (b.shroud.radius_at(x) - b.hub.radius_at(x))
    t = best_of(lambda: b.suction_face.theta_at(x, r))
    out["face_theta_at_points_per_s"] = round(n / t)
    th_s, th_p, _ = b.wall_angles(x, r)
    pts = cylindrical_to_cartesian(x, r, th_s + rng.uniform(0, 1, n) * (th_p - th_s))
    t = best_of(lambda: b.suction_face.closest_points(pts))
    out["face_closest_point_points_per_s"] = round(n / t)
    return out


def memory_figures(field, poses, pts):
    """Why the field is memory bound: its grid's size, one core's throughput, and random loads.

    A dependent random load (pointer chase) within 0.5 MB, 16 MB and the
    grid's size, and independent random loads over the grid itself: a query
    reads four cache lines of the grid, so uncached queries cannot beat a
    quarter of the independent load rate.
    """
    @numba.njit
    def chase(nxt, n):
        i = 0
        for _ in range(n):
            i = nxt[i]
        return i

    @numba.njit
    def gather(a, idx):
        s = 0.0
        for i in idx:
            s += a[i]
        return s

    grid = field.kernel_args(0)[1]
    out = {"fast_grid_mb": round(grid.nbytes / 1e6, 1)}
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        t = best_of(lambda: field.pose_clearances(poses, pts))
    finally:
        numba.set_num_threads(threads)
    out["fast_points_per_s_one_core"] = round(len(poses) * len(pts) / t)
    rng = np.random.default_rng(0)
    for mb in (0.5, 16, round(grid.nbytes / 1e6)):
        n = int(mb * 1e6 / 8)
        perm = rng.permutation(n)
        nxt = np.empty(n, dtype=np.int64)
        nxt[perm] = np.roll(perm, -1)
        chase(nxt, 1000)
        t = best_of(lambda: chase(nxt, 2_000_000))
        out[f"dependent_random_load_ns_{mb}mb"] = round(t / 2e6 * 1e9, 1)
    idx = rng.integers(0, len(grid), 20_000_000)
    gather(grid, idx[:10])
    t = best_of(lambda: gather(grid, idx))
    out["independent_random_loads_per_s_over_grid"] = round(len(idx) / t)
    return out


def bench_interference():
    """Fast, exact, triangle-exact and trimesh clearances on the default blisk; service round trip."""


    g = load_geometry(CONFIG / "default_blisk.yaml")
    b, e = g.blisk, g.electrodes[0]
    out = {"electrode_points": int(len(e.mesh.vertices))}
    with tempfile.TemporaryDirectory() as cache:
        t = time.perf_counter()
        field = FastChannelField(b, spacing=0.1)
        out["fast_build_s"] = round(time.perf_counter() - t, 2)
        FastChannelField(b, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)      # built and written
        loads = []
        for _ in range(3):
            t = time.perf_counter()
            FastChannelField(b, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)
            loads.append(time.perf_counter() - t)
        out["fast_cached_load_s"] = round(float(np.median(loads)), 3)
    out["fast_error_bound_mm"] = field.error_bound
    out["fast_measured_max_error_mm"] = {k: float(v) for k, v in getattr(field, "measured_max_error", {}).items()}
    pts = e.mesh.vertices
    poses = poses_near(e.final_pose, 200)
    field.pose_clearances(poses[:2], pts)                      # JIT warm-up
    t = best_of(lambda: field.pose_clearances(poses, pts))
    out["fast_points_per_s"] = round(len(poses) * len(pts) / t)
    out.update(memory_figures(field, poses, pts))
    world = transform_points(poses[:1], pts)[0]
    checker = ChannelChecker(b, {"main": (e.mesh, e.final_pose)}, g.geometry_id, CheckerOptions())
    t = best_of(lambda: checker.exact.clearances(world[:4000]), repeat=1)
    out["exact_points_per_s"] = round(4000 / t)
    meshes = b.channel_meshes()
    t = time.perf_counter()
    for m in meshes.values():
        trimesh.proximity.closest_point(m, world[:2000])
    out["trimesh_closest_point_points_per_s"] = round(2000 / (time.perf_counter() - t))
    # verification of a plan: exact minimum per pose (the field's branch and bound + numba exact solves),
    # 10^4 poses within ~0.02 mm / 2e-4 rad of the final pose, where the electrode's faces parallel the
    # walls at the gap and thousands of vertices per surface can attain the minimum
    checker._fast = field
    field.exact_pose_clearances(e.final_pose[None], pts[:50])           # JIT warm-up
    many = poses_near(e.final_pose, 10000, seed=1, spread=0.02)
    t = time.perf_counter()
    verified = checker.check(many, method=Method.EXACT)
    spent = time.perf_counter() - t
    out["exact_verify_10000_poses_near_final_s"] = round(spent, 1)
    out["exact_verify_s_per_pose_near_final"] = round(spent / len(many), 4)
    out["exact_verify_poses_clear"] = int((~verified.colliding).sum())
    out["exact_verify_solves_per_pose_mean"] = round(float(field.exact_pose_clearances(many[:200], pts)[2].mean()))
    # verification of a whole real plan: every vertex at every one of >= 10^4 samples, exactly

    out.update(bench_verify_plan(g))
    t = time.perf_counter()
    mesh_result = checker.check(many[:20], method=Method.MESH)
    out["mesh_method_s_per_pose"] = round((time.perf_counter() - t) / 20, 3)
    out["mesh_faceting_bound_mm"] = mesh_result.error_bound

    out["service_round_trip_1000_poses_ms"] = service_round_trip(1000, poses_near)
    return out




PLANNING_RUNS = (("default", "default", {}), ("ga", "ga", {}), ("max_min_distance", "max_min_distance", {}),
                 ("max_free_distance", "max_free_distance", {}),
                 # the GA again with the wider A bound it was first tuned with (same as C's, 0.02 rad per node)
                 ("ga_a_step_0.02", "ga", {"a_step": 0.02}))


def bench_planning(runs=PLANNING_RUNS):
    """Issue 4: every method on the same channel of the default blisk, side by side.

    The default blisk's primitive electrode cannot leave its 104-degree channel;
    the benchmark plans the rear electrode of a front/rear split (h = 0.03 rad,
    radial reduction 3 mm), 5 axes, step 0.1 mm, exit downstream. The distance
    field is built (or loaded from the cache) before the clock starts.
    """
    g = load_geometry(CONFIG / "default_blisk.yaml")
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=DEFAULT_CACHE, cache_key=g.geometry_id)
    design = rear_design()
    design_electrodes(g.blisk, design)                    # numba warm-up outside the clock
    out = {"electrode": "rear", "design": design.to_dict(), "axes": 5, "step_mm": 0.1, "exit_side": "downstream"}
    for label, method, extra in runs:
        opts = PlanOptions(search=SearchOptions(method=method, step=0.1, exit_side="downstream", time_budget=900.0,
                                                **extra))
        plan = plan_channel(g, 0, "rear", opts, field=field, design=design)
        m = plan.metrics
        out[label] = {
            "method": method, "options": extra, "result": plan.error_code.name, "planning_s": round(m.planning_time, 2), "nodes": m.node_count,
            "samples": len(plan.samples), "objfun1": round(m.objfun1, 4), "objfun2": round(m.objfun2, 3),
            "smoothness_per_axis": dict(zip(m.axis_names, (float(f"{v:.4g}") for v in m.smoothness))),
            "sharp_points_per_axis": dict(zip(m.axis_names, m.sharp_points)),
            "clearance_lower_bound_mm": {k: round(v, 4) for k, v in m.by_surface("clearance_lower_bound").items()},
            "clearance_exact_mm": {k: round(v, 4) for k, v in m.by_surface("clearance_exact").items()},
            "path_length_mm": round(m.path_length, 2), "evaluations": m.solver_evaluations,
            "message": plan.message[:200]}
        _log.warning("planning %s: %s", label, out[label])
    return out




def bench_roughing(check_positions=5):
    """Issue 7: plunge roughing of the default blisk's channel 0 (Chen & Dong), automatic tool radius.

    Figures: planning time, positions, eq. 14-15 statistics at the initial (radial plunge) poses,
    after the paper's iteration alone and after the polish, the reduction of the mean absolute error
    beside the paper's 57.79 %, and the gap between our optimum and a brute-force search on
    ``check_positions`` positions spread over the travel order (``gap_mm`` = ours - brute force;
    negative: ours is lower).
    """
    g = load_geometry(CONFIG / "default_blisk.yaml")
    opts = RoughingOptions()
    t = time.perf_counter()
    res = plan_roughing(g.blisk, 0, opts)
    plan_s = time.perf_counter() - t
    out = {"channel": 0, "tool_radius": "automatic (r_max)", "planning_s": round(plan_s, 2),
           "positions": res.position_count, "groove_positions": res.groove_count, "expansion_lines": res.line_count,
           "l_min_mm": round(res.l_min, 4), "r_max_mm": round(res.r_max, 4), "allowance_mm": opts.allowance,
           "mu": opts.mu, "path_samples": len(res.samples),
           "iterations_paper_mean": round(float(res.iterations.mean()), 2),
           "iterations_polish_mean": round(float(res.polish_iterations.mean()), 2),
           "secondary_positions": int(res.secondary.sum())}
    for key, st in (("initial", res.stats_initial), ("paper_iteration", res.stats_paper), ("optimised", res.stats)):
        out[f"stats_{key}_mm"] = {k: float(f"{v:.6g}") for k, v in st.to_dict().items() if k != "count"}
    out["bottom_points"] = res.stats.count
    out["hausdorff_mean_mm"] = {"initial": float(f"{res.hausdorff_initial.mean():.6g}"),
                                "paper_iteration": float(f"{res.hausdorff_paper.mean():.6g}"),
                                "optimised": float(f"{res.hausdorff.mean():.6g}")}
    out["mae_reduction_percent"] = round(res.mae_reduction_percent, 2)
    out["mae_reduction_percent_paper_iteration"] = round(
        reduction_percent(res.stats_initial.mean_abs, res.stats_paper.mean_abs), 2)
    out["std_reduction_percent"] = round(res.std_reduction_percent, 2)
    out["paper_mae_reduction_percent"] = PAPER_MAE_REDUCTION_PERCENT
    # the optimum against a brute-force search, position by position
    dist = RevolutionDistance(target_surface(g.blisk, opts.allowance))
    bottom = bottom_points(res.tool_radius, opts.bottom_rings, opts.bottom_points)
    gaps, brute_s = [], 0.0
    for i in res.order[np.linspace(0, res.position_count - 1, check_positions).round().astype(int)]:
        model = ToolPoseModel(dist, res.initial_poses[i], bottom, res.tool_radius)
        opt = optimise_pose(model, opts.rotation_range, opts.translation_range, opts.secondary_rotation_range,
                            opts.eta, opts.increment_tolerance, opts.objective_tolerance, opts.max_iterations)
        t = time.perf_counter()
        _, h_brute = brute_force_optimum(model, opts.rotation_range, opts.translation_range)
        brute_s += time.perf_counter() - t
        gaps.append({"position": res.labels[i], "optimised_mm": float(f"{opt.h:.9g}"),
                     "paper_iteration_mm": float(f"{opt.h_paper:.9g}"), "brute_force_mm": float(f"{h_brute:.9g}"),
                     "gap_mm": float(f"{opt.h - h_brute:.3g}")})
    out["brute_force_check"] = gaps
    out["brute_force_max_abs_gap_mm"] = float(f"{max(abs(gp['gap_mm']) for gp in gaps):.3g}")
    out["brute_force_s_per_position"] = round(brute_s / check_positions, 2)
    return out
