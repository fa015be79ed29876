"""Plunge roughing of shrouded channels before EDM finishing (Chen & Dong, issue 7).

Functional core (numpy/scipy, no ROS): :func:`plan_roughing` with
:class:`RoughingOptions` returns a :class:`RoughingResult` (tool poses,
error statistics, an untimed X Y Z A C axis path). Modules, one concern each:

* ``positions`` -- eq. 10-13: blade gap, largest tool radius, grooving
  positions, expansion lines, triangular travel order;
* ``distance`` -- eq. 4-8: exact distance to a surface of revolution;
* ``hausdorff`` -- eq. 1-2, 9 and section 3.2: the pose optimisation, its
  trust-region polish and a brute-force check;
* ``stats`` -- eq. 14-15;
* ``path`` -- frames, machine axes, the plunge path;
* ``planner`` -- the entry point.
"""

from .options import RoughingOptions, RoughingOptionsError
from .planner import PAPER_MAE_REDUCTION_PERCENT, RoughingResult, plan_roughing, roughing_plan_id
from .stats import ErrorStats, error_stats, reduction_percent

__all__ = ["RoughingOptions", "RoughingOptionsError", "RoughingResult", "plan_roughing", "roughing_plan_id", "ErrorStats",
           "error_stats", "reduction_percent", "PAPER_MAE_REDUCTION_PERCENT"]
