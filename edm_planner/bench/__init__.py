"""Benchmarks (``make bench``): speed figures as JSON, never asserted in tests.

Usage: ``python -m edm_planner.bench --out out/bench.json [--only geometry]`` (see ``__main__``).
Each figure states its unit in its key. One process, one core in use.
"""
