"""Deprecated module: the exact re-check of poses is :mod:`edm_planner.interference.pose_check`, that of an
exported plan :mod:`edm_planner.records.plan_check` (issue 27). Its names still import from here, with a
DeprecationWarning, until release 0.3.0 (:mod:`edm_planner.deprecation`)."""

from .. import deprecation


def __getattr__(name):
    # a deprecated alias only: these imports run when an old name is asked for (.importlinter allows them)
    from ..records import plan_check
    from . import pose_check
    return deprecation.moved_name(__name__, name, pose_check, plan_check)
