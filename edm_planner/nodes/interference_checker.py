"""interference_checker node: clearances of electrode poses over DDS.

Builds its models from the geometry_loader's latched ``geometry`` topic
(every geometry it has seen, by id) and serves ``check_interference``
(edm_planner_msgs/CheckInterference). A request may re-design the electrodes
(ElectrodeDesign overrides, as PlanChannel's); each design is made once and
kept (the ``max_designs`` most recently used), sharing the geometry's
distance field.

Parameters
----------
max_poses : int
    Most poses one request may hold.
fast_spacing : float
    Distance-field spacing [mm].
cache_dir : str
    Directory of cached distance fields ('' : ~/.cache/edm_planner).
mesh_resolution : float
    Surface mesh edge length of the MESH method [mm].
paper_delta1 : float
    Huang's Delta1 [mm].
paper_delta2 : float
    Huang's Delta2 [rad].
prebuild_fast : bool
    Build the distance field as soon as a geometry arrives.
max_designs : int
    Re-designed electrode sets kept in memory (least recently used dropped).
unknown_geometry_wait : float
    How long a request for a geometry id not received yet waits for it on ``geometry`` [s] (one loaded just
    before may still be on its way).
"""

import collections
import json
import threading

import numpy as np
from edm_planner_msgs.msg import BliskGeometry, SegmentCheck, SurfaceClearance
from edm_planner_msgs.srv import CheckInterference
from geometry_msgs.msg import Point
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node

from ..ros.startup import prepare_process

#: this entry point's set-up, before the core's kernel modules load (numba reads its cache directory then) and
#: before rclpy.init (Fast DDS on loopback): :func:`edm_planner.ros.startup.prepare_process`
DDS_SETUP = prepare_process()

from .. import CACHE_ROOT
from ..errors import EdmError, ErrorCode
from ..geometry.as_measured import MeasuredBlades, channel_blisk, channel_field_key
from ..geometry.blisk import Blisk
from ..geometry.electrode import ElectrodeDesign
from ..geometry.electrode_cache import cached_design
from ..interference.checker import ChannelChecker, CheckerOptions, Method
from ..cnc.kinematics import AXES_5, FiveAxisKinematics
from ..ros.runtime import answer, spin_node
from ..ros.conversions import (design_override, error_code, msg_to_mesh, pose_to_matrix, poses_to_arrays,
                          quaternions_to_matrices)
from ..ros.received import ReceivedGeometries, Unusable
from ..ros.shared import LATCHED


class InterferenceCheckerNode(Node):
    """Serves CheckInterference for every geometry published on ``geometry``."""

    def __init__(self, **kwargs):
        super().__init__("interference_checker", **kwargs)
        self.declare_parameter("max_poses", 20000)
        self.declare_parameter("fast_spacing", 0.1)
        self.declare_parameter("cache_dir", "")
        self.declare_parameter("mesh_resolution", 0.25)
        self.declare_parameter("paper_delta1", 0.0)
        self.declare_parameter("paper_delta2", 0.0)
        self.declare_parameter("prebuild_fast", True)
        self.declare_parameter("max_designs", 8)
        self.declare_parameter("unknown_geometry_wait", 5.0)
        self.measured = {}                  # geometry id -> its blades as measured (MeasuredBlades) or None
        self.channel_checkers = {}          # (geometry id, channel) -> the checker of that channel's own walls
        self.designs = {}                   # geometry id -> the geometry file's electrode design
        # (geometry id, design) -> checker with those electrodes, least recently used first
        self.redesigned = collections.OrderedDict()
        self.max_designs = max(1, int(self.get_parameter("max_designs").value))
        self._lock = threading.Lock()
        self.received = ReceivedGeometries(self._lock)       # geometry id -> ChannelChecker (or Unusable)
        self.create_subscription(BliskGeometry, "geometry", self.on_geometry, LATCHED,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.service = self.create_service(CheckInterference, "check_interference", self.on_check,
                                           callback_group=MutuallyExclusiveCallbackGroup())

    def _options(self):
        cache = self.get_parameter("cache_dir").value or CACHE_ROOT
        return CheckerOptions(
            max_poses=int(self.get_parameter("max_poses").value),
            fast_spacing=float(self.get_parameter("fast_spacing").value), cache_dir=cache,
            mesh_resolution=float(self.get_parameter("mesh_resolution").value),
            paper_delta1=float(self.get_parameter("paper_delta1").value),
            paper_delta2=float(self.get_parameter("paper_delta2").value))

    def on_geometry(self, msg):
        gid = msg.summary.geometry_id
        if self.received.again(gid):            # loaded again after another: the latest once more
            return
        try:
            model = json.loads(msg.model_json)
            blisk = Blisk.from_dict(model)
            design = ElectrodeDesign.from_dict(model.get("electrode_design") or {})
            electrodes = {eid: (msg_to_mesh(m), pose_to_matrix(p))
                          for eid, m, p in zip(msg.electrode_ids, msg.electrodes, msg.electrode_final_poses)}
            checker = ChannelChecker(blisk, electrodes, gid, self._options())
            measured = MeasuredBlades.from_dict(model.get("as_measured"))
        except Exception as exc:  # a geometry we cannot use must not take the node down
            self.get_logger().error(f"geometry {gid[:12]} not usable: {exc!r}")
            self.received.add(gid, Unusable(exc))  # the latest: its requests are told, not answered for another
            return
        with self._lock:
            self.measured[gid] = measured
            self.designs[gid] = design
        self.received.add(gid, checker)         # after its design and blades: a waiting request uses them
        self.get_logger().info(f"geometry {gid[:12]}: {blisk.blade_count} channels, "
                               f"electrodes {sorted(electrodes)}")
        if self.get_parameter("prebuild_fast").value:
            threading.Thread(target=self._prebuild, args=(checker,), daemon=True).start()

    def _own_channel(self, gid, checker, channel):
        """The checker of channel ``channel``'s own walls on a blisk as measured (kept per channel), else ``checker``.

        Its field is the channel's own (its key :func:`channel_field_key`), built on the first query."""
        measured = self.measured.get(gid)
        if measured is None or not 0 <= channel < checker.blisk.blade_count:
            return checker               # nominal, or a bad channel that checker.validate refuses
        key = (gid, int(channel))
        with self._lock:
            own = self.channel_checkers.get(key)
        if own is None:                  # built once per channel (the channel's blisk is validated on the way)
            blisk = channel_blisk(checker.blisk, measured, int(channel))
            own = checker if blisk is checker.blisk else ChannelChecker(
                blisk, checker.electrodes, channel_field_key(gid, int(channel)), self._options())
            with self._lock:
                own = self.channel_checkers.setdefault(key, own)
        return own

    def _prebuild(self, checker):
        try:
            field = checker.fast
            self.get_logger().info(f"distance field ready for {checker.geometry_id[:12]}: "
                                   f"error bound {field.error_bound * 1e3:.2f} um")
        except Exception as exc:
            self.get_logger().error(f"distance field build failed: {exc!r}")

    def on_check(self, request, response):
        return answer(self, "CheckInterference", self._check, request, response)

    def _check(self, request, response):
        # a geometry loaded just before the request may still be on its way on the latched topic
        gid, checker = self.received.require(request.geometry_id,
                                             float(self.get_parameter("unknown_geometry_wait").value))
        try:
            method = Method(request.method)
        except ValueError:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"unknown method {request.method}") from None
        if not np.isfinite(request.threshold):
            raise EdmError(ErrorCode.INVALID_REQUEST, "threshold must be finite (mm)")
        checker = self._own_channel(gid, checker, request.channel)
        checker = self._redesigned(gid, checker, request.electrode)
        mesh, final_pose = checker.electrode(request.electrode_id)
        poses = self._poses(request, checker, final_pose)
        result = checker.check(poses, channel=request.channel, electrode_id=request.electrode_id,
                               method=method, threshold=request.threshold,
                               closest=request.closest_points and method != Method.PAPER_CRITERIA,
                               segments=request.segments)
        # one conversion to Python floats for the whole batch, then plain constructors
        clear = result.clearances.tolist()
        minimum = np.min(result.clearances, axis=1).tolist()
        colliding = result.colliding.tolist()
        out = [SurfaceClearance(suction=a, pressure=b, hub=h, shroud=s, minimum=m, colliding=k)
               for (a, b, h, s), m, k in zip(clear, minimum, colliding)]
        if result.closest is not None:
            for c, pairs in zip(out, result.closest.tolist()):
                c.electrode_points = [Point(x=x, y=y, z=z) for x, y, z in (pair[0] for pair in pairs)]
                c.surface_points = [Point(x=x, y=y, z=z) for x, y, z in (pair[1] for pair in pairs)]
        response.clearances = out
        for seg in result.segments:
            response.segment_checks.append(SegmentCheck(
                certified=seg.certified, first_contact=float(seg.first_contact),
                penetration_bound=float(seg.penetration_bound), subdivisions=int(seg.evaluations)))
        response.error_bound = float(result.error_bound)
        response.clearance_kind = int(result.kind)
        n_coll = int(result.colliding.sum())
        response.message = (f"{len(poses)} pose(s), {n_coll} colliding, method {method.name.lower()}: clearances "
                            f"{result.kind.describe(result.error_bound)}")
        response.error_code = error_code(ErrorCode.SUCCESS)

    def _redesigned(self, gid, checker, msg):
        """The checker of the request's electrode design (the geometry's own when not overridden)."""
        design = design_override(msg, self.designs[gid])
        if design is None:
            return checker
        key = (gid, json.dumps(design.to_dict(), sort_keys=True, default=str))
        with self._lock:
            known = self.redesigned.get(key)
            if known is not None:
                self.redesigned.move_to_end(key)
        if known is None:
            try:
                electrodes = cached_design(checker.blisk, design, cache_dir=self._options().cache_dir)
            except ValueError as exc:
                raise EdmError(ErrorCode.INVALID_REQUEST, f"electrode design: {exc}") from None
            known = checker.with_electrodes({e.electrode_id: (e.mesh, e.final_pose) for e in electrodes})
            with self._lock:
                self.redesigned[key] = known
                while len(self.redesigned) > self.max_designs:      # each holds its electrodes' meshes
                    self.redesigned.popitem(last=False)
            self.get_logger().info(f"geometry {gid[:12]}: electrodes {sorted(known.electrodes)} re-designed")
        return known

    @staticmethod
    def _poses(request, checker, final_pose):
        if request.axis_names or request.axis_values:
            if request.poses:
                raise EdmError(ErrorCode.INVALID_REQUEST, "give poses or axis values, not both")
            if tuple(request.axis_names) != AXES_5:
                raise EdmError(ErrorCode.INVALID_REQUEST,
                               f"axis_names must be {list(AXES_5)} for this five-axis machine, "
                               f"got {list(request.axis_names)}")
            rows = [list(p.positions) for p in request.axis_values]
            short = [i for i, row in enumerate(rows) if len(row) != 5]
            if not rows or short:             # checked before numpy: rows of unequal length make no array
                raise EdmError(ErrorCode.INVALID_REQUEST, "each axis value needs 5 positions (X, Y, Z mm; A, C rad)"
                               + (f": axis_values[{short[0]}] has {len(rows[short[0]])}" if short else
                                  ": no axis_values given"))
            q = np.array(rows, dtype=np.float64)
            if not np.isfinite(q).all():
                raise EdmError(ErrorCode.INVALID_REQUEST, "axis values contain NaN or infinite values")
            return FiveAxisKinematics(final_pose, checker.blisk.pitch).forward(q)
        if not request.poses:
            raise EdmError(ErrorCode.INVALID_REQUEST, "no poses given")
        quats, positions = poses_to_arrays(request.poses)
        finite = np.isfinite(quats).all(axis=1) & np.isfinite(positions).all(axis=1)
        norm = np.linalg.norm(quats, axis=1)
        bad = np.flatnonzero(~finite | (np.abs(norm - 1.0) > 1e-6))
        if len(bad):
            i = int(bad[0])                 # the first bad pose, as a loop over them would report it
            if not finite[i]:
                raise EdmError(ErrorCode.INVALID_REQUEST, f"pose {i} contains NaN or infinite values")
            raise EdmError(ErrorCode.INVALID_REQUEST, f"pose {i}: quaternion is not unit (norm {norm[i]:.6g})")
        return quaternions_to_matrices(quats, positions)


def main(args=None):
    """Console entry point ``interference_checker``."""
    return spin_node(InterferenceCheckerNode, args)
