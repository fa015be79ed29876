"""Triangle-exact clearance of an electrode mesh to the channel surfaces (python-fcl).

Point-based methods see the electrode only at its sample points; between
them a flat triangle of the electrode can pass closer to a convex wall (the
rounded trailing edge) than any vertex does. This module measures the exact
distance between the electrode's triangle mesh and each labelled surface mesh
with FCL's BVH distance query. The surface meshes are sampled from the exact
model with every vertex on it; their faceting error (largest deviation of a
triangle from the exact surface, measured at build) is exposed as
``faceting_bound`` so the result brackets the true clearance.

FCL's distance between open surfaces is unsigned and it reports no depth
for mesh pairs, so the sign comes from the exact model: an electrode whose
origin lies behind a wall without crossing it is wholly inside the material.
In collision the depth is the larger of the deepest electrode vertex behind
the wall (exact signed distance) and the deepest wall-mesh vertex inside the
electrode (trimesh signed distance), at least ``faceting_bound``.
"""

import logging

import fcl
import numpy as np
import trimesh

from . import SURFACES
from ..geometry.frames import rotation_about_x
from .exact_points import ExactChannelDistance, transform_points

_log = logging.getLogger(__name__)


def _bvh(mesh):
    model = fcl.BVHModel()
    model.beginModel(len(mesh.vertices), len(mesh.faces))
    model.addSubModel(np.ascontiguousarray(mesh.vertices, dtype=np.float64),
                      np.ascontiguousarray(mesh.faces, dtype=np.int32))
    model.endModel()
    return model


def _transform(pose):
    return fcl.Transform(np.ascontiguousarray(pose[:3, :3]), np.ascontiguousarray(pose[:3, 3]))


class MeshChannelChecker:
    """FCL distance between an electrode mesh and the four surfaces of a channel.

    Parameters
    ----------
    blisk : Blisk
    resolution : float
        Edge length of the surface meshes [mm].
    exact : ExactChannelDistance, optional
        Shared exact point distance (for penetration depths and the faceting bound).
    """

    def __init__(self, blisk, resolution=0.25, exact=None):
        self.blisk = blisk
        self.exact = exact or ExactChannelDistance(blisk)
        self.meshes = blisk.channel_meshes(channel=0, resolution=resolution)
        self._surfaces = {label: fcl.CollisionObject(_bvh(self.meshes[label]), fcl.Transform())
                          for label in SURFACES}
        self._electrodes = {}
        self.faceting_bound = self._measure_faceting()

    def _measure_faceting(self):
        """Largest distance of a triangle's centroid and edge midpoints from the exact surface [mm]."""
        worst = 0.0
        for col, label in enumerate(SURFACES):
            m = self.meshes[label]
            tri = m.triangles
            pts = np.vstack([tri.mean(axis=1), 0.5 * (tri[:, 0] + tri[:, 1]),
                             0.5 * (tri[:, 1] + tri[:, 2]), 0.5 * (tri[:, 2] + tri[:, 0])])
            rng = np.random.default_rng(0)
            pick = pts[rng.choice(len(pts), size=min(len(pts), 4000), replace=False)]
            worst = max(worst, float(np.abs(self.exact.clearances(pick)[:, col]).max()))
        _log.info("channel meshes: faceting bound %.2e mm", worst)
        return worst

    def _electrode(self, mesh):
        key = id(mesh)
        if key not in self._electrodes:
            self._electrodes[key] = (mesh, _bvh(mesh))
        return self._electrodes[key][1]

    def clearances(self, electrode_mesh, poses, channel=0, closest=False):
        """Signed clearance of the electrode mesh at each pose to each surface.

        Parameters
        ----------
        electrode_mesh : trimesh.Trimesh
            In the electrode frame [mm], closed.
        poses : (P, 4, 4) float
            Electrode frame -> W, in channel ``channel``.
        closest : bool
            Also return the nearest point pairs (in W).

        Returns
        -------
        distance : (P, 4) float
            [mm], order of ``SURFACES``; negative for penetration.
        pairs : (P, 4, 2, 3) float, only with ``closest``
            [electrode point, surface point] per pose and surface.
        """
        poses = np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        back = rotation_about_x(-channel * self.blisk.pitch)     # the surfaces are channel 0's
        forth = rotation_about_x(channel * self.blisk.pitch)
        model = self._electrode(electrode_mesh)
        request = fcl.DistanceRequest(enable_nearest_points=True)
        out = np.empty((len(poses), len(SURFACES)))
        pairs = np.full((len(poses), len(SURFACES), 2, 3), np.nan)
        for i, pose in enumerate(poses):
            local = back @ pose
            obj = fcl.CollisionObject(model, _transform(local))
            origin_side = self.exact.clearances(local[None, :3, 3])[0]
            vertex_depth = None
            for j, label in enumerate(SURFACES):
                result = fcl.DistanceResult()
                d = fcl.distance(obj, self._surfaces[label], request, result)
                if d <= 0 or origin_side[j] < 0:
                    if vertex_depth is None:
                        verts = transform_points(local[None], electrode_mesh.vertices)[0]
                        vertex_depth = self.exact.clearances(verts).min(axis=0)
                    d = -max(-float(vertex_depth[j]), self._wall_depth(electrode_mesh, local, label),
                             self.faceting_bound)
                out[i, j] = d
                if closest:
                    a, b = (np.asarray(p, dtype=np.float64) for p in result.nearest_points)
                    pairs[i, j, 0] = forth[:3, :3] @ a
                    pairs[i, j, 1] = forth[:3, :3] @ b
        return (out, pairs) if closest else out

    def _wall_depth(self, electrode_mesh, pose, label):
        """Deepest vertex of a wall mesh inside the electrode at ``pose`` [mm] (0 if none)."""
        inv = np.linalg.inv(pose)
        verts = self.meshes[label].vertices @ inv[:3, :3].T + inv[:3, 3]
        lo, hi = electrode_mesh.bounds
        near = verts[np.all((verts >= lo) & (verts <= hi), axis=1)]
        if not len(near):
            return 0.0
        depth = trimesh.proximity.signed_distance(electrode_mesh, near)     # positive inside
        return float(max(depth.max(), 0.0))
