"""Benchmarks (``make bench``): speed figures as JSON, never asserted in tests.

Usage: ``python -m edm_planner.bench --out out/bench.json [--only geometry]``.
Each figure states its unit in its key. One process, one core in use.
"""

import argparse
import json
import logging
import pathlib
import platform
import resource
import time

import numpy as np

CONFIG = pathlib.Path(__file__).resolve().parent.parent / "config"
_log = logging.getLogger(__name__)


def _best_of(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def bench_geometry():
    """Loading the three example geometries and the face queries the planner makes."""
    from .geometry.loader import load_geometry

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
    t = _best_of(lambda: b.suction_face.theta_at(x, r))
    out["face_theta_at_points_per_s"] = round(n / t)
    th_s, th_p, _ = b.wall_angles(x, r)
    from .geometry.frames import cylindrical_to_cartesian
    pts = cylindrical_to_cartesian(x, r, th_s + rng.uniform(0, 1, n) * (th_p - th_s))
    t = _best_of(lambda: b.suction_face.closest_points(pts))
    out["face_closest_point_points_per_s"] = round(n / t)
    return out


def _poses_near(final_pose, n, seed=0, spread=0.05):
    """n electrode poses near the final pose (small random rigid motions)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    poses = np.repeat(final_pose[None], n, axis=0)
    rot = Rotation.from_rotvec(rng.normal(scale=spread / 100.0, size=(n, 3))).as_matrix()
    poses[:, :3, :3] = rot @ final_pose[:3, :3]
    poses[:, :3, 3] += rng.normal(scale=spread, size=(n, 3))
    return poses


def bench_interference():
    """Fast, exact, triangle-exact and trimesh clearances on the default blisk; service round trip."""
    import tempfile

    import trimesh

    from .interference.checker import ChannelChecker, CheckerOptions, Method
    from .interference.exact_points import transform_points
    from .interference.fast import FastChannelField
    from .geometry.loader import load_geometry

    g = load_geometry(CONFIG / "default_blisk.yaml")
    b, e = g.blisk, g.electrodes[0]
    out = {"electrode_points": int(len(e.mesh.vertices))}
    with tempfile.TemporaryDirectory() as cache:
        t = time.perf_counter()
        field = FastChannelField(b, spacing=0.1)
        out["fast_build_s"] = round(time.perf_counter() - t, 2)
        t = time.perf_counter()
        FastChannelField(b, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)
        FastChannelField(b, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)
        out["fast_cached_load_s"] = round((time.perf_counter() - t) / 2, 2)
    out["fast_error_bound_mm"] = field.error_bound
    out["fast_measured_max_error_mm"] = {k: float(v) for k, v in getattr(field, "measured_max_error", {}).items()}
    pts = e.mesh.vertices
    poses = _poses_near(e.final_pose, 200)
    field.pose_clearances(poses[:2], pts)                      # JIT warm-up
    t = _best_of(lambda: field.pose_clearances(poses, pts))
    out["fast_points_per_s"] = round(len(poses) * len(pts) / t)
    world = transform_points(poses[:1], pts)[0]
    checker = ChannelChecker(b, {"main": (e.mesh, e.final_pose)}, g.geometry_id, CheckerOptions())
    t = _best_of(lambda: checker.exact.clearances(world[:4000]), repeat=1)
    out["exact_points_per_s"] = round(4000 / t)
    meshes = b.channel_meshes()
    t = time.perf_counter()
    for m in meshes.values():
        trimesh.proximity.closest_point(m, world[:2000])
    out["trimesh_closest_point_points_per_s"] = round(2000 / (time.perf_counter() - t))
    # verification of a plan: exact minimum per pose (fast pre-filter + exact candidates), near the
    # final pose, where the electrode's faces parallel the walls and most vertices are candidates
    checker._fast = field
    many = _poses_near(e.final_pose, 20, seed=1, spread=0.01)
    t = time.perf_counter()
    checker.check(many, method=Method.EXACT)
    out["exact_verify_s_per_pose_near_final"] = round((time.perf_counter() - t) / len(many), 3)
    out["exact_verify_10000_poses_near_final_s_extrapolated"] = round(
        1e4 * (time.perf_counter() - t) / len(many), 1)
    t = time.perf_counter()
    mesh_result = checker.check(many[:20], method=Method.MESH)
    out["mesh_method_s_per_pose"] = round((time.perf_counter() - t) / 20, 3)
    out["mesh_faceting_bound_mm"] = mesh_result.error_bound
    out["service_round_trip_1000_poses_ms"] = _service_round_trip(1000)
    return out


def _service_round_trip(n_poses, repeat=5):
    """Median round trip of CheckInterference (fast method) over DDS, nodes in this process."""
    import os
    import threading

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(101 - os.getpid() % 50))
    import rclpy
    from edm_planner_msgs.srv import CheckInterference
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node

    from .nodes.conversions import matrix_to_pose, pose_to_matrix
    from .nodes.geometry_loader import GeometryLoaderNode
    from .nodes.interference_checker import InterferenceCheckerNode

    ctx = Context()
    rclpy.init(context=ctx)
    ex = MultiThreadedExecutor(context=ctx)
    loader = GeometryLoaderNode(context=ctx)
    checker = InterferenceCheckerNode(context=ctx)
    client = Node("bench_client", context=ctx)
    for node in (loader, checker, client):
        ex.add_node(node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    try:
        deadline = time.monotonic() + 120
        while not checker.checkers and time.monotonic() < deadline:
            time.sleep(0.1)
        gid, ch = next(iter(checker.checkers.items()))
        ch.fast                                                  # field built before timing
        final = next(iter(ch.electrodes.values()))[1]
        req = CheckInterference.Request(geometry_id=gid, method=CheckInterference.Request.METHOD_FAST)
        req.poses = [matrix_to_pose(p) for p in _poses_near(final, n_poses)]
        cli = client.create_client(CheckInterference, "check_interference")
        cli.wait_for_service(timeout_sec=30)
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            fut = cli.call_async(req)
            while not fut.done():
                time.sleep(0.0005)
            times.append(time.perf_counter() - t)
        del pose_to_matrix
        return round(1e3 * float(np.median(times)), 1)
    finally:
        ex.shutdown()
        for node in (loader, checker, client):
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)


SUITES = {"geometry": bench_geometry, "interference": bench_interference}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench.json", help="JSON file to write")
    parser.add_argument("--only", choices=sorted(SUITES), action="append", help="run only these suites")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    result = {"machine": {"python": platform.python_version(), "processor": platform.machine()},
              "timestamp": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    for name in args.only or sorted(SUITES):
        t = time.perf_counter()
        result[name] = SUITES[name]()
        result[name]["suite_s"] = round(time.perf_counter() - t, 2)
    result["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    path = pathlib.Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
