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
threads, since numba compiles under one global lock, once it has ended
(another thread's clock runs on while it compiles, then steps back).

Plain Python and numba; no rclpy. Units: s.
"""

import time

from numba.core import event

# numba's own accumulating timer of the outermost events; compile events run one at a time under numba's
# global compiler lock, so it needs no lock of ours
_COMPILING = event.TimingListener()
event.register("numba:compile", _COMPILING)


def compile_seconds():
    """Seconds numba has spent compiling in this process so far, up to the last compile that ended [s]."""
    return _COMPILING.duration if _COMPILING.done else 0.0


def budget_clock():
    """``time.perf_counter()`` less the seconds numba has spent compiling in this process [s]."""
    return time.perf_counter() - compile_seconds()
