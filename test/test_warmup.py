"""The numba warm-up that make setup runs: the whole of it, in its two processes, finishes and says so."""

import subprocess
import sys

from conftest import REPO


def test_warm_up_runs_both_parts_and_reports():
    run = subprocess.run([sys.executable, "-m", "edm_planner.warmup"], cwd=REPO, capture_output=True, text=True,
                         timeout=1800)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "warm-up (part 0): numba kernels compiled or loaded from the cache in" in run.stdout
    assert "warm-up (part 1): numba kernels compiled or loaded from the cache in" in run.stdout
    assert "warm-up: done in" in run.stdout


def test_a_bad_part_is_refused_with_a_usage_line():
    run = subprocess.run([sys.executable, "-m", "edm_planner.warmup", "--part", "7"], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "invalid choice" in run.stderr and "Traceback" not in run.stderr
