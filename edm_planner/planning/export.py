"""Deprecated module: the plan export moved to :mod:`edm_planner.records.plan_export` and the re-check of an
export to :mod:`edm_planner.records.plan_check`; ``axes_to_poses`` is in
:mod:`edm_planner.cnc.kinematics`, the tolerances in :mod:`edm_planner.constants` (issue 27). Its names
still import from here, with a DeprecationWarning, until release 0.3.0 (:mod:`edm_planner.deprecation`)."""

from .. import deprecation


def __getattr__(name):
    # a deprecated alias only: these imports run when an old name is asked for (.importlinter allows them)
    from .. import constants
    from ..cnc import kinematics
    from ..records import plan_check, plan_export
    return deprecation.moved_name(__name__, name, kinematics, constants, plan_export, plan_check)
