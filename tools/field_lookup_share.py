"""How many of the field's lookups a pose's minimum needs near the final pose (issue 29; docs/performance.md).

    .venv/bin/python tools/field_lookup_share.py

The speed suite's case (the default blisk's first electrode, 200 poses near its final pose): the share of
electrode vertices whose clearance to a blade wall (either) or to the hub or shroud lies within a threshold of
the poses' median minimum for that surface, at the final pose, and how far the vertices move between the final
pose and the poses. A vertex farther than the threshold plus twice that motion and twice the field's error
bound from a surface's minimum cannot attain it at any of the poses (the distance is 1-Lipschitz), so its
lookup for that surface could be skipped: the share within the threshold bounds what such pruning saves.
Prints one JSON object.
"""

import json

import numpy as np

from edm_planner.bench.common import CONFIG, poses_near
from edm_planner.bench.speed import DEFAULT_CACHE
from edm_planner.geometry.loader import load_geometry
from edm_planner.interference.fast import FastChannelField

THRESHOLDS_MM = (0.2, 0.5, 1.0, 2.0)


def main():
    g = load_geometry(CONFIG / "default_blisk.yaml")
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=DEFAULT_CACHE, cache_key=g.geometry_id)
    e = g.electrodes[0]
    pts = np.asarray(e.mesh.vertices)
    poses = poses_near(e.final_pose, 200)
    minima = np.median(field.pose_clearances(poses, pts)[0], axis=0)           # per surface, over the poses
    at_final = field.posed_clearances(e.final_pose[None], pts)[0]               # (M, 4)
    placed = poses[:, :3, :3] @ pts.T + poses[:, :3, 3:4]                         # (P, 3, M)
    moved = np.linalg.norm(placed - (e.final_pose[:3, :3] @ pts.T + e.final_pose[:3, 3:4]), axis=1)
    out = {"vertices": len(pts), "poses": len(poses), "error_bound_mm": field.error_bound,
           "motion_mm": {"max": float(moved.max()), "median": float(np.median(moved))}, "shares": {}}
    for t in THRESHOLDS_MM:
        near = at_final - minima[None] <= t
        blade, hub_shroud = near[:, 0] | near[:, 1], near[:, 2] | near[:, 3]
        out["shares"][f"{t} mm"] = {"blade": round(float(blade.mean()), 3),
                                    "hub_or_shroud": round(float(hub_shroud.mean()), 3),
                                    "neither": round(float((~blade & ~hub_shroud).mean()), 3)}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
