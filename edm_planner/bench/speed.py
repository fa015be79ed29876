"""Issue 13's speed targets, each measured the way a user meets it (``--only speed``).

Every timing is the median of several repetitions after an untimed warm-up
run (numba's first call, DDS discovery, the field's load from its cache), and
compared methods do the same work. Figures, units in the keys:

* ``field``: the fast field's throughput, 200 poses near the final pose x the
  29 430 vertices of the default blisk's electrode, all four surfaces per
  point, on one core and on all; the same with every pose equal to the final
  pose (every cell in cache: what the arithmetic alone allows);
* ``check_interference_1000_poses_ms``: the CheckInterference round trip
  over DDS (fast method, the nodes and the client in one child process:
  :mod:`edm_planner.bench.service`);
* ``load_geometry_already_loaded_ms``: LoadGeometry of the file the node
  loaded at start (answered from memory by content hash);
* ``plan_certify``: the planning benchmark's case (default blisk, channel 0,
  rear electrode of a front/rear split, 5 axes, step 0.1 mm, exit downstream)
  planned and certified, with its quality figures;
* ``edm_plan_cli_s``: ``edm-plan plan`` of that electrode as a new process
  (``--store none``: a real plan each time), with the field, numba and
  electrode caches warm (the untimed first run fills them, as a cell's first
  channel does);
* ``demo``: ``python -m edm_planner.nodes.programs.demo`` (what ``make demo`` runs)
  with an empty field cache and plan store (a new HOME; numba's cache kept,
  as ``make setup`` leaves it), then once more with what the first run left.

Usage: ``python -m edm_planner.bench --out out/bench_speed.json --only speed``.
"""

import logging
import os
import pathlib
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numba
import numpy as np

from ..cli import DEFAULT_CACHE
from ..geometry.loader import load_geometry
from ..interference.fast import FastChannelField
from ..planning.plan import PlanOptions
from ..planning.planner import plan_channel
from ..planning.search import SearchOptions
from .common import CONFIG, poses_near, rear_design
from .service import service_round_trips

_log = logging.getLogger(__name__)

REPEAT = 7


def median_time(fn, repeat=REPEAT):
    """Median wall time [s] of ``repeat`` calls of ``fn`` after one untimed call."""
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def field_throughput(geometry, field):
    """Points per second of ``pose_clearances`` on one thread and on all of numba's."""

    e = geometry.electrodes[0]
    pts = np.asarray(e.mesh.vertices)
    near = poses_near(e.final_pose, 200)
    same = np.repeat(e.final_pose[None], 200, axis=0)
    out = {"electrode_points": len(pts), "poses": len(near), "threads_all": numba.get_num_threads()}
    threads = numba.get_num_threads()
    for label, count in (("one_core", 1), ("all_cores", threads)):
        numba.set_num_threads(count)
        try:
            for case, poses in (("near_final_pose", near), ("cells_in_cache", same)):
                t = median_time(lambda: field.pose_clearances(poses, pts))
                out[f"points_per_s_{label}_{case}"] = round(len(poses) * len(pts) / t)
        finally:
            numba.set_num_threads(threads)
    out["error_bound_mm"] = field.error_bound
    return out


def plan_certify(geometry, field, repeat=5):
    """The planning benchmark's default case: planning time (search + fit + certification) and quality."""

    design = rear_design()
    opts = PlanOptions(search=SearchOptions(method="default", step=0.1, exit_side="downstream"))

    def once():
        plan = plan_channel(geometry, 0, "rear", opts, field=field, design=design)
        if not plan.success:
            raise RuntimeError(f"plan_certify: planning failed: {plan.message}")
        return plan

    once()
    plans = [once() for _ in range(repeat)]
    m = plans[-1].metrics
    return {"planning_s_median": round(statistics.median(p.metrics.planning_time for p in plans), 3),
            "planning_s_all": [round(p.metrics.planning_time, 3) for p in plans],
            "nodes": m.node_count, "objfun1": round(m.objfun1, 4),
            "smoothness_per_axis": dict(zip(m.axis_names, (float(f"{v:.4g}") for v in m.smoothness))),
            "sharp_points_per_axis": dict(zip(m.axis_names, m.sharp_points)),
            "clearance_lower_bound_mm": round(min(m.by_surface("clearance_lower_bound").values()), 4),
            "clearance_exact_mm": round(min(m.by_surface("clearance_exact").values()), 4)}


def _run(cmd, env=None, cwd=None):
    t = time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    spent = time.perf_counter() - t
    if done.returncode:
        raise RuntimeError(f"{' '.join(map(str, cmd))} exited {done.returncode}: {done.stderr.strip()[-400:]}")
    return spent, done.stdout


def edm_plan_cli(repeat=3):
    """Wall time [s] of ``edm-plan plan`` of one electrode (a new process each time, caches warm)."""
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "edm_planner.cli", "plan", "--geometry", str(CONFIG / "default_blisk.yaml"),
               "--channel", "0", "--out", out, "--electrode", "rear", "--split", "front_rear",
               "--circumferential-reduction", "0.03", "--radial-reduction", "3", "--split-overlap", "1",
               "--exit-side", "downstream", "--store", "none", "--progress", "none"]
        _run(cmd)
        times = [_run(cmd)[0] for _ in range(repeat)]
    return {"edm_plan_cli_s_median": round(statistics.median(times), 2), "edm_plan_cli_s_all": [round(t, 2) for t in times]}


def demo_runs():
    """``make demo``'s program with an empty field cache and plan store, then repeated."""
    home = pathlib.Path(tempfile.mkdtemp(prefix="edm_bench_home_"))
    try:
        # numba's cache stays where make setup filled it: edm_planner set NUMBA_CACHE_DIR from the old HOME
        env = dict(os.environ, HOME=str(home), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.pop("EDM_PLANNER_PLAN_STORE", None)
        env.setdefault("AMENT_PREFIX_PATH", sys.prefix)          # as the Makefile sets it: the nodes' share dir
        cmd = [sys.executable, "-m", "edm_planner.nodes.programs.demo", "--out", str(home / "demo")]
        first, log = _run(cmd, env=env)
        again, _ = _run(cmd, env=env)
        # the first run designs the set (the plan store is empty), the second finds it in the store
        return {"demo_first_s": round(first, 1), "demo_repeated_s": round(again, 1),
                "demo_first_output_tail": log.strip().splitlines()[-3:], "numba_cache": os.environ["NUMBA_CACHE_DIR"]}
    finally:
        shutil.rmtree(home, ignore_errors=True)


def bench_speed():
    """Every figure of issue 13's targets (see the module's docstring)."""

    g = load_geometry(CONFIG / "default_blisk.yaml")
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=DEFAULT_CACHE, cache_key=g.geometry_id)
    out = {"field": field_throughput(g, field)}
    _log.warning("speed: field %s", out["field"])
    # one bring-up for both round trips (a child process: the bench imports no ROS)
    trips = service_round_trips(offsets=poses_near(np.eye(4), 1000), load_geometry="default_blisk.yaml")
    out["check_interference_1000_poses_ms"] = trips["check_interference_ms"]
    out["load_geometry_already_loaded_ms"] = trips["load_geometry_ms"]
    out["plan_certify"] = plan_certify(g, field)
    _log.warning("speed: plan_certify %s", out["plan_certify"])
    out.update(edm_plan_cli())
    out.update(demo_runs())
    out["targets"] = {"field_points_per_s_one_core": 50e6, "check_interference_1000_poses_ms": 300,
                      "load_geometry_already_loaded_ms": 1000, "plan_certify_s": 0.5, "edm_plan_cli_s": 5,
                      "demo_first_s": 90, "demo_repeated_s": 20}
    return out
