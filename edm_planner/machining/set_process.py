"""Deprecated module: the EDM process of a designed set moved to :mod:`edm_planner.process.set_process`
(issue 27: ``machining`` lies below ``process`` and imports nothing of it). Its names still import from here,
with a DeprecationWarning, until release 0.3.0 (:mod:`edm_planner.deprecation`)."""

from .. import deprecation


def __getattr__(name):
    # a deprecated alias only: this import runs when an old name is asked for
    from ..process import set_process
    return deprecation.moved_name(__name__, name, set_process)
