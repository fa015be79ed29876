"""make demo's flow end to end: four node processes, the cell controller over DDS, the files it writes."""

import os
import subprocess
import sys

from edm_planner.planning.export import read_plan


def test_demo_runs_end_to_end_and_writes_its_pictures(tmp_path):
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) + 101) % 232)   # away from the in-process tests
    env["HOME"] = str(tmp_path / "home")          # a fresh user: caches and plan store start empty
    env.pop("EDM_PLANNER_PLAN_STORE", None)
    out = tmp_path / "demo"
    run = subprocess.run([sys.executable, "-m", "edm_planner.nodes.demo", "--out", str(out)], env=env,
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout + run.stderr
    text = run.stdout
    for word in ("LoadGeometry", "PlanChannel", "ExecutePlan", "Summary", "min clearance", "all nodes stopped"):
        assert word in text
    for name in ("axes_vs_time.png", "axes_vs_index.png", "clearance.png", "channel.png", "channel.glb"):
        assert (out / name).stat().st_size > 10_000, name
    plans = list((out / "plans").iterdir())
    assert len(plans) == 1
    exported = read_plan(plans[0])
    assert exported.channel == 0 and len(exported.axes) > 100
    # no node process outlives the demo
    ps = subprocess.run(["pgrep", "-f", str(out / "logs")], capture_output=True, text=True)
    assert ps.stdout.strip() == ""
