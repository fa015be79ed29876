"""The whole blisk as measured in one command (issue 28): every channel group planned as a task, on its own walls.

The test blisk is the default blisk with only channel 43's two walls as measured (``measured_blisk.py``, seed
59, ``only_channel=43``): two groups, channel 43 alone and the 59 nominal channels. A fixed electrode design
(the rear electrode of a front/rear split, the one test_as_measured.py plans) keeps every run to a plan and a
cycle per group, no set design. ``edm-plan plan --all-channels`` plans both groups in two local worker
processes and keeps them in a plan store of this module; channel 43's plan is bit for bit ``edm-plan plan
--channel 43``'s; ``edm-plan export --all-channels DIR`` writes the whole blisk's NC program with channel 43's
own plan there and the nominal one elsewhere; a rerun plans nothing; a group that fails is named and the other
is kept. On a local two-node Ray cluster the group tasks run as Ray tasks, one per node, with the local bits,
and a task whose worker is killed is run again. Every wait has a deadline. Units: mm, rad, s.
"""

import io
import json
import os
import signal
import time
from dataclasses import replace

import numpy as np
import pytest

from edm_planner.cli import main
from edm_planner.geometry.loader import load_geometry
from edm_planner.machining.blisk_plan import BliskRequest, channel_ranges, plan_blisk
from edm_planner.machining.cycle import CycleOptions
from edm_planner.planning.plan import PlanOptions
from edm_planner.planning.search import SearchOptions
from edm_planner.records.store import open_store, stored_to_plan
from measured_blisk import write_measured_blisk
from ray_cluster import task_processes, two_node_cluster

SEED, CHANNEL = 59, 43
#: seconds any one wait of this file may take before it fails
DEADLINE = 240.0
#: the fixed design and search settings of every run here (test_as_measured.py's rear electrode)
DESIGN_ARGS = ["--electrode", "rear", "--split", "front_rear", "--circumferential-reduction", "0.03",
               "--radial-reduction", "3", "--split-overlap", "1", "--exit-side", "downstream",
               "--margin-blade", "0.08", "--margin-hub-shroud", "0.08"]


def run(argv):
    out, err = io.StringIO(), io.StringIO()
    return main(argv, out, err), out.getvalue(), err.getvalue()


def blisk_argv(yaml, out, store, field_cache, *extra):
    return (["plan", "--all-channels", "--geometry", str(yaml), "--out", str(out), "--cache-dir", str(field_cache),
             "--store", str(store), "--workers", "2"] + DESIGN_ARGS + list(extra))


@pytest.fixture(scope="module")
def one_channel(tmp_path_factory, default_geometry):
    path, _ = write_measured_blisk(tmp_path_factory.mktemp("blisk_one_channel"), default_geometry.blisk, seed=SEED,
                                   only_channel=CHANNEL)
    return load_geometry(path)


@pytest.fixture(scope="module")
def whole(one_channel, tmp_path_factory, field_cache):
    """The first `edm-plan plan --all-channels` run: (directory, store directory, status, stdout, stderr, seconds)."""
    root = tmp_path_factory.mktemp("whole_blisk")
    t0 = time.perf_counter()
    rc, out, err = run(blisk_argv(one_channel.source, root / "out", root / "store", field_cache))
    return root / "out", root / "store", rc, out, err, time.perf_counter() - t0


def request_of(geometry, field_cache):
    """The BliskRequest `edm-plan plan --all-channels` makes of DESIGN_ARGS (the file's design, changed)."""
    options = PlanOptions(search=SearchOptions(margin_blade=0.08, margin_hub_shroud=0.08, exit_side="downstream"))
    design = replace(geometry.design, split="front_rear", circumferential_reduction=0.03, radial_reduction=3.0,
                     split_overlap=1.0)
    return BliskRequest(options, True, design, ("rear",), CycleOptions(tolerance=0.02), str(field_cache))


def test_every_group_is_planned_on_its_own_walls_and_kept(whole, one_channel):
    out_dir, store_dir, rc, out, err, _ = whole
    assert rc == 0, out + err
    doc = json.loads((out_dir / "blisk.json").read_text())
    assert doc["complete"] and doc["geometry_id"] == one_channel.geometry_id and doc["blade_count"] == 60
    groups = {g["representative"]: g for g in doc["groups"]}
    assert sorted(groups) == [0, CHANNEL] and groups[CHANNEL]["members"] == [CHANNEL]
    assert sorted(groups[0]["members"] + [CHANNEL]) == list(range(60))
    store = open_store(store_dir)
    for rep, g in groups.items():
        assert g["status"] == "planned" and g["error_code"] == "SUCCESS" and len(g["plan_ids"]) == 1
        low, exact = g["clearance_lower_bound_mm"], g["clearance_exact_mm"]
        assert min(low.values()) >= 0.08 - 1e-9                   # certified at the machining margin
        assert all(exact[s] >= low[s] - 1e-6 for s in low)        # one truth
        rec = store.get(g["plan_ids"][0])                          # kept with its certified cycle
        assert rec is not None and rec.channel == rep and stored_to_plan(rec).cycle.certified
        assert (out_dir / g["exports"][0] / "plan.json").is_file() and (out_dir / g["exports"][0] / "cycle.csv").is_file()
    assert groups[0]["plan_ids"] != groups[CHANNEL]["plan_ids"]
    # progress per group as it finished: which channels, where, how long
    lines = [line for line in err.splitlines() if "group " in line and "planned on node" in line]
    assert len(lines) == 2 and any(f"channel {CHANNEL}: planned" in line for line in lines), err
    assert any("channels 0-42, 44-59 (group of channel 0): planned" in line for line in lines), err
    assert all("(pid " in line and " s; plans " in line for line in lines), err
    # the program is in the store too: every channel once
    seq = store.get_sequence(doc["program_id"])
    assert seq is not None and sorted(k for _, k in seq.steps) == list(range(60))


def test_channel_43_is_bit_for_bit_the_plan_of_edm_plan_plan_channel_43(whole, one_channel, field_cache, tmp_path):
    out_dir, store_dir, rc, *_ = whole
    assert rc == 0
    doc = json.loads((out_dir / "blisk.json").read_text())
    plan_id = next(g["plan_ids"][0] for g in doc["groups"] if g["representative"] == CHANNEL)
    rc, out, err = run(["plan", "--geometry", one_channel.source, "--channel", str(CHANNEL), "--out",
                        str(tmp_path / "plan"), "--cache-dir", field_cache, "--store", str(tmp_path / "store"),
                        "--progress", "none"] + DESIGN_ARGS)
    assert rc == 0, err
    single = open_store(tmp_path / "store").get(plan_id)
    assert single is not None, f"edm-plan plan --channel {CHANNEL} made another plan id"
    ours = open_store(store_dir).get(plan_id)
    for name in ("poses", "samples"):
        a, b = getattr(ours, name), getattr(single, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name


def test_export_all_channels_writes_the_whole_blisk_with_each_channels_own_plan(whole, tmp_path):
    from edm_planner.cli import _export_job
    from edm_planner.machining.program import program_runs

    out_dir, _, rc, *_ = whole
    assert rc == 0
    doc = json.loads((out_dir / "blisk.json").read_text())
    own = next(g["plan_ids"][0] for g in doc["groups"] if g["representative"] == CHANNEL)
    nominal = next(g["plan_ids"][0] for g in doc["groups"] if g["representative"] == 0)
    job = _export_job(str(out_dir), "none", True)
    assert job["kind"] == "blisk_program" and job["name"] == doc["program_id"]
    assert sorted(k for _, k in job["steps"]) == list(range(60))           # every channel once per electrode
    assert dict((k, p) for p, k in job["steps"]) == {k: own if k == CHANNEL else nominal for k in range(60)}
    runs = program_runs(job["steps"], job["plans"], job["pitch"])
    assert [r.plan.plan_id for r in runs] == [nominal, own] and runs[1].channels == [CHANNEL]
    feed = [leg for leg in runs[1].legs if leg.phase == "feed"][0]
    assert np.array_equal(feed.samples, job["plans"][own].samples)          # channel 43's own feed, in channel 43
    rc, out, err = run(["export", "--all-channels", str(out_dir), "--out", str(tmp_path / "nc"), "--format", "nc"])
    assert rc == 0, err
    nc = (tmp_path / "nc" / f"{doc['program_id']}.nc").read_text()
    assert f"(PLAN {own.upper()} CHANNELS {CHANNEL})" in nc
    assert f"(PLAN {nominal.upper()} CHANNELS 0,1,2," in nc and "(BLISK_PROGRAM 2 ELECTRODES)" in nc


def test_a_rerun_plans_nothing_and_gives_the_same_program(whole, one_channel, field_cache, tmp_path):
    out_dir, store_dir, rc, *_ = whole
    assert rc == 0
    first = json.loads((out_dir / "blisk.json").read_text())
    created = {r["plan_id"]: r["created"] for r in open_store(store_dir).list()}
    t0 = time.perf_counter()
    rc, out, err = run(blisk_argv(one_channel.source, tmp_path / "again", store_dir, field_cache))
    assert rc == 0, err
    again = json.loads((tmp_path / "again" / "blisk.json").read_text())
    assert [g["status"] for g in again["groups"]] == ["stored", "stored"] and "local worker" not in err
    assert again["program_id"] == first["program_id"] and again["steps"] == first["steps"]
    assert {r["plan_id"]: r["created"] for r in open_store(store_dir).list()} == created     # nothing written anew
    assert time.perf_counter() - t0 < 60.0


def test_a_failing_group_is_named_and_the_other_is_kept(whole, one_channel, field_cache, tmp_path):
    """Channel 43's export cannot be written (a file where its directory goes): that group fails with
    FILE_ERROR, named; the other group is written and kept; no program; export refuses; after the cause is gone a
    rerun completes from the store."""
    from edm_planner.errors import ErrorCode

    _, store_dir, rc, *_ = whole
    assert rc == 0
    out_dir = tmp_path / "blocked"
    out_dir.mkdir()
    (out_dir / f"channel_{CHANNEL}").write_text("in the way\n")
    rc, out, err = run(blisk_argv(one_channel.source, out_dir, store_dir, field_cache))
    assert rc == int(ErrorCode.FILE_ERROR), out + err
    assert f"1 of 2 channel group(s) failed (channel {CHANNEL}: FILE_ERROR" in err, err
    assert "no whole-blisk program is written with a channel missing" in err
    doc = json.loads((out_dir / "blisk.json").read_text())
    groups = {g["representative"]: g for g in doc["groups"]}
    assert not doc["complete"] and doc["steps"] is None and doc["program_id"] == ""
    assert groups[CHANNEL]["status"] == "failed" and groups[CHANNEL]["error_code"] == "FILE_ERROR"
    assert groups[0]["status"] == "stored" and (out_dir / groups[0]["exports"][0] / "plan.json").is_file()
    rc, out, err = run(["export", "--all-channels", str(out_dir), "--out", str(tmp_path / "nc")])
    assert rc == int(ErrorCode.INFEASIBLE) and "not complete" in err and f"channels [{CHANNEL}]" in err, err
    assert not (tmp_path / "nc").exists()
    (out_dir / f"channel_{CHANNEL}").unlink()
    rc, out, err = run(blisk_argv(one_channel.source, out_dir, store_dir, field_cache))
    assert rc == 0, err
    assert json.loads((out_dir / "blisk.json").read_text())["complete"]


def test_bad_requests_are_refused_before_planning(one_channel, tmp_path, field_cache):
    from edm_planner.errors import ErrorCode

    base = ["plan", "--geometry", one_channel.source, "--out", str(tmp_path / "o"), "--store", "none",
            "--cache-dir", field_cache]
    rc, _, err = run(base)
    assert rc == int(ErrorCode.INVALID_REQUEST) and "--channel K or --all-channels" in err
    rc, _, err = run(base + ["--channel", "3", "--all-channels"])
    assert rc == int(ErrorCode.INVALID_REQUEST) and "--channel K or --all-channels" in err
    rc, _, err = run(base + ["--all-channels", "--size-electrode"])
    assert rc == int(ErrorCode.INVALID_REQUEST) and "--size-electrode" in err
    rc, _, err = run(base + ["--all-channels", "--workers", "0"])
    assert rc == int(ErrorCode.INVALID_REQUEST) and "--workers" in err
    rc, _, err = run(base + ["--all-channels", "--electrode", "middle", "--split", "front_rear"])
    assert rc == int(ErrorCode.UNKNOWN_ID) and "'middle'" in err and "front" in err
    assert not (tmp_path / "o").exists()
    assert channel_ranges([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"


# -- on a local two-node Ray cluster --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cluster():
    with two_node_cluster() as made:
        yield made


@pytest.mark.slow
def test_on_a_ray_cluster_each_group_is_a_ray_task_with_the_local_bits(cluster, whole, one_channel, field_cache):
    import ray

    c, _ = cluster
    _, store_dir, rc, *_ = whole
    assert rc == 0
    reports = []
    result = plan_blisk(one_channel, request_of(one_channel, field_cache), ray_address=c.address,
                        report=lambda g, done, total, message="": reports.append((g, done, total, message)))
    assert not result.failed, [g.message for g in result.failed]
    assert result.executor.startswith("the Ray cluster at") and "(2 CPUs)" in result.executor
    alive = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
    assert {g.node for g in result.groups} == alive                # one CPU per node, two groups: one on each
    assert [r[1] for r in reports if r[0] is not None] == [1, 2]  # each reported as it finished
    store = open_store(store_dir)
    for g in result.groups:
        want = store.get(g.plans[0].plan_id)                       # the local workers' plan of the same request
        assert want is not None, g.name
        for name in ("poses", "samples"):
            assert np.asarray(getattr(g.plans[0], name)).tobytes() == getattr(want, name).tobytes(), name
        assert g.plans[0].cycle.certified
    assert result.program_id == json.loads((whole[0] / "blisk.json").read_text())["program_id"]


@pytest.mark.slow
def test_on_a_ray_cluster_a_group_whose_worker_is_killed_is_run_again(cluster, whole, one_channel, field_cache):
    import threading

    _, nodes = cluster
    _, store_dir, rc, *_ = whole
    assert rc == 0
    got, failure = {}, []

    def plan():
        try:
            got["result"] = plan_blisk(one_channel, request_of(one_channel, field_cache), ray_address=cluster[0].address)
        except BaseException as exc:        # reported by the assertions below
            failure.append(exc)

    thread = threading.Thread(target=plan, daemon=True)
    thread.start()
    deadline = time.monotonic() + DEADLINE
    running = []
    while not running and thread.is_alive() and time.monotonic() < deadline:
        running = task_processes(nodes)
        time.sleep(0.01)
    assert running, "no group task was seen running"
    # killed as soon as it is seen, inside the task (a channel's plan, about a second): a kill after it had
    # finished would not test the re-run (the worker check below fails then)
    os.kill(running[0], signal.SIGKILL)
    thread.join(DEADLINE)
    assert not thread.is_alive() and not failure, failure
    result = got["result"]
    assert not result.failed, [g.message for g in result.failed]
    assert f"pid {running[0]}" not in [g.worker for g in result.groups]     # another worker ran it again
    store = open_store(store_dir)
    for g in result.groups:
        assert g.plans[0].poses.tobytes() == store.get(g.plans[0].plan_id).poses.tobytes()
