"""make setup compiles the package's bytecode: no process that imports edm_planner compiles its sources again.

The Makefile keeps Python from writing bytecode itself (PYTHONDONTWRITEBYTECODE), so without this step
every node, CLI and test process compiled the package's sources anew, about 0.3 s of CPU apiece.
"""

import importlib.util
import os
import pathlib
import struct
import subprocess
import sys

from conftest import REPO


def _up_to_date(source):
    """Whether the .pyc Python would read for ``source`` exists and matches it (the import system's own test)."""
    cached = pathlib.Path(importlib.util.cache_from_source(str(source)))
    if not cached.exists():
        return False
    head = cached.read_bytes()[:16]
    if head[:4] != importlib.util.MAGIC_NUMBER:
        return False
    if struct.unpack("<I", head[4:8])[0] & 1:                       # hash-based .pyc (PEP 552)
        return head[8:16] == importlib.util.source_hash(source.read_bytes())
    stat = os.stat(source)
    return struct.unpack("<II", head[8:16]) == (int(stat.st_mtime) & 0xFFFFFFFF, stat.st_size & 0xFFFFFFFF)


def test_setup_leaves_every_module_of_the_package_compiled():
    done = subprocess.run(["bash", "tools/setup.sh"], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    modules = sorted((REPO / "edm_planner").rglob("*.py"))
    assert len(modules) > 100
    stale = [str(p.relative_to(REPO)) for p in modules if not _up_to_date(p)]
    assert not stale, f"no up-to-date bytecode after make setup: {stale[:10]}"


def test_a_changed_module_is_seen_as_stale(tmp_path):
    # the check above can fail: a source newer than its bytecode is not up to date
    source = tmp_path / "module.py"
    source.write_text("VALUE = 1\n")
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(source)], check=True)
    assert _up_to_date(source)
    source.write_text("VALUE = 22\n")
    assert not _up_to_date(source)
