"""``quick_exit.exit_now``: the process ends with the status, after what a normal exit does that matters."""

import subprocess
import sys

PROGRAM = """
import atexit, pathlib, sys, tempfile, threading, time
from edm_planner.quick_exit import exit_now

out = pathlib.Path(sys.argv[1])
kept = tempfile.TemporaryDirectory(dir=out)             # its finalizer removes it at exit
(pathlib.Path(kept.name) / "x").write_text("x")
print(kept.name)


def late():                                             # a non-daemon thread still working when main ends
    time.sleep(0.5)
    (out / "thread").write_text("done")


threading.Thread(target=late).start()
atexit.register(lambda: (out / "atexit").write_text("ran"))
sys.stdout.write("no newline, still buffered")          # a pipe: block-buffered, flushed by exit_now
exit_now(int(sys.argv[2]))
"""


def test_exit_now_joins_threads_runs_atexit_flushes_and_keeps_the_status(tmp_path):
    for status in (0, 3):
        run = tmp_path / str(status)
        run.mkdir()
        done = subprocess.run([sys.executable, "-c", PROGRAM, str(run), str(status)], capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == status, done.stderr
        temp, tail = done.stdout.splitlines()
        assert tail == "no newline, still buffered"
        assert (run / "thread").read_text() == "done" and (run / "atexit").read_text() == "ran"
        assert not (run / temp).exists(), "the temporary directory's finalizer did not run"


def test_exit_now_of_a_message_exits_as_systemexit_does():
    done = subprocess.run([sys.executable, "-c", "from edm_planner.quick_exit import exit_now; exit_now('bad input')"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and done.stderr.strip() == "bad input"


STUCK = """
import sys, threading
from edm_planner.quick_exit import exit_now


def waits_for_ever():                                   # a non-daemon thread whose call never returns
    threading.Event().wait()


threading.Thread(target=waits_for_ever, name="stuck-worker").start()
print("main done", flush=True)
exit_now(5, deadline=float(sys.argv[1]))
"""


def test_a_thread_that_never_ends_does_not_keep_the_program_its_stack_is_printed():
    done = subprocess.run([sys.executable, "-c", STUCK, "1.0"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 5, done.stderr
    assert done.stdout == "main done\n"
    assert "exit: not done after 1 s (threads still running: stuck-worker)" in done.stderr
    assert "in waits_for_ever" in done.stderr, done.stderr          # the stuck thread's own frame


STUCK_LOGGING = """
import logging, sys, threading
from edm_planner.quick_exit import exit_now


class Blocks(logging.Handler):                          # a handler whose output never drains
    def emit(self, record):
        threading.Event().wait()


logging.getLogger().addHandler(Blocks())
threading.Thread(target=logging.error, args=("never written",), name="logs-for-ever").start()
exit_now(5, deadline=float(sys.argv[1]))
"""


def test_a_report_stuck_behind_a_thread_holding_logging_still_ends_the_process():
    # the stuck thread holds the handler's lock, so the deadline's report blocks too: faulthandler ends it
    done = subprocess.run([sys.executable, "-c", STUCK_LOGGING, "1.0"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "Timeout (0:00:06)!" in done.stderr and "in emit" in done.stderr, done.stderr
