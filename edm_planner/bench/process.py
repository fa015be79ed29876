"""Bench suite ``process`` (issue 25): the removed-volume field's accuracy against resolution, and its cost.

Two parts:

* **closed forms** -- a box electrode (20 x 6 x 12 mm, gap 0.25 mm, tilted 7 deg so that no face lines up with
  the voxels) plunged 8 mm into a block, and a cylinder electrode (radius 3 mm, 20 mm long, gap 0.25 mm)
  turned 30 deg about a parallel axis 110 mm away: the exact volume against the estimate and the certified
  bracket at resolutions 1, 0.5, 0.25 and 0.125 mm, with the seconds each took;
* **blisks** -- the delivered electrode set of channel 0 of each configured blisk (designed with the machine's
  process section, or taken from the ``electrode_set`` suite's run when it ran first in the same process):
  the channel's removed volume, its bracket and the seconds at resolutions 1 and 0.5 mm (and 0.25 mm on the
  default blisk), beside the
  channel's cavity volume (quadrature of its walls, :func:`~edm_planner.process.volume.channel_cavity_volume`),
  and the process report at the default resolution (eroding time per channel and blisk, wear, electrodes).

Every figure names what it is: exact (closed form), a voxel estimate, a certified bracket, or a model estimate.
"""

import logging
import math
import time

import numpy as np
import trimesh

from ..cli import DEFAULT_CACHE
from ..geometry.loader import load_geometry
from ..interference.fast import FastChannelField
from ..cnc.config import load_machine
from ..machining.electrode_set import SetDesigner
from ..process.report import ProcessRun, plan_process
from ..process.set_process import add_process
from ..process.volume import Cut, MeshBlank, channel_cavity_volume, removed_volumes
from .common import BLISKS, CONFIG, DESIGNED

_log = logging.getLogger(__name__)

RESOLUTIONS = (1.0, 0.5, 0.25, 0.125)
#: per blisk: the default's channel also at 0.25 mm (32 s); Rotor 37's and the mesh blisk's larger channels
#: take 30 M voxels and many minutes there
BLISK_RESOLUTIONS = {"default_blisk": (1.0, 0.5, 0.25), "rotor37": (1.0, 0.5), "mesh_blisk": (1.0, 0.5)}

#: the sets designed by bench_electrode_set in this process (name -> ElectrodeSet), reused here
def _rot(axis, angle):
    """4x4 rotation by ``angle`` about the coordinate axis ``axis`` (0, 1, 2)."""
    return trimesh.transformations.rotation_matrix(angle, np.eye(3)[axis])


def _box_volume_grown(a, b, c, g):
    """Volume of an a x b x c box grown by a ball of radius g (Steiner's formula)."""
    return a * b * c + 2 * g * (a * b + b * c + c * a) + math.pi * g * g * (a + b + c) + 4 / 3 * math.pi * g ** 3


def closed_forms(resolutions=RESOLUTIONS):
    """The plunge and the rotation sweep, exact against estimate and bracket per resolution."""

    a, b, c, g = 20.0, 6.0, 12.0, 0.25
    box = trimesh.creation.box((a, b, c))
    tilt = _rot(2, math.radians(7.0))          # about the plunge direction: no face lines up with the voxels
    # plunge: the grown box K starts with its bottom on the block's top face z = 0 and moves D down. Along
    # each vertical line of its shadow (area A, the rounded a x b rectangle) the sweep below z = 0 is
    # [z_lo - D, 0], z_lo the height of K's bottom there: 0 under the flat bottom, g - sqrt(g^2 - s^2) on
    # the rounded rim. V = D A - (2 (a + b) g^2 (1 - pi/4) + pi g^3 / 3).
    depth = c + 2 * g + 8.0
    shadow = a * b + 2 * g * (a + b) + math.pi * g * g
    exact_plunge = depth * shadow - (2 * (a + b) * g * g * (1 - math.pi / 4) + math.pi * g ** 3 / 3)
    block = trimesh.creation.box((80.0, 60.0, 80.0))
    block.apply_translation((0.0, 0.0, -40.0))
    start = c / 2 + g
    poses = []
    for z in np.linspace(start, start - depth, 241):
        p = tilt.copy()
        p[2, 3] = z
        poses.append(p)
    plunge = [Cut("plunge", np.asarray(box.vertices), np.asarray(box.faces), np.array(poses), g)]
    # rotation: a cylinder electrode (radius R, length L, its axis parallel to X, 110 mm from it) turned 30
    # deg about X. Every section of the grown cylinder across X is a disk of radius rho(x) (R + g along the
    # cylinder, R + sqrt(g^2 - s^2) over its rounded ends, s beyond an end) centred r0 from the axis, which a
    # circle about the axis meets in one arc; the section sweeps the disk plus the annulus sector of the
    # turn: V = integral of (pi rho^2 + 2 r0 turn rho) dx = pi (R+g)^2 L + 2 pi (R^2 g + pi R g^2 / 2
    # + 2 g^3 / 3) + 2 r0 turn (L (R + g) + 2 R g + pi g^2 / 2). (A box's far corners would make two arcs.)
    R, L, r0, turn = 3.0, 20.0, 110.0, math.radians(30.0)
    cyl = trimesh.creation.cylinder(radius=R, height=L, sections=256)
    cyl.apply_transform(_rot(1, math.pi / 2))                 # its axis along X
    ring = trimesh.creation.annulus(r_min=90.0, r_max=130.0, height=60.0, sections=256)
    ring.apply_transform(_rot(1, math.pi / 2))
    centre = np.eye(4)
    centre[1, 3] = r0
    rposes = np.array([_rot(0, t) @ centre for t in np.linspace(0.0, turn, 601)])
    rot = [Cut("rotation", np.asarray(cyl.vertices), np.asarray(cyl.faces), rposes, g)]
    exact_rotation = (math.pi * (R + g) ** 2 * L + 2 * math.pi * (R * R * g + math.pi * R * g * g / 2 + 2 * g ** 3 / 3)
                      + 2 * r0 * turn * (L * (R + g) + 2 * R * g + math.pi * g * g / 2))
    # the 256-gon's section is smaller than the disk by about R^2 (pi - 256 sin(pi / 128) / 2) = 0.009 mm^2
    cases = {"plunge": (MeshBlank(np.asarray(block.vertices), np.asarray(block.faces)), plunge, exact_plunge),
             "rotation": (MeshBlank(np.asarray(ring.vertices), np.asarray(ring.faces)), rot, exact_rotation)}
    out = {}
    for name, (blank, cuts, exact) in cases.items():
        rows = []
        for res in resolutions:
            t = time.perf_counter()
            r = removed_volumes(blank, cuts, resolution=res)
            rows.append({"resolution_mm": res, "estimate_mm3": round(r.total, 2),
                         "error_percent": round(100 * (r.total - exact) / exact, 3),
                         "bracket_mm3": [round(r.total_lower, 1), round(r.total_upper, 1)],
                         "exact_within_bracket": bool(r.total_lower <= exact <= r.total_upper),
                         "voxels": r.voxels, "seconds": round(time.perf_counter() - t, 2)})
        out[name] = {"exact_mm3": round(exact, 2), "by_resolution": rows}
        _log.warning("process volume %s: exact %.1f mm^3: %s", name, exact, rows)
    return out


def _design(name, path, process):
    if name in DESIGNED:
        return DESIGNED[name]
    g = load_geometry(path)
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=DEFAULT_CACHE, cache_key=g.geometry_id)
    result = SetDesigner(g, field, field_cache=(DEFAULT_CACHE, g.geometry_id), process=process,
                         process_step=add_process).design(0)
    DESIGNED[name] = (g, result)
    return g, result


def blisks(names=None, resolutions=BLISK_RESOLUTIONS):
    """Per configured blisk: the delivered set's removed volume against resolution, and its process report."""

    process = load_machine(CONFIG / "machine.yaml").process
    out = {}
    for name in names or ("default_blisk", "rotor37", "mesh_blisk"):
        g, result = _design(name, BLISKS[name], process)
        chosen = result.delivered
        if chosen is None:
            out[name] = {"delivered": None, "message": result.message[:300]}
            continue
        runs = [ProcessRun(p.label, p.regime, np.asarray(p.plan.electrode_mesh.vertices),
                             np.asarray(p.plan.electrode_mesh.faces), np.asarray(p.plan.final_pose),
                             tuple(p.plan.axis_names), p.cycle) for p in chosen.pieces]
        rows = []
        for res in resolutions[name]:
            rep = plan_process(g.blisk, runs, process, resolution=res)
            rows.append({"resolution_mm": res, "estimate_mm3": round(rep.channel_removed_volume, 1),
                         "bracket_mm3": [round(rep.volume_lower, 1), round(rep.volume_upper, 1)],
                         "seconds": round(rep.seconds, 2)})
        entry = {"delivered": chosen.name, "electrodes": [p.label for p in chosen.pieces],
                 "cavity_volume_mm3": round(channel_cavity_volume(g.blisk), 1), "volume_by_resolution": rows,
                 "process_at_0.5_mm": chosen.process.to_dict() if chosen.process is not None else None,
                 "roughing_allowance": chosen.allowance, "roughing_notes": list(chosen.roughing_notes)}
        out[name] = entry
        _log.warning("process %s: %s", name, rows)
    return out


def bench_process():
    return {"closed_forms": closed_forms(), "blisks": blisks(),
            "what": "closed forms: exact vs voxel estimate and certified bracket; blisks: voxel estimates with "
                    "their bracket, beside the cavity (quadrature); process figures are model estimates from "
                    "config/machine.yaml's process section"}
