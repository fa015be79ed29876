"""A cancelled set design leaves no worker process: not even one that a concurrent ``submit`` was spawning.

CI caught this on 2026-11-28: the design's starter thread (``SetDesigner._start_workers``) was spawning a
worker when the action was cancelled; ``terminate_pool`` had copied the pool's processes before the spawn
ended, and the new worker outlived the cancel. CI then caught this test itself failing (2026-11-28, then
3 of 25 runs on a loaded machine): the pool's manager thread had reaped a terminated worker but not yet
recorded its exit, so the worker still looked alive; ``terminate_pool`` now waits for that thread too.
"""

import concurrent.futures
import multiprocessing
import threading
import time

from edm_planner.machining.set_progress import terminate_pool

#: larger than a pipe's buffer: spawning a worker holds its ``submit`` (and the pool's shutdown lock) until the
#: worker has started and read it, as the set designer's geometry and field do
START_DATA = bytes(32 << 20)


def _start_and_never_finish(data):
    """A worker's start-up that does not end: the worker lives until it is terminated."""
    threading.Event().wait()


def test_terminate_pool_stops_a_worker_being_spawned_by_another_thread():
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn"),
                                                  initializer=_start_and_never_finish, initargs=(START_DATA,))
    refused = []
    before = set(multiprocessing.active_children())      # another test's processes are not this test's business

    def submit():               # as the starter thread does: one task per worker, each spawning one
        try:
            for _ in range(2):
                pool.submit(abs, 1)
        except RuntimeError as exc:     # the pool was shut down meanwhile
            refused.append(exc)

    starter = threading.Thread(target=submit, name="starter")
    try:
        starter.start()
        # terminate while a worker is being spawned: its submit then holds the pool's shutdown lock
        deadline = time.monotonic() + 120
        while not pool._shutdown_lock.locked():
            assert starter.is_alive(), "the starter ended before a spawn was seen (the test saw no race)"
            assert time.monotonic() < deadline, "no worker spawn started within 120 s"
            time.sleep(0.0005)
        table = pool._processes
        terminate_pool(pool)
        # on return, not later: every worker has exited and its exit is recorded
        assert table and all(p.exitcode is not None for p in table.values()), f"still running: {table}"
        starter.join(120)
        assert not starter.is_alive(), "the starter thread hangs after terminate_pool"
        alive = [p for p in multiprocessing.active_children() if p not in before]
        assert not alive, f"a worker spawned during terminate_pool outlived it: {alive}"
    finally:
        for process in set(multiprocessing.active_children()) - before:    # a failed run must not leave them
            process.kill()
            process.join(10)
