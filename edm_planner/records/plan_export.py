"""Plan export: the directory that downstream tools and independent checks read.

Layout of format ``edm_planner.plan/1`` (units mm and rad, frame W: X is the
blisk's rotation axis, ``theta = atan2(z, y)``)::

    plan.json       metadata, settings, samples in feed order (axis values and the
                    4x4 row-major pose electrode frame -> W), metrics, file hashes
    electrode.stl   the electrode mesh that was checked, in the electrode frame;
                    ASCII with shortest round-trip digits, so it reads back bit-exact
    workpiece.stl   the channel sector in W: suction, pressure, hub and shroud
                    patches concatenated in this order (face ranges in plan.json);
                    binary, float32: a reference for viewers, the exact check uses
                    the model surfaces; plan.json states per surface how far the
                    mesh lies into the channel and into the material (upper bounds,
                    :mod:`edm_planner.geometry.mesh_deviation`)
    axes.csv        header ``X [mm],Y [mm],...``, one row per sample

:func:`write_plan` writes the directory, :func:`read_plan` reads and validates
it, :func:`~edm_planner.records.plan_check.verify_exported_plan` re-checks it with the exact clearance of every
electrode vertex, independently of how the planner checked it.
"""

import csv
import dataclasses
import datetime
import enum
import hashlib
import io
import json
import logging
import math
import os
import pathlib
import zlib
from dataclasses import dataclass, field

import numpy as np
import trimesh

from .. import __version__
from ..errors import EdmError, ErrorCode
from ..interference import SURFACES
from ..geometry import mesh_deviation
from ..geometry.disk_cache import arrays_digest, content_key, get_or_make
from ..constants import RIGID_TOLERANCE
from ..planning.plan import AXIS_NAMES

_log = logging.getLogger(__name__)


FORMAT = "edm_planner.plan/1"
UNITS = {"length": "mm", "angle": "rad"}
AXIS_UNITS = {"X": "mm", "Y": "mm", "Z": "mm", "A": "rad", "C": "rad", "B": "rad"}
FRAME = {
    "id": "workpiece",
    "description": "W: X is the blisk's rotation axis, theta = atan2(z, y); channel k lies between the "
                   "suction face of blade k and the pressure face of blade k+1",
    "pose": "4x4 row-major homogeneous matrix mapping electrode-frame points to W",
    "electrode_frame": "origin at the electrode's centre of volume, X along the blisk axis, Z radial",
}
AXES_CONVENTION = ("machine axis values measured from the electrode's final machining pose in channel 0; "
                   "pose = Rx(A) . T(X, Y, Z) . T_final . Rz(C) (. Ry(B)), A includes channel * pitch "
                   "(fixed at channel * pitch on a 4-axis machine)")
FILES = {"plan": "plan.json", "electrode": "electrode.stl", "workpiece": "workpiece.stl", "axes": "axes.csv",
         "cycle": "cycle.csv"}

#: largest move of any electrode vertex between consecutive samples that format 1 allows [mm]
MAX_VERTEX_STEP = 0.05
#: plan.json's statement on electrode.stl: it is the checked mesh itself, not an approximation of it
ELECTRODE_DEVIATION = {
    "kind": "exact", "deviation": 0.0,
    "statement": "the very mesh whose clearances were checked, its vertices written with shortest round-trip "
                 "digits: it reads back bit-exact, so a check against it measures the checked electrode",
}


class PlanFileError(EdmError):
    """An exported plan directory that is missing, unreadable or malformed (FILE_ERROR)."""

    def __init__(self, message: str):
        super().__init__(ErrorCode.FILE_ERROR, message)


# -- writing ------------------------------------------------------------------------------

def json_safe(value):
    """Plain JSON values from dataclasses, enums, numpy values and tuples; NaN/inf become None."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: json_safe(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not f.name.startswith("_")}
    if isinstance(value, enum.Enum):
        return value.name
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf" and (value.dtype.kind != "f"
                                                                       or np.isfinite(value).all()):
        return value.tolist()                               # the same values, without a call per element
    if isinstance(value, (list, tuple, np.ndarray)):
        return [json_safe(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def _sha256(path):
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def _write_atomic(path, data):
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data if isinstance(data, bytes) else data.encode())
    os.replace(tmp, path)


#: electrode.stl texts kept (zlib, about 4 MB apiece for the default blisk's 59 000 triangles)
STL_CACHE_KEEP = 24


def _electrode_stl(mesh, cache_dir=None):
    """electrode.stl's bytes (trimesh's ASCII STL: every coordinate's shortest round-trip digits).

    Formatting 700 000 floats takes 0.2 to 0.7 s on the AMD Zen 3, and a set's plans are written again
    whenever a stored set is exported; with ``cache_dir`` the text is kept there by the mesh's content
    (as bytes: read from the cache, it is written out without a decode and an encode of its 17 MB).
    """
    def make():
        return trimesh.exchange.stl.export_stl_ascii(mesh).encode()

    if not cache_dir:
        return make()
    mesh_digest = arrays_digest(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64))
    key = content_key({"format": "electrode-stl/1", "mesh": mesh_digest, "name": mesh.metadata.get("name", ""),
                       "trimesh": trimesh.__version__})
    return get_or_make(pathlib.Path(cache_dir) / "electrode_stl" / f"{key[:32]}.stl.z", _read_stl, make,
                       lambda out, data: out.write(zlib.compress(data, 1)), keep=STL_CACHE_KEEP,
                       what="electrode STL")


def _read_stl(path):
    """A cached electrode.stl (bytes); None when missing or unreadable."""
    try:
        return zlib.decompress(path.read_bytes())
    except FileNotFoundError:
        return None
    except (OSError, zlib.error) as exc:
        _log.warning("electrode STL cache %s: unreadable (%s); written again", path, exc)
        return None


def _axes_csv(axis_names, samples):
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["sample"] + [f"{n} [{AXIS_UNITS[n]}]" for n in axis_names])
    for i, row in enumerate(samples):
        w.writerow([i] + [repr(float(v)) for v in row])     # repr: shortest digits that round-trip
    return buf.getvalue()


def _cycle_csv(axis_names, cycle):
    """The whole machining cycle, one row per sample, with its phase and leg (rest at every leg's ends) and, last,
    the discharge regime of the leg (the generator's, for the motion that ends at the row; '' : off)."""
    units = ",".join(f"{n}_{AXIS_UNITS[n]}" for n in axis_names)
    rows = [f"phase,leg,{units},regime"]
    for i, (phase, label, a, b) in enumerate(cycle.leg_ranges):
        leg = cycle.legs[i].samples
        regime = cycle.legs[i].regime
        for j, q in enumerate(leg):
            if i and j == 0:
                continue                  # the rest sample shared with the previous leg
            rows.append(f"{phase},{i}," + ",".join(repr(float(v)) for v in q) + f",{regime}")
    return "\n".join(rows) + "\n"


def _workpiece_deviation(blisk, channel, resolution, meshes, cache_dir=None):
    """plan.json's statement of how far workpiece.stl (float32, as written) lies from the true surfaces.

    Per surface, the upper bounds ``into_channel`` and ``into_material`` [mm] of
    :func:`~edm_planner.geometry.mesh_deviation.channel_mesh_deviation`, the
    sampled extremes they rest on and the remainder added between samples.
    """
    dev = mesh_deviation.cached_channel_mesh_deviation(blisk, channel, resolution, float32=True,
                                                       cache_dir=cache_dir, meshes=meshes)
    return {
        "kind": mesh_deviation.KIND,
        "units": "mm",
        "definition": dict(mesh_deviation.DEFINITION,
                           measured="the largest sample alone: a deviation the mesh attains, so the true largest "
                                    "lies between it and the bound"),
        "method": mesh_deviation.METHOD,
        "float32": True,
        "surfaces": {s: json_safe(dev[s].to_dict()) for s in SURFACES},
    }


def write_plan(plan, out_dir, blisk, workpiece_resolution=0.5, cache_dir=None):
    """Write a plan as an export directory (format ``edm_planner.plan/1``).

    Failed plans are written too (with their error code, message and how far the
    search got); :func:`read_plan` refuses them unless asked not to.

    Parameters
    ----------
    plan : Plan
    out_dir : path
        Created if missing; the four files in it are replaced.
    blisk : Blisk
        The geometry the plan was made for (its channel sector goes to workpiece.stl).
    workpiece_resolution : float
        Edge length of the workpiece surface meshes [mm]; plan.json states their
        deviation from the true surfaces per surface and side (upper bounds).
    cache_dir : path, optional
        Where that deviation is kept between exports of the same channel
        (:func:`~edm_planner.geometry.mesh_deviation.cached_channel_mesh_deviation`), and electrode.stl's
        text by the mesh's content; None: measured and formatted anew.

    Returns
    -------
    pathlib.Path
        The plan.json written.

    Raises
    ------
    EdmError
        INTERNAL for a plan whose arrays are inconsistent or not finite,
        FILE_ERROR when the directory cannot be written.
    """
    names = tuple(plan.axis_names)
    samples = np.asanyarray(plan.samples, dtype=np.float64).reshape(-1, len(names))
    poses = np.asanyarray(plan.poses, dtype=np.float64).reshape(-1, 4, 4)
    nodes = np.asanyarray(plan.nodes, dtype=np.float64).reshape(-1, len(names))
    if names not in AXIS_NAMES.values():
        raise EdmError(ErrorCode.INTERNAL, f"plan {plan.plan_id}: unknown axis names {names}")
    if len(samples) != len(poses):
        raise EdmError(ErrorCode.INTERNAL, f"plan {plan.plan_id}: {len(samples)} axis samples but {len(poses)} poses")
    for what, arr in (("samples", samples), ("poses", poses), ("nodes", nodes), ("final_pose", plan.final_pose)):
        if not np.isfinite(arr).all():
            raise EdmError(ErrorCode.INTERNAL, f"plan {plan.plan_id}: {what} are not all finite")
    if plan.success and len(samples) < 2:
        raise EdmError(ErrorCode.INTERNAL, f"plan {plan.plan_id}: a successful plan needs at least 2 samples")
    out = pathlib.Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        electrode = out / FILES["electrode"]
        _write_atomic(electrode, _electrode_stl(plan.electrode_mesh, cache_dir))
        meshes = blisk.channel_meshes(plan.channel, workpiece_resolution)
        ranges, start = {}, 0
        for s in SURFACES:
            ranges[s] = [start, start + len(meshes[s].faces)]
            start += len(meshes[s].faces)
        workpiece = out / FILES["workpiece"]
        _write_atomic(workpiece, trimesh.util.concatenate([meshes[s] for s in SURFACES]).export(file_type="stl"))
        deviation = _workpiece_deviation(blisk, plan.channel, workpiece_resolution, meshes, cache_dir)
        axes = out / FILES["axes"]
        _write_atomic(axes, _axes_csv(names, samples))
        doc = {
            "format": FORMAT,
            "units": UNITS,
            "frame": FRAME,
            "plan_id": plan.plan_id,
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "edm_planner_version": __version__,
            "geometry_id": plan.geometry_id,
            "channel": int(plan.channel),
            "blade_count": int(blisk.blade_count),
            "electrode_id": plan.electrode_id,
            "method": plan.options.search.method,
            "error_code": ErrorCode(plan.error_code).name,
            "message": plan.message,
            "settings": json_safe(plan.options),
            "axis_names": list(names),
            "axis_units": [AXIS_UNITS[n] for n in names],
            "axes_convention": AXES_CONVENTION,
            "final_pose": json_safe(np.asarray(plan.final_pose).reshape(-1)),
            "samples": [{"axes": json_safe(q), "pose": json_safe(p.reshape(-1))} for q, p in zip(samples, poses)],
            "nodes": json_safe(nodes),
            "metrics": json_safe(plan.metrics.to_dict()),
            "failure": {"furthest_node": int(plan.furthest_node),
                        "furthest_reference": json_safe(plan.furthest_reference),
                        "blocking_surface": plan.blocking_surface,
                        "blocking_clearance_lower_bound": json_safe(plan.blocking_clearance_lower_bound)},
            "files": {
                "electrode": {"name": FILES["electrode"], "sha256": _sha256(electrode), "encoding": "ascii",
                              "vertices": len(plan.electrode_mesh.vertices),
                              "faces": len(plan.electrode_mesh.faces), "deviation": ELECTRODE_DEVIATION},
                "workpiece": {"name": FILES["workpiece"], "sha256": _sha256(workpiece), "encoding": "binary",
                              "resolution": float(workpiece_resolution), "surfaces": ranges,
                              "deviation": deviation},
                "axes": {"name": FILES["axes"], "sha256": _sha256(axes)},
            },
        }
        if getattr(plan, "cycle", None) is not None:
            cycle_file = out / FILES["cycle"]
            _write_atomic(cycle_file, _cycle_csv(names, plan.cycle))
            doc["cycle"] = json_safe(plan.cycle.to_dict())
            doc["cycle"]["phases"] = [{"phase": p, "first": a, "last": b} for p, a, b in plan.cycle.phase_ranges]
            doc["files"]["cycle"] = {"name": FILES["cycle"], "sha256": _sha256(cycle_file),
                                     "samples": int(len(plan.cycle.samples))}
        if getattr(plan, "removal", None) is not None:
            # the material-removal proof of the electrode set this plan belongs to
            doc["removal"] = json_safe(plan.removal)
            doc["set_id"] = getattr(plan, "set_id", "")
        path = out / FILES["plan"]
        _write_atomic(path, json.dumps(doc, indent=1, allow_nan=False))
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"cannot write the plan to {out}: {exc}") from exc
    return path


# -- reading ------------------------------------------------------------------------------

@dataclass(eq=False)
class ExportedPlan:
    """A validated export directory.

    Attributes
    ----------
    path : pathlib.Path
        The directory.
    doc : dict
        plan.json as read.
    axis_names : tuple of str
    axes : (N, k) float
        Axis values per sample, feed order.
    poses : (N, 4, 4) float
        Electrode frame -> W per sample.
    final_pose : (4, 4) float
        Electrode frame -> W at the machining pose in channel 0.
    electrode_mesh : trimesh.Trimesh
        From electrode.stl (coincident vertices merged exactly).
    error_code : ErrorCode
    """

    path: pathlib.Path
    doc: dict
    axis_names: tuple
    axes: np.ndarray
    poses: np.ndarray
    final_pose: np.ndarray
    electrode_mesh: trimesh.Trimesh
    error_code: ErrorCode
    nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def success(self):
        return self.error_code == ErrorCode.SUCCESS

    @property
    def channel(self):
        return int(self.doc["channel"])

    @property
    def geometry_id(self):
        return self.doc["geometry_id"]

    def workpiece_meshes(self):
        """The channel sector from workpiece.stl, split into its labelled surfaces (W)."""
        mesh = _load_stl(self.path / FILES["workpiece"])
        out = {}
        for s, (a, b) in self.doc["files"]["workpiece"]["surfaces"].items():
            out[s] = trimesh.Trimesh(mesh.vertices, mesh.faces[a:b], process=False)
            out[s].remove_unreferenced_vertices()
        return out


def _load_stl(path):
    """An STL as a mesh whose vertices are merged only where bit-identical (no rounding)."""
    with open(path, "rb") as f:
        soup = trimesh.exchange.stl.load_stl(f)
    tri = np.asarray(soup["vertices"], dtype=np.float64)[np.asarray(soup["faces"])]
    vertices, inverse = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)
    return trimesh.Trimesh(vertices, inverse.reshape(-1, 3), process=False)


def _matrix(value, shape, where):
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PlanFileError(f"{where}: expected {int(np.prod(shape))} numbers, got {str(value)[:60]}") from None
    if a.size != int(np.prod(shape)) or a.ndim != 1:
        raise PlanFileError(f"{where}: expected {int(np.prod(shape))} numbers, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise PlanFileError(f"{where}: contains NaN, infinite or null values")
    return a.reshape(shape)


def check_rigid(poses, where="pose"):
    """Raise PlanFileError unless every pose is a rigid motion (R^T R = I, det R = +1, last row 0 0 0 1)."""
    poses = np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    R = poses[:, :3, :3]
    ortho = np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.abs(np.linalg.det(R) - 1.0)
    row = np.abs(poses[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1)
    bad = np.flatnonzero((ortho > RIGID_TOLERANCE) | (det > RIGID_TOLERANCE) | (row > RIGID_TOLERANCE))
    if len(bad):
        i = int(bad[0])
        raise PlanFileError(f"{where}: pose {i} is not a rigid motion: |R^T R - I| = {ortho[i]:.3g}, "
                            f"|det R - 1| = {det[i]:.3g}, last row {poses[i, 3].tolist()}")


def read_plan(path, require_success=True):
    """Read and validate an export directory.

    Checks the format and units, the shape and finiteness of every sample, that
    every pose is rigid, that electrode.stl is the file plan.json names (sha256)
    and that axes.csv holds the same axis values as plan.json.

    Parameters
    ----------
    path : path
        The directory (or its plan.json).
    require_success : bool
        Refuse a plan whose error code is not SUCCESS.

    Returns
    -------
    ExportedPlan

    Raises
    ------
    PlanFileError
        (FILE_ERROR) on a missing, unreadable or malformed file, naming the file and key.
    EdmError
        With the plan's own error code when it failed and ``require_success``.
    """
    path = pathlib.Path(path)
    if path.name == FILES["plan"]:
        path = path.parent
    pj = path / FILES["plan"]
    try:
        doc = json.loads(pj.read_text())
    except FileNotFoundError:
        raise PlanFileError(f"{pj}: no such file (not a plan export directory)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PlanFileError(f"{pj}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise PlanFileError(f"{pj}: not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise PlanFileError(f"{pj}: expected a JSON object at the top level")
    if doc.get("format") != FORMAT:
        raise PlanFileError(f"{pj}: format is {doc.get('format')!r}, this reader understands {FORMAT!r}")
    for key in ("units", "geometry_id", "channel", "electrode_id", "axis_names", "samples", "final_pose",
                "metrics", "error_code", "message", "plan_id", "files"):
        if key not in doc:
            raise PlanFileError(f"{pj}: missing key {key!r}")
    if doc["units"] != UNITS:
        raise PlanFileError(f"{pj}: units are {doc['units']}, expected {UNITS}")
    names = tuple(doc["axis_names"]) if isinstance(doc["axis_names"], list) else None
    if names not in AXIS_NAMES.values():
        raise PlanFileError(f"{pj}: axis_names {doc['axis_names']!r} is none of {list(AXIS_NAMES.values())}")
    if not isinstance(doc["channel"], int) or doc["channel"] < 0:
        raise PlanFileError(f"{pj}: channel must be an integer >= 0, got {doc['channel']!r}")
    try:
        code = ErrorCode[doc["error_code"]]
    except (KeyError, TypeError):
        raise PlanFileError(f"{pj}: unknown error_code {doc['error_code']!r}") from None
    if code != ErrorCode.SUCCESS and require_success:
        raise EdmError(code, f"{pj}: the plan failed and has no certified path: {doc['message']}")
    samples = doc["samples"]
    if not isinstance(samples, list) or (code == ErrorCode.SUCCESS and len(samples) < 2):
        raise PlanFileError(f"{pj}: samples must be a list of at least 2 samples")
    k = len(names)
    axes, poses = np.zeros((len(samples), k)), np.zeros((len(samples), 4, 4))
    for i, s in enumerate(samples):
        if not isinstance(s, dict) or "axes" not in s or "pose" not in s:
            raise PlanFileError(f"{pj}: samples[{i}] needs 'axes' and 'pose'")
        axes[i] = _matrix(s["axes"], (k,), f"{pj}: samples[{i}].axes")
        poses[i] = _matrix(s["pose"], (4, 4), f"{pj}: samples[{i}].pose")
    check_rigid(poses, f"{pj}: samples")
    final = _matrix(doc["final_pose"], (4, 4), f"{pj}: final_pose")
    check_rigid(final, f"{pj}: final_pose")
    try:
        nodes = np.array(doc.get("nodes") or np.zeros((0, k)), dtype=np.float64).reshape(-1, k)
    except (TypeError, ValueError):
        raise PlanFileError(f"{pj}: nodes must be a list of {k} axis values per node") from None
    # the companion files: the electrode that plan.json names, the same axis values in axes.csv
    files = doc["files"]
    if not isinstance(files, dict) or not isinstance(files.get("electrode"), dict):
        raise PlanFileError(f"{pj}: files must name the electrode file and its sha256")
    el = path / FILES["electrode"]
    if not el.is_file():
        raise PlanFileError(f"{el}: no such file")
    if _sha256(el) != files["electrode"].get("sha256"):
        raise PlanFileError(f"{el}: sha256 differs from the one plan.json records (file replaced or damaged)")
    try:
        mesh = _load_stl(el)
    except Exception as exc:       # trimesh raises several types on a broken STL
        raise PlanFileError(f"{el}: not a readable STL: {exc}") from None
    if not len(mesh.faces) or not np.isfinite(mesh.vertices).all():
        raise PlanFileError(f"{el}: empty or not finite")
    if not (path / FILES["workpiece"]).is_file():
        raise PlanFileError(f"{path / FILES['workpiece']}: no such file")
    ax = path / FILES["axes"]
    try:
        rows = list(csv.reader(ax.read_text().splitlines()))
        header, body = rows[0], np.array([[float(v) for v in r[1:]] for r in rows[1:]]).reshape(-1, k)
    except FileNotFoundError:
        raise PlanFileError(f"{ax}: no such file") from None
    except (IndexError, ValueError) as exc:
        raise PlanFileError(f"{ax}: malformed: {exc}") from None
    if [h.split(" ")[0] for h in header[1:]] != list(names):
        raise PlanFileError(f"{ax}: header {header} does not name the axes {list(names)}")
    if body.shape != axes.shape or not np.array_equal(body, axes):
        raise PlanFileError(f"{ax}: axis values differ from plan.json's samples")
    return ExportedPlan(path, doc, names, axes, poses, final, mesh, code, nodes)
