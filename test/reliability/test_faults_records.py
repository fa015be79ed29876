"""Helpers of the fault tests (no tests here): records of known content and the rows of a store."""

import os
import sqlite3

import numpy as np

from edm_planner.records.store import FILE_NAME, StoredPlan


def record(i):
    """Record ``i``: a plan-sized record (about 350 kB of arrays) whose content follows from ``i`` alone."""
    rng = np.random.default_rng(i)
    return StoredPlan(plan_id=f"{i:016x}", kind="channel", geometry_id="f" * 64, channel=i % 7,
                      electrode_id="rear", method="default", axis_names=("X", "Y", "Z", "A", "C"),
                      samples=rng.normal(size=(2000, 5)), final_pose=np.eye(4), poses=rng.normal(size=(2000, 4, 4)),
                      meta={"message": f"record {i}", "index": i}, arrays={"nodes": rng.normal(size=(200, 5))},
                      created=f"2026-01-01T00:00:{i % 60:02d}+00:00")


def store_rows(directory):
    """Every row of a plan store, record bytes included, after SQLite's integrity check."""
    con = sqlite3.connect(os.path.join(directory, FILE_NAME))
    try:
        assert con.execute("PRAGMA integrity_check").fetchall() == [("ok",)]
        plans = {r[0]: r[1:] for r in con.execute("SELECT plan_id, request_key, sha256, record FROM plans")}
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        seqs = ({r[0]: r[1:] for r in con.execute("SELECT sequence_id, sha256, record FROM sequences")}
                if "sequences" in tables else {})
        return plans, seqs
    finally:
        con.close()
