"""What a channel becomes after EDM: the material-removal simulation and its report.

In EDM the material within the discharge gap g of the electrode is eroded,
so the channel after machining is the union, over every electrode and every
pose t, of the electrode E_t grown by g (its Minkowski sum with a ball of
radius g). At a point p of a final channel surface the stock left is

    stock(p) = min over electrodes, poses t of  sd(p, E_t) - g

with sd the signed distance to the closed electrode mesh (positive
outside). This is exact for the Minkowski sum: the distance from an outside
point to E + B(g) is d(p, E) - g. stock > 0 is material left, stock < 0 an
overcut of depth -stock.

The simulation is split by concern:

* :mod:`.mesh_distance` -- the exact signed distance to a closed mesh (:class:`MeshDistance`);
* :mod:`.swept_stock` -- the stock electrode sweeps leave at points (:class:`Sweep`,
  :func:`stock_at_points`: the exact minimum over every pose, pruned by branch and bound);
* :mod:`.wall_samples` -- the four channel surfaces sampled on grids (:func:`wall_samples`);
* :mod:`.corner_rounding` -- the stock an ideal electrode leaves in the concave corners
  (:func:`corner_rounding_stock`);
* :mod:`.removal_tolerances` -- the settings and tolerances of all of them (:data:`REMOVAL`);
* this module -- :func:`simulate_removal`, which applies them to the four surfaces of channel 0 and reports
  the stock per surface (:class:`RemovalReport`, :class:`SurfaceStock`).

The stock maps (``plot_stock_maps``, ``stock_vertex_colours``) are drawn by the records layer,
:mod:`edm_planner.records.stock_maps`; their old names here are deprecated aliases.

Plain numpy/scipy/trimesh/numba; no rclpy. Units: mm, rad, s.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from .. import deprecation
from .corner_rounding import CORNERS, corner_rounding_stock
from .mesh_distance import MeshDistance
from .removal_tolerances import REMOVAL, REMOVAL_EDGE_DEPTHS, RemovalTolerances
from .swept_stock import Sweep, _inverse, _poses, _step_travel, stock_at_points
from .wall_samples import WallSamples, wall_samples

__all__ = ["CORNERS", "REMOVAL", "REMOVAL_EDGE_DEPTHS", "MeshDistance", "RemovalReport", "RemovalTolerances",
           "SurfaceStock", "Sweep", "WallSamples", "corner_rounding_stock", "simulate_removal", "stock_at_points",
           "wall_samples"]


# -- the report --------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SurfaceStock:
    """Stock left on one channel surface.

    Attributes
    ----------
    surface : str
    stock : (rows, cols) float
        [mm] at the samples; NaN where the surface was not sampled (``valid`` false).
    u, v : (rows, cols) float
        Map coordinates [mm] (see :class:`WallSamples`).
    which : (rows, cols, 2) int
        (sweep, pose) attaining the stock.
    area : float
        Sampled area [mm^2].
    stock_max, stock_mean : float
        Largest and area-weighted mean stock [mm].
    area_fraction_above_tolerance : float
        Area fraction with stock > tolerance.
    inherent_max, area_fraction_beyond_inherent : float
        With an ``inherent`` stock or a ``reference`` in :func:`simulate_removal`
        (what an ideal electrode, the channel shrunk by the gap, leaves: the EDM
        corner rounding, radius = gap, which no electrode can avoid in a
        concave corner): its largest value, and the area fraction whose stock
        exceeds it by more than the tolerance (the electrode set's acceptance
        figure); NaN without.
    overcut_max : float
        max(0, -min stock) [mm].
    inherent : (rows, cols) float or None
        The inherent stock at the samples [mm] (NaN where not sampled).
    """

    surface: str
    stock: np.ndarray
    u: np.ndarray
    v: np.ndarray
    which: np.ndarray
    area: float
    stock_max: float
    stock_mean: float
    area_fraction_above_tolerance: float
    overcut_max: float
    inherent_max: float = float("nan")
    area_fraction_beyond_inherent: float = float("nan")
    inherent: np.ndarray = field(default=None, repr=False)

    def to_dict(self):
        return {
            "area_mm2": round(self.area, 2),
            "stock_max_mm": _mm(self.stock_max),
            "stock_mean_mm": _mm(self.stock_mean),
            "area_fraction_above_tolerance": round(self.area_fraction_above_tolerance, 5),
            "inherent_stock_max_mm": None if np.isnan(self.inherent_max) else _mm(self.inherent_max),
            "area_fraction_beyond_inherent": (None if np.isnan(self.area_fraction_beyond_inherent)
                                              else round(self.area_fraction_beyond_inherent, 5)),
            "overcut_max_mm": _mm(self.overcut_max),
        }


def _mm(value):
    # 0.1 um: far below every tolerance, above float noise
    return round(float(value), 4)


@dataclass(frozen=True, eq=False)
class RemovalReport:
    """The channel after EDM: stock on its four surfaces and how far to trust it.

    Attributes
    ----------
    surfaces : dict
        'suction', 'pressure', 'hub', 'shroud' -> :class:`SurfaceStock`.
    gap : tuple of float
        Discharge gap per sweep [mm].
    tolerance : float
        Stock (and overcut) accepted as finished [mm].
    every_sample_within_tolerance : bool
        Every sample within [-tolerance, tolerance] of the sharp-cornered
        channel (the strict figure; the corner rounding alone fails it). Not
        the electrode set's acceptance, which allows the corner rounding
        (``area_fraction_beyond_inherent``, :func:`..electrode_set.acceptance`).
    spacing : float
        Largest distance between neighbouring wall samples [mm].
    pose_count : int
        Poses over all sweeps.
    continuous_bound : float
        Half the largest travel of a sample point (in the electrode frame)
        between consecutive poses [mm]: the continuous motion between two
        poses can remove at most this much more than the poses themselves
        (if a point's path between them is no longer than its chord).
    exact : str
        What the values are.
    elapsed : float
        [s].
    inherent_reference : str
        What the inherent stock is ("" without one).
    queries : int
        Distance queries made (of sample count x pose count pairs).
    """

    surfaces: dict
    gap: tuple
    tolerance: float
    every_sample_within_tolerance: bool
    spacing: float
    pose_count: int
    continuous_bound: float
    exact: str
    elapsed: float
    queries: int = 0
    samples: dict = field(default=None, repr=False)
    inherent_reference: str = ""

    @property
    def stock_max(self):
        """Largest stock on any surface [mm]."""
        return max(s.stock_max for s in self.surfaces.values())

    @property
    def overcut_max(self):
        """Deepest overcut on any surface [mm]."""
        return max(s.overcut_max for s in self.surfaces.values())

    def to_dict(self):
        """JSON-safe summary (no arrays) for plan.json."""
        return {
            "every_sample_within_tolerance": bool(self.every_sample_within_tolerance),
            "tolerance_mm": _mm(self.tolerance),
            "discharge_gap_mm": [_mm(g) for g in self.gap],
            "stock_max_mm": _mm(self.stock_max),
            "overcut_max_mm": _mm(self.overcut_max),
            "surfaces": {name: s.to_dict() for name, s in self.surfaces.items()},
            "accuracy": {
                "sample_spacing_mm": _mm(self.spacing),
                "exact": self.exact,
                "continuous_bound_mm": _mm(self.continuous_bound),
                "inherent_reference": self.inherent_reference,
            },
            "pose_count": int(self.pose_count),
            "distance_queries": int(self.queries),
            "elapsed_s": round(self.elapsed, 2),
        }


def _stock_in_parts(points, sweeps, gap, executor, parts, stats):
    """``stock_at_points`` over interleaved parts of the points in an executor's processes, joined.

    Every point's minimum is its own (the pruning is exact per point), so the
    parts give the same stock as one call; interleaving keeps their work even.
    """
    if executor is None or parts < 2 or len(points) < 1000 * parts:
        return stock_at_points(points, sweeps, gap, stats=stats)
    sweeps = [(sw.vertices, sw.faces, sw.poses) for sw in sweeps]
    owner = np.arange(len(points)) % parts
    futures = [executor.submit(_stock_part, points[owner == i], sweeps, gap) for i in range(parts)]
    stock, which = np.empty(len(points)), np.empty((len(points), 2), dtype=np.int64)
    for i, future in enumerate(futures):
        part_stock, part_which, part_stats = future.result()
        stock[owner == i], which[owner == i] = part_stock, part_which
        for key, value in part_stats.items():
            stats[key] = stats.get(key, 0) + value
    return stock, which


def _stock_part(points, sweeps, gap):
    stats = {}
    stock, which = stock_at_points(points, sweeps, gap, stats=stats)
    return stock, which, stats


def _as_sweep(sweep):
    """A :class:`Sweep` of float64 arrays from a Sweep or a plain (vertices, faces, poses) tuple."""
    v, f, p = sweep
    return Sweep(np.asarray(v, dtype=np.float64), np.asarray(f), _poses(p), getattr(sweep, "breaks", None))


def simulate_removal(blisk, sweeps, gap, tolerance=REMOVAL.stock, spacing=REMOVAL.spacing, samples=None,
                     reference=None, executor=None, parts=1, inherent=None):
    """Stock left on the four surfaces of channel 0 after the given electrode sweeps.

    Parameters
    ----------
    blisk : Blisk
    sweeps : sequence of Sweep or (vertices, faces, poses)
        As for :func:`stock_at_points`; poses in channel-0 position.
    gap : float or sequence of float
        Discharge gap [mm], one or one per sweep.
    tolerance : float
        Stock accepted as finished [mm].
    spacing : float
        Wall sample spacing [mm] (ignored with ``samples``).
    samples : dict, optional
        :func:`wall_samples` output to reuse.
    reference : sequence of sweeps, optional
        An ideal electrode (the whole channel shrunk by the gap at its machining
        pose): its stock is the inherent one (concave corners keep a fillet of
        radius ``gap`` whatever the electrodes), reported beside the stock.
    inherent : dict or True, optional
        The inherent stock itself, surface -> (n,) per sample of ``samples``
        (:func:`corner_rounding_stock`, computed from the walls, independent of
        any electrode design; ``True`` computes it); instead of ``reference``.
    executor : concurrent.futures.Executor, optional
        With ``parts`` > 1, the points are shared out among its processes in
        that many interleaved parts (the same stock as one process).
    parts : int

    Returns
    -------
    RemovalReport
    """
    t0 = time.perf_counter()
    samples = samples or wall_samples(blisk, spacing)
    sweeps = [_as_sweep(sw) for sw in sweeps]
    names = list(samples)
    valid = [samples[s].valid for s in names]
    points = np.vstack([samples[s].points[m] for s, m in zip(names, valid)])
    stats = {}
    stock, which = _stock_in_parts(points, sweeps, gap, executor, parts, stats)
    first_gap = float(gap if np.ndim(gap) == 0 else gap[0])
    described = ""
    if inherent is True:
        inherent = corner_rounding_stock(blisk, samples, first_gap)
    if inherent is not None:
        if reference is not None:
            raise ValueError("give the inherent stock or a reference electrode, not both")
        inherent = np.concatenate([np.asarray(inherent[s], dtype=np.float64)[m] for s, m in zip(names, valid)])
        described = (f"the EDM corner rounding of the walls' own geometry (radius = gap {first_gap:g} mm, from the "
                     f"corner angles; independent of the electrode design)")
    elif reference is not None:
        ref = [Sweep(np.asarray(v, dtype=np.float64), np.asarray(f), _poses(p)) for v, f, p in reference]
        inherent = np.maximum(stock_at_points(points, ref, first_gap)[0], 0.0)
        described = "the stock of the given reference electrode"
    centre = points.mean(axis=0)
    radius = float(np.linalg.norm(points - centre, axis=1).max())
    step = max((float(np.delete(_step_travel(*_inverse(sw.poses), centre, radius),
                                np.asarray([] if sw.breaks is None else sw.breaks, dtype=np.int64)).max(initial=0.0))
                for sw in sweeps), default=0.0)
    surfaces = {}
    offset = 0
    ok = True
    for name, m in zip(names, valid):
        smp = samples[name]
        k = int(m.sum())
        full = np.full(len(m), np.nan)
        full[m] = stock[offset:offset + k]
        w_full = np.full((len(m), 2), -1, dtype=np.int64)
        w_full[m] = which[offset:offset + k]
        inh = None if inherent is None else inherent[offset:offset + k]
        inh_full = None
        if inh is not None:
            inh_full = np.full(len(m), np.nan)
            inh_full[m] = inh
            inh_full = inh_full.reshape(smp.shape)
        offset += k
        s, w = full[m], smp.weights[m]
        area = float(w.sum())
        surfaces[name] = SurfaceStock(
            surface=name, stock=full.reshape(smp.shape), u=smp.u, v=smp.v,
            which=w_full.reshape(*smp.shape, 2), area=area,
            stock_max=float(s.max()), stock_mean=float((s * w).sum() / area),
            area_fraction_above_tolerance=float(w[s > tolerance].sum() / area),
            overcut_max=float(max(0.0, -s.min())),
            inherent_max=float("nan") if inh is None else float(inh.max()),
            area_fraction_beyond_inherent=(float("nan") if inh is None
                                           else float(w[s - inh > tolerance].sum() / area)),
            inherent=inh_full)
        ok &= bool(s.max() <= tolerance and -s.min() <= tolerance)
    reach = max(smp.spacing for smp in samples.values())
    pose_count = sum(len(sw.poses) for sw in sweeps)
    return RemovalReport(
        surfaces=surfaces,
        gap=tuple(float(g) for g in np.broadcast_to(np.asarray(gap, dtype=float), (len(sweeps),))),
        tolerance=float(tolerance), every_sample_within_tolerance=ok, spacing=reach, pose_count=pose_count,
        continuous_bound=0.5 * step,
        exact=(f"exact at the wall samples (<= {reach:.3g} mm apart) to float precision for the "
               f"{pose_count} given poses, with respect to the electrode meshes"),
        elapsed=time.perf_counter() - t0, queries=int(stats.get("queries", 0)), samples=samples,
        inherent_reference=described)


#: the stock maps' names, moved to :mod:`edm_planner.records.stock_maps` (the records layer; deprecated here)
_MOVED_TO_RECORDS = ("plot_stock_maps", "stock_colour_scale", "stock_vertex_colours", "_TITLES")


def __getattr__(name):
    # PEP 562, a deprecated alias only: the stock maps moved up to the records layer; this import runs when an
    # old name is asked for (machining imports no records module at load time)
    if name in _MOVED_TO_RECORDS:
        from ..records import stock_maps
        return deprecation.moved_name(__name__, name, stock_maps)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
