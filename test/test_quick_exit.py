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


#: Ctrl-C arriving inside importlib, made certain: a trace function sends SIGINT at the third line of the first
#: ``_get_module_lock`` call (just after it took the global import lock), then another thread imports a module
INTERRUPTED_IMPORT = """
import os, signal, sys, threading, time
from edm_planner.quick_exit import interrupt_outside_imports

if sys.argv[1] == "ours":
    interrupt_outside_imports()
else:
    signal.signal(signal.SIGINT, signal.default_int_handler)     # Python's own
lines = []


def tracer(frame, event, arg):
    if frame.f_code.co_name != "_get_module_lock" or lines:
        return None

    def local(frame, event, arg):
        if event == "line" and len(lines) < 3:
            lines.append(frame.f_lineno)
            if len(lines) == 3:
                os.kill(os.getpid(), signal.SIGINT)
        return local
    return local


sys.settrace(tracer)
try:
    import email.mime.text
    time.sleep(30)                  # (the interrupt comes here, 10 ms after the import, or in it)
except KeyboardInterrupt:
    print("interrupted; imported:", "email.mime.text" in sys.modules, flush=True)
sys.settrace(None)
other = threading.Thread(target=__import__, args=("xml.dom.minidom",), daemon=True)
other.start()
other.join(10)
print("other thread's import", "stuck" if other.is_alive() else "done", flush=True)
"""


def test_ctrl_c_inside_an_import_is_raised_once_the_import_is_done_and_leaves_no_lock_held():
    """With Python's handler the KeyboardInterrupt left the import machinery locked: another thread's next import
    waited for ever (make demo's pictures thread, interrupted). The programs' handler raises it after the import."""
    def run(handler):
        done = subprocess.run([sys.executable, "-c", INTERRUPTED_IMPORT, handler], capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, done.stderr
        return done.stdout.splitlines()

    assert run("ours") == ["interrupted; imported: True", "other thread's import done"]
    assert run("python") == ["interrupted; imported: False", "other thread's import stuck"]
