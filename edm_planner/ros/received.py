"""What a node made of each geometry received on the latched ``geometry`` topic, and a wait for one on its way.

The geometry loader answers LoadGeometry once it has published the geometry; a node that a cell controller
calls right after that answer may not have received it yet (DDS delivers it a moment later). Both nodes that
serve requests by geometry id (the interference checker, the trajectory planner) wait for it here, up to a
deadline of their own (their parameter ``unknown_geometry_wait``), before they answer UNKNOWN_ID.
"""

import threading
from dataclasses import dataclass

from ..errors import EdmError, ErrorCode


@dataclass(frozen=True)
class Unusable:
    """What a node keeps for a geometry it received but cannot use: its requests are told why."""

    error: Exception


class ReceivedGeometries:
    """Items by geometry id (what the node built from each message), the latest, and :meth:`get` that waits.

    Parameters
    ----------
    lock : threading.Lock
        The node's lock that also guards its other state (the wait's condition is built on it).
    """

    def __init__(self, lock):
        self.items = {}
        self.latest = None
        self.waiting = 0                         # requests now waiting for a geometry not received yet
        self._arrived = threading.Condition(lock)

    def again(self, gid):
        """True, and ``gid`` the latest once more, if it was received before (loaded again after another)."""
        with self._arrived:
            if gid not in self.items:
                return False
            self.latest = gid
            return True

    def add(self, gid, item):
        """Keep ``item`` for ``gid``, now the latest; wakes the requests waiting for it."""
        with self._arrived:
            self.items[gid] = item
            self.latest = gid
            self._arrived.notify_all()

    def get(self, gid, timeout):
        """``(id, item)`` of ``gid`` ('' or None: the latest), waiting up to ``timeout`` s for it to arrive.

        The item is None when it did not arrive in time (the id is then the one asked for, or None).
        """
        with self._arrived:
            if (gid or self.latest) not in self.items:
                self.waiting += 1
                try:
                    self._arrived.wait_for(lambda: (gid or self.latest) in self.items, timeout=max(timeout, 0.0))
                finally:
                    self.waiting -= 1
            gid = gid or self.latest
            return gid, self.items.get(gid) if gid else None

    def require(self, gid, timeout):
        """:meth:`get`, raising UNKNOWN_ID when the geometry did not arrive within ``timeout`` s and
        INVALID_GEOMETRY when it arrived :class:`Unusable`."""
        found, item = self.get(gid, timeout)
        if item is None:
            what = f"unknown geometry id {gid!r}" if gid else "unknown geometry (none received yet)"
            raise EdmError(ErrorCode.UNKNOWN_ID, f"{what} (waited {timeout:g} s for it on the geometry topic); "
                                                 "load it with the geometry_loader first")
        if isinstance(item, Unusable):
            raise EdmError(ErrorCode.INVALID_GEOMETRY, f"geometry {found[:12]} not usable: {item.error}")
        return found, item
