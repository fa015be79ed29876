#!/usr/bin/env bash
# Bring .venv up to date: pinned dependencies and the pinned developer and test tools (colcon)
# (by uv), the ROS wheel fixes, the interface package,
# edm_planner installed in the ament layout, its bytecode and its numba kernels compiled
# into numba's cache.
# Each step runs only when its inputs changed (stamps hold content hashes),
# so a second run with nothing changed takes about a second.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=$ROOT/.venv
STAMPS=$VENV/.stamps
PY=${PYTHON:-python3}

hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }
fresh() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
# pip, with its output kept in build/pip.log and shown only when it fails
pip_quiet() {
  mkdir -p build
  "$VENV/bin/pip" -q --disable-pip-version-check "$@" > build/pip.log 2>&1 \
    || { grep -v "^WARNING: Location" build/pip.log | tail -40; echo "setup: pip $* failed"; exit 1; }
}
stamp() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PY" -m venv "$VENV"
fi

# The pinned dependencies and the developer and test tools (colcon: it must run with the Python that has the
# ROS wheels), in one step by uv (pinned in requirements-setup.txt): on a new clone 41 s where pip took 109 s
# (pip unpacks and compiles the 2.4 GB serially on one core; uv in parallel, the same files). uv does not read
# pip's configuration: its index and find-links settings are passed on (pip_sources), and where uv fails
# (an index only pip can reach, no writable cache) pip installs the same pins.
pip_sources() {
  # pip's merged settings (its files, PIP_CONFIG_FILE, PIP_* variables); per option the variable over the
  # install section over the global one, as pip ranks them
  "$VENV/bin/pip" config list 2>/dev/null | "$VENV/bin/python" -c '
import ast, sys
rank, got = {"global": 0, "install": 1, ":env:": 2}, {}
for line in sys.stdin:
    key, _, value = line.strip().partition("=")
    section, _, option = key.rpartition(".")
    if section in rank and option in ("index-url", "extra-index-url", "find-links") and value:
        if rank[section] >= got.get(option, (-1, ""))[0]:
            got[option] = (rank[section], ast.literal_eval(value))
for option in ("index-url", "extra-index-url", "find-links"):
    for url in got.get(option, (0, ""))[1].split():
        print("--" + option)
        print(url)
'
}
h=$(hash_of requirements-setup.txt requirements.txt requirements-dev.txt constraints.txt)
if ! fresh deps "$h"; then
  echo "setup: installing the pinned dependencies and developer tools (about 40 s on a new clone)"
  pip_quiet install -r requirements-setup.txt
  mapfile -t sources < <(pip_sources)
  if ! "$VENV/bin/uv" pip install --quiet --python "$VENV/bin/python" --compile-bytecode \
        --index-strategy unsafe-best-match "${sources[@]}" \
        -r requirements.txt -r requirements-dev.txt -c constraints.txt > build/uv.log 2>&1; then
    tail -5 build/uv.log
    echo "setup: uv could not install them (build/uv.log); pip installs the same pins (about 2 minutes)"
    pip_quiet install -r requirements.txt -r requirements-dev.txt -c constraints.txt
  fi
  "$VENV/bin/python" tools/fix_ros_wheels.py
  stamp deps "$h"
fi

h=$(hash_of $(find msg_defs -type f | sort) requirements.txt)
if ! fresh msgs "$h" || [ ! -d "$VENV/share/edm_planner_msgs" ]; then
  echo "setup: building the interface package edm_planner_msgs (about a minute)"
  export VIRTUAL_ENV=$VENV
  cmake -S msg_defs -B build/edm_planner_msgs -DCMAKE_INSTALL_PREFIX="$VENV" \
    -DCMAKE_PREFIX_PATH="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" \
    -DBUILD_TESTING=OFF > build/cmake-configure.log 2>&1 \
    || { mkdir -p build; cat build/cmake-configure.log; exit 1; }
  cmake --build build/edm_planner_msgs -j2 > build/cmake-build.log 2>&1 || { tail -50 build/cmake-build.log; exit 1; }
  cmake --install build/edm_planner_msgs > build/cmake-install.log 2>&1 || { tail -20 build/cmake-install.log; exit 1; }
  stamp msgs "$h"
fi

h=$(hash_of setup.py setup.cfg package.xml resource/edm_planner tools/install_ament_layout.py $(find config launch -type f | sort))
if ! fresh pkg "$h"; then
  echo "setup: installing edm_planner (editable) in the ament layout"
  pip_quiet install --no-deps --no-build-isolation -e .
  "$VENV/bin/python" tools/install_ament_layout.py
  stamp pkg "$h"
fi

# the package's bytecode, compiled here because the Makefile keeps every other run from writing it
# (PYTHONDONTWRITEBYTECODE): without it each process that imports edm_planner (the four nodes, the CLI,
# every test's child process) compiles the package's sources again, about 0.3 s of CPU apiece; the files
# changed since are compiled again here (about 0.1 s when none did), and Python reads a .pyc only while it
# matches its source's time stamp and size
"$VENV/bin/python" -m compileall -q edm_planner

# numba's on-disk cache is keyed by the kernels' source files: compile them once here, in two processes,
# instead of in every node, worker and test process that first needs them (at once, on a new clone)
# (one directory per version of the kernel sources: edm_planner.environment names it in NUMBA_CACHE_DIR)
NUMBA_DIR=$("$VENV/bin/python" -c 'from edm_planner.environment import configure_process; print(configure_process())')
h=$( (echo "$ROOT"; cat requirements.txt; echo "$NUMBA_DIR") | sha256sum | cut -c1-16)
if ! fresh numba "$h" || [ ! -d "$NUMBA_DIR" ]; then
  echo "setup: compiling the numba kernels into $NUMBA_DIR (about 2 minutes on a new clone)"
  mkdir -p build
  "$VENV/bin/python" -m edm_planner.apps.warmup > build/warmup.log 2>&1 || { tail -30 build/warmup.log; exit 1; }
  stamp numba "$h"
fi
