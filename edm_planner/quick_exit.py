"""Leaving a program's process: on Ctrl-C, and without Python's final teardown (what ``edm-plan`` and ``make demo``
end with).

Ctrl-C (:func:`interrupt_outside_imports`): Python raises a SIGINT's KeyboardInterrupt in whatever the main thread
runs next, importlib's own code included; raised between its taking of the global import lock and the ``try`` that
releases it (``_get_module_lock``, or the weak-reference callback that garbage collection runs anywhere), it leaves
the lock held for good, and every other thread's next import waits for ever. Seen in ``make demo`` interrupted
while its pictures thread imported matplotlib: the thread never ended, and the exit's deadline ended the process
60 s later. The programs' handler raises KeyboardInterrupt only outside importlib's frames.

Exit:

A normal exit joins the non-daemon threads, runs the ``atexit`` handlers, then frees every module and object and
runs the native libraries' destructors. That last part does nothing a later process reads, and after the planner,
rclpy and matplotlib were loaded it takes 0.9 to 1.4 s (AMD Zen 3; 0.5 s of it numba's, 0.2 s rclpy's, 0.2 s
matplotlib's), longer than some of the commands' own steps. :func:`exit_now` does the first two parts as Python
does them, flushes the standard streams (:func:`flush_standard_streams`), and ends the process with
``os._exit``. Only for a program's own process (its ``__main__`` or console script): the library and the tests
call ``main()`` and get its status back.
No rclpy.
"""

import atexit
import faulthandler
import logging
import os
import signal
import sys
import threading

#: how long :func:`exit_now` lets the threads' joins and the ``atexit`` handlers take [s] before it prints every
#: thread's stack and leaves without them: a thread that never ends must not keep the program (and a caller
#: reading its output to the end) waiting for ever
EXIT_DEADLINE = 60.0

#: seconds after the deadline at which faulthandler's own thread (C, no Python lock) dumps every stack and ends
#: the process with status 1, should the report itself be stuck (a lock of logging held by a stuck thread)
BACKSTOP = 5.0
#: how the deadline's report starts (what a caller looks for in a program's output)
STUCK_REPORT = "exit: not done after"

#: how soon a signal that arrived during an import is raised again [s]
INTERRUPT_RETRY = 0.01

_log = logging.getLogger(__name__)


def interrupt_outside_imports(*signums):
    """Make each signal (default SIGINT) raise KeyboardInterrupt in the main thread, but never inside an import.

    The handler looks at the main thread's stack where the signal arrived: within importlib's frames it sends
    the signal again ``INTERRUPT_RETRY`` seconds later (until the import is done: a module's own code runs
    within them too), elsewhere it raises KeyboardInterrupt as Python's default handler does. Installs it
    also where the process started with the signal ignored (a background job of a non-interactive shell).
    """
    for signum in signums or (signal.SIGINT,):
        signal.signal(signum, _raise_outside_imports)


def _raise_outside_imports(signum, frame):
    if _in_import(frame):
        again = threading.Timer(INTERRUPT_RETRY, os.kill, args=(os.getpid(), signum))
        again.daemon = True
        again.start()
        return
    raise KeyboardInterrupt


def _in_import(frame):
    """Whether a frame of this stack is importlib's (the import system's own code, frozen in the interpreter)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def exit_now(status, deadline=EXIT_DEADLINE):
    """End the process with ``status`` (an int, or None for 0) after what a normal exit does that matters.

    In Python's own order: the non-daemon threads joined (``threading._shutdown``, which also runs the exit hooks
    of :mod:`concurrent.futures`' executors), the ``atexit`` handlers (logging's flush, :mod:`multiprocessing`'s
    children, the finalizers of temporary directories, Ray's shutdown), then stdout and stderr flushed. A failure
    of any of these falls back to the normal exit, which retries what is left. Whatever of it still runs after
    ``deadline`` seconds (a thread stuck in a call that never returns) is logged, every thread's stack dumped on
    stderr, and the process ends with ``status`` all the same; should that report itself get stuck,
    faulthandler ends the process ``BACKSTOP`` seconds later (status 1, the stacks on stderr).
    """
    code = 0 if status is None else status
    if not isinstance(code, int):          # SystemExit's convention: anything else is printed, status 1
        raise SystemExit(code)
    watchdog = threading.Timer(deadline, _leave_stuck, args=(code, deadline))
    watchdog.daemon = True                 # not among the threads the exit joins; it ends with the process
    watchdog.start()
    try:
        faulthandler.dump_traceback_later(deadline + BACKSTOP, exit=True)
    except (AttributeError, OSError, ValueError):          # no stderr to dump to: the watchdog alone
        pass
    try:
        threading._shutdown()
        atexit._run_exitfuncs()
    except BaseException:
        raise SystemExit(code)
    flush_standard_streams()
    os._exit(code)


def _leave_stuck(code, deadline):
    """The exit's deadline passed: name the threads still running (logged), dump every thread's stack on stderr,
    end the process with ``code``."""
    left = [t.name for t in threading.enumerate()
            if t is not threading.current_thread() and t is not threading.main_thread() and t.is_alive()]
    flush_standard_streams()
    _log.error("%s %g s (threads still running: %s); every thread's stack follows on stderr",
               STUCK_REPORT, deadline, ", ".join(left) or "none")
    try:
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    except (AttributeError, OSError, ValueError):          # no stderr left to write to: end all the same
        pass
    os._exit(code)


def flush_standard_streams():
    """Flush stdout and stderr, as Python's exit does; a missing or closed stream has nothing left to write."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
