"""Pictures of a plan: axis curves, clearances along the path, the electrode in the channel.

Plain matplotlib (Agg backend, files only) and trimesh; no rclpy. Units: mm, rad, s.
"""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the file-only backend)
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from ..interference import SURFACES  # noqa: E402

_UNIT = {"X": "mm", "Y": "mm", "Z": "mm", "A": "rad", "B": "rad", "C": "rad"}
_COLOURS = {"suction": "tab:blue", "pressure": "tab:orange", "hub": "tab:green", "shroud": "tab:red"}


def axis_curves(x, values, axis_names, path, xlabel, title, marks=()):
    """One panel per axis: ``values`` (n, k) against ``x`` (n,); written to ``path`` (PNG).

    ``marks``: (label, x) pairs drawn as labelled vertical lines (the phases of a cycle).
    """
    values = np.asarray(values)
    fig, axes = plt.subplots(len(axis_names), 1, figsize=(8, 1.8 * len(axis_names)), sharex=True)
    for k, (ax, name, col) in enumerate(zip(np.atleast_1d(axes), axis_names, values.T)):
        ax.plot(x, col, lw=1.2)
        for label, at in marks:
            ax.axvline(at, color="0.5", lw=0.7, ls=":")
            if k == 0:
                ax.annotate(label, (at, 1.0), xycoords=("data", "axes fraction"), fontsize=7, rotation=90,
                            va="bottom", ha="right")
        # planner axes (X .. C) or machine joints named after them (edm_x .. edm_c)
        ax.set_ylabel(f"{name} [{_UNIT.get(name) or _UNIT.get(name[-1:].upper(), '')}]")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[-1].set_xlabel(xlabel)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def clearance_plot(x, clearances, margins, path, kind, xlabel="sample (feed order)"):
    """Per-surface clearance (n, 4) along the path with the margins; written to ``path`` (PNG).

    ``kind`` says what the values are, e.g. "fast values, exact within +-3.5 um" (in the title).
    """
    clearances = np.asarray(clearances)
    fig, ax = plt.subplots(figsize=(8, 4))
    for j, name in enumerate(SURFACES):
        ax.plot(x, clearances[:, j], lw=1.2, label=name, color=_COLOURS[name])
        ax.axhline(margins[j], color=_COLOURS[name], lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_ylabel("clearance [mm] (dashed: margins)")
    ax.set_xlabel(xlabel)
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3, which="both")
    ax.set_title(f"Smallest clearance of the electrode to each channel surface\n({kind})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def channel_scene(workpiece, electrode_mesh, poses, count=12):
    """trimesh Scene: the channel surfaces and the electrode at ``count`` poses spread along the path.

    Parameters
    ----------
    workpiece : dict
        surface name -> trimesh.Trimesh in W [mm].
    electrode_mesh : trimesh.Trimesh
        In the electrode frame [mm].
    poses : (N, 4, 4) float
        Electrode frame -> W.
    """
    scene = trimesh.Scene()
    for name, mesh in workpiece.items():
        m = mesh.copy()
        rgb = (np.array(matplotlib.colors.to_rgb(_COLOURS[name])) * 255).astype(np.uint8)
        m.visual.face_colors = np.append(rgb, 110)
        scene.add_geometry(m, node_name=name)
    idx = np.unique(np.linspace(0, len(poses) - 1, min(count, len(poses))).astype(int))
    for i in idx:
        e = electrode_mesh.copy()
        e.apply_transform(poses[i])
        e.visual.face_colors = [184, 115, 51, 90 if i != idx[-1] else 255]      # copper; solid at the end
        scene.add_geometry(e, node_name=f"electrode_{i}")
    return scene


def channel_view(workpiece, electrode_mesh, poses, glb_path, png_path, count=12):
    """The electrode's swept positions in the channel: an interactive GLB and a PNG."""
    scene = channel_scene(workpiece, electrode_mesh, poses, count)
    scene.export(glb_path)
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    for name, mesh in workpiece.items():
        faces = mesh.vertices[mesh.faces[:: max(1, len(mesh.faces) // 3000)]]
        ax.add_collection3d(Poly3DCollection(faces, alpha=0.15, facecolor=_COLOURS[name], edgecolor="none"))
    idx = np.unique(np.linspace(0, len(poses) - 1, min(count, len(poses))).astype(int))
    outline = electrode_mesh.vertices[electrode_mesh.faces[:: max(1, len(electrode_mesh.faces) // 400)]]
    for i in idx:
        tri = outline @ poses[i][:3, :3].T + poses[i][:3, 3]
        ax.add_collection3d(Poly3DCollection(tri, alpha=0.5 if i == idx[-1] else 0.12, facecolor="#b87333",
                                             edgecolor="none"))
    origin = poses[:, :3, 3]
    ax.plot(origin[:, 0], origin[:, 1], origin[:, 2], color="k", lw=1.0, label="electrode origin path")
    pts = np.vstack([m.vertices for m in workpiece.values()] + [origin])
    centre, half = pts.mean(axis=0), 0.5 * np.ptp(pts, axis=0).max()
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_xlabel("X [mm]")
    ax.set_ylabel("Y [mm]")
    ax.set_zlabel("Z [mm]")
    ax.legend(loc="upper left")
    ax.set_title("Electrode feed path in the channel (copper: sampled poses, solid: machining pose)")
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
    return glb_path, png_path


def process_plot(report, path):
    """The process of a channel's set (model estimates): eroding time per electrode and phase, coloured by
    regime, and each electrode's frontal wear per channel against the wear it may take."""
    electrodes = report.electrodes
    labels = [e.label for e in electrodes]
    phases = sorted({p for e in electrodes for p, *_ in e.legs})
    colours = {"rough": "tab:red", "finish": "tab:blue"}
    fig, (ax_t, ax_w) = plt.subplots(1, 2, figsize=(13, 0.6 * len(labels) + 2.2))
    y = np.arange(len(labels))
    left = np.zeros(len(labels))
    for k, phase in enumerate(phases):
        hours = np.array([sum(t for p, _, _, t in e.legs if p == phase) / 3600.0 for e in electrodes])
        ax_t.barh(y, hours, left=left, color=[colours.get(e.regime, "0.5") for e in electrodes],
                  alpha=1.0 - 0.35 * k, edgecolor="k", lw=0.5, label=phase)
        for yi, l, h in zip(y, left, hours):
            if h > 0.02 * max(report.channel_eroding_time / 3600.0, 1e-9):
                ax_t.text(l + h / 2, yi, phase, ha="center", va="center", fontsize=7)
        left += hours
    ax_t.set_yticks(y, [f"{e.label} ({e.regime}, {e.condition_code})" for e in electrodes])
    ax_t.invert_yaxis()
    ax_t.set_xlabel("eroding time per channel [h]")
    ax_t.set_title(f"channel {report.channel_eroding_time / 3600:.2f} h, blisk "
                   f"{report.blisk_eroding_time / 3600:.1f} h ({report.blade_count} channels)", fontsize=9)
    ax_t.grid(axis="x", alpha=0.3)
    wear = [e.worst_face_wear for e in electrodes]
    ax_w.barh(y, wear, color=[colours.get(e.regime, "0.5") for e in electrodes], edgecolor="k", lw=0.5)
    for yi, e in zip(y, electrodes):
        ax_w.plot([e.wear_limit] * 2, [yi - 0.4, yi + 0.4], color="k", ls="--", lw=1)
        ax_w.text(e.worst_face_wear, yi, f" {e.electrodes_per_channel}/channel, {e.electrodes_per_blisk}/blisk "
                                         f"(limit {e.wear_limit:g} mm, dashed)", va="center", fontsize=7)
    ax_w.set_xlim(0.0, 2.2 * max(wear + [e.wear_limit for e in electrodes]))     # room for the counts
    ax_w.set_yticks(y, labels)
    ax_w.invert_yaxis()
    ax_w.set_xlabel("wear of the worst face per channel [mm]")
    ax_w.set_title("electrode wear (model estimate)", fontsize=9)
    ax_w.grid(axis="x", alpha=0.3)
    fig.suptitle("EDM process of the channel (model estimates from the machine's process section)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
