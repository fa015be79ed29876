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


DIES_WHILE_STARTING = """
import os
import sys

if __name__ == "__mp_main__":          # a spawned worker imports the program first: this one dies there
    os._exit(3)

if __name__ == "__main__":
    from concurrent.futures.process import BrokenProcessPool
    from edm_planner.machining.executors import LocalExecutor

    pool = LocalExecutor(1, print, (bytes(8 << 20),))      # start-up data far beyond a pipe's buffer
    setup_file = pool.setup_path
    try:
        pool.submit(len, "x").result(timeout=600)
    except BrokenProcessPool:
        print("the pool failed")
    pool.shutdown(wait=False)
    print("setup file left:", os.path.exists(setup_file))
"""


def test_a_worker_that_dies_while_it_starts_fails_the_pool_instead_of_hanging_it(tmp_path):
    """CPython writes a spawned worker's start-up data into its pipe as the worker reads it: with the geometry
    in it (megabytes), a worker that died first (here: while it imports the program, as one without a
    __main__ guard does) left the pool in that write for ever. LocalExecutor sends it through a file."""
    import subprocess
    import sys

    program = tmp_path / "program.py"
    program.write_text(DIES_WHILE_STARTING)
    done = subprocess.run([sys.executable, str(program)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.stdout.splitlines() == ["the pool failed", "setup file left: False"], done.stdout + done.stderr
