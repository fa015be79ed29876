"""What a channel's electrodes do to the blisk and how long it takes: removed volume, erosion time, wear.

:func:`plan_process` takes the electrodes of a set in machining order (roughing ones first when the set has
them), computes the volume every leg of every cycle removes from the solid channel (or a pre-machined
stock) with what earlier legs removed subtracted (:func:`~.volume.removed_volumes`), and writes it onto
the legs (``Leg.removed_volume``; ``Leg.regime`` on every leg that removes something), so that the axis
bridge times each cutting leg by its regime's removal rate. It then reports per electrode, per channel and
for the whole blisk:

* removed volume [mm^3]: the voxel estimate with its certified bracket (:mod:`.volume`);
* eroding time [h]: removed volume / removal rate, per leg (a model estimate with the regime's inputs);
* electrode wear: volume = removed volume x the regime's volumetric wear ratio, leg by leg. A leg's wear
  lies on the faces that lead its motion: it is spread over the electrode's silhouette seen along the
  leg's direction of motion (electrode frame; the feed's last direction for the feed), and summed per
  leading face (the electrode-frame axis nearest that direction; the feed's face is the **front**). A
  model estimate: real wear concentrates on edges and corners, which this even spread does not show;
* electrodes needed: an electrode may take the process model's wear limit on its worst face
  (:meth:`~.model.ProcessModel.wear_limit`: the tolerance for a finishing electrode, the allowance band
  for a roughing one), so a channel needs ceil(worst face wear / limit) of each (at least one) and the
  whole blisk, where one electrode goes through every channel in turn, ceil(N x worst face wear / limit);
* wear compensation by feed depth (``wear_compensation``; :func:`compensation_schedule`): channel after
  channel the cycle runs with the electrode moved along its front by the wear the front has taken, so the
  front may wear up to ``max_compensated_wear_mm`` while the other faces keep their limit: an electrode
  lasts as many channels as both allow, and the blisk needs ceil(N / that).

Units: mm, mm^3, s (h in the text). No rclpy.
"""

import logging
import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from ..errors import EdmError, ErrorCode
from ..cnc.kinematics import axis_poses
from ..machining.proof_path import proof_legs
from .volume import AnnulusBlank, Cut, channel_cavity_volume, removed_volumes

_log = logging.getLogger(__name__)

#: the phases whose legs may erode; approach and retract run outside the blisk, return retraces the feed
CUTTING_PHASES = ("approach", "feed", "process", "retract")


@dataclass
class ProcessRun:
    """One electrode of the set, as the process plan needs it.

    Attributes
    ----------
    label : str
        front, rear, main, ... (``rough-front`` for a roughing twin).
    regime : str
        The process model's regime it erodes in (rough, finish).
    vertices, faces : arrays
        The electrode mesh, electrode frame [mm].
    final_pose : (4, 4) float
        Electrode frame -> W with every axis at 0 (channel 0).
    axis_names : tuple of str
    cycle : MachiningCycle
        Channel-0 axis values; its legs get ``removed_volume`` and ``regime``.
    """

    label: str
    regime: str
    vertices: np.ndarray
    faces: np.ndarray
    final_pose: np.ndarray
    axis_names: tuple
    cycle: object


@dataclass
class ElectrodeProcess:
    """The process figures of one electrode in one channel (model estimates; volumes with their bracket)."""

    label: str
    regime: str
    condition_code: str
    removed_volume: float            # mm^3, estimate
    removed_volume_lower: float      # mm^3, certified bracket
    removed_volume_upper: float
    eroding_time: float              # s
    wear_volume: float               # mm^3
    frontal_area: float              # mm^2, silhouette along the feed's last direction
    frontal_wear: float              # mm per channel, on the front
    face_wear: dict                  # mm per channel, per leading face (front, face +y, ...)
    wear_limit: float                # mm, what one electrode may take on its worst face
    electrodes_per_channel: int
    electrodes_per_blisk: int
    legs: list = field(default_factory=list)     # [(phase, label, volume mm^3, eroding time s)]
    compensation: dict = None        # wear compensation by feed depth (compensation_schedule), None: none

    @property
    def worst_face_wear(self):
        return max(self.face_wear.values(), default=0.0)

    def to_dict(self):
        return {"label": self.label, "regime": self.regime, "condition_code": self.condition_code,
                "removed_volume_mm3": round(self.removed_volume, 2),
                "removed_volume_bracket_mm3": [round(self.removed_volume_lower, 2),
                                               round(self.removed_volume_upper, 2)],
                "eroding_time_h": round(self.eroding_time / 3600.0, 4),
                "wear_volume_mm3": round(self.wear_volume, 3), "frontal_area_mm2": round(self.frontal_area, 2),
                "frontal_wear_per_channel_mm": round(self.frontal_wear, 4),
                "face_wear_per_channel_mm": {k: round(v, 4) for k, v in self.face_wear.items()},
                "wear_limit_mm": self.wear_limit,
                "worst_face_wear_per_channel_mm": round(self.worst_face_wear, 4),
                "electrodes_per_channel": self.electrodes_per_channel,
                "electrodes_per_blisk": self.electrodes_per_blisk,
                "legs": [{"phase": p, "label": lab, "removed_volume_mm3": round(v, 3), "eroding_time_s": round(t, 1)}
                         for p, lab, v, t in self.legs],
                "wear_compensation": self.compensation}


@dataclass
class ProcessReport:
    """The process of one channel's set and of the whole blisk (every figure a model estimate)."""

    electrodes: list                  # ElectrodeProcess, machining order
    blade_count: int
    channel_removed_volume: float     # mm^3
    channel_eroding_time: float       # s
    cavity_volume: float              # mm^3, the channel's cavity between its final walls (reference)
    resolution: float                 # mm, voxel size of the volume field
    volume_lower: float               # mm^3, certified bracket of the channel's removed volume
    volume_upper: float
    accuracy: str                     # what the volume bracket covers
    process: object                   # ProcessModel
    seconds: float                    # computing time
    blank: str = "the solid ring between hub and shroud over the blades' axial range"

    @property
    def blisk_eroding_time(self):
        return self.blade_count * self.channel_eroding_time

    def to_dict(self):
        return {"what": "model estimates from the machine's process model (inputs below); volumes are voxel "
                        "estimates with a certified bracket",
                "electrodes": [e.to_dict() for e in self.electrodes],
                "channel": {"removed_volume_mm3": round(self.channel_removed_volume, 1),
                            "removed_volume_bracket_mm3": [round(self.volume_lower, 1), round(self.volume_upper, 1)],
                            "cavity_volume_mm3": round(self.cavity_volume, 1),
                            "eroding_time_h": round(self.channel_eroding_time / 3600.0, 3)},
                "blisk": {"blade_count": self.blade_count,
                          "eroding_time_h": round(self.blisk_eroding_time / 3600.0, 2),
                          "electrodes_needed": {e.label: e.electrodes_per_blisk for e in self.electrodes}},
                "reference": "Liu et al. 2024: 4.07 to 4.25 h per channel, 249.3 h for a 60-channel shrouded "
                             "blisk (another blisk and machine: set beside, not compared)",
                "volume_resolution_mm": self.resolution, "volume_accuracy": self.accuracy, "blank": self.blank,
                "process": self.process.to_dict(), "seconds": round(self.seconds, 2)}

    def summary(self):
        """A few lines for logs and the CLI."""
        lines = [f"process (model estimates): channel {self.channel_removed_volume:.0f} mm^3 removed "
                 f"[{self.volume_lower:.0f}, {self.volume_upper:.0f}] (cavity {self.cavity_volume:.0f} mm^3), eroding {self.channel_eroding_time / 3600:.2f} h per "
                 f"channel, {self.blisk_eroding_time / 3600:.1f} h for the {self.blade_count}-channel blisk "
                 f"(Liu et al. 2024: 4.07-4.25 h per channel on another blisk)"]
        for e in self.electrodes:
            lines.append(f"  {e.label:14s} {e.regime:6s} {e.removed_volume:8.0f} mm^3 "
                         f"[{e.removed_volume_lower:.0f}, {e.removed_volume_upper:.0f}]  "
                         f"{e.eroding_time / 3600:6.2f} h  wear {e.wear_volume:6.1f} mm^3, front "
                         f"{e.frontal_wear:.3f} mm, worst face {e.worst_face_wear:.3f} mm per channel (limit "
                         f"{e.wear_limit:g} mm): {e.electrodes_per_channel}/channel, {e.electrodes_per_blisk}/blisk")
            c = e.compensation
            if c and c["depths_mm"]:
                lines.append(f"  {'':14s} wear compensation: the cycle moved 0 .. {c['depths_mm'][-1]:.4f} mm along "
                             f"the front over {c['channels_per_electrode']} channel(s), then a fresh electrode")
            elif c:
                lines.append(f"  {'':14s} no wear compensation: {c['note']}")
        return "\n".join(lines)


@numba.njit(cache=True)
def _raster(uv, faces, lo, pixel, nx, ny):
    """Pixels (centres) of an nx x ny grid covered by any projected triangle."""
    covered = np.zeros((nx, ny), dtype=np.bool_)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        x0, y0, x1, y1 = uv[a, 0], uv[a, 1], uv[b, 0] - uv[a, 0], uv[b, 1] - uv[a, 1]
        x2, y2 = uv[c, 0] - uv[a, 0], uv[c, 1] - uv[a, 1]
        det = x1 * y2 - y1 * x2
        if abs(det) < 1e-18:
            continue                                  # a triangle seen edge-on covers nothing
        i0 = max(0, int((min(uv[a, 0], uv[b, 0], uv[c, 0]) - lo[0]) / pixel) - 1)
        i1 = min(nx - 1, int((max(uv[a, 0], uv[b, 0], uv[c, 0]) - lo[0]) / pixel) + 1)
        j0 = max(0, int((min(uv[a, 1], uv[b, 1], uv[c, 1]) - lo[1]) / pixel) - 1)
        j1 = min(ny - 1, int((max(uv[a, 1], uv[b, 1], uv[c, 1]) - lo[1]) / pixel) + 1)
        for i in range(i0, i1 + 1):
            qx = lo[0] + (i + 0.5) * pixel - x0
            for j in range(j0, j1 + 1):
                qy = lo[1] + (j + 0.5) * pixel - y0
                s = (qx * y2 - qy * x2) / det
                t = (x1 * qy - y1 * qx) / det
                if s >= 0.0 and t >= 0.0 and s + t <= 1.0:
                    covered[i, j] = True
    return covered


def silhouette_area(vertices, faces, direction, pixel=0.05):
    """Area of the mesh's silhouette seen along ``direction`` [mm^2]: its projected triangles rasterised on a
    ``pixel`` grid (exact to about the outline's length x pixel / 2)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    a = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    uv = np.ascontiguousarray(np.asarray(vertices, float) @ np.column_stack([a, b]))
    lo = uv.min(axis=0)
    nx, ny = (np.ceil((uv.max(axis=0) - lo) / pixel).astype(int) + 1)
    covered = _raster(uv, np.ascontiguousarray(np.asarray(faces, dtype=np.int64)), lo, float(pixel), int(nx), int(ny))
    return float(covered.sum()) * pixel * pixel


_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")


def leg_direction(run, leg):
    """Unit direction of the electrode's motion over a leg, in the electrode frame (the feed: over its last
    20 samples, the way the front meets the material at the end), or None for a leg that does not move it."""
    s = np.asarray(leg.samples, float)
    if leg.phase == "feed":
        s = s[max(0, len(s) - 21):]
    poses = axis_poses(run.final_pose, run.axis_names, s[[0, -1]])
    centre = np.asarray(run.vertices, float).mean(axis=0)
    move = poses[1][:3, :3] @ centre + poses[1][:3, 3] - (poses[0][:3, :3] @ centre + poses[0][:3, 3])
    step = poses[0][:3, :3].T @ move
    n = np.linalg.norm(step)
    return step / n if n > 1e-12 else None


def _face(direction):
    k = int(np.argmax(np.abs(direction)))
    return _AXES[2 * k + (0 if direction[k] > 0 else 1)]


def face_wear(run, regime):
    """Wear depth per leading face [mm] of one electrode's legs (removed_volume set): {face: depth}, where the
    feed's face is called ``front``; and the silhouette area of each face [mm^2]."""
    depth, areas, cache = {}, {}, {}
    front = None
    for leg in run.cycle.legs:
        if not leg.regime or not leg.removed_volume > 0:
            continue
        d = leg_direction(run, leg)
        if d is None:
            continue
        face = _face(d)
        if leg.phase == "feed":
            front = face
        key = (face, tuple(np.round(d, 1)))
        if key not in cache:
            cache[key] = silhouette_area(run.vertices, run.faces, d)
        wear = leg.removed_volume * regime.wear_ratio / 100.0
        depth[face] = depth.get(face, 0.0) + wear / cache[key]
        areas[face] = cache[key]
    names = {f: ("front" if f == front else f"face {f}") for f in depth}
    return {names[f]: v for f, v in depth.items()}, {names[f]: a for f, a in areas.items()}


def compensation_schedule(e, max_compensated_wear, blade_count, has_front=True):
    """Wear compensation by feed depth for one electrode: its schedule, and its counts updated.

    The control runs the j-th channel of an electrode's life with the electrode moved along its front by
    the wear the front has taken before that channel, ``j x frontal_wear`` (never more than the wear
    already done: :meth:`~edm_planner.machining.cycle.MachiningCycle.with_compensation_depth`). Within a
    channel the wear still grows by one channel's, so every face must keep within its limit over one
    channel (``e.electrodes_per_channel == 1``); across channels the front may wear up to
    ``max_compensated_wear`` and every other face up to ``e.wear_limit``. The electrode lasts L channels,
    the fewest any face allows, and the blisk needs ceil(N / L).

    Sets ``e.compensation`` ({depths_mm, channels_per_electrode, note}) and, where compensation applies,
    ``e.electrodes_per_blisk``; returns the depths (empty: no compensation, and why in the note).
    """
    front = e.face_wear.get("front", 0.0)
    sides = max((v for k, v in e.face_wear.items() if k != "front"), default=0.0)
    depths, life = [], 0
    if not has_front or front <= 0:
        note = "the feed removes nothing: no front wear to compensate"
    elif e.electrodes_per_channel > 1:
        note = (f"a face wears {e.worst_face_wear:.4f} mm in one channel, more than its {e.wear_limit:g} mm limit: "
                f"the electrode is redressed within the channel, compensation between channels does not help")
    else:
        life_front = math.floor(max_compensated_wear / front + 1e-9)
        life_sides = math.floor(e.wear_limit / sides + 1e-9) if sides > 0 else blade_count
        life = max(0, min(life_front, life_sides, blade_count))
        if life == 0:
            note = f"the front wears {front:.4f} mm per channel, more than max_compensated_wear {max_compensated_wear:g} mm"
        else:
            depths = [j * front for j in range(life)]
            e.electrodes_per_blisk = math.ceil(blade_count / life)
            why = ("every channel done" if life == blade_count else
                   "its front reaches max_compensated_wear" if life == life_front else "a side face reaches its limit")
            note = f"the cycle moved along the front by its wear, channel after channel; replaced after {life} channel(s): {why}"
    e.compensation = {"depths_mm": [round(float(d), 5) for d in depths], "channels_per_electrode": life,
                      "max_compensated_wear_mm": max_compensated_wear, "note": note}
    return depths


def _cuts(runs, process):
    """One Cut per leg that may erode, and where each cut's result goes (run index, leg index); a leg that
    retraces earlier ones (:func:`~edm_planner.machining.proof_path.proof_legs`) erodes nothing."""
    cuts, where = [], []
    for i, run in enumerate(runs):
        gap = process.regimes[run.regime].spark_gap
        kept = {id(leg) for leg in proof_legs(run.cycle)}
        for j, leg in enumerate(run.cycle.legs):
            if leg.phase in CUTTING_PHASES and id(leg) in kept:
                poses = axis_poses(run.final_pose, run.axis_names, np.asarray(leg.samples, dtype=np.float64))
                cuts.append(Cut(f"{run.label}/{j}", np.asarray(run.vertices, float), np.asarray(run.faces),
                                poses, gap))
                where.append((i, j))
    return cuts, where


def _electrode_brackets(result, per_run):
    """Per electrode a certified bracket of its removed volume: the sum of its cuts' lower bounds (their
    removals are disjoint), and the total's upper bound less every other electrode's lower bound (tighter
    than the sum of its cuts' upper bounds, whose uncertain bands overlap)."""
    lows = [sum(c.lower for c in cvs) for cvs in per_run]
    out = []
    for i, cvs in enumerate(per_run):
        high = min(sum(c.upper for c in cvs), result.total_upper - (sum(lows) - lows[i]))
        out.append((lows[i], max(high, lows[i])))
    return out


def plan_process(blisk, runs, process, resolution=0.5, stock_mesh=None, progress=None):
    """Removed volume, erosion time and wear of a channel's electrodes; the legs get volume and regime.

    Parameters
    ----------
    blisk : Blisk
    runs : list of ProcessRun
        Machining order.
    process : ProcessModel
    resolution : float
        Voxel size of the volume field [mm].
    stock_mesh : MeshBlank, optional
        A pre-machined stock (closed mesh, W frame; :func:`~.volume.load_stock_mesh`) instead of the solid
        channel.
    progress : callable, optional
        ``progress(message)``.

    Returns
    -------
    ProcessReport
    """
    t0 = time.perf_counter()
    for run in runs:
        if run.regime not in process.regimes:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"electrode {run.label}: regime {run.regime!r} is not in the "
                                                      f"process model ({sorted(process.regimes)})")
    cuts, where = _cuts(runs, process)
    if progress:
        progress(f"removed volume of {len(cuts)} legs at {resolution:g} mm")
    blank = AnnulusBlank.from_blisk(blisk) if stock_mesh is None else stock_mesh
    result = removed_volumes(blank, cuts, resolution=resolution, max_travel=resolution / 4)
    for run in runs:
        for leg in run.cycle.legs:
            leg.removed_volume, leg.regime = 0.0, ""          # retraced and non-cutting legs remove nothing
    per_run = [[] for _ in runs]
    for cv, (i, j) in zip(result.cuts, where):
        leg = runs[i].cycle.legs[j]
        leg.removed_volume = float(cv.volume)
        leg.regime = runs[i].regime if cv.volume > 0 else ""
        per_run[i].append(cv)
    electrodes = []
    bracket = _electrode_brackets(result, per_run)
    for run, cvs, (low, high) in zip(runs, per_run, bracket):
        regime = process.regimes[run.regime]
        volume = sum(c.volume for c in cvs)
        eroding = sum(regime.erosion_seconds(leg.removed_volume) for leg in run.cycle.legs if leg.regime)
        faces, areas = face_wear(run, regime)
        worst = max(faces.values(), default=0.0)
        limit = process.wear_limit(regime.name)
        electrodes.append(ElectrodeProcess(
            run.label, regime.name, regime.condition_code, volume, low, high, eroding,
            volume * regime.wear_ratio / 100.0, areas.get("front", float("nan")), faces.get("front", 0.0), faces,
            limit, max(1, math.ceil(worst / limit - 1e-12)), max(1, math.ceil(blisk.blade_count * worst / limit - 1e-12)),
            [(leg.phase, leg.label, float(leg.removed_volume), regime.erosion_seconds(leg.removed_volume))
             for leg in run.cycle.legs if leg.regime]))
    report = ProcessReport(electrodes, blisk.blade_count, result.total, sum(e.eroding_time for e in electrodes),
                           channel_cavity_volume(blisk), resolution, result.total_lower, result.total_upper,
                           result.to_dict().get("accuracy", ""), process,
                           time.perf_counter() - t0)
    if stock_mesh is not None:
        report.blank = f"a pre-machined stock mesh ({len(stock_mesh.faces)} triangles)"
    _log.info("%s", report.summary())
    return report
