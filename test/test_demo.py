"""make demo's flow end to end: four node processes, the cell controller over DDS, the files it writes."""

import os
import subprocess
import sys

import pytest

from edm_planner.planning.export import read_plan

pytestmark = pytest.mark.slow          # nodes over DDS that plan, or the whole product: not in make test-fast


def processes_of(home):
    """Pids of the processes whose environment has HOME=home (the demo and the nodes it started)."""
    import pathlib

    want = f"HOME={home}".encode()
    pids = []
    for d in pathlib.Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if want in (d / "environ").read_bytes().split(b"\0"):
                    pids.append(int(d.name))
            except OSError:
                pass
    return pids


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
    assert processes_of(env["HOME"]) == []


def test_demo_interrupted_stops_every_node_and_exits_non_zero(tmp_path):
    """Ctrl-C while the planner works: the demo stops all four processes and exits with 130."""
    import signal
    import time

    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) + 103) % 232)
    env["HOME"] = str(tmp_path / "home")
    env.pop("EDM_PLANNER_PLAN_STORE", None)
    env["PYTHONUNBUFFERED"] = "1"
    out = tmp_path / "demo"
    proc = subprocess.Popen([sys.executable, "-m", "edm_planner.nodes.demo", "--out", str(out)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    deadline = time.monotonic() + 300
    for line in proc.stdout:                      # wait until the cell controller has asked for the plan
        lines.append(line)
        if "] PlanChannel:" in line or time.monotonic() > deadline:
            break
    assert any("] PlanChannel:" in x for x in lines), "".join(lines)
    running = processes_of(env["HOME"])
    assert len(running) >= 5, running                # the demo and its four nodes
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=120)
    text = "".join(lines) + rest
    assert proc.returncode == 130, text
    assert "interrupted" in text and "all nodes stopped" in text
    assert processes_of(env["HOME"]) == [], running
