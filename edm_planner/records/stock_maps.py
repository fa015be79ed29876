"""The stock maps: what the material-removal proof leaves on the channel's walls, as pictures and colours.

:func:`plot_stock_maps` draws the stock on the four channel surfaces (blade
walls in (x, r), hub and shroud unrolled in (x, r theta)) to one PNG;
:func:`stock_vertex_colours` colours a channel surface mesh the same way
(the electrode set's ``stock.glb``, :func:`~.set_files.write_stock_glb`).
Both take a :class:`~edm_planner.machining.removal.RemovalReport`.

matplotlib is imported inside the functions that draw (an optional, heavy
dependency). No rclpy. Units: mm.
"""

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.blisk import CHANNEL_SURFACES


_TITLES = {"suction": "suction wall", "pressure": "pressure wall", "hub": "hub (unrolled)",
           "shroud": "shroud (unrolled)"}


def stock_colour_scale(tolerance, stock_max, overcut_max):
    """Colour map and norm of the stock maps (no pyplot needed).

    Within +-tolerance ("done") near-white to pale green (a faint cyan tint
    below 0), overcut beyond the tolerance blue (deeper is darker), stock
    above the tolerance yellow -> orange -> red -> dark red. The bands keep
    fixed fractions of the colour bar whatever the range.

    Parameters
    ----------
    tolerance, stock_max, overcut_max : float
        [mm].

    Returns
    -------
    cmap : matplotlib Colormap
    norm : matplotlib Normalize
        Maps stock [mm] to 0..1.
    """
    from matplotlib.colors import FuncNorm, LinearSegmentedColormap  # heavy, optional: only to draw

    vmin = -max(overcut_max, 2.0 * tolerance)
    vmax = max(stock_max, 4.0 * tolerance)
    # colour-bar fractions where -tolerance, 0 and +tolerance fall
    a, z, b = 0.18, 0.30, 0.42
    xs, ys = np.array([vmin, -tolerance, 0.0, tolerance, vmax]), np.array([0.0, a, z, b, 1.0])
    norm = FuncNorm((lambda v: np.interp(v, xs, ys), lambda y: np.interp(y, ys, xs)), vmin=vmin, vmax=vmax)
    cmap = LinearSegmentedColormap.from_list("stock", [
        (0.0, "#08306b"), (a - 0.001, "#6baed6"),                 # overcut beyond tolerance: blue
        (a, "#d5eef3"), (z, "#f4fbf1"), (b, "#a1d99b"),           # within +-tolerance: done
        (b + 0.001, "#ffeda0"), (b + 0.25 * (1 - b), "#feb24c"),
        (b + 0.6 * (1 - b), "#f03b20"), (1.0, "#67000d")])        # stock above: yellow -> dark red
    return cmap.with_extremes(bad="#bdbdbd"), norm


def plot_stock_maps(report, path, tolerance=None):
    """Four stock maps in one PNG: blade walls in (x, r), hub and shroud unrolled in (x, r theta).

    Parameters
    ----------
    report : RemovalReport
    path : str or Path
        PNG to write.
    tolerance : float, optional
        [mm]; default the report's.

    Returns
    -------
    path
    """
    import matplotlib  # heavy, optional: only to draw

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tol = report.tolerance if tolerance is None else float(tolerance)
    cmap, norm = stock_colour_scale(tol, report.stock_max, report.overcut_max)
    fig, axes = plt.subplots(2, 2, figsize=(13, 10), constrained_layout=True)
    for ax, name in zip(axes.ravel(), CHANNEL_SURFACES):
        s = report.surfaces[name]
        mesh = ax.pcolormesh(s.u, s.v, np.ma.masked_invalid(s.stock), cmap=cmap, norm=norm,
                             shading="nearest", rasterized=True)
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("r [mm]" if name in ("suction", "pressure") else "r·θ [mm]")
        above = 100.0 * s.area_fraction_above_tolerance
        beyond = ("" if np.isnan(s.area_fraction_beyond_inherent)
                  else f" ({100.0 * s.area_fraction_beyond_inherent:.2f} % beyond the corner rounding)")
        ax.set_title(f"{_TITLES[name]}: stock max {s.stock_max:.3f}, mean {s.stock_mean:.4f} mm\n"
                     f"{above:.2f} % of area above {tol:g} mm{beyond}, overcut max {s.overcut_max:.3f} mm",
                     fontsize=10)
    ticks = sorted({norm.vmin, -tol, 0.0, tol, *np.linspace(tol, norm.vmax, 5)[1:]})
    bar = fig.colorbar(mesh, ax=axes, shrink=0.85, ticks=ticks)
    bar.set_label(f"stock left [mm]   (blue: overcut, green: done within ±{tol:g} mm, warm: stock above)")
    bar.ax.set_yticklabels([f"{t:.3f}" for t in ticks])
    verdict = ("every sample within" if report.every_sample_within_tolerance
               else "not every sample within")
    fig.suptitle(
        f"Stock after EDM ({verdict} ±{tol:g} mm of the sharp-cornered channel) = min over {report.pose_count} pose(s) of distance to the "
        f"electrode less the gap {', '.join(f'{g:g}' for g in sorted(set(report.gap)))} mm\n"
        f"exact at wall samples ≤ {report.spacing:.2f} mm apart; continuous motion between poses "
        f"removes at most {report.continuous_bound:.4f} mm more", fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def stock_vertex_colours(mesh, report, surface, transform=None, tolerance=None):
    """RGBA vertex colours of a channel surface mesh by its nearest wall sample's stock.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        E.g. ``blisk.channel_meshes(k)[surface]``.
    report : RemovalReport
    surface : str
        'suction', 'pressure', 'hub' or 'shroud'.
    transform : (4, 4) float, optional
        Channel 0 -> the mesh's position (``blisk.channel_transform(k)``).
    tolerance : float, optional
        [mm]; default the report's.

    Returns
    -------
    (v, 4) uint8
        Same colour scale as :func:`plot_stock_maps`; grey where the mesh lies
        farther than two sample spacings from any sample (outside the sampled range).
    """
    tol = report.tolerance if tolerance is None else float(tolerance)
    cmap, norm = stock_colour_scale(tol, report.stock_max, report.overcut_max)
    smp = report.samples[surface]
    stock = report.surfaces[surface].stock.ravel()
    pts, stock = smp.points[smp.valid], stock[smp.valid]
    if transform is not None:
        t = np.asarray(transform, dtype=float)
        pts = pts @ t[:3, :3].T + t[:3, 3]
    d, i = cKDTree(pts).query(np.asarray(mesh.vertices))
    values = np.where(d <= 2.0 * report.spacing, stock[i], np.nan)
    return (np.asarray(cmap(norm(np.ma.masked_invalid(values)))) * 255).round().astype(np.uint8)
