# edm_planner: the two commands a new user types are `make demo` and `make test`.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
# DDS stays on loopback in everything the project runs here.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export AMENT_PREFIX_PATH := $(CURDIR)/$(VENV)
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: setup demo test bench clean

setup:
	@bash tools/setup.sh

demo: setup
	$(PY) -m edm_planner.nodes.demo --out out/demo

test: setup
	$(PY) -m pytest -q test

bench: setup
	$(PY) -m edm_planner.bench --out out/bench.json

clean:
	rm -rf build out .pytest_cache
