"""Paired speed comparison of this checkout against an earlier commit, on a host whose speed drifts.

    .venv/bin/python tools/compare_speed.py ac09aba --rounds 3

The earlier commit is checked out in a temporary git worktree with a field
cache of its own; each round runs the measurement below once for it and once
for this checkout, alternated, each in a new process (numba's caches kept), and
prints one JSON line per run: the field's points per second on one core (200
poses near the final pose, ``pose_clearances`` as the speed suite calls it),
``pose_clearances`` of 1000 poses on all cores [s] (CheckInterference's
kernel), and the speed suite's ``plan_certify`` median of 5 [s] with its
Objfun1. Only APIs both sides have are used. Not a benchmark of record: the
speed suite (``make bench BENCH_ARGS="--only speed"``) is; this separates a
change from the host's drift (docs/performance.md, issue 29).
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent

MEASURE = r'''
import json, sys
import numba, numpy as np
import edm_planner
from edm_planner.bench.common import CONFIG, poses_near
from edm_planner.bench.speed import median_time, plan_certify
from edm_planner.geometry.loader import load_geometry
from edm_planner.interference.fast import FastChannelField

g = load_geometry(CONFIG / "default_blisk.yaml")
field = FastChannelField(g.blisk, spacing=0.1, cache_dir=sys.argv[1], cache_key=g.geometry_id)
e = g.electrodes[0]
pts = np.asarray(e.mesh.vertices)
near, many = poses_near(e.final_pose, 200), poses_near(e.final_pose, 1000)
out = {"code": str(edm_planner.__file__)}
out["pose_clearances_1000_all_cores_s"] = round(median_time(lambda: field.pose_clearances(many, pts), 5), 4)
threads = numba.get_num_threads()
numba.set_num_threads(1)
out["field_one_core_M_points_per_s"] = round(len(near) * len(pts) / median_time(
    lambda: field.pose_clearances(near, pts)) / 1e6, 2)
numba.set_num_threads(threads)
plan = plan_certify(g, field)
out["plan_certify_s"], out["objfun1"] = plan["planning_s_median"], plan["objfun1"]
print(json.dumps(out))
'''


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("commit", help="the earlier commit (anything git rev-parse takes)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="edm_compare_") as tmp:
        tmp = pathlib.Path(tmp)
        tree = tmp / "earlier"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), args.commit], check=True,
                       capture_output=True)
        script = tmp / "measure.py"
        script.write_text(MEASURE)
        sides = {"earlier": (tree, tmp / "field_cache_earlier"), "this": (ROOT, tmp / "field_cache_this")}
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.setdefault("AMENT_PREFIX_PATH", sys.prefix)
        try:
            for r in range(args.rounds):
                for name, (code, cache) in sides.items():
                    done = subprocess.run([sys.executable, str(script), str(cache)], cwd=tmp, capture_output=True,
                                          text=True, env=dict(env, PYTHONPATH=str(code)))
                    if done.returncode:
                        raise SystemExit(f"{name} failed: {done.stderr.strip()[-800:]}")
                    line = json.loads(done.stdout.strip().splitlines()[-1])
                    print(json.dumps(dict(line, side=name, round=r)), flush=True)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], capture_output=True)


if __name__ == "__main__":
    main()
