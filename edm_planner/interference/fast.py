"""Fast interference checking: a precomputed distance field with a measured error bound.

:class:`FastChannelField` answers the question of
:class:`~.exact_points.ExactChannelDistance` -- the signed distances of points
to the suction, pressure, hub and shroud surfaces of channel k -- from tables
built once per geometry:

* **Blade walls**: one 3-D grid over cylindrical coordinates (x, r, theta) of
  channel 0, two float32 values per node: the exact signed distance to the
  suction wall (blade 0's +theta face) and to the pressure wall (blade 0's
  -theta face turned by one pitch), with the sign rule of the exact method
  (negative behind a wall within its face's meridional footprint: up to one
  pitch below the suction wall, up to one pitch above the pressure wall).
  A query is trilinear, with weights shared by both values; channel k is
  channel 0 with the query angle turned by -k * pitch.
* **Hub and shroud**: surfaces of revolution, whose distance depends on
  (x, r) only (Chen & Dong eq. 4-8): an (x, r) table of the exact signed
  profile distance, bilinear; outside the table the exact distance itself
  (1-D Newton on the profile's cubic pieces, in numba).

Filling the grid takes millions of point-to-surface distances, which the
vectorised ``BladeFace.closest_points`` (about 4e4 points/s) cannot give in
seconds. They come from a small numba evaluator of the faces' bicubic
B-splines (the same control nets and knots; values, first and second
derivatives) and a numba Newton projection with backtracking, started from
the extrapolated closest points of the previous nodes along theta and checked
against the global closest points of a coarse grid (every 4th node, started
from the nearest sample of the face) wherever the closest point may jump.
Only nodes within ``band`` (2.7 mm) of a face are solved; the rest are
interpolated from the coarse grid, only to say "far".

Where trilinear interpolation is not accurate enough -- second differences
along the axes adding up to more than ``curvature_tol`` (leading and trailing
edge noses; less beside the faces' edges), or values jumping between
neighbours (where the sign rule changes) -- a node is stored as NaN, and a
query in a cell touching it goes to the exact numba solver (the slow path;
also for points outside the hub/shroud table). The fast path pays one NaN
test for it.

The error within 2 mm of the surfaces is measured at build against the exact
method on random points near each surface (both sides) and around the blade
edges, and exposed as :attr:`FastChannelField.error_bound`: no pose may be
accepted as clear on this method alone unless its clearance exceeds the
required one by more than the bound. Farther than 2 mm from a face the blade
values are not held to the bound (coarser, from the coarse grid) and outside
the grid they are conservative lower bounds (the value at the nearest grid
point minus the distance to it, or the distance to the faces' (x, r)
bounding box, whichever is larger), never larger than the truth.

This module holds the class: a thin layer over modules by concern:
:mod:`.field_params` (the kernels' named arguments), :mod:`.field_layout`
(the grids' extents, the splines' arrays), :mod:`.field_build` (the grid
fill), :mod:`.field_query` (per point and per pose), :mod:`.exact_solvers`
(the exact blade and profile solvers), :mod:`.min_search` (the exact minimum
over a pose sequence, for :mod:`.pose_check`), :mod:`.field_error` (the
error measurement), :mod:`.field_cache` (the disk cache) and
:mod:`.field_lock` (one build per machine).

Units: mm, rad. Frame W: X the blisk axis, theta = atan2(z, y).
"""

import functools
import importlib
import logging
import math
import time

import numpy as np

from ..geometry.frames import rotation_about_x
from ..geometry.spline_kernels import spline_surface_eval
from .exact_solvers import _behind_kernel, _exact_blade_feet
from .field_build import build_tables
from .field_cache import ARRAYS, cache_path, fingerprint, read_cache, write_cache
from .field_error import error_sample_points, measure_error, reference_clearances
from .field_layout import face_arrays, grid_layout, profile_arrays, uv_starts
from .field_lock import build_lock
from .field_params import ACCURATE_WITHIN, CACHE_VERSION, ExactTables, FieldParams, GridShape, KernelArgs
from .field_query import _exact_pose_kernel, _points_kernel, _pose_kernel, _posed_kernel
from .wall_features import WallFeatures

_log = logging.getLogger(__name__)

#: the public names (the constants and the spline evaluator as before the split; the kernels' argument types)
__all__ = ["FastChannelField", "ACCURATE_WITHIN", "CACHE_VERSION", "spline_surface_eval", "KernelArgs", "FieldParams",
           "GridShape", "ExactTables"]

#: where the kernels and helpers that lived in this module before it was split by concern are now
_MOVED_TO = ("field_params", "exact_solvers", "field_build", "field_query", "min_search", "field_layout",
             "field_error", "field_cache", "field_lock")

#: helpers renamed on the way (old name -> new name)
_RENAMED = {"_face_arrays": "face_arrays", "_profile_arrays": "profile_arrays", "_axis": "grid_axis",
            "_build_lock": "build_lock"}


def __getattr__(name):
    """The old names stay importable from here (``fast._slow_point``, ``fast._min_search``, ``fast._axis``)."""
    if not name.startswith("__"):
        name = _RENAMED.get(name, name)
        for module in _MOVED_TO:
            names = vars(importlib.import_module(f"{__package__}.{module}"))
            if name in names:
                return names[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _poses_and_points(poses, points, where):
    """(P, 4, 4) poses and (M, 3) points, M >= 1, as contiguous float64 for the pose kernels."""
    poses = np.ascontiguousarray(np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4))
    pts = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"{where}: points must be (M, 3) with M >= 1, got {pts.shape}")
    return poses, pts


class FastChannelField:
    """Signed distances to a channel's four surfaces from a precomputed field.

    Parameters
    ----------
    blisk : Blisk
    spacing : float
        Grid spacing [mm] of the blade grid in x and r; in theta it is
        ``spacing / r_mid``. The hub/shroud (x, r) table has the same.
    cache_dir : path, optional
        Directory of the cached arrays (``.npz``); with ``cache_key``, the
        field is loaded from there when a matching file exists and written
        there after a build.
    cache_key : str, optional
        Identifies the geometry (the loader's geometry id).
    band : float
        Nodes farther than this from a face [mm] are interpolated from the
        coarse grid instead of solved (their values only need to say "far").
    curvature_tol, edge_curvature_tol : float
        Summed absolute second differences [mm] above which a node is left to
        the exact solver (the trilinear error is about an eighth of it); the
        second applies beside the faces' edges (``_flag_nodes``).
    error_samples : int
        Random points per surface for the error measurement at build.

    Attributes
    ----------
    error_bound : float
        [mm] Bound of ``|fast - exact|`` for points within ``ACCURATE_WITHIN``
        (2 mm) of a surface and inside the grid: the largest error measured
        at build times 1.5, plus the float32 quantisation. No pose may be
        taken as clear on this method alone unless its clearance exceeds the
        required one by more than this. Beyond 2 mm from a blade face the
        blade values are coarser (not held to the bound); outside the grid
        they are lower bounds.
    measured_max_error : dict
        Surface name -> max ``|fast - exact|`` [mm] measured at build (the
        exact reference refined as in :meth:`reference_clearances`).
    error_sample_count : dict
        Surface name -> number of measured points within 2 mm of it.
    far_error_bound : float
        [mm] The same (measured maximum times 1.5) for points inside the grid
        farther than 2 mm from a surface, where the blade values come from
        the coarse grid: tens of micrometres up to 3-5 mm, about 0.1-0.2 mm
        beyond.
    exact_method_excess : float
        [mm] How far ``ExactChannelDistance`` was from the refined reference
        on the measured points (where its closest-point solvers stop short).
    build_seconds : float
        Time of the build (0 when loaded from the cache).
    stats : dict
        Figures of the build: grid shape and spacing, fractions of solved
        nodes and of nodes left to the exact solver, stage times [s].

    Notes
    -----
    Memory: two float32 per node; the default blisk at 0.1 mm has 345 x 245 x
    305 nodes (197 MB). The numba kernels run on numba's threads for the
    build (``numba.set_num_threads``) and on one thread for queries.
    """

    def __init__(self, blisk, spacing=0.1, cache_dir=None, cache_key=None, *, band=2.7,
                 curvature_tol=0.024, edge_curvature_tol=0.016, error_samples=1500):
        self.blisk = blisk
        self.spacing = float(spacing)
        self.band = float(band)
        self.curvature_tol = float(curvature_tol)
        self.edge_curvature_tol = float(edge_curvature_tol)
        self._splines = face_arrays(blisk.suction_face) + face_arrays(blisk.pressure_face)
        self._hub = profile_arrays(blisk.hub)
        self._shroud = profile_arrays(blisk.shroud)
        self._fingerprint = fingerprint(self._splines + self._hub + self._shroud, blisk.pitch,
                                        [self.spacing, self.band, self.curvature_tol, self.edge_curvature_tol])
        self.build_seconds = 0.0
        path = self._cache_path(cache_dir, cache_key)
        if path is not None and self._load(path):
            _log.info("fast field: loaded %s", path)
            return
        # one build per field and machine: processes that need the same field at once (the planner and
        # the checker starting together, the set designer's workers) wait for the one building it
        with build_lock(path):
            if path is not None and self._load(path):
                _log.info("fast field: loaded %s (built by another process meanwhile)", path)
                return
            t = time.perf_counter()
            self._build()
            self._measure_error(error_samples)
            self.build_seconds = time.perf_counter() - t
            _log.info("fast field: built in %.2f s, grid %s, error bound %.2e mm",
                      self.build_seconds, self._grid.shape[:3], self.error_bound)
            if path is not None:
                self._save(path)

    # -- building ------------------------------------------------------------
    def _layout(self):
        """The grids' extents: (FieldParams, GridShape) (:func:`.field_layout.grid_layout`)."""
        return grid_layout(self.blisk, self.spacing)

    def _xr_starts(self):
        """The exact solver's start samples (:func:`.field_layout.uv_starts`)."""
        return uv_starts(self.blisk)

    def _build(self):
        params, shape = self._layout()
        tables, self.stats = build_tables(self.blisk, params, shape, self._splines, self._hub, self._shroud,
                                          self.band, self.curvature_tol, self.edge_curvature_tol)
        self._set_arrays(dict({"_" + name: value for name, value in tables.items()},
                              _fp=np.array(params, dtype=np.float64), _ip=np.array(shape, dtype=np.int64)))

    def _set_arrays(self, arrays):
        """Take the arrays of :data:`.field_cache.ARRAYS` (built or mapped) and the named parameters from them."""
        for name in ARRAYS:
            setattr(self, name, arrays[name])
        self._params = FieldParams(*(float(v) for v in self._fp))
        self._shape = GridShape(*(int(v) for v in self._ip))
        self._tables = None                   # the exact solvers' tables, made on first use
        self._plain = {}                      # channel -> _plain_args

    # -- queries ---------------------------------------------------------------
    def kernel_args(self, channel=0):
        """What numba callers pass on for channel k: a :class:`.field_params.KernelArgs`.

        ``(channel_angle, grid, walls, fast, fast_shape, params, shape, tables)``:
        ``_fast_point(x, y, z, grid, walls, fast, fast_shape)`` answers from the tables,
        ``_exact_at(s, x, y, z, channel_angle, params, shape, tables, work)`` and
        ``_behind_at(face, ...)`` solve exactly (``work = new_work()``).
        """
        if self._tables is None:
            self._tables = ExactTables(*self._splines, self._line_uv, self._coarse_uv, self._kind, self._line_theta,
                                       self._line_inside, *self._hub, *self._shroud, *self._xr_starts())
        params = self._params
        angle = params.tc + channel * self.blisk.pitch
        fast = params._replace(ca=math.cos(angle), sa=math.sin(angle))
        return KernelArgs(float(channel) * self.blisk.pitch, self._grid.reshape(-1), self._hs.reshape(-1), fast,
                          self._shape, params, self._shape, self._tables)

    def _plain_args(self, channel):
        """``kernel_args`` with plain tuples for the named ones, cached per channel: what the methods (and
        :func:`.pose_check.verify_poses`) splat into the entry kernels.

        numba types a plain tuple in C and a named tuple in Python (about 20 us
        more per call); the entry kernels name them (``field_params.named_args``).
        """
        plain = self._plain.get(channel)
        if plain is None:
            args = self.kernel_args(channel)
            plain = self._plain[channel] = KernelArgs(*args[:3], *(tuple(named) for named in args[3:]))
        return plain

    def _kernel_args(self, channel=0):
        """``kernel_args`` without the channel angle: ``(grid, walls, fast, fast_shape, params, shape, tables)``."""
        return self.kernel_args(channel)[1:]

    def clearances(self, points, channel=0):
        """Signed distances of points in W to channel k's four surfaces.

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        (n, 4) float
            [mm], columns in the order of ``SURFACES``; within ``error_bound``
            of ``ExactChannelDistance.clearances`` for points within 2 mm of a
            surface, a lower bound of it outside the grid.
        """
        return self._points(points, channel, 0)

    def _points(self, points, channel, mode):
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must be (n, 3), got {p.shape}")
        args = self._plain_args(channel)
        return _points_kernel(p, args[0], mode, *args[1:])

    def posed_clearances(self, poses, points, channel=0):
        """(P, M, 4): the four clearances of every point under every pose [mm].

        ``clearances`` of the points placed by each pose (parameters as
        :meth:`pose_clearances`), in one numba loop on all threads.
        """
        poses, pts = _poses_and_points(poses, points, "posed_clearances")
        return _posed_kernel(poses, pts, *self._plain_args(channel))

    @functools.cached_property
    def wall_features(self):
        """The blade edges and blunt end caps of channel 0, densely sampled (:class:`.wall_features.WallFeatures`).

        What a vertex check cannot see: the certificate measures them against the electrode's triangles.
        Built on first use (~0.05 s), not cached on disk.
        """
        return WallFeatures.from_blisk(self.blisk)

    @property
    def skip_margin(self):
        """What ``pose_clearances`` takes off the node values' bound before it skips an exact solve [mm]:
        the field's error bound (the nodes' values against the solver's) and 1 nm of rounding."""
        return float(self.error_bound) + 1e-6

    def pose_clearances(self, poses, points, channel=0):
        """Per pose and surface: the minimum signed distance over the electrode points.

        Transform, lookup and minimum run in one numba loop (no (P, M, 3)
        temporaries). A point in a cell marked for the exact solver is solved
        only where it can attain a minimum (``skip_margin``): the same result.

        Parameters
        ----------
        poses : (P, 4, 4) float
            Electrode frame -> W.
        points : (M, 3) float
            In the electrode frame [mm].
        channel : int

        Returns
        -------
        minimum : (P, 4) float
            [mm], columns in the order of ``SURFACES``.
        argmin : (P, 4) int
            Index of the electrode point that attains it.
        """
        poses, pts = _poses_and_points(poses, points, "pose_clearances")
        best, arg, _ = _pose_kernel(poses, pts, self.skip_margin, *self._plain_args(channel))
        return best, arg

    def exact_pose_clearances(self, poses, points, channel=0):
        """Per pose and surface: the exact minimum signed distance over the electrode points.

        The field prunes (``_exact_pose_kernel``): only points whose field value
        is within the field's error bounds of the smallest exact value found
        are solved exactly, by the numba solvers of ``exact_blade_distances``
        and ``exact_profile_distances``; the result is the exact minimum over
        all points.

        Parameters
        ----------
        poses : (P, 4, 4) float
            Electrode frame -> W.
        points : (M, 3) float
            In the electrode frame [mm].
        channel : int

        Returns
        -------
        minimum : (P, 4) float
            [mm], columns in the order of ``SURFACES``.
        argmin : (P, 4) int
        solved : (P,) int
            Exact solves per pose (the pruning's cost).
        """
        poses = np.ascontiguousarray(np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4))
        pts = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise ValueError(f"exact_pose_clearances: points must be (M, 3) with M >= 1, got {pts.shape}")
        far = float(getattr(self, "far_error_bound", np.inf))
        far = max(far, self.error_bound) if np.isfinite(far) else np.inf     # unknown: prune nothing
        args = self._plain_args(channel)
        return _exact_pose_kernel(poses, pts, args[0], float(self.error_bound), far, *args[1:])

    def exact_blade_feet(self, points, channel=0):
        """Exact signed distances to the two walls (as ``exact_blade_distances``) and their closest points.

        Returns
        -------
        distances : (n, 2) float
            [mm], suction and pressure wall.
        feet : (n, 2, 3) float
            The closest points on the walls, in W [mm].
        """
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        args = self._plain_args(channel)
        dist, uv = _exact_blade_feet(p, args[0], *args[5:])           # channel angle, params, shape, tables
        feet = np.empty((len(p), 2, 3))
        for face, cp in enumerate((self.blisk.suction_face, self.blisk.pressure_face)):
            s = cp.surface
            local = spline_surface_eval(s.control_points, s.knots_u, s.knots_v, uv[:, face, 0], uv[:, face, 1])[:, 0]
            # blade 0's face -> the wall of channel k (the pressure wall is blade k+1's)
            feet[:, face] = local @ rotation_about_x((channel + face) * self.blisk.pitch)[:3, :3].T
        return dist, feet

    def fast_path(self, points, channel=0):
        """Which points are answered from the tables alone (no exact solve, inside the hub/shroud table).

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        (n,) bool
        """
        return self._points(points, channel, 2)[:, 0] > 0.5

    def inside_grid(self, points, channel=0):
        """Which points lie inside the blade grid (elsewhere the blade values are lower bounds).

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.

        Returns
        -------
        (n,) bool
        """
        p = np.atleast_2d(np.asanyarray(points, dtype=np.float64))
        (x0, x1), (r0, r1), (t0, t1) = self.grid_bounds
        rho = np.hypot(p[:, 1], p[:, 2])
        th = np.arctan2(p[:, 2], p[:, 1]) - channel * self.blisk.pitch
        th -= 2 * np.pi * np.floor((th - self._params.tc + np.pi) / (2 * np.pi))
        return (p[:, 0] >= x0) & (p[:, 0] <= x1) & (rho >= r0) & (rho <= r1) & (th >= t0) & (th <= t1)

    @property
    def grid_bounds(self):
        """((x_min, x_max), (r_min, r_max), (theta_min, theta_max)) of the blade grid [mm, rad], channel 0."""
        p, n = self._params, self._shape
        return ((p.x0, p.x0 + (n.nx - 1) * p.hx), (p.r0, p.r0 + (n.nr - 1) * p.hr), (p.t0, p.t0 + (n.nt - 1) * p.ht))

    # -- error measurement -------------------------------------------------------
    def error_sample_points(self, n=1500, seed=0):
        """Random points within 2 mm of channel 0's surfaces (:func:`.field_error.error_sample_points`).

        Returns
        -------
        (m, 3) float
            Points in W [mm].
        """
        return error_sample_points(self.blisk, n, seed)

    def exact_blade_distances(self, points, channel=0):
        """Exact signed distances to the two blade walls by the numba solver (no grid).

        The same sign rule and the same surfaces as ``ExactChannelDistance``;
        the closest point from the coarse grid's closest points, Newton with
        an active set on the face's edges.

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        (n, 2) float
            [mm], suction and pressure wall.
        """
        return self._points(points, channel, 1)[:, :2]

    def behind_walls(self, points, channel=0):
        """Which points lie behind the suction / pressure wall: the sign of ``exact_blade_distances`` alone.

        Far cheaper than the distances (no closest point): the face's angle at
        the point's (x, r) from the (x, r) lines, Newton where they cannot decide.

        Returns
        -------
        (n, 2) bool
            True where the exact signed distance to that wall is negative.
        """
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        args = self._plain_args(channel)
        return _behind_kernel(p, args[0], *args[5:])                   # channel angle, params, shape, tables

    def exact_profile_distances(self, points):
        """Exact signed distances to the hub and the shroud by the numba profile solver (no table).

        Returns
        -------
        (n, 2) float
            [mm], hub and shroud.
        """
        return self._points(points, 0, 1)[:, 2:]

    def reference_clearances(self, points, channel=0, exact=None):
        """The best known signed distances (:func:`.field_error.reference_clearances`).

        Returns
        -------
        reference : (n, 4) float
            [mm], columns in the order of ``SURFACES``.
        exact : (n, 4) float
            ``ExactChannelDistance.clearances`` unchanged.
        """
        return reference_clearances(self, points, channel, exact)

    def _measure_error(self, n):
        for name, value in measure_error(self, n).items():
            setattr(self, name, value)

    # -- cache -------------------------------------------------------------------
    _ARRAYS = ARRAYS

    def _cache_path(self, cache_dir, cache_key):
        return cache_path(cache_dir, cache_key, self.spacing)

    def _save(self, path):
        meta = {"fingerprint": self._fingerprint,
                "error_bound": self.error_bound, "measured_max_error": self.measured_max_error,
                "exact_method_excess": self.exact_method_excess, "far_error_bound": self.far_error_bound,
                "error_sample_count": self.error_sample_count, "stats": self.stats,
                "build_seconds": self.build_seconds}
        write_cache(path, {name: getattr(self, name) for name in ARRAYS}, meta)

    def _load(self, path):
        """Load the arrays from ``path``; False (and a rebuild) if missing, stale or corrupt."""
        arrays, meta = read_cache(path, self._fingerprint, self._layout)
        if arrays is None:
            return False
        self._set_arrays(arrays)
        self.error_bound = meta["error_bound"]
        self.measured_max_error = meta["measured_max_error"]
        self.error_sample_count = meta.get("error_sample_count", {})
        self.exact_method_excess = float(meta.get("exact_method_excess", float("nan")))
        self.far_error_bound = float(meta.get("far_error_bound", float("nan")))
        self.stats = dict(meta.get("stats", {}), loaded_from=str(path))
        return True
