"""What ``test_cpu_variants`` compares across compile targets: kernel outputs and a whole plan.

Run as a script (``python cpu_variant_values.py OUT.npz FIELD_CACHE``) it writes them for the numba
target its environment names (``NUMBA_CPU_NAME``, ``NUMBA_CPU_FEATURES``); imported, ``values`` gives
the same for this process's target.
"""

import pathlib
import sys

import numpy as np

CONFIG = pathlib.Path(__file__).resolve().parent.parent / "config"


def _poses(final_pose):
    """Poses near the final pose, pulled back out of the channel (off the blade grid) and turned about C."""
    from edm_planner.bench.common import poses_near

    near = poses_near(final_pose, 24, seed=3)
    out = near[:6].copy()
    out[:, 0, 3] += np.linspace(5.0, 40.0, 6)                      # on the way out: outside the grid
    turned = near[:6].copy()
    turned[:, :3, :3] = turned[:, :3, :3] @ np.array([[np.cos(0.05), -np.sin(0.05), 0], [np.sin(0.05), np.cos(0.05), 0],
                                                       [0, 0, 1]])
    return np.concatenate([near, out, turned])


def values(field_cache):
    from edm_planner.bench.common import rear_design
    from edm_planner.geometry.loader import load_geometry
    from edm_planner.interference.fast import FastChannelField
    from edm_planner.interference.wall_features import TriangleGrid
    from edm_planner.planning.plan import PlanOptions
    from edm_planner.planning.planner import plan_channel
    from edm_planner.planning.search import SearchOptions

    g = load_geometry(CONFIG / "default_blisk.yaml")
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=field_cache, cache_key=g.geometry_id)
    e = g.electrodes[0]
    pts = np.asarray(e.mesh.vertices)
    poses = _poses(e.final_pose)
    best, arg = field.pose_clearances(poses, pts)
    world = (pts[::7] @ poses[0, :3, :3].T + poses[0, :3, 3])
    grid = TriangleGrid.from_mesh(e.mesh.vertices, e.mesh.faces)
    # the child compiles every kernel for the other CPU inside this plan: the budget does not count that
    # (edm_planner.budget; once, on a loaded CI, it did and the default 60 s ran out)
    plan = plan_channel(g, 0, "rear", PlanOptions(search=SearchOptions(method="default", step=0.1,
                                                                         exit_side="downstream")),
                        field=field, design=rear_design(), exact_clearance=False)
    if len(plan.samples) == 0:
        raise RuntimeError(f"the plan failed: {plan.error_code.name}: {plan.message}")
    return {"pose_min": best, "pose_arg": arg,
            "pose_min_channel_3": field.pose_clearances(poses[::4], pts, channel=3)[0],
            "posed": field.posed_clearances(poses[::6], pts[::3], 0),
            "points": field.clearances(world),
            "features": field.wall_features.clearances(poses, grid, reach=0.4),
            "plan_samples": np.asarray(plan.samples), "plan_objfun1": np.array(plan.metrics.objfun1)}


if __name__ == "__main__":
    np.savez(sys.argv[1], **values(sys.argv[2]))
