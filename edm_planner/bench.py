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


SUITES = {"geometry": bench_geometry}


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
