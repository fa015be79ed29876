"""Deprecated module: the plan store moved to :mod:`edm_planner.records.store` (a cycle as a record:
:mod:`edm_planner.records.cycle_record`) (issue 27). Its names still import from here, with a
DeprecationWarning, until release 0.3.0 (:mod:`edm_planner.deprecation`)."""

from .. import deprecation


def __getattr__(name):
    # a deprecated alias only: these imports run when an old name is asked for (.importlinter allows them)
    from ..records import cycle_record, store
    return deprecation.moved_name(__name__, name, store, cycle_record)
