"""Deprecated module: moved to :mod:`edm_planner.cnc.config` (issue 27). Its names still import from here, with a
DeprecationWarning, until release 0.3.0 (:mod:`edm_planner.deprecation`)."""

from .. import deprecation


def __getattr__(name):
    # a deprecated alias only: this import runs when an old name is asked for
    from ..cnc import config
    return deprecation.moved_name(__name__, name, config)
