"""Bench suite ``scaleout`` (issue 28, part 3): the set design's tasks on 1 and 2 workers, local and Ray.

The same real tasks of the default blisk each time: sizing steps (certified-plan attempts,
:func:`~edm_planner.machining.electrode_set._plan_in_worker`) of the front/rear candidate's two pieces at the
sizing's start designs, :data:`STEPS` of them. For every executor kind (``local``: spawn worker processes;
``ray``: a local Ray started on demand, :mod:`edm_planner.machining.executors`) and 1 and 2 workers, from cold:
the executor's start (``start_s``), the whole run (``wall_s``: the start, each worker's set-up (the
package imported, the field loaded from the cache), the tasks), the same tasks again on the warm workers
(``warm_s``), and the speed-up of 2 workers over 1 of the same kind, cold (``speedup``) and warm
(``speedup_warm``). Every run's plans must be bit for bit the serial ones computed in this process first
(``same_bits``).

Measured on this machine: 2 cores (the CPU is in the bench's ``machine.cpu`` record,
:mod:`.cpu`), so 2 workers is the most a speed-up can show here; on a cluster the tasks spread over its
nodes (docs/performance.md, "Scale-out").
"""

import hashlib
import logging
import os
import time
from dataclasses import replace

import numpy as np

from ..cli import DEFAULT_CACHE
from ..geometry.loader import load_geometry
from ..interference.fast import FastChannelField
from ..machining.electrode_set import Piece, SetDesigner, _plan_in_worker, candidate_sets
from .common import CONFIG
from .cpu import cpu_label, cpu_record

_log = logging.getLogger(__name__)

#: the sizing's start designs tried per piece: (share of h_max, share of the radial start)
STARTS = ((0.5, 1.0), (0.25, 1.0), (1.0, 2.0))
STEPS = 2 * len(STARTS)
WORKERS = (1, 2)
KINDS = ("local", "ray")


def step_tasks(designer):
    """The sizing steps: (piece, h, radial) of the front/rear candidate's pieces at the start designs."""
    (_, pieces), = [(n, p) for n, p in candidate_sets(designer.blisk, designer.base, designer.options)
                    if n == "front/rear"]
    return [(Piece(lab, eid, d), fh * designer.h_max, fr * designer.r_start)
            for lab, eid, d in pieces for fh, fr in STARTS]


def plan_digest(plan):
    """SHA-256 (16 hex) of a sizing step's outcome: the plan's samples and poses ('none' without a plan)."""
    if plan is None:
        return "none"
    h = hashlib.sha256()
    for a in (plan.samples, plan.poses, np.asarray(plan.metrics.clearance_lower_bound)):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def run_steps(geometry, field, cache, kind, workers):
    """One cold run: (figures, digests) of :func:`step_tasks` on a fresh executor of ``kind``."""
    designer = SetDesigner(geometry, field, field_cache=(cache, geometry.geometry_id), workers=workers,
                           executor=kind)
    designer.base = replace(designer.base, axial_range=designer.closed_channel_range())
    tasks = step_tasks(designer)
    t0 = time.perf_counter()
    pool = designer.make_executor(workers, kind)
    start = time.perf_counter() - t0
    try:
        futures = [pool.submit(_plan_in_worker, piece, h, r) for piece, h, r in tasks]
        done = []
        for f in futures:
            piece, plan = f.result()
            done.append((time.perf_counter() - t0, piece.label, piece.tried[-1][2][:60], plan_digest(plan)))
        wall = time.perf_counter() - t0
        t1 = time.perf_counter()                     # the same tasks again on the started, warm workers
        warm = [plan_digest(f.result()[1]) for f in [pool.submit(_plan_in_worker, *task) for task in tasks]]
        warm_s = time.perf_counter() - t1
        where = dict(getattr(pool, "where", {}))
    finally:
        pool.shutdown()
    return {"kind": kind, "workers": workers, "start_s": round(start, 2), "wall_s": round(wall, 2),
            "warm_s": round(warm_s, 2), "warm_same_bits": warm == [d[3] for d in done], "nodes": len(where) or 1,
            "tasks": [{"done_at_s": round(t, 2), "piece": lab, "result": res, "plan": dig}
                      for t, lab, res, dig in done]}, [d[3] for d in done]


def bench_scaleout(kinds=KINDS, workers=WORKERS):
    g = load_geometry(CONFIG / "default_blisk.yaml")
    cache = DEFAULT_CACHE
    FastChannelField(g.blisk, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)     # built before the clock
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)
    cpu = cpu_record()
    out = {"label": f"measured on this machine: {os.cpu_count()} cores, {cpu_label(cpu)}",
           "cores": os.cpu_count(), "task": f"{STEPS} sizing steps (certified-plan attempts) of the default "
                                            f"blisk's front/rear pieces", "runs": []}
    designer = SetDesigner(g, field, workers=1)              # the serial reference, in this process
    designer.base = replace(designer.base, axial_range=designer.closed_channel_range())
    t0 = time.perf_counter()
    reference = []
    for piece, h, r in step_tasks(designer):
        designer.t0 = time.perf_counter()
        reference.append(plan_digest(designer._plan(piece, h, r)[0]))
    out["serial_in_process_s"] = round(time.perf_counter() - t0, 2)
    out["serial_plans"] = reference
    for kind in kinds:
        for w in workers:
            figures, digests = run_steps(g, field, cache, kind, w)
            figures["same_bits"] = digests == reference
            out["runs"].append(figures)
            _log.warning("scaleout %s x%d: %s", kind, w, figures)
    by = {(r["kind"], r["workers"]): r["wall_s"] for r in out["runs"]}
    out["speedup"] = {kind: {str(w): round(by[(kind, workers[0])] / by[(kind, w)], 2) for w in workers}
                      for kind in kinds}
    warm = {(r["kind"], r["workers"]): r["warm_s"] for r in out["runs"]}
    out["speedup_warm"] = {kind: {str(w): round(warm[(kind, workers[0])] / warm[(kind, w)], 2) for w in workers}
                           for kind in kinds}
    out["same_bits"] = all(r["same_bits"] and r["warm_same_bits"] for r in out["runs"])
    return out
