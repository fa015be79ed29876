"""Scale-out with Ray (issue 28, part 3) on a local multi-node cluster: two Ray nodes of one CPU each.

Real tasks of the default blisk (config/default_blisk.yaml): sizing steps of the rear piece of the front/rear
candidate (certified-plan attempts, what :meth:`SetDesigner.size_piece` is made of) and shares of a removal
proof, handed out by the set designer's Ray executor (:mod:`edm_planner.machining.executors`). The tasks spread
over the nodes, their results are bit for bit the serial ones computed in this process, progress records come
back through the Ray queue, and a task whose worker process is killed is run again and loses nothing.

The cluster keeps to loopback, without a dashboard, its files and token in a temporary directory; it is
started once for the module and shut down at its end. Every wait has a deadline. Units: mm, rad, s.
"""

import os
import signal
import sys
import time
from dataclasses import replace

import numpy as np
import pytest

from edm_planner.machining import executors
from edm_planner.machining.electrode_set import Candidate, Piece, SetDesigner, _plan_in_worker, candidate_sets
from edm_planner.machining.removal import _stock_in_parts
from edm_planner.machining.swept_stock import Sweep, stock_at_points
from edm_planner.machining.wall_samples import wall_samples
from edm_planner.cnc.kinematics import axis_poses

from conftest import CONFIG
from ray_cluster import task_processes, two_node_cluster

#: seconds any one wait of this file may take before it fails
DEADLINE = 240.0


@pytest.fixture(scope="module")
def cluster():
    """A Ray cluster of two nodes of one CPU each on loopback, this process connected; (cluster, nodes)."""
    with two_node_cluster() as made:
        yield made


@pytest.fixture(scope="module")
def steps(cluster, default_geometry, default_field, field_cache):
    """(designer on the cluster, the rear piece's sizing steps [(piece, h, radial)], their serial plans)."""
    c, _ = cluster
    g = default_geometry
    records = []
    designer = SetDesigner(g, default_field, field_cache=(field_cache, g.geometry_id), workers=1,
                           ray_address=c.address, detail=records.append)
    designer.base = replace(designer.base, axial_range=designer.closed_channel_range())
    (_, pieces), = [(n, p) for n, p in candidate_sets(g.blisk, designer.base, designer.options) if n == "front/rear"]
    lab, eid, design = pieces[1]
    assert lab == "rear"
    # a certified start design and one that is not: both real outcomes of the sizing
    tasks = [(Piece(lab, eid, design), designer.h_max, 2.0 * designer.r_start),
             (Piece(lab, eid, design), 0.5 * designer.h_max, designer.r_start)]
    serial = []
    for piece, h, r in tasks:
        designer.t0 = time.perf_counter()
        local = Piece(piece.label, piece.electrode_id, piece.design)
        serial.append((local, designer._plan(local, h, r)[0]))
    assert serial[0][1] is not None and serial[1][1] is None, [p.tried for p, _ in serial]
    records.clear()
    return designer, tasks, serial


def assert_same_bits(got, want):
    (piece, plan), (piece0, plan0) = got, want
    assert piece.tried == piece0.tried
    assert (plan is None) == (plan0 is None)
    if plan is not None:
        for name in ("samples", "poses"):
            a, b = np.asarray(getattr(plan, name)), np.asarray(getattr(plan0, name))
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name
        assert plan.metrics.clearance_lower_bound == plan0.metrics.clearance_lower_bound
        assert plan.plan_id == plan0.plan_id


def results(futures):
    out = []
    for f in futures:
        out.append(f.result(timeout=DEADLINE))
    return out


@pytest.mark.slow
def test_sizing_steps_spread_over_the_nodes_and_give_the_serial_bits(cluster, steps):
    designer, tasks, serial = steps
    pool = designer._workers_pool()
    assert pool.kind == "ray" and designer.workers == 2        # the cluster's CPUs
    futures = [pool.submit(_plan_in_worker, *task) for task in tasks]
    for got, want in zip(results(futures), serial):
        assert_same_bits(got, want)
    # one CPU per node and two tasks at once: one on each node
    placed = [f.node_id for f in futures]
    assert len(set(placed)) == 2, placed
    alive = {n["NodeID"] for n in __import__("ray").nodes() if n["Alive"]}
    assert set(placed) == alive and sum(pool.where.values()) == 2
    # the workers' progress (each step's start, with its values) came back through the Ray queue
    deadline = time.monotonic() + 30
    records = executors.drain(designer._reports)
    while len(records) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
        records += executors.drain(designer._reports)
    assert {(r.piece, r.sizing_step) for r in records} >= {("rear", 1)}
    assert sorted(round(r.circumferential_reduction, 9) for r in records) == sorted(
        round(h, 9) for _, h, _ in tasks)


@pytest.mark.slow
def test_proof_shares_on_the_nodes_give_the_serial_stock(cluster, steps, default_geometry):
    designer, _, serial = steps
    plan = serial[0][1]
    mesh = plan.electrode_mesh
    poses = axis_poses(plan.final_pose, plan.axis_names, plan.samples[::4])
    sweeps = [Sweep(np.asarray(mesh.vertices), np.asarray(mesh.faces), poses, None)]
    walls = wall_samples(default_geometry.blisk, 1.0)
    points = np.vstack([w.points for w in walls.values()])
    points = points[np.linspace(0, len(points) - 1, 4000).astype(int)]
    gap = float(designer.base.discharge_gap)
    want, which = stock_at_points(points, sweeps, gap)
    pool = designer._workers_pool()
    stats = {}
    got, got_which = _stock_in_parts(points, sweeps, gap, pool, 2, stats)
    assert got.tobytes() == want.tobytes() and np.array_equal(got_which, which)
    assert stats


@pytest.mark.slow
def test_the_designer_sizes_a_candidates_pieces_on_the_nodes_and_reports_each_as_it_finishes(cluster, steps):
    designer, tasks, _ = steps
    records = []
    designer.detail = records.append
    piece = tasks[0][0]
    cand = Candidate("two rear pieces", [Piece(piece.label, piece.electrode_id, piece.design) for _ in range(2)])
    designer.t0 = time.perf_counter()
    designer._where, designer._name, designer._fraction = (0, 1, 0, 2), cand.name, 0.0
    assert designer._size_all(cand, 0, 1) == [True, True]
    a, b = cand.pieces
    assert a.tried == b.tried and a.plan.samples.tobytes() == b.plan.samples.tobytes()
    assert a.cycle.certified and b.cycle.certified
    finished = [r for r in records if "electrode sized (on node " in r.message]
    assert len(finished) == 2 and len({r.message.rsplit("node ", 1)[1] for r in finished}) == 2
    steps_seen = [r for r in records if r.sizing_step > 0 and r.piece == "rear"]
    assert {r.piece_index for r in steps_seen} == {0, 1}          # the workers' steps, as they ran
    fractions = [r.fraction for r in records]
    assert fractions == sorted(fractions) and len(fractions) > len(finished)


@pytest.mark.slow
def test_a_task_whose_worker_is_killed_is_run_again_and_loses_nothing(cluster, steps):
    _, nodes = cluster
    designer, tasks, serial = steps
    pool = designer._workers_pool()
    future = pool.submit(_plan_in_worker, *tasks[0])
    deadline = time.monotonic() + DEADLINE
    running = []
    while not running and not future.done() and time.monotonic() < deadline:
        running = task_processes(nodes)
        time.sleep(0.01)
    assert running, "the task was never seen running"
    # killed as soon as it is seen: the task (a certified-plan attempt) takes about 0.5 s of planning, and a
    # kill after it had finished would not test the re-run
    assert not future.done()
    os.kill(running[0], signal.SIGKILL)
    got = future.result(timeout=DEADLINE)
    assert future.pid != running[0]                   # another worker process ran it again
    assert_same_bits(got, serial[0])


def test_the_executor_kind_follows_the_address_and_ray_is_imported_only_for_ray():
    assert executors.kind_for("") == executors.DEFAULT_KIND == "local"
    assert executors.kind_for("127.0.0.1:6379") == "ray"
    assert executors.kind_for("", "ray") == executors.kind_for("local") == "ray"
    with pytest.raises(ValueError):
        executors.kind_for("", "dask")
    import subprocess
    code = ("import sys; import edm_planner.machining.electrode_set, edm_planner.machining.executors; "
            "print('ray' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "False", out.stderr


def test_edm_plan_hands_its_ray_address_to_the_set_designer(monkeypatch, tmp_path, field_cache):
    import io

    from edm_planner import cli
    from edm_planner.machining import electrode_set

    given = {}

    class Stop(Exception):
        pass

    def designer(*args, **kwargs):
        given.update(kwargs)
        raise Stop("stop before designing")

    monkeypatch.setattr(electrode_set, "SetDesigner", designer)
    err = io.StringIO()
    status = cli.main(["plan", "--geometry", str(CONFIG / "default_blisk.yaml"), "--channel", "0", "--out",
                       str(tmp_path / "set"), "--cache-dir", field_cache, "--ray-address", "127.0.0.1:6379",
                       "--progress", "none", "--store", "none"], out=io.StringIO(), err=err)
    assert status != 0 and "stop before designing" in err.getvalue()
    assert given["ray_address"] == "127.0.0.1:6379"
    assert cli._parser().parse_args(["plan", "--geometry", "g.yaml", "--channel", "0", "--out", "o"]).ray_address == ""
