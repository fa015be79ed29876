"""Benchmark of the fast method of interference checking against the exact ones.

``bench_fast(blisk, electrode)`` measures, on one core (numba and the
KD-tree queries limited to one thread for every figure):

* the build time of :class:`~.interference.fast.FastChannelField` (numba
  compilation excluded) and the load time from its cache;
* the throughput of ``pose_clearances`` in electrode points per second (all
  four surfaces per point) for 1000 poses near the final pose times the
  electrode's sample points, best of three;
* the throughput of :class:`~.interference.exact_points.ExactChannelDistance`
  and of ``trimesh.proximity.closest_point`` against the four channel meshes
  on subsets of the same points;
* the accuracy: max |fast - exact| per surface within 2 mm of it, on the
  electrode points under some of those poses and on fresh random points near
  the surfaces, next to the exposed ``error_bound``.

``bench_verify_plan(geometry)`` measures the exact verification of a whole
densely sampled plan (issue 3): the rear electrode of a front/rear split
planned on the default blisk with samples close enough for at least 10^4 of
them, every electrode vertex at every sample checked by
:func:`~..interference.pose_check.verify_poses` (exact minimum clearance per surface),
on all of numba's threads and on one; and the same on the plan at the
default sample spacing, and the whole re-check of its export directory.

Every figure is a plain JSON number; its unit is in its key.
Usage: ``python -m edm_planner.bench.interference [--config FILE] [--out FILE] [--no-verify-plan]``.
"""

import argparse
import json
import logging
import pathlib
import tempfile
import time

import numba
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from ..geometry.loader import load_geometry
from ..interference import SURFACES
from ..interference.exact_points import ExactChannelDistance
from ..interference.fast import ACCURATE_WITHIN, FastChannelField
from ..interference.pose_check import verify_poses
from ..planning.plan import PlanOptions
from ..planning.planner import plan_channel
from ..planning.search import SearchOptions
from ..records.plan_check import verify_exported_plan
from ..records.plan_export import write_plan
from .common import CONFIG, rear_design

_log = logging.getLogger(__name__)


def best_of(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def poses_near(final_pose, n, seed=0, shift=0.05, turn=0.002):
    """n electrode poses: the final pose moved by small random rigid motions.

    Parameters
    ----------
    final_pose : (4, 4) float
        Electrode frame -> W.
    n : int
    shift : float
        Standard deviation of the translation [mm] per axis.
    turn : float
        Standard deviation of the rotation vector [rad] per axis, about the
        electrode origin.

    Returns
    -------
    (n, 4, 4) float
    """

    rng = np.random.default_rng(seed)
    poses = np.repeat(np.asarray(final_pose, dtype=np.float64)[None], n, axis=0)
    poses[:, :3, :3] = final_pose[:3, :3] @ Rotation.from_rotvec(rng.normal(scale=turn, size=(n, 3))).as_matrix()
    poses[:, :3, 3] += rng.normal(scale=shift, size=(n, 3))
    return poses


def _max_errors(field, points, exact):
    """Per surface: max |fast - exact| and max |fast - reference| within 2 mm (inside the grid) [mm]."""
    ref, raw = field.reference_clearances(points, 0, exact)
    got = field.clearances(points)
    inside = field.inside_grid(points)[:, None]
    out = {}
    for name, reference in (("vs_exact", raw), ("vs_reference", ref)):
        near = (np.abs(reference) <= ACCURATE_WITHIN) & inside
        err = np.where(near, np.abs(got - reference), 0.0)
        out[name] = {s: float(err[:, k].max()) for k, s in enumerate(SURFACES)}
    return out


def bench_fast(blisk, electrode, spacing=0.1, n_poses=1000, seed=0):
    """Speed and accuracy of the fast method on one core.

    Parameters
    ----------
    blisk : Blisk
    electrode : Electrode
        Its sample points (all four sides) at poses near its final pose are
        the query points.
    spacing : float
        Grid spacing of the field [mm].
    n_poses : int
    seed : int

    Returns
    -------
    dict
        JSON-serialisable figures, units in the keys.
    """

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        # compile every kernel on a coarse field first: the build time is the build's, not numba's
        warm = FastChannelField(blisk, spacing=1.0, error_samples=50)
        warm.pose_clearances(electrode.final_pose[None], electrode.samples["left"][:10])
        t = time.perf_counter()
        field = FastChannelField(blisk, spacing=spacing)
        out = {"fast_build_s": round(time.perf_counter() - t, 3), "fast_spacing_mm": spacing,
               "fast_grid_shape": field.stats["grid_shape"], "fast_grid_MB": field.stats["grid_megabytes"],
               "fast_exact_fallback_node_fraction": field.stats["exact_fallback_node_fraction"],
               "fast_build_stage_s": {k: v for k, v in field.stats.items() if k.endswith("_s")}}
        with tempfile.TemporaryDirectory() as cache:
            field._save(field._cache_path(cache, "bench"))
            t = time.perf_counter()
            loaded = FastChannelField(blisk, spacing=spacing, cache_dir=cache, cache_key="bench")
            out["fast_cache_load_s"] = round(time.perf_counter() - t, 3)
            if loaded.build_seconds:
                _log.warning("bench_fast: the field was rebuilt instead of loaded from the cache")

        points = np.concatenate([electrode.samples[k] for k in ("left", "right", "upper", "lower")])
        poses = poses_near(electrode.final_pose, n_poses, seed)
        field.pose_clearances(poses[:2], points)                       # warm
        t = best_of(lambda: field.pose_clearances(poses, points))
        n = len(poses) * len(points)
        out.update({"electrode_points": len(points), "poses": len(poses),
                    "fast_pose_clearances_points_per_s": round(n / t),
                    "fast_pose_clearances_s": round(t, 4)})
        world = points @ electrode.final_pose[:3, :3].T + electrode.final_pose[:3, 3]
        slow = ~field.fast_path(world)
        out["fast_slow_path_point_fraction_at_final_pose"] = round(float(slow.mean()), 5)
        out["fast_slow_path_point_fraction_near_final_pose"] = round(float(np.mean(
            [(~field.fast_path(points @ p[:3, :3].T + p[:3, 3])).mean() for p in poses[::100]])), 5)

        exact = ExactChannelDistance(blisk)
        sub = world[:: max(1, len(world) // 4000)]
        exact.clearances(sub[:10])
        t = best_of(lambda: exact.clearances(sub), repeat=1)
        out["exact_points_per_s"] = round(len(sub) / t)
        meshes = list(blisk.channel_meshes().values())
        few = world[:: max(1, len(world) // 1000)]
        t = time.perf_counter()
        for m in meshes:
            trimesh.proximity.closest_point(m, few)
        out["trimesh_closest_point_points_per_s"] = round(len(few) / (time.perf_counter() - t))
        out["trimesh_channel_mesh_triangles"] = int(sum(len(m.faces) for m in meshes))

        # accuracy within 2 mm of each surface
        pts = np.concatenate([world] + [points @ p[:3, :3].T + p[:3, 3] for p in poses[:: max(1, n_poses // 5)]])
        pts = pts[:: max(1, len(pts) // 20000)]
        acc = {"electrode": _max_errors(field, pts, exact),
               "random_near_surfaces": _max_errors(field, field.error_sample_points(1000, seed=seed + 1), exact)}
        out.update({
            "fast_error_bound_mm": field.error_bound,
            "fast_measured_max_error_at_build_mm": field.measured_max_error,
            "fast_max_abs_error_within_2mm_mm": acc,
            "fast_far_error_bound_mm": field.far_error_bound,
            "exact_method_excess_at_build_mm": field.exact_method_excess,
            "threads": 1,
        })
        return out
    finally:
        numba.set_num_threads(threads)


def _plan_rear(geometry, field, sample_spacing):
    """The rear electrode of a front/rear split (h = 0.03 rad, radial reduction 3 mm) in channel 0: 5 axes,
    step 0.1 mm, exit downstream (as the planning benchmark), samples ``sample_spacing`` mm apart."""

    design = rear_design()
    opts = PlanOptions(search=SearchOptions(step=0.1, exit_side="downstream"), sample_spacing=sample_spacing)
    t = time.perf_counter()
    plan = plan_channel(geometry, 0, "rear", opts, field=field, design=design, exact_clearance=False)
    if not plan.success:
        raise RuntimeError(f"bench_verify_plan: planning failed: {plan.message}")
    return plan, time.perf_counter() - t


def bench_verify_plan(geometry, sample_spacing=0.009, cache_dir=None):
    """Exact verification of every vertex at every sample of a real plan of at least 10^4 samples.

    Parameters
    ----------
    geometry : LoadedGeometry
        The default blisk.
    sample_spacing : float
        Largest vertex move between samples of the dense plan [mm] (0.009: 10509 samples).
    cache_dir : str, optional
        Distance field cache (built in a temporary directory when not given).

    Returns
    -------
    dict
        JSON-serialisable figures, units in the keys; ``exact_verify_plan_10000_samples_s`` is the time of
        :func:`~..interference.pose_check.verify_poses` on all threads, without the field's load (given separately).
    """

    b = geometry.blisk
    threads = numba.get_num_threads()
    with tempfile.TemporaryDirectory() as tmp:
        cache = cache_dir or tmp
        FastChannelField(b, spacing=0.1, cache_dir=cache, cache_key=geometry.geometry_id)    # built or loaded
        t = time.perf_counter()
        field = FastChannelField(b, spacing=0.1, cache_dir=cache, cache_key=geometry.geometry_id)
        load = time.perf_counter() - t
        dense, planning = _plan_rear(geometry, field, sample_spacing)
        default, _ = _plan_rear(geometry, field, 0.05)
        V = dense.electrode_mesh.vertices
        verify_poses(dense.poses[-3:], V[:20], 0, b, field)                          # numba warm-up
        t = time.perf_counter()
        check = verify_poses(dense.poses, V, 0, b, field)
        spent = time.perf_counter() - t
        numba.set_num_threads(1)
        try:
            t = time.perf_counter()
            one = verify_poses(dense.poses, V, 0, b, field, threads=1)
            spent_one = time.perf_counter() - t
        finally:
            numba.set_num_threads(threads)
        t = time.perf_counter()
        small = verify_poses(default.poses, default.electrode_mesh.vertices, 0, b, field)
        spent_default = time.perf_counter() - t
        write_plan(dense, pathlib.Path(tmp) / "plan", b)
        t = time.perf_counter()
        exported = verify_exported_plan(pathlib.Path(tmp) / "plan", b, field=field, geometry_id=geometry.geometry_id)
        spent_export = time.perf_counter() - t
    if one.clearance_exact != check.clearance_exact or exported.clearance_exact != check.clearance_exact:
        _log.warning("bench_verify_plan: the minima depend on the thread count or the export")
    return {
        "exact_verify_plan_10000_samples_s": round(spent, 2),
        "exact_verify_plan_10000_samples_1_thread_s": round(spent_one, 2),
        "exact_verify_plan_10000_samples_export_s": round(spent_export, 2),
        "exact_verify_plan_threads": threads,
        "exact_verify_plan_samples": check.samples,
        "exact_verify_plan_vertices": check.vertices,
        "exact_verify_plan_vertex_positions": check.samples * check.vertices,
        "exact_verify_plan_exact_evaluations": check.exact_evaluations,
        "exact_verify_plan_exact_solves_by_surface": check.exact_by_surface,
        "exact_verify_plan_side_test_anchor_samples": check.anchor_samples,
        "exact_verify_plan_clearance_exact_mm": check.clearance_exact,
        "exact_verify_plan_argmin_sample_vertex": {k: list(v) for k, v in check.argmin.items()},
        "exact_verify_plan_max_vertex_step_mm": round(check.max_vertex_step, 6),
        "exact_verify_plan_passed": check.passed and exported.passed,
        "exact_verify_plan_sample_spacing_mm": sample_spacing,
        "exact_verify_plan_planning_s": round(planning, 2),
        "exact_verify_plan_field_load_s": round(load, 2),
        "exact_verify_default_spacing_plan_samples": small.samples,
        "exact_verify_default_spacing_plan_s": round(spent_default, 2),
        "exact_verify_default_spacing_plan_exact_evaluations": small.exact_evaluations,
        "exact_verify_default_spacing_plan_clearance_exact_mm": small.clearance_exact,
    }


def main(argv=None):
    """Run :func:`bench_fast` and :func:`bench_verify_plan` on a geometry and write the figures as JSON."""

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(CONFIG / "default_blisk.yaml"))
    parser.add_argument("--spacing", type=float, default=0.1)
    parser.add_argument("--out", default="out/bench_interference.json")
    parser.add_argument("--no-verify-plan", action="store_true", help="skip bench_verify_plan")
    parser.add_argument("--cache-dir", default=None, help="distance field cache for bench_verify_plan")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    g = load_geometry(args.config)
    result = {"geometry": g.blisk.name or args.config,
              **bench_fast(g.blisk, g.electrodes[0], spacing=args.spacing)}
    if not args.no_verify_plan:
        result.update(bench_verify_plan(g, cache_dir=args.cache_dir))
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    _log.info("%s", json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
