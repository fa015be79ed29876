"""make demo's flow end to end: four node processes, the cell controller over DDS, the files it writes."""

import json
import os
import re
import subprocess
import sys
import time

import pytest

from edm_planner.records.plan_export import read_plan

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
    run = subprocess.run([sys.executable, "-m", "edm_planner.nodes.programs.demo", "--out", str(out)], env=env,
                         capture_output=True, text=True, timeout=480)   # within the test's deadline
    assert run.returncode == 0, run.stdout + run.stderr
    text = run.stdout
    for word in ("LoadGeometry", "PlanElectrodeSet", "ExecutePlan", "CheckInterference", "Summary",
                 "certified lower bound, whole path", "exact minimum, vertices at samples", "stock left",
                 "all nodes stopped"):
        assert word in text
    # the set's EDM process step is a progress line of its own, past 80 %, naming the set
    assert re.search(r"^ +(8\d|9\d)\.\d % .*front/rear: the EDM process", text, re.M), text
    # per electrode, side by side: the certified lower bound never above the exact minimum, surface by surface
    lines = text.splitlines()
    rows = [i for i, line in enumerate(lines) if "certified lower bound, whole path" in line]
    assert rows
    for i in rows:
        lower = [float(v) for v in lines[i].split("whole path")[1].split()]
        exact = [float(v) for v in lines[i + 1].split("vertices at samples")[1].split()]
        if lines[i].split()[0].startswith("rough-"):
            # a roughing twin: its own feed certificate, well clear of the walls; the exact re-check is the
            # finishing plan's only (not computed: nan)
            assert all(v != v for v in exact) and min(lower) > 0.2, lines[i:i + 2]
            continue
        assert len(lower) == len(exact) == 4 and all(lo <= ex for lo, ex in zip(lower, exact)), lines[i:i + 2]
    # the process (issue 25): every electrode's removed volume, eroding time and wear, the channel and the
    # blisk, set beside Liu et al.'s channel time; each trajectory erosion-timed with the generator on
    assert "process (model estimates, config/machine.yaml)" in text and "Liu et al. 2024" in text
    durations = [line for line in lines if " cycle " in line and "generator on" in line]
    assert len(durations) == text.count("] ExecutePlan:")
    for line in durations:
        hours, on = float(line.split(" = ")[1].split(" h")[0]), float(line.split("generator on ")[1].split(" h")[0])
        assert 0 < on <= hours, line
    for name in ("axes_vs_time.png", "axes_vs_index.png", "clearance.png", "channel.png", "channel.glb",
                 "stock.png", "process.png"):
        assert (out / name).stat().st_size > 10_000, name
    (set_dir,) = list((out / "plans").iterdir())               # the set export, named by the set id
    doc = json.loads((set_dir / "set.json").read_text())
    assert len(doc["electrodes"]) >= 2                          # the primitive electrode cannot leave
    for e in doc["electrodes"]:
        exported = read_plan(set_dir / e["export"])
        assert exported.channel == 0 and len(exported.axes) > 100
        assert (set_dir / e["export"] / "cycle.csv").exists()
    assert text.count("] ExecutePlan:") == len(doc["electrodes"])
    regimes = [e["regime"] for e in doc["electrodes"]]
    assert set(regimes) <= {"rough", "finish"} and regimes == sorted(regimes, key=lambda r: r != "rough"), \
        f"roughing twins first, then the finishing electrodes: {regimes}"
    assert doc["process"]["plot"] == "process.png" and len(doc["process"]["electrodes"]) == len(regimes)
    # one truth for the times: each export (plan.json's legs and cycle.csv) times its cycle as the bridge did
    # from the plan store (the same regimes and removed volumes, timed on the same machine file)
    from edm_planner.cli import _exported_plan
    from edm_planner.cnc.config import default_machine_path, load_machine
    from edm_planner.cnc.trajectory import time_run
    from edm_planner.machining.program import program_runs

    machine = load_machine(default_machine_path())
    printed = {line.split()[0]: float(line.split(" cycle ")[1].split(" s")[0]) for line in durations}
    for e in doc["electrodes"]:
        plan, _ = _exported_plan(set_dir / e["export"])
        assert all(leg.regime in ("", e["regime"]) for leg in plan.cycle.legs)
        assert any(leg.regime for leg in plan.cycle.legs), f"{e['label']}: its cutting legs carry their regime"
        duration = time_run(program_runs([(plan.plan_id, 0)], {plan.plan_id: plan})[0].legs, machine).duration
        assert duration == pytest.approx(printed[e["label"]], abs=0.06), e["label"]
    # no node process outlives the demo
    assert processes_of(env["HOME"]) == []


def test_demo_interrupted_stops_every_node_and_exits_non_zero(tmp_path):
    """Ctrl-C while the planner works: the demo stops all four processes and exits with 130."""
    import signal

    from hang_report import register
    from ros_harness import OutputLines

    from edm_planner.quick_exit import STUCK_REPORT

    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) + 103) % 232)
    env["HOME"] = str(tmp_path / "home")
    env.pop("EDM_PLANNER_PLAN_STORE", None)
    env["PYTHONUNBUFFERED"] = "1"
    out = tmp_path / "demo"
    proc = register(subprocess.Popen([sys.executable, "-m", "edm_planner.nodes.programs.demo", "--out", str(out)],
                                     env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True), "demo")
    output = OutputLines(proc)
    try:
        output.wait_for("] PlanElectrodeSet:", timeout=300)     # the cell controller has asked for the plan
        running = processes_of(env["HOME"])
        assert len(running) >= 5, running                # the demo and its four nodes
        proc.send_signal(signal.SIGINT)
        try:
            text = output.rest(timeout=120)
        except TimeoutError as exc:       # who keeps the output open, and where each of them is stuck
            from hang_report import holders_report
            raise AssertionError(f"{exc}\ndemo {'running' if proc.poll() is None else f'exited {proc.returncode}'}; "
                                 f"{holders_report(proc.stdout)}") from exc
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, text
    assert "interrupted" in text and "all nodes stopped" in text
    assert STUCK_REPORT not in text, text                    # its exit needed no deadline (quick_exit's watchdog)
    assert processes_of(env["HOME"]) == [], running


def test_the_demos_pictures_are_drawn_in_their_thread_in_order_and_a_failure_reaches_the_demo():
    import threading

    from edm_planner.nodes.programs.demo_steps import Pictures

    pictures, drawn = Pictures(), []
    try:
        pictures.draw(lambda plots, k: drawn.append((k, plots.__name__, threading.current_thread().name)), 1)
        pictures.draw(lambda plots: 1 / 0)
        pictures.draw(lambda plots, k: drawn.append((k, plots.__name__, threading.current_thread().name)), 3)
        with pytest.raises(ZeroDivisionError):
            pictures.wait(120)
    finally:
        pictures.close()
    assert [d[:2] for d in drawn] == [(1, "edm_planner.records.plots"), (3, "edm_planner.records.plots")]
    assert {d[2] for d in drawn} == {"demo-pictures_0"}


def test_the_failure_report_names_the_process_that_keeps_an_output_open():
    """What the interrupted demo's test reports when the output does not end: the process still holding the pipe."""
    from hang_report import holders_report, pipe_holders

    shell = subprocess.Popen(["bash", "-c", "sleep 60 & echo started"], stdout=subprocess.PIPE, text=True)
    try:
        assert shell.stdout.readline() == "started\n"
        shell.wait(timeout=30)                           # the shell is gone; the sleep it left keeps the pipe open
        # the background job is a fork of the shell until it has exec'd sleep (seen under load: its command line
        # still the shell's): wait for that, with a deadline
        deadline = time.monotonic() + 30
        holders = pipe_holders(shell.stdout)
        while [cmd for _, cmd in holders] != ["sleep 60"]:
            assert time.monotonic() < deadline, holders
            time.sleep(0.05)
            holders = pipe_holders(shell.stdout)
        assert f"pid {holders[0][0]} holds the pipe: sleep 60" in holders_report(shell.stdout)
    finally:
        for pid, _ in pipe_holders(shell.stdout):
            os.kill(pid, 9)
        shell.stdout.close()
