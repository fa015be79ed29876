"""``make soak``: many mixed service calls against one set of node processes; memory and latency.

Starts ``geometry_loader``, ``interference_checker`` and ``trajectory_planner``
as OS processes (as ``make demo`` does) and drives them from two client nodes,
each in a thread of its own, with a mixed schedule: CheckInterference of the
bench case's plan path (distance-field method; every tenth call, by default, the
exact one on a few poses) and PlanChannel of the bench case (the default blisk's rear
electrode of a front/rear split) with distinct (channel, seed) pairs, planned
anew, and repeats of earlier requests, answered from the plan store. Every
``sample_every`` calls it records each node's resident memory (``VmRSS`` of
``/proc/<pid>/status``) and its private part (``RssAnon``: what a leak grows;
the rest is pages of mapped files, such as the distance field mapped from its
cache, which the kernel can drop and which grow as queries first touch them);
at the end the latency percentiles per kind of call.

A repeated PlanChannel must return its first answer's axis path and poses bit
for bit; every call must succeed. ``python -m edm_planner.nodes.programs.soak --out
out/soak.json`` (``make soak``: 1000 CheckInterference, 100 PlanChannel).
"""

import argparse
import json
import logging
import os
import pathlib
import random
import sys
import tempfile
import threading
import time

from ...environment import CACHE_ROOT, configure_process

# this entry point's set-up, before numpy loads OpenBLAS and the core's kernel modules load (both read it)
configure_process()

import numpy as np
import rclpy
from edm_planner_msgs.msg import ElectrodeDesign
from edm_planner_msgs.srv import CheckInterference, PlanChannel
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from ...geometry.loader import parse_document
from ...ros.shared import config_directory
from ...ros.dds import loopback_unless_told
from .bringup import Bringup

_log = logging.getLogger(__name__)

#: the nodes a soak runs against
SOAK_NODES = ("geometry_loader", "interference_checker", "trajectory_planner")
#: resident memory a node may gain from the first sample after the calls began to the last [MB] (``make soak``
#: fails beyond it): the planner's rises by about 10 MB with each of its first few plans, then levels off
RSS_GROWTH_BOUND_MB = 30.0


def rss_mb(pid, field="VmRSS"):
    """Resident memory of a process [MB] from ``/proc/<pid>/status``: all of it (VmRSS) or ``field``
    (RssAnon: the private memory, without the pages of mapped files)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no {field} for process {pid}")


def _memory_sample(calls, seconds, pids):
    return {"calls": calls, "seconds": round(seconds, 1), "rss_mb": {n: round(rss_mb(p), 1) for n, p in pids.items()},
            "private_mb": {n: round(rss_mb(p, "RssAnon"), 1) for n, p in pids.items()}}


def rear_design_msg():
    """The bench case's electrode design overrides: the rear electrode of a front/rear split."""

    nan = float("nan")
    return ElectrodeDesign(discharge_gap=nan, circumferential_reduction=0.03, reduction_side="",
                           radial_reduction=3.0, axial_start=nan, axial_end=nan, split="front_rear",
                           split_fraction=nan, split_overlap=1.0)


class ServiceLost(RuntimeError):
    """A service call that cannot complete: the server process is gone or the call timed out."""

def call(client, request, timeout, alive):
    """Call ``client``'s service and wait for the answer; (response, seconds).

    ``alive()`` raises when a node process has exited: a request to a server that died never
    completes, so it is checked while waiting, as is ``timeout`` [s].
    """
    done = threading.Event()
    t = time.perf_counter()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    deadline = time.monotonic() + timeout
    while not done.wait(0.05):
        alive()
        if time.monotonic() > deadline:
            client.remove_pending_request(future)
            raise ServiceLost(f"service {client.srv_name} did not answer within {timeout:.0f} s")
    return future.result(), time.perf_counter() - t


def percentiles(seconds):
    """p50, p90, p99, max and mean of latencies [ms]."""
    if not len(seconds):
        return {}
    a = np.asarray(seconds) * 1e3
    return {"count": int(len(a)), "p50_ms": round(float(np.percentile(a, 50)), 2),
            "p90_ms": round(float(np.percentile(a, 90)), 2), "p99_ms": round(float(np.percentile(a, 99)), 2),
            "max_ms": round(float(a.max()), 2), "mean_ms": round(float(a.mean()), 2)}


def schedule(n_check, n_plan, n_distinct, blade_count, seed=7):
    """The calls in order: ("check", i) and ("plan", (channel, seed)); distinct plans first seen in order.

    The distinct requests are channels 1, 2, ... with seed 1 (then seed 2 from channel 0 on): channel 0
    seed 1 is the soak's first plan, made before the calls.

    The PlanChannel calls are spread evenly among the CheckInterference calls; a repeat names a
    request issued before it.
    """
    rng = random.Random(seed)
    distinct = [(k % blade_count, 1 + k // blade_count) for k in range(1, n_distinct + 1)]   # (0, 1): the first
    plans, issued = [], 0
    for i in range(n_plan):
        left, slots = n_distinct - issued, n_plan - i
        if issued == 0 or (left and rng.random() < left / slots):
            plans.append(distinct[issued])
            issued += 1
        else:
            plans.append(distinct[rng.randrange(issued)])
    total = n_check + n_plan
    at = {round((k + 0.5) * total / n_plan) for k in range(n_plan)} if n_plan else set()
    out, p, c = [], 0, 0
    for j in range(total):
        if (j in at and p < n_plan) or c == n_check:
            out.append(("plan", plans[p]))
            p += 1
        else:
            out.append(("check", c))
            c += 1
    return out


def run_soak(work_dir, n_check=1000, n_plan=100, n_distinct=50, sample_every=100, cache_dir=None,
             store_dir=None, poses_per_check=200, exact_every=10, timeout=600.0, progress=_log.info):
    """Run the soak; returns the figures (JSON-safe dict).

    Parameters
    ----------
    work_dir : path
        Node logs (``logs/``) and, unless given, the plan store.
    n_check, n_plan : int
        CheckInterference and PlanChannel calls in all (both clients together).
    n_distinct : int
        Distinct PlanChannel requests (planned anew); the other PlanChannel calls repeat them.
    cache_dir, store_dir : path, optional
        The distance-field cache (default the user's) and the plan store (default a new one in
        ``work_dir``: the distinct requests are planned, not found).
    poses_per_check : int
        About this many poses of the first plan's path per distance-field check.
    exact_every : int
        Every so many CheckInterference calls one is the exact method on 5 or 6 poses.
    """

    loopback_unless_told()
    os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 30))
    os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    work = pathlib.Path(work_dir)
    store_dir = str(store_dir or work / "plan_store")
    cache_dir = str(cache_dir or CACHE_ROOT)
    node_params = {"trajectory_planner": {"plan_store": store_dir, "cache_dir": cache_dir,
                                          "unknown_geometry_wait": 120.0, "geometry_wait": 900.0},   # a new field
                   "interference_checker": {"cache_dir": cache_dir}}
    bringup = Bringup(work / "logs", node_params)
    ctx = Context()
    rclpy.init(context=ctx)
    executor = MultiThreadedExecutor(num_threads=4, context=ctx)
    clients = [Node(f"soak_client_{c}", context=ctx) for c in "ab"]
    for node in clients:
        executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    t_start = time.perf_counter()
    try:
        bringup.start(SOAK_NODES)
        pids = {name: proc.pid for name, (proc, _) in bringup.procs.items()}
        plan_clients = [n.create_client(PlanChannel, "plan_channel") for n in clients]
        check_clients = [n.create_client(CheckInterference, "check_interference") for n in clients]
        for cl in plan_clients + check_clients:
            deadline = time.monotonic() + 120
            while not cl.wait_for_service(timeout_sec=0.5):
                bringup.check_alive()
                if time.monotonic() > deadline:
                    raise ServiceLost(f"service {cl.srv_name} not available after 120 s")

        # the first plan (the planner receives the latched geometry and loads its field meanwhile):
        # its path is what CheckInterference checks
        first_req = PlanChannel.Request(channel=0, electrode_id="rear", electrode=rear_design_msg())
        first_req.settings.seed = 1
        first, first_s = call(plan_clients[0], first_req, max(timeout, 900.0), bringup.check_alive)
        if not first.success:
            raise RuntimeError(f"first PlanChannel failed: {first.message}")
        progress(f"first plan {first.plan_id} in {first_s:.1f} s (with the planner's geometry and field)")
        poses = list(first.poses.poses)
        step = max(1, len(poses) // poses_per_check)
        fast_req = CheckInterference.Request(channel=0, electrode_id="rear", electrode=rear_design_msg(),
                                             method=CheckInterference.Request.METHOD_FAST, poses=poses[::step])
        exact_req = CheckInterference.Request(channel=0, electrode_id="rear", electrode=rear_design_msg(),
                                              method=CheckInterference.Request.METHOD_EXACT,
                                              poses=poses[::max(1, len(poses) // 5)])
        # the checker may still be receiving the geometry and loading its field: ask until it answers
        deadline = time.monotonic() + max(timeout, 900.0)
        while True:
            res, _ = call(check_clients[0], fast_req, timeout, bringup.check_alive)
            if res.error_code.val == 0 or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        if res.error_code.val != 0:
            raise RuntimeError(f"CheckInterference never succeeded: {res.message}")
        expected_min = min(c.minimum for c in res.clearances)

        blade_count = _blade_count()
        calls = schedule(n_check, n_plan, n_distinct, blade_count)
        lock = threading.Lock()
        state = {"done": 0, "failures": [], "mismatches": []}
        lat = {"check_fast": [], "check_exact": [], "plan_new": [], "plan_stored": []}
        answers = {(0, 1): first}
        memory = [_memory_sample(0, time.perf_counter() - t_start, pids)]

        def worker(k):
            for j in range(k, len(calls), 2):
                kind, arg = calls[j]
                try:
                    if kind == "check":
                        req = exact_req if arg % exact_every == exact_every - 1 else fast_req
                        res, s = call(check_clients[k], req, timeout, bringup.check_alive)
                        ok = res.error_code.val == 0 and len(res.clearances) == len(req.poses)
                        if ok and req is fast_req and abs(min(c.minimum for c in res.clearances)
                                                          - expected_min) > 1e-12:
                            ok = False
                        label = "check_exact" if req is exact_req else "check_fast"
                    else:
                        channel, seed = arg
                        req = PlanChannel.Request(channel=channel, electrode_id="rear", electrode=rear_design_msg())
                        req.settings.seed = seed
                        res, s = call(plan_clients[k], req, timeout, bringup.check_alive)
                        ok = res.success
                        label = "plan_stored" if res.message.startswith("from the plan store") else "plan_new"
                        with lock:
                            before = answers.setdefault(arg, res)
                        if ok and before is not res and not _same_plan(before, res):
                            with lock:
                                state["mismatches"].append(f"{arg}: {before.plan_id} vs {res.plan_id}")
                except Exception as exc:  # collected; the soak reports every failure
                    with lock:
                        state["failures"].append(f"call {j} ({kind} {arg}): {exc!r}")
                    return
                with lock:
                    if not ok:
                        state["failures"].append(f"call {j} ({kind} {arg}): {res.message}")
                    lat[label].append(s)
                    state["done"] += 1
                    if state["done"] % sample_every == 0:
                        memory.append(_memory_sample(state["done"], time.perf_counter() - t_start, pids))
                        progress(f"{state['done']} calls: RSS " + ", ".join(
                            f"{n} {v:.0f} MB" for n, v in memory[-1]["rss_mb"].items()))

        t_calls = time.perf_counter()
        threads = [threading.Thread(target=worker, args=(k,)) for k in range(2)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        calls_s = time.perf_counter() - t_calls
        bringup.check_alive()
        base = memory[1] if len(memory) > 2 else memory[0]       # after the first block: fields loaded
        growth = {n: round(memory[-1]["rss_mb"][n] - base["rss_mb"][n], 1) for n in pids}
        private = {n: round(memory[-1]["private_mb"][n] - base["private_mb"][n], 1) for n in pids}
        return {"check_calls": n_check, "plan_calls": n_plan, "distinct_plans": n_distinct, "exact_every": exact_every,
                "poses_per_fast_check": len(fast_req.poses), "poses_per_exact_check": len(exact_req.poses),
                "calls_done": state["done"], "failures": state["failures"], "mismatches": state["mismatches"],
                "calls_s": round(calls_s, 1), "total_s": round(time.perf_counter() - t_start, 1),
                "latency": {k: percentiles(v) for k, v in lat.items()},
                "memory": memory, "rss_growth_mb": growth, "private_growth_mb": private, "growth_from_calls": base["calls"],
                "rss_growth_bound_mb": RSS_GROWTH_BOUND_MB,
                "store": store_dir}
    finally:
        bringup.stop()
        executor.shutdown()
        for node in clients:
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        spinner.join(timeout=5)


def _blade_count():
    """The default blisk's blade count, from its YAML (not the whole geometry, which the nodes load)."""

    path = config_directory() / "default_blisk.yaml"
    return int(parse_document(path.read_text(), str(path))["blade_count"])


def _same_plan(a, b):
    """Two PlanChannel answers of one request: same plan, axis path and poses bit for bit."""
    qa = np.array([p.positions for p in a.axis_path.points])
    qb = np.array([p.positions for p in b.axis_path.points])
    pa = [(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
           p.orientation.w) for p in a.poses.poses]
    pb = [(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
           p.orientation.w) for p in b.poses.poses]
    return a.plan_id == b.plan_id and qa.shape == qb.shape and np.array_equal(qa, qb) and pa == pb


def main(argv=None):
    parser = argparse.ArgumentParser(description="Soak the nodes with mixed service calls (JSON out).")
    parser.add_argument("--out", default="out/soak.json", help="JSON file to write")
    parser.add_argument("--checks", type=int, default=1000, help="CheckInterference calls")
    parser.add_argument("--plans", type=int, default=100, help="PlanChannel calls")
    parser.add_argument("--distinct", type=int, default=50, help="distinct PlanChannel requests (planned anew)")
    parser.add_argument("--cache-dir", default=None, help="distance-field cache (default the user's)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
    with tempfile.TemporaryDirectory(prefix="edm_soak_") as work:
        result = run_soak(work, args.checks, args.plans, args.distinct, cache_dir=args.cache_dir)
    result["timestamp"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    path = pathlib.Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
    _log.info("%s", json.dumps({k: v for k, v in result.items() if k != "memory"}, indent=2))
    grown = {n: g for n, g in result["private_growth_mb"].items() if g > RSS_GROWTH_BOUND_MB}
    if grown:
        _log.error("memory grew beyond %s MB: %s", RSS_GROWTH_BOUND_MB, grown)
    return 0 if not result["failures"] and not result["mismatches"] and not grown else 1


if __name__ == "__main__":
    raise SystemExit(main())
