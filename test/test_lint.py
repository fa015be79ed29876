"""Static check of the whole tree (pyflakes): unused imports and names, undefined names, redefinitions."""

import subprocess
import sys

from conftest import REPO


def test_pyflakes_finds_nothing():
    run = subprocess.run([sys.executable, "-m", "pyflakes", "edm_planner", "test", "tools", "launch", "setup.py"],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and not run.stdout.strip(), run.stdout + run.stderr
