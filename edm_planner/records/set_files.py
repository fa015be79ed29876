"""The files of an electrode set: its plan exports, set.json, the stock maps (PNG and GLB) and the process plot.

:func:`write_set` writes a set just designed (an
:class:`~edm_planner.machining.electrode_set.ElectrodeSet`), and keeps its plans in the plan store;
:func:`write_stored_set` writes one read back from the store (its plans and stored ``set.json``
meta, without the proof's arrays: no new stock map); :func:`write_stock_glb` colours the channel's surfaces
by the stock left. The designer (:mod:`edm_planner.machining.electrode_set`) writes no file.
No rclpy. Units: mm, rad, s.
"""

import json
import pathlib

import trimesh

from ..errors import EdmError, ErrorCode
from .plan_export import json_safe, write_plan
from .stock_maps import plot_stock_maps, stock_vertex_colours
from .store import PlanStoreError, plan_to_stored


def write_set(result, out_dir, blisk, store=None, channels=None, cache_dir=None):
    """Write a designed set: one plan export per electrode (with its cycle), set.json and the stock maps.

    Parameters
    ----------
    result : ElectrodeSet
    out_dir : path
        ``<out>/<label>/`` per electrode (in machining order), ``<out>/set.json``,
        ``<out>/stock.png`` (the chosen set's stock maps).
    blisk : Blisk
    store : PlanStore, optional
        The chosen pieces' plans (with their cycles) are kept there, after
        every file is written: a store that cannot take them (a full disk)
        loses no file; :class:`~.store.PlanStoreError` is raised
        at the end, naming the plans not kept.
    channels : list of int, optional
        The channels the set may machine (``set.json`` ``channels``): on a blisk as measured, the group of
        channels whose walls agree with the designed one's (``LoadedGeometry.channel_groups``); None: all.
    cache_dir : path, optional
        Where the exports' workpiece deviations are kept (:func:`.plan_export.write_plan`); None: measured anew.

    Returns
    -------
    pathlib.Path
        set.json.
    """
    out = pathlib.Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"cannot write the electrode set to {out}: {exc}") from exc
    doc = json_safe(result.to_dict())
    doc["format"] = "edm_planner.electrode_set/1"
    doc["units"] = {"length": "mm", "angle": "rad", "time": "s"}
    if channels is not None:
        doc["channels"] = sorted(int(k) for k in channels)
    chosen = result.delivered
    if chosen is not None:
        doc["electrodes"] = []
        for order, piece in enumerate(chosen.pieces):
            path = write_plan(piece.plan, out / piece.label, blisk, cache_dir=cache_dir)
            doc["electrodes"].append({"order": order, "label": piece.label, "plan_id": piece.plan.plan_id,
                                      "regime": piece.regime, "export": str(path.parent.relative_to(out))})
        if chosen.process is not None:
            from .plots import process_plot     # matplotlib at its top: heavy, only to draw

            process_plot(chosen.process, out / "process.png")
            doc["process"] = dict(json_safe(chosen.process.to_dict()), plot="process.png")
    # the chosen set's stock, or the closest candidate's: where the stock stays is what an engineer asks next
    proven = [c for c in result.candidates if c.removal is not None]
    shown = chosen if chosen is not None else min(
        proven, key=lambda c: max(w.area_fraction_beyond_inherent for w in c.removal.surfaces.values()),
        default=None)
    if shown is not None and shown.removal is not None:
        plot_stock_maps(shown.removal, out / "stock.png")
        write_stock_glb(shown.removal, blisk, result.channel, out / "stock.glb")
        doc["stock_map"] = {"file": "stock.png", "glb": "stock.glb", "candidate": shown.name}
    path = _write_set_json(out, doc)
    if store is not None and chosen is not None:
        failed = []
        for piece in chosen.pieces:
            try:
                store.put(plan_to_stored(piece.plan))
            except PlanStoreError as exc:
                failed.append(exc.message)
        if failed:
            raise PlanStoreError(f"the set is written to {out}, but {len(failed)} of its {len(chosen.pieces)} "
                                 f"plans are not kept in the plan store: {failed[0]}")
    return path


def write_stored_set(plans, labels, meta, out_dir, blisk, cache_dir=None):
    """Write a set kept in the plan store: its plan exports and set.json (``meta``, as stored).

    The stock map needs the proof's arrays, which the store does not keep: an
    existing ``stock.png`` of the same set (same directory) is left in place.
    """
    out = pathlib.Path(out_dir)
    doc = dict(json_safe(meta), format="edm_planner.electrode_set/1",
               units={"length": "mm", "angle": "rad", "time": "s"})
    doc["electrodes"] = []
    for order, (plan, label) in enumerate(zip(plans, labels)):
        path = write_plan(plan, out / label, blisk, cache_dir=cache_dir)
        doc["electrodes"].append({"order": order, "label": label, "plan_id": plan.plan_id,
                                  "export": str(path.parent.relative_to(out))})
    if (out / "stock.png").exists():
        doc["stock_map"] = {"file": "stock.png", "candidate": meta.get("delivered")}
    return _write_set_json(out, doc)


def write_stock_glb(report, blisk, channel, path, resolution=0.25):
    """The channel's four surfaces coloured by the stock left (the stock maps' colours), as GLB."""
    scene = trimesh.Scene()
    transform = blisk.channel_transform(channel)
    for name, mesh in blisk.channel_meshes(channel, resolution).items():
        m = mesh.copy()
        m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=stock_vertex_colours(m, report, name,
                                                                                     transform=transform))
        scene.add_geometry(m, node_name=f"{name} (stock)")
    scene.export(path)
    return path


def _write_set_json(out, doc):
    path = out / "set.json"
    try:
        path.write_text(json.dumps(doc, indent=1, allow_nan=False))
    except OSError as exc:
        raise EdmError(ErrorCode.FILE_ERROR, f"cannot write {path}: {exc}") from exc
    return path
