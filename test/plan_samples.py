"""Plans made by hand for the export tests: no search, only what ``write_plan`` reads."""

import numpy as np
import trimesh

from edm_planner.errors import ErrorCode
from edm_planner.planning.plan import AXIS_NAMES, Plan, PlanMetrics, PlanOptions


def failed_box_plan(geometry, channel, plan_id):
    """A failed plan of a 4 x 2 x 10 mm box electrode for ``channel`` (``write_plan`` writes its workpiece too)."""
    return Plan(plan_id=plan_id, error_code=ErrorCode.INFEASIBLE, message="no path", geometry_id=geometry.geometry_id,
                channel=channel, electrode_id="box", electrode_mesh=trimesh.creation.box((4.0, 2.0, 10.0)),
                final_pose=np.eye(4), options=PlanOptions(), axis_names=AXIS_NAMES[5], samples=np.zeros((0, 5)),
                poses=np.zeros((0, 4, 4)), nodes=np.zeros((0, 5)), metrics=PlanMetrics())
