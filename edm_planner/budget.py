"""The clock of time budgets: this process's time, less what numba spent compiling its kernels.

A plan's or a set's time budget bounds the work. Compiling the kernels is a
one-time cost of a cold cache, such as a new machine, a new CPU target or a
new version of a kernel. If a budget counted it, the first run on a fresh
machine would time out where every later run succeeds, and a set designed
there would differ from one designed with a warm cache. Measured: on blisk72,
with the kernels compiling, the first plan of the one-electrode sizing ran
out of its 60 s. The sizing went on from a thinner electrode, which left
stock, and a front/rear set came out instead of the one electrode.

Only ``numba:compile`` events count: compilation proper, which numba
broadcasts (``numba.core.event``). Loading a cached kernel, about 0.08 s, is
not a compile event and still counts. The clock is per process. A
compilation in one thread is taken off the budgets of all the process's
threads, since numba compiles under one global lock.

Plain Python and numba; no rclpy. Units: s.
"""

import threading
import time

from numba.core import event


class _CompileTime(event.Listener):
    """Total seconds of the process's outermost ``numba:compile`` events (nested compiles counted once)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._depth = 0
        self._started = 0.0
        self.total = 0.0

    def on_start(self, event):
        with self._lock:
            if self._depth == 0:
                self._started = time.perf_counter()
            self._depth += 1

    def on_end(self, event):
        with self._lock:
            self._depth -= 1
            if self._depth == 0:
                self.total += time.perf_counter() - self._started

    def now(self):
        """Seconds compiled so far, the one under way included."""
        with self._lock:
            running = time.perf_counter() - self._started if self._depth else 0.0
            return self.total + running


_COMPILING = _CompileTime()
event.register("numba:compile", _COMPILING)


def budget_clock():
    """``time.perf_counter()`` less the seconds numba has spent compiling in this process [s]."""
    return time.perf_counter() - _COMPILING.now()


def compile_seconds():
    """Seconds numba has spent compiling in this process so far [s]."""
    return _COMPILING.now()
