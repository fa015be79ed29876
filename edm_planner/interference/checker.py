"""The interference checker's core: one geometry, its electrodes, every method.

Methods (mirrored by CheckInterference.srv's METHOD_* constants):

* EXACT -- exact signed distances of the electrode's vertices to the model
  surfaces. With a fast field available only the vertices that can attain the
  minimum (field value within its error bounds of the smallest exact value
  found) are evaluated exactly, by the field's numba solvers, which gives the
  same minimum at a fraction of the cost.
* FAST -- the distance field; a pose counts as colliding whenever its
  clearance is below the threshold plus the field's error bound, so no pose
  is accepted as clear on the fast method alone inside its error band.
* PAPER_CRITERIA -- Huang eq. 3 (torus test) and the neighbour-angle test:
  feasibility flags only (clearances NaN).
* MESH -- triangle-exact clearance of the electrode mesh (python-fcl).
"""

import copy
import logging
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..errors import EdmError, ErrorCode
from .criteria import PaperCriteria
from .exact_points import ExactChannelDistance, pose_clearances
from .fast import FastChannelField
from .mesh_exact import MeshChannelChecker
from .segment import certify_segment, screw_motion

_log = logging.getLogger(__name__)


class Method(IntEnum):
    """Clearance methods (CheckInterference.srv METHOD_*)."""

    EXACT = 0
    FAST = 1
    PAPER_CRITERIA = 2
    MESH = 3


class ClearanceKind(IntEnum):
    """What a method's clearances are (CheckInterference.srv CLEARANCE_*)."""

    EXACT = 0                   #: exact signed distance of the electrode's vertices
    WITHIN_ERROR_BOUND = 1      #: a fast value; the exact one lies within +- the error bound
    NONE = 2                    #: no clearances, feasibility flags only

    @classmethod
    def of(cls, method):
        return {Method.EXACT: cls.EXACT, Method.FAST: cls.WITHIN_ERROR_BOUND,
                Method.MESH: cls.WITHIN_ERROR_BOUND, Method.PAPER_CRITERIA: cls.NONE}[Method(method)]

    def describe(self, error_bound):
        """How a figure of this kind reads, e.g. 'fast, exact within +-3.5 um'."""
        if self == ClearanceKind.EXACT:
            return "exact"
        if self == ClearanceKind.NONE:
            return "no clearances, feasibility flags only"
        return f"fast, exact within +-{error_bound * 1e3:.1f} um"


@dataclass(frozen=True)
class CheckerOptions:
    """Options of a ChannelChecker."""

    #: most poses one request may hold
    max_poses: int = 20000
    #: fast field spacing [mm]
    fast_spacing: float = 0.1
    #: directory for cached fast fields (None: no cache)
    cache_dir: str = None
    #: edge length of the surface meshes of the MESH method [mm]
    mesh_resolution: float = 0.25
    #: Huang's Delta1 [mm] and Delta2 [rad] for PAPER_CRITERIA
    paper_delta1: float = 0.0
    paper_delta2: float = 0.0


@dataclass
class CheckResult:
    """Clearances of a batch of poses (CheckInterference response)."""

    clearances: np.ndarray            # (P, 4) mm, order of SURFACES (NaN for paper criteria)
    colliding: np.ndarray             # (P,) bool
    error_bound: float                # mm
    kind: ClearanceKind               # what the clearances are
    closest: np.ndarray = None        # (P, 4, 2, 3) [electrode point, surface point] in W
    segments: list = field(default_factory=list)

    @property
    def minimum(self):
        return np.min(self.clearances, axis=1)


class ChannelChecker:
    """Clearance queries for one loaded geometry (any channel, any of its electrodes).

    Parameters
    ----------
    blisk : Blisk
    electrodes : dict
        electrode id -> (mesh in its frame, final pose (4, 4) in channel 0).
    geometry_id : str
    options : CheckerOptions
    """

    def __init__(self, blisk, electrodes, geometry_id="", options=None):
        self.blisk = blisk
        self.electrodes = dict(electrodes)
        self.geometry_id = geometry_id
        self.options = options or CheckerOptions()
        self.exact = ExactChannelDistance(blisk)
        self._fast = None
        self._mesh = None
        self._paper = None

    # -- lazily built methods ------------------------------------------------
    @property
    def fast(self):
        if self._fast is None:
            self._fast = FastChannelField(self.blisk, spacing=self.options.fast_spacing,
                                          cache_dir=self.options.cache_dir, cache_key=self.geometry_id or None)
        return self._fast

    @property
    def mesh(self):
        if self._mesh is None:
            self._mesh = MeshChannelChecker(self.blisk, resolution=self.options.mesh_resolution, exact=self.exact)
        return self._mesh

    @property
    def paper(self):
        if self._paper is None:
            self._paper = PaperCriteria(self.blisk, delta1=self.options.paper_delta1,
                                        delta2=self.options.paper_delta2)
        return self._paper

    def with_electrodes(self, electrodes):
        """The same geometry and methods (their models shared, built once) with other electrodes.

        Parameters
        ----------
        electrodes : dict
            electrode id -> (mesh in its frame, final pose (4, 4) in channel 0).
        """
        other = copy.copy(self)
        other.electrodes = dict(electrodes)
        other._fast = self.fast            # built (or loaded) once, shared
        return other

    # -- validation ----------------------------------------------------------
    def electrode(self, electrode_id):
        if not electrode_id:
            electrode_id = next(iter(self.electrodes))
        if electrode_id not in self.electrodes:
            raise EdmError(ErrorCode.UNKNOWN_ID,
                           f"unknown electrode id {electrode_id!r}; known: {sorted(self.electrodes)}")
        return self.electrodes[electrode_id]

    def validate(self, poses, channel):
        poses = np.asanyarray(poses, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
            raise EdmError(ErrorCode.INVALID_REQUEST, "no poses given (expected a list of electrode poses)")
        if len(poses) > self.options.max_poses:
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"{len(poses)} poses in one request; at most {self.options.max_poses}")
        if not np.isfinite(poses).all():
            bad = int(np.where(~np.isfinite(poses).all(axis=(1, 2)))[0][0])
            raise EdmError(ErrorCode.INVALID_REQUEST, f"pose {bad} contains NaN or infinite values")
        ortho = np.abs(np.einsum("pji,pjk->pik", poses[:, :3, :3], poses[:, :3, :3]) - np.eye(3)).max(axis=(1, 2))
        if (ortho > 1e-6).any():
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"pose {int(np.argmax(ortho > 1e-6))} has no proper rotation (non-unit quaternion?)")
        if not 0 <= channel < self.blisk.blade_count:
            raise EdmError(ErrorCode.INVALID_REQUEST,
                           f"channel {channel} does not exist: the blisk has {self.blisk.blade_count} channels")
        return poses

    # -- queries ---------------------------------------------------------------
    def lower_bound(self, poses, points, channel, method, mesh=None):
        """(P,) lower bound of each pose's clearance (min over surfaces) by a method."""
        if method == Method.FAST:
            return self.fast.pose_clearances(poses, points, channel)[0].min(axis=1) - self.fast.error_bound
        if method == Method.MESH:
            return self.mesh.clearances(mesh, poses, channel).min(axis=1) - self.mesh.faceting_bound
        return self.exact_pose_clearances(poses, points, channel)[0].min(axis=1)

    def exact_pose_clearances(self, poses, points, channel):
        """Exact per-surface minima over the points and the points attaining them.

        With a fast field: its numba branch and bound, which solves exactly
        (numba solvers) only the points whose field value lies within the
        field's error bounds of the smallest exact value found. Without one:
        ``ExactChannelDistance`` on every point.
        """
        if self._fast is None:
            return pose_clearances(self.exact.clearances, poses, points, channel)
        minimum, argmin, _ = self._fast.exact_pose_clearances(poses, points, channel)
        return minimum, argmin

    def closest_pairs(self, poses, points, argmin, channel):
        """(P, 4, 2, 3) [electrode point, surface point] in W for the points attaining the minima."""
        P = len(poses)
        R, t = poses[:, :3, :3], poses[:, :3, 3]
        pts = np.einsum("pij,pkj->pki", R, points[argmin]) + t[:, None]        # (P, 4, 3)
        _, feet = self.exact.clearances(pts.reshape(-1, 3), channel, closest=True)
        feet = feet.reshape(P, 4, 4, 3)[:, np.arange(4), np.arange(4)]
        if self._fast is not None:
            # the blade feet from the numba solver that gave the distances (ExactChannelDistance can stop short)
            _, blade = self._fast.exact_blade_feet(pts[:, :2].reshape(-1, 3), channel)
            feet[:, :2] = blade.reshape(P, 2, 2, 3)[:, np.arange(2), np.arange(2)]
        return np.stack([pts, feet], axis=2)

    def check(self, poses, channel=0, electrode_id="", method=Method.EXACT, threshold=0.0,
              closest=False, segments=False):
        """Clearances of electrode poses in channel k.

        Parameters
        ----------
        poses : (P, 4, 4) float
            Electrode frame -> W [mm].
        method : Method
        threshold : float
            Clearance below which a pose counts as colliding [mm].
        closest : bool
            Closest point pairs (not for PAPER_CRITERIA).
        segments : bool
            Certify the motion between consecutive poses.

        Returns
        -------
        CheckResult
        """
        method = Method(method)
        poses = self.validate(poses, channel)
        mesh, _ = self.electrode(electrode_id)
        points = np.asarray(mesh.vertices)
        pairs = None
        if method == Method.PAPER_CRITERIA:
            feasible, = per_distinct_pose(poses, lambda p: (self.paper.pose_feasible(p, points, channel=channel),))
            clear = np.full((len(poses), 4), np.nan)
            colliding = ~feasible.all(axis=1)
            bound = 0.0
        elif method == Method.MESH:
            if closest:
                clear, pairs = per_distinct_pose(poses, lambda p: self.mesh.clearances(mesh, p, channel, closest=True))
            else:
                clear, = per_distinct_pose(poses, lambda p: (self.mesh.clearances(mesh, p, channel),))
            bound = self.mesh.faceting_bound
            colliding = clear.min(axis=1) < threshold + bound
        else:
            minima = self.fast.pose_clearances if method == Method.FAST else self.exact_pose_clearances
            bound = self.fast.error_bound if method == Method.FAST else 0.0

            def evaluate(p):                     # the closest pairs too, once per distinct pose
                clear, arg = minima(p, points, channel)
                return (clear, self.closest_pairs(p, points, arg, channel)) if closest else (clear,)

            clear, *rest = per_distinct_pose(poses, evaluate)
            pairs = rest[0] if closest else None
            colliding = clear.min(axis=1) < threshold + bound
        result = CheckResult(clear, colliding, float(bound), ClearanceKind.of(method), pairs)
        if segments and method != Method.PAPER_CRITERIA:
            ends = clear.min(axis=1) - bound
            for i in range(len(poses) - 1):
                pose_at, lip = screw_motion(poses[i], poses[i + 1], points)
                result.segments.append(certify_segment(
                    lambda p: self.lower_bound(p, points, channel, method, mesh), pose_at, lip, threshold,
                    c0=ends[i], c1=ends[i + 1]))
        return result


def per_distinct_pose(poses, evaluate):
    """``evaluate(poses)`` (a tuple of per-pose arrays) run once per distinct pose, then given to every pose.

    A cycle's return leg retraces its feed leg, so about half of a whole cycle's poses repeat: each pose's
    values depend on that pose alone, so they are computed once. Poses are the same when their matrices
    are the same bytes (0.0 and -0.0 differ), so every answer is bit for bit the one of the pose itself; the
    distinct poses keep the order they first appear in (neighbouring poses of a path share cells in cache).
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    n = len(poses)
    if n < 2:
        return evaluate(poses)
    _, first, inverse = np.unique(poses.reshape(n, -1).view(np.uint64), axis=0, return_index=True,
                                  return_inverse=True)
    if len(first) == n:
        return evaluate(poses)
    order = np.argsort(first)                        # the distinct poses, in the order they first appear
    rank = np.empty(len(first), dtype=np.int64)
    rank[order] = np.arange(len(first))
    rows = rank[inverse.ravel()]
    return tuple(np.asarray(values)[rows] for values in evaluate(poses[first[order]]))
