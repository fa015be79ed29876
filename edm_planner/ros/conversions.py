"""Message <-> numpy/trimesh conversions, the one place nodes translate types.

Coordinates stay in millimetres in every message (geometry_msgs positions
included, as the message definitions state); RViz markers get a 0.001 scale.
"""

import array
from dataclasses import replace

import numpy as np
import trimesh
from edm_planner_msgs.msg import AxisPath, AxisPoint, ErrorCode, GeometrySummary, TriangleMesh
from geometry_msgs.msg import Point, Pose
from scipy.spatial.transform import Rotation
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker

from ..errors import EdmError
from ..errors import ErrorCode as CoreErrorCode
from ..machining.cycle import ClearZone, Leg, MachiningCycle, ProcessReach


def error_code(code):
    """ErrorCode message from the core enum (same values, checked by a test)."""
    return ErrorCode(val=int(CoreErrorCode(code)))


def mesh_to_msg(mesh):
    """trimesh -> edm_planner_msgs/TriangleMesh (mm): the vertices and triangles as two flat arrays."""
    msg = TriangleMesh()
    vertices, triangles = array.array("d"), array.array("I")
    vertices.frombytes(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    triangles.frombytes(np.ascontiguousarray(mesh.faces, dtype=np.uint32).tobytes())
    msg.vertices, msg.triangles = vertices, triangles
    return msg


def msg_to_mesh(msg):
    """edm_planner_msgs/TriangleMesh -> trimesh (mm), vertices kept as given.

    Raises ValueError for arrays that are no mesh: lengths not multiples of 3, an index beyond the vertices.
    """
    vertices = np.array(msg.vertices, dtype=np.float64)
    faces = np.array(msg.triangles, dtype=np.int64)
    if len(vertices) % 3 or len(faces) % 3:
        raise ValueError(f"a TriangleMesh holds 3 values per vertex and per triangle: got {len(vertices)} "
                         f"vertex and {len(faces)} triangle values")
    vertices, faces = vertices.reshape(-1, 3), faces.reshape(-1, 3)
    if len(faces) and faces.max() >= len(vertices):
        raise ValueError(f"triangle index {int(faces.max())} beyond the {len(vertices)} vertices")
    return trimesh.Trimesh(vertices, faces, process=False)


def matrix_to_pose(matrix):
    """4x4 homogeneous transform -> geometry_msgs/Pose (position in mm)."""
    return matrices_to_poses(np.asanyarray(matrix, dtype=np.float64)[None])[0]


def matrices_to_poses(matrices):
    """(n, 4, 4) homogeneous transforms -> n geometry_msgs/Pose (positions in mm).

    One ``Rotation.from_matrix`` for all: per matrix it cost about 0.25 ms (SciPy's checks), 1 s for the
    three plans of an electrode set.
    """
    m = np.asanyarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    rows = np.column_stack([m[:, :3, 3], Rotation.from_matrix(m[:, :3, :3]).as_quat()]).tolist() if len(m) else []
    poses = []
    for x, y, z, qx, qy, qz, qw in rows:
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = x, y, z
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = qx, qy, qz, qw
        poses.append(pose)
    return poses


def pose_to_matrix(pose):
    """geometry_msgs/Pose (position in mm) -> 4x4 transform."""
    q = pose.orientation
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    m[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return m


def poses_to_arrays(poses):
    """geometry_msgs/Pose list -> quaternions (n, 4) [x, y, z, w] and positions (n, 3) [mm], one pass."""
    flat = np.array([(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w,
                      p.position.x, p.position.y, p.position.z) for p in poses], dtype=np.float64).reshape(-1, 7)
    return flat[:, :4], flat[:, 4:]


def quaternions_to_matrices(quats, positions):
    """Quaternions (n, 4) [x, y, z, w] and positions (n, 3) -> (n, 4, 4) transforms, vectorised."""
    m = np.zeros((len(quats), 4, 4))
    if len(quats):
        m[:, :3, :3] = Rotation.from_quat(quats).as_matrix()
    m[:, :3, 3] = positions
    m[:, 3, 3] = 1.0
    return m


def summary_to_msg(summary):
    """Core summary dict -> GeometrySummary."""
    msg = GeometrySummary()
    for key, value in summary.items():
        setattr(msg, key, value)
    return msg


def mesh_marker(mesh, ns, marker_id, frame_id, stamp, rgba, pose=None):
    """A TRIANGLE_LIST marker of a mesh in mm, scaled 0.001 for RViz's metres."""
    m = Marker()
    m.header.frame_id = frame_id
    m.header.stamp = stamp
    m.ns, m.id, m.type, m.action = ns, marker_id, Marker.TRIANGLE_LIST, Marker.ADD
    if pose is not None:
        m.pose = matrix_to_pose(pose)
        m.pose.position.x *= 1e-3
        m.pose.position.y *= 1e-3
        m.pose.position.z *= 1e-3
    else:
        m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = 1e-3
    m.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
    tri = mesh.vertices[mesh.faces.reshape(-1)]
    m.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in tri]
    return m


_DESIGN_FLOATS = ("discharge_gap", "circumferential_reduction", "radial_reduction", "split_fraction",
                  "split_overlap")


def design_override(msg, base):
    """ElectrodeDesign message -> design, or None when the message is untouched (all zero / empty)."""
    floats = {name: float(getattr(msg, name)) for name in _DESIGN_FLOATS + ("axial_start", "axial_end")}
    if not msg.reduction_side and not msg.split and all(v == 0.0 for v in floats.values()):
        return None
    changes = {k: v for k, v in floats.items() if k in _DESIGN_FLOATS and not np.isnan(v)}
    if msg.reduction_side:
        changes["reduction_side"] = msg.reduction_side
    if msg.split:
        changes["split"] = msg.split
    a0, a1 = floats["axial_start"], floats["axial_end"]
    if not (np.isnan(a0) and np.isnan(a1)):
        if np.isnan(a0) or np.isnan(a1):
            raise EdmError(CoreErrorCode.INVALID_REQUEST, "electrode.axial_start and axial_end: give both or neither")
        changes["axial_range"] = (a0, a1)
    if not all(np.isfinite(v) for v in changes.values() if isinstance(v, float)):
        raise EdmError(CoreErrorCode.INVALID_REQUEST, "electrode design values must be finite numbers")
    return replace(base, **changes)


# -- machining cycles and the removal proof ---------------------------------------------------

def cycle_fields(cycle, set_id=""):
    """The ChannelPlan fields of a MachiningCycle (None: empty cycle, NaN margin), as a dict of keyword args."""
    if cycle is None:
        return {"cycle_margin": float("nan"), "set_id": set_id or ""}
    samples = cycle.samples
    return {"cycle_path": AxisPath(axis_names=list(cycle.axis_names),
                                   points=[AxisPoint(positions=row) for row in samples.tolist()]),
            "leg_phases": [leg.phase for leg in cycle.legs], "leg_labels": [leg.label for leg in cycle.legs],
            "leg_last": [int(b) for _, _, _, b in cycle.leg_ranges],
            "leg_clearance_lower_bound": [float(v) for leg in cycle.legs for v in np.asarray(leg.clearance_lower_bound).reshape(4)],
            "leg_regimes": [leg.regime for leg in cycle.legs],
            "leg_removed_volume": [float(leg.removed_volume) for leg in cycle.legs],
            "cycle_margin": float(cycle.margin), "cycle_certified": bool(cycle.certified),
            "cycle_message": cycle.message, "set_id": set_id or "",
            "clear_zone": [] if cycle.clear_zone is None else [
                float(v) for v in (cycle.clear_zone.side, *cycle.clear_zone.envelope, cycle.clear_zone.sphere_radius,
                                   cycle.clear_zone.origin_x, cycle.clear_zone.clear_x, cycle.clear_zone.blade_gap)]}


def cycle_to_msg(msg, cycle, set_id=""):
    """Fill a ChannelPlan message's cycle fields from a MachiningCycle (or leave them empty for None)."""
    for key, value in cycle_fields(cycle, set_id).items():
        setattr(msg, key, value)
    return msg


def msg_to_cycle(msg):
    """The MachiningCycle of a ChannelPlan message (legs rebuilt from cycle_path and leg_last), or None."""
    if not msg.leg_phases:
        return None
    names = tuple(msg.cycle_path.axis_names)
    samples = np.array([p.positions for p in msg.cycle_path.points], dtype=np.float64).reshape(-1, len(names))
    last = [int(v) for v in msg.leg_last]
    n = len(msg.leg_phases)
    if len(msg.leg_labels) != n or len(last) != n or (last and last[-1] != len(samples) - 1) or \
            any(b <= a for a, b in zip([0] + last, last)):
        raise EdmError(CoreErrorCode.INVALID_REQUEST,
                       f"plan {msg.plan_id}: cycle fields do not agree ({n} phases, {len(msg.leg_labels)} labels, "
                       f"leg_last {last[:5]}..., {len(samples)} cycle samples)")
    clear = np.array(msg.leg_clearance_lower_bound, dtype=np.float64)
    clear = clear.reshape(n, 4) if clear.size == 4 * n else np.full((n, 4), np.nan)
    regimes = list(msg.leg_regimes) if len(msg.leg_regimes) == n else [""] * n      # older publishers: none
    volumes = list(msg.leg_removed_volume) if len(msg.leg_removed_volume) == n else [float("nan")] * n
    legs, first = [], 0
    for i, (phase, label, b) in enumerate(zip(msg.leg_phases, msg.leg_labels, last)):
        legs.append(Leg(phase, label, samples[first:b + 1].copy(), clear[i].copy(), regimes[i], float(volumes[i])))
        first = b
    zone = list(msg.clear_zone)
    if zone and len(zone) != 7:
        raise EdmError(CoreErrorCode.INVALID_REQUEST, f"plan {msg.plan_id}: clear_zone has {len(zone)} values, not 7")
    zone = ClearZone(zone[0], (zone[1], zone[2]), *zone[3:]) if zone else None
    return MachiningCycle(names, legs, ProcessReach(), float(msg.cycle_margin), bool(msg.cycle_certified),
                          msg.cycle_message, zone)


_SURFACE_ORDER = ("suction", "pressure", "hub", "shroud")


def machining_figures(cycle, removal):
    """The PlanMetrics machining fields (dict of keyword args) of a cycle and a removal proof (``to_dict()``).

    NaN, False and empty where there is no cycle or no proof.
    """
    nan = float("nan")
    out = {"machining_margin": nan if cycle is None else float(cycle.margin),
           "cycle_certified": bool(cycle is not None and cycle.certified),
           "stock_tolerance": nan, "stock_max_exact": [], "stock_mean": [], "stock_area_fraction_above": [],
           "overcut_max": [], "stock_sample_spacing": nan, "stock_continuous_bound": nan}
    if not removal:
        return out
    surfaces = removal.get("surfaces") or {}

    def per_surface(key):
        return [nan if surfaces.get(s, {}).get(key) is None else float(surfaces[s][key]) for s in _SURFACE_ORDER]

    def number(value):
        return nan if value is None else float(value)

    accuracy = removal.get("accuracy") or {}
    out.update(stock_tolerance=number(removal.get("tolerance_mm")), stock_max_exact=per_surface("stock_max_mm"),
               stock_mean=per_surface("stock_mean_mm"),
               stock_area_fraction_above=per_surface("area_fraction_above_tolerance"),
               overcut_max=per_surface("overcut_max_mm"),
               stock_sample_spacing=number(accuracy.get("sample_spacing_mm")),
               stock_continuous_bound=number(accuracy.get("continuous_bound_mm")))
    return out
