"""Imported first by the nodes' fork server (:mod:`.bringup`): the server ends without Python's final teardown.

The server holds the nodes' modules (rclpy, numba, SciPy, trimesh and the core). When the program that started it
ends, it is told so and exits, and Python's teardown of those modules took it about 1 s (AMD Zen 3), during
which it still held the program's stdout and stderr: a caller reading the program's output to its end (a pipe,
``subprocess.run`` with ``capture_output``, the speed suite's demo figures) waited for it. Registered here, before
any module the server imports registers its own, the handler runs after all of theirs (``atexit`` runs the
last registered first), flushes the streams and leaves with ``os._exit``. The nodes it forks never run it: a
forked child of the server ends with ``os._exit`` after its target, without ``atexit``.
"""

import atexit
import os

from ...quick_exit import flush_standard_streams


def _leave():
    flush_standard_streams()
    os._exit(0)


atexit.register(_leave)
