# edm_planner: the two commands a new user types are `make demo` and `make test`.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
# DDS stays on loopback in everything the project runs here.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export AMENT_PREFIX_PATH := $(CURDIR)/$(VENV)
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: setup demo test test-fast bench soak docs clean

setup:
	@bash tools/setup.sh

demo: setup
	$(PY) -m edm_planner.nodes.programs.demo --out out/demo

# The whole suite in three pytest-xdist workers on the two cores (the tests that wait on node
# processes leave a core idle otherwise: 957 -> 870 s measured, docs/tests.md), each test file in one
# worker (its module fixtures built once), the files in the order of test/conftest.py (the longest
# first; xdist would otherwise start the files with the most tests first). PYTEST_ARGS adds options,
# e.g. PYTEST_ARGS=--durations=10.
TEST_WORKERS ?= 3
XDIST := -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder
test: setup
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS) test

# The inner loop: everything but the tests marked slow (whole-product runs, planning over DDS).
test-fast: setup
	$(PY) -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS) test

bench: setup
	$(PY) -m edm_planner.bench --out out/bench.json $(BENCH_ARGS)

# 1000 CheckInterference and 100 PlanChannel calls from two clients against one set of node processes:
# memory every 100 calls and the latency percentiles (docs/reliability.md, Soak).
soak: setup
	$(PY) -m edm_planner.nodes.programs.soak --out out/soak.json

# The documentation site (docs/, mkdocs.yml) into out/site: open out/site/index.html. --strict: a broken
# link or anchor, a page missing from the nav or a docstring griffe cannot parse fails the build.
docs: setup
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict -d out/site

clean:
	rm -rf build out .pytest_cache
