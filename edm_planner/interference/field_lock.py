"""One build of a fast field per machine: an exclusive lock of its cache file while it is built.

Processes that need the same field at once (the planner and the checker
starting together, the set designer's workers) wait for the one building it
and then load what it wrote (:class:`.fast.FastChannelField`).
"""

import contextlib
import fcntl
import logging
import os

_log = logging.getLogger(__name__)


@contextlib.contextmanager
def build_lock(path):
    """Exclusive lock of a field's cache file while it is built (``<cache>.lock``, flock); none without a cache.

    The lock is the kernel's (released when its holder exits, also by kill -9),
    so a crashed builder never blocks the next one. Where the lock file cannot
    be made (a read-only cache directory) the field is built unlocked.

    Parameters
    ----------
    path : pathlib.Path or None
        The cache file the field will be written to.
    """
    if path is None:
        yield
        return
    lock = path.with_name(path.name + ".lock")
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        _log.warning("fast field: no build lock %s (%s); building without it", lock, exc)
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            _log.info("fast field: another process is building %s; waiting for it", path.name)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)                     # closing releases the lock
