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

This module holds the class (build, cache, queries, error measurement); its
numba kernels live by concern in :mod:`.field_params` (the parameter
layout), :mod:`.field_build` (the grid fill), :mod:`.field_query` (per point
and per pose), :mod:`.exact_solvers` (the exact blade and profile solvers)
and :mod:`.min_search` (the exact minimum over a pose sequence, for
:mod:`.plan_check`).

Units: mm, rad. Frame W: X the blisk axis, theta = atan2(z, y).
"""

import contextlib
import fcntl
import functools
import hashlib
import importlib
import json
import logging
import math
import os
import pathlib
import re
import tempfile
import time

import numba
import numpy as np
from scipy.spatial import cKDTree

from . import SURFACES
from ..geometry.frames import cylindrical_to_cartesian, rotation_about_x
from ..geometry.spline_kernels import spline_surface_eval  # noqa: F401  (a public name of this module)
from .exact_points import ExactChannelDistance
from .field_params import (
    ACCURATE_WITHIN, CACHE_VERSION, _CA, _COARSE, _FR0, _FR1, _FX0, _FX1, _HHR, _HHX, _HR, _HR0, _HT, _HX,
    _HX0, _IHHR, _IHHX, _IHR, _IHT, _IHX, _JUMP, _NCR, _NCT, _NCX, _NHR, _NHX, _NIPAR, _NPAR, _NR, _NT, _NX,
    _PITCH, _R0, _SA, _SCALE, _T0, _TC, _X0)
from .exact_solvers import _behind_kernel, _exact_blade_feet, _fill_profile_table
from .field_build import _classify_coarse, _fill_coarse, _fill_fine, _fill_lines, _flag_nodes
from .npz_map import map_npz
from .field_query import _exact_pose_kernel, _points_kernel, _pose_kernel, _posed_kernel

_log = logging.getLogger(__name__)

#: where the kernels that lived in this module before it was split by concern are now
_KERNEL_MODULES = ("field_params", "exact_solvers", "field_build", "field_query", "min_search")


def __getattr__(name):
    """The kernels' old names stay importable from here (``fast._slow_point``, ``fast._min_search``, ...)."""
    if not name.startswith("__"):
        for module in _KERNEL_MODULES:
            kernels = vars(importlib.import_module(f"{__package__}.{module}"))
            if name in kernels:
                return kernels[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _face_arrays(face):
    """Control net by coordinate (3, nv, nu) and the knot vectors of a face's spline."""
    s = face.surface
    return (np.ascontiguousarray(np.moveaxis(s.control_points, 2, 0), dtype=np.float64),
            np.ascontiguousarray(s.knots_u, dtype=np.float64),
            np.ascontiguousarray(s.knots_v, dtype=np.float64))


def _profile_arrays(profile):
    """Breakpoints (n,), cubic coefficients (4, n-1) and (max|r'|, max|r''|) of a profile.

    The PCHIP pieces of ``RevolutionProfile`` (the interpolant ``ProfileDistance`` uses).
    """
    interp = profile._interp
    xb = np.ascontiguousarray(interp.x, dtype=np.float64)
    t = np.linspace(xb[0], xb[-1], 20 * len(xb) + 200)
    bounds = np.array([np.abs(interp.derivative()(t)).max() * 1.1 + 1e-9,
                       np.abs(interp.derivative(2)(t)).max() * 1.1 + 1e-9])
    return xb, np.ascontiguousarray(interp.c, dtype=np.float64), bounds


@contextlib.contextmanager
def _build_lock(path):
    """Exclusive lock of a field's cache file while it is built (``<cache>.lock``, flock); none without a cache.

    The lock is the kernel's (released when its holder exits, also by kill -9),
    so a crashed builder never blocks the next one. Where the lock file cannot
    be made (a read-only cache directory) the field is built unlocked.
    """
    if path is None:
        yield
        return
    lock = path.with_name(path.name + ".lock")
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        _log.warning("fast field: no build lock %s (%s); building without it", lock, exc)
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            _log.info("fast field: another process is building %s; waiting for it", path.name)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)                     # closing releases the lock


def _poses_and_points(poses, points, where):
    """(P, 4, 4) poses and (M, 3) points, M >= 1, as contiguous float64 for the pose kernels."""
    poses = np.ascontiguousarray(np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4))
    pts = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"{where}: points must be (M, 3) with M >= 1, got {pts.shape}")
    return poses, pts


def _axis(lo, hi, step, multiple):
    """Node count (a multiple of ``multiple`` intervals plus one) and spacing <= step covering [lo, hi]."""
    m = max(multiple, int(math.ceil((hi - lo) / step / multiple - 1e-9)) * multiple)
    return m + 1, (hi - lo) / m


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
        self._cp_s, self._tu_s, self._tv_s = _face_arrays(blisk.suction_face)
        self._cp_p, self._tu_p, self._tv_p = _face_arrays(blisk.pressure_face)
        self._hub_xb, self._hub_c, self._hub_b = _profile_arrays(blisk.hub)
        self._sh_xb, self._sh_c, self._sh_b = _profile_arrays(blisk.shroud)
        self._fingerprint = self._geometry_fingerprint()
        self.build_seconds = 0.0
        path = self._cache_path(cache_dir, cache_key)
        if path is not None and self._load(path):
            _log.info("fast field: loaded %s", path)
            return
        # one build per field and machine: processes that need the same field at once (the planner and
        # the checker starting together, the set designer's workers) wait for the one building it
        with _build_lock(path):
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
    def _geometry_fingerprint(self):
        h = hashlib.sha256()
        for a in (self._cp_s, self._tu_s, self._tv_s, self._cp_p, self._tu_p, self._tv_p,
                  self._hub_xb, self._hub_c, self._hub_b, self._sh_xb, self._sh_c, self._sh_b):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(np.float64(self.blisk.pitch).tobytes())
        h.update(json.dumps([CACHE_VERSION, self.spacing, self.band, self.curvature_tol,
                             self.edge_curvature_tol]).encode())
        return h.hexdigest()

    def _layout(self):
        """Grid extents: the float and integer parameter vectors of the kernels."""
        b = self.blisk
        h = self.spacing
        coarse = 4
        x0, x1 = b.axial_range
        xs = np.linspace(x0 - 4.0, x1 + 4.0, 800)
        r_lo = float(b.hub.radius_at(xs).min()) - 1.0
        r_hi = float(b.shroud.radius_at(xs).max()) + 1.0
        uu, vv = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 101))
        th_s = b.suction_face.surface.evaluate(uu, vv)
        th_p = b.pressure_face.surface.evaluate(uu, vv)
        fx = np.concatenate([th_s[..., 0].ravel(), th_p[..., 0].ravel()])
        fr = np.concatenate([np.hypot(th_s[..., 1], th_s[..., 2]).ravel(),
                             np.hypot(th_p[..., 1], th_p[..., 2]).ravel()])
        t_lo = float(np.arctan2(th_s[..., 2], th_s[..., 1]).min()) - 3.0 / r_lo
        t_hi = float(np.arctan2(th_p[..., 2], th_p[..., 1]).max()) + b.pitch + 3.0 / r_lo
        r_mid = 0.5 * (r_lo + r_hi)
        nx, hx = _axis(x0 - 4.0, x1 + 4.0, h, coarse)
        nr, hr = _axis(r_lo, r_hi, h, coarse)
        nt, ht = _axis(t_lo, t_hi, h / r_mid, coarse)
        # hub/shroud table: longer in x, so that an electrode leaving the channel axially (its far end
        # an electrode length past the blades) stays in it
        ext = max(10.0, 1.25 * (x1 - x0))
        nhx, hhx = _axis(x0 - 4.0 - ext, x1 + 4.0 + ext, h, 1)
        nhr, hhr = _axis(r_lo, r_hi, h, 1)
        fp = np.zeros(_NPAR)
        fp[[_X0, _HX, _R0, _HR, _T0, _HT]] = x0 - 4.0, hx, r_lo, hr, t_lo, ht
        fp[_PITCH] = b.pitch
        fp[_TC] = 0.5 * (t_lo + t_hi)
        fp[[_HX0, _HHX, _HR0, _HHR]] = x0 - 4.0 - ext, hhx, r_lo, hhr
        fp[[_FX0, _FX1, _FR0, _FR1]] = fx.min() - 0.01, fx.max() + 0.01, fr.min() - 0.01, fr.max() + 0.01
        fp[[_IHX, _IHR, _IHT, _IHHX, _IHHR]] = 1.0 / hx, 1.0 / hr, 1.0 / ht, 1.0 / hhx, 1.0 / hhr
        # a coarse cell's diagonal: how far apart two of its corners' closest points may lie
        fp[_JUMP] = coarse * math.sqrt(hx ** 2 + hr ** 2 + r_hi ** 2 * ht ** 2)
        for k, face in enumerate((b.suction_face, b.pressure_face)):
            s_u, s_v = face.surface.derivatives(*np.meshgrid(np.linspace(0, 1, 21), np.linspace(0, 1, 21)))
            fp[_SCALE + 2 * k] = np.linalg.norm(s_u, axis=-1).mean()
            fp[_SCALE + 2 * k + 1] = np.linalg.norm(s_v, axis=-1).mean()
        ip = np.zeros(_NIPAR, dtype=np.int64)
        ip[[_NX, _NR, _NT, _COARSE]] = nx, nr, nt, coarse
        ip[[_NCX, _NCR, _NCT]] = (nx - 1) // coarse + 1, (nr - 1) // coarse + 1, (nt - 1) // coarse + 1
        ip[[_NHX, _NHR]] = nhx, nhr
        return fp, ip

    def _xr_starts(self, n=64):
        """The starts of ``BladeFace.uv_at``: n x n face samples in (x, r) scaled by their extent.

        The footprint test must start where the exact method starts (see
        ``_exact_blade``); this repeats ``BladeFace``'s sampling.

        Returns
        -------
        samples : (2, n*n, 2) float
            Scaled (x, r) of the suction and the pressure face's samples.
        uv : (2, n*n, 2) float
        scale : (2, 2) float
        box, start, items
            Bins of the samples for ``_nearest_start``.
        """
        samples = np.empty((2, n * n, 2))
        uv = np.empty((2, n * n, 2))
        scale = np.empty((2, 2))
        nb = n // 2                                   # bins of the nearest-sample search
        box = np.empty((2, 4))
        start = np.empty((2, nb * nb + 1), dtype=np.int64)
        items = np.empty((2, n * n), dtype=np.int64)
        uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
        for k, face in enumerate((self.blisk.suction_face, self.blisk.pressure_face)):
            pts = face.surface.evaluate(uu, vv).reshape(-1, 3)
            xr = np.column_stack([pts[:, 0], np.hypot(pts[:, 1], pts[:, 2])])
            scale[k] = np.ptp(xr, axis=0) + 1e-9
            samples[k] = xr / scale[k]
            uv[k] = np.column_stack([uu.ravel(), vv.ravel()])
            lo = samples[k].min(axis=0)
            size = (samples[k].max(axis=0) - lo) / nb + 1e-12
            box[k] = lo[0], lo[1], size[0], size[1]
            cell = np.minimum(((samples[k] - lo) / size).astype(np.int64), nb - 1)
            bins = cell[:, 0] * nb + cell[:, 1]
            items[k] = np.argsort(bins, kind="stable")
            start[k] = np.searchsorted(bins[items[k]], np.arange(nb * nb + 1))
        return samples, uv, scale, box, start, items

    @staticmethod
    def _face_seeds(face, points, near_cut):
        """Global starts for Newton: the nearest sample of the face.

        A 32 x 32 sampling first; points whose distance to it is below
        ``near_cut`` plus that sampling's gap get the nearest of a 96 x 96
        sampling instead.

        Returns
        -------
        uv : (m, 2) float
        far : (m,) bool
            Certainly farther than ``near_cut`` from the face.
        """
        def sampling(n):
            uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
            s = face.surface.evaluate(uu, vv)
            diag = np.maximum(np.linalg.norm(s[1:, 1:] - s[:-1, :-1], axis=-1),
                              np.linalg.norm(s[1:, :-1] - s[:-1, 1:], axis=-1))
            # no face point lies farther than ``gap`` from a sample
            return np.column_stack([uu.ravel(), vv.ravel()]), s.reshape(-1, 3), 0.6 * float(diag.max())

        uv_c, s_c, gap_c = sampling(32)
        workers = numba.get_num_threads()
        dist, idx = cKDTree(s_c).query(points, workers=workers)
        uv = uv_c[idx]
        near = dist < near_cut + gap_c
        uv_f, s_f, _ = sampling(96)
        _, idx_f = cKDTree(s_f).query(points[near], workers=workers)
        uv[near] = uv_f[idx_f]
        return uv, ~near

    def _build(self):
        b = self.blisk
        times = {}
        t = time.perf_counter()
        fp, ip = self._layout()
        nx, nr, nt, C = (int(v) for v in ip[[_NX, _NR, _NT, _COARSE]])
        ncx, ncr, nct = (int(v) for v in ip[[_NCX, _NCR, _NCT]])
        xg = fp[_X0] + fp[_HX] * np.arange(nx)
        rg = fp[_R0] + fp[_HR] * np.arange(nr)
        tg = fp[_T0] + fp[_HT] * np.arange(nt)
        faces = (b.suction_face, b.pressure_face)
        kern = (self._cp_s, self._tu_s, self._tv_s, self._cp_p, self._tu_p, self._tv_p)

        # 1. per (x, r): both faces' angles and the footprint (the sign rule)
        X, R = np.meshgrid(xg, rg, indexing="ij")
        seeds = np.empty((nx * nr, 2, 2))
        xr_s, xr_uv, xr_scale = self._xr_starts()[:3]
        for k in range(2):
            _, idx = cKDTree(xr_s[k]).query(np.column_stack([X.ravel() / xr_scale[k, 0], R.ravel() / xr_scale[k, 1]]),
                                            workers=numba.get_num_threads())
            seeds[:, k] = xr_uv[k, idx]
        line_uv, line_theta, line_inside = _fill_lines(*kern, X.ravel(), R.ravel(), seeds)
        line_uv = line_uv.reshape(nx, nr, 2, 2)
        line_theta = line_theta.reshape(nx, nr, 2)
        line_inside = line_inside.reshape(nx, nr, 2)
        times["lines_s"] = time.perf_counter() - t

        # 2. coarse nodes: global closest points from a dense sampling, then Newton
        t = time.perf_counter()
        cX, cR, cT = np.meshgrid(xg[::C], rg[::C], tg[::C], indexing="ij")
        cseeds = np.empty((ncx, ncr, nct, 2, 2))
        cfar = np.empty((ncx, ncr, nct, 2), dtype=bool)
        diag = fp[_JUMP]
        for k, face in enumerate(faces):
            pts = cylindrical_to_cartesian(cX, cR, cT - k * b.pitch).reshape(-1, 3)
            # corners of far cells next to solved ones lie within band + diag: those get the fine starts
            uv, far = self._face_seeds(face, pts, self.band + diag + 0.1)
            cseeds[..., k, :] = uv.reshape(ncx, ncr, nct, 2)
            cfar[..., k] = far.reshape(ncx, ncr, nct)
        coarse_values, coarse_uv, coarse_xyz = _fill_coarse(*kern, fp, ip, line_theta, line_inside, cseeds, cfar)
        kind = _classify_coarse(coarse_values, coarse_xyz, coarse_uv, fp, ip, self.band, 1.5 * diag, 0.35)
        times["coarse_s"] = time.perf_counter() - t

        # 3. fine nodes: solved near the faces, interpolated far from them
        t = time.perf_counter()
        grid = np.empty((nx, nr, nt, 2), dtype=np.float32)
        edge = np.empty((nx, nr, nt, 2), dtype=np.uint8)
        scales = fp[_SCALE:_SCALE + 4].copy()
        solved, rechecked = _fill_fine(*kern, fp, ip, line_theta, line_inside, coarse_values, coarse_uv, kind,
                                       scales, diag, grid, edge)
        times["fine_s"] = time.perf_counter() - t
        t = time.perf_counter()
        flagged = _flag_nodes(grid, edge, fp, ip, self.curvature_tol, self.edge_curvature_tol,
                              ACCURATE_WITHIN + 0.25, 0.05)
        del edge
        times["flag_s"] = time.perf_counter() - t

        # 4. hub and shroud: the exact profile distance on an (x, r) table
        t = time.perf_counter()
        nhx, nhr = int(ip[_NHX]), int(ip[_NHR])
        hs = np.empty((nhx, nhr, 2), dtype=np.float32)
        table = (fp[_HX0], fp[_HHX], nhx, fp[_HR0], fp[_HHR], nhr)
        hs[..., 0] = _fill_profile_table(self._hub_xb, self._hub_c, self._hub_b, 1.0, *table)
        hs[..., 1] = _fill_profile_table(self._sh_xb, self._sh_c, self._sh_b, -1.0, *table)
        times["hub_shroud_s"] = time.perf_counter() - t

        self._fp, self._ip = fp, ip
        self._grid = grid
        self._hs = hs
        self._line_uv = np.ascontiguousarray(line_uv)
        self._coarse_uv = np.ascontiguousarray(coarse_uv)
        self._kind = kind
        self._line_theta = np.ascontiguousarray(line_theta)
        self._line_inside = np.ascontiguousarray(line_inside)
        nodes = 2.0 * nx * nr * nt
        self.stats = {
            "grid_shape": [nx, nr, nt],
            "grid_spacing_mm": [float(fp[_HX]), float(fp[_HR]), float(fp[_HT] * (fp[_R0] + 0.5 * (nr - 1) * fp[_HR]))],
            "grid_megabytes": round(grid.nbytes / 2**20, 1),
            "solved_node_fraction": round(solved / nodes, 4),
            "ambiguous_cell_fraction": round(float((kind == 2).mean()), 4),
            "restarted_node_fraction": round(rechecked / nodes, 4),
            "exact_fallback_node_fraction": round(flagged / nodes, 4),
            "hub_shroud_table_shape": [nhx, nhr],
            **{k: round(v, 3) for k, v in times.items()},
        }

    # -- queries ---------------------------------------------------------------
    def _kernel_args(self, channel=0):
        """The arrays the numba kernels take: (flat grid, flat hub/shroud table, fp tuple, ip tuple, fp, ip, slow)."""
        if getattr(self, "_xr_cache", None) is None:
            self._xr_cache = self._xr_starts()
        slow = (self._cp_s, self._tu_s, self._tv_s, self._cp_p, self._tu_p, self._tv_p, self._line_uv,
                self._coarse_uv, self._kind, self._line_theta, self._line_inside, self._hub_xb, self._hub_c,
                self._hub_b, self._sh_xb, self._sh_c, self._sh_b) + self._xr_cache
        fpt = self._fp.copy()
        angle = self._fp[_TC] + channel * self.blisk.pitch
        fpt[_CA], fpt[_SA] = math.cos(angle), math.sin(angle)
        return (self._grid.reshape(-1), self._hs.reshape(-1), tuple(float(v) for v in fpt),
                tuple(int(v) for v in self._ip), self._fp, self._ip, slow)

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
        return _points_kernel(p, float(channel) * self.blisk.pitch, mode, *self._kernel_args(channel))

    def posed_clearances(self, poses, points, channel=0):
        """(P, M, 4): the four clearances of every point under every pose [mm].

        ``clearances`` of the points placed by each pose (parameters as
        :meth:`pose_clearances`), in one numba loop on all threads.
        """
        poses, pts = _poses_and_points(poses, points, "posed_clearances")
        return _posed_kernel(poses, pts, float(channel) * self.blisk.pitch, *self._kernel_args(channel))

    @functools.cached_property
    def wall_features(self):
        """The blade edges and blunt end caps of channel 0, densely sampled (:class:`.wall_features.WallFeatures`).

        What a vertex check cannot see: the certificate measures them against the electrode's triangles.
        Built on first use (~0.05 s), not cached on disk.
        """
        from .wall_features import WallFeatures
        return WallFeatures.from_blisk(self.blisk)

    def pose_clearances(self, poses, points, channel=0):
        """Per pose and surface: the minimum signed distance over the electrode points.

        Transform, lookup and minimum run in one numba loop (no (P, M, 3)
        temporaries).

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
        return _pose_kernel(poses, pts, float(channel) * self.blisk.pitch, *self._kernel_args(channel))

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
        return _exact_pose_kernel(poses, pts, float(channel) * self.blisk.pitch, float(self.error_bound), far,
                                  *self._kernel_args(channel))

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
        args = self._kernel_args(channel)
        dist, uv = _exact_blade_feet(p, float(channel) * self.blisk.pitch, *args[4:])
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
        th -= 2 * np.pi * np.floor((th - self._fp[_TC] + np.pi) / (2 * np.pi))
        return (p[:, 0] >= x0) & (p[:, 0] <= x1) & (rho >= r0) & (rho <= r1) & (th >= t0) & (th <= t1)

    @property
    def grid_bounds(self):
        """((x_min, x_max), (r_min, r_max), (theta_min, theta_max)) of the blade grid [mm, rad], channel 0."""
        fp, ip = self._fp, self._ip
        return tuple((fp[o], fp[o] + (ip[n] - 1) * fp[h])
                     for o, h, n in ((_X0, _HX, _NX), (_R0, _HR, _NR), (_T0, _HT, _NT)))

    # -- error measurement -------------------------------------------------------
    def error_sample_points(self, n=1500, seed=0):
        """Random points within 2 mm of channel 0's surfaces, for the error measurement.

        Per surface ``n`` points at -0.5 ... 2 mm from it (nominal; on both
        sides: a shallow penetration must be seen as well), spread over the
        channel, and ``n`` points within 2 mm of the leading and trailing
        edges of blades 0 and 1 (all around the edge).

        Returns
        -------
        (m, 3) float
            Points in W [mm].
        """
        b = self.blisk
        rng = np.random.default_rng(seed)
        x0, x1 = b.full_span_axial_range
        out = []
        x = rng.uniform(x0, x1, 4 * n)
        hub, shr = b.hub.radius_at(x), b.shroud.radius_at(x)
        r = hub + rng.uniform(0.02, 0.98, 4 * n) * (shr - hub)
        th_s, th_p, inside = b.wall_angles(x, r)
        delta = rng.uniform(-0.5, 2.0, 4 * n)
        frac = rng.uniform(0, 1, 4 * n)
        th_any = th_s + frac * (th_p - th_s)
        sl = [slice(k * n, (k + 1) * n) for k in range(4)]
        out.append(cylindrical_to_cartesian(x[sl[0]], r[sl[0]], th_s[sl[0]] + delta[sl[0]] / r[sl[0]]))
        out.append(cylindrical_to_cartesian(x[sl[1]], r[sl[1]], th_p[sl[1]] - delta[sl[1]] / r[sl[1]]))
        out.append(cylindrical_to_cartesian(x[sl[2]], hub[sl[2]] + delta[sl[2]], th_any[sl[2]]))
        out.append(cylindrical_to_cartesian(x[sl[3]], shr[sl[3]] - delta[sl[3]], th_any[sl[3]]))
        # around the edges: balls of 2 mm about the faces' leading and trailing edge lines
        v = rng.uniform(0.03, 0.97, n)
        u = rng.integers(0, 2, n).astype(float)
        edge = b.suction_face.surface.evaluate(u, v)
        ex, er, et = edge[:, 0], np.hypot(edge[:, 1], edge[:, 2]), np.arctan2(edge[:, 2], edge[:, 1])
        et = et + b.pitch * rng.integers(0, 2, n)          # blade 0 or blade 1
        d = rng.normal(size=(n, 3))
        d *= (rng.uniform(0, 1, n) ** (1 / 3) * 2.0 / np.linalg.norm(d, axis=1))[:, None]
        out.append(cylindrical_to_cartesian(ex, er, et) + d)
        return np.concatenate(out)

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
        return _behind_kernel(p, float(channel) * self.blisk.pitch, *self._kernel_args(channel)[4:])

    def kernel_args(self, channel=0):
        """What numba callers pass on for channel k: ``(channel_angle, flat, hs, fpt, ipt, fp, ip, slow)``.

        ``_fast_point(x, y, z, flat, hs, fpt, ipt)`` answers from the tables,
        ``_exact_at(s, x, y, z, channel_angle, fp, ip, slow, work)`` and
        ``_behind_at(face, ...)`` solve exactly (``work = new_work()``).
        """
        return (float(channel) * self.blisk.pitch,) + self._kernel_args(channel)

    def exact_profile_distances(self, points):
        """Exact signed distances to the hub and the shroud by the numba profile solver (no table).

        Returns
        -------
        (n, 2) float
            [mm], hub and shroud.
        """
        return self._points(points, 0, 1)[:, 2:]

    def reference_clearances(self, points, channel=0, exact=None):
        """The best known signed distances: ``ExactChannelDistance``, refined by the numba solvers.

        Every closest-point solver returns the distance to an actual surface
        point, an upper bound of the true distance; where a numba solver finds
        a closer point than the exact method (``BladeFace.closest_points`` can
        stop short of the minimum when the closest point lies on an edge of
        the face, ``ProfileDistance.signed`` when it lies on the kink at an end
        of the profile), its distance is taken, with the exact method's sign.

        Returns
        -------
        reference : (n, 4) float
            [mm], columns in the order of ``SURFACES``.
        exact : (n, 4) float
            ``ExactChannelDistance.clearances`` unchanged.
        """
        exact = exact or ExactChannelDistance(self.blisk)
        ref = exact.clearances(points, channel)
        mine = self._points(points, channel, 1)
        closer = (np.abs(mine) < np.abs(ref)) & (np.sign(mine) == np.sign(ref))
        return np.where(closer, mine, ref), ref

    def _measure_error(self, n):
        # near the surfaces, and (for the far-field figure) anywhere in the grid
        (x0, x1), (r0, r1), (t0, t1) = self.grid_bounds
        rng = np.random.default_rng(1)
        anywhere = cylindrical_to_cartesian(rng.uniform(x0, x1, n), rng.uniform(r0, r1, n), rng.uniform(t0, t1, n))
        pts = np.concatenate([self.error_sample_points(n), anywhere])
        ref, raw = self.reference_clearances(pts)
        got = self.clearances(pts)
        err = np.abs(got - ref)
        # outside the grid the values are lower bounds by design, not approximations
        inside = self.inside_grid(pts)[:, None]
        far = (np.abs(ref) > ACCURATE_WITHIN) & inside
        self.far_error_bound = 1.5 * float(err[far].max(initial=0.0))
        near = (np.abs(ref) <= ACCURATE_WITHIN) & inside
        self.measured_max_error = {name: float(err[near[:, k], k].max(initial=0.0))
                                   for k, name in enumerate(SURFACES)}
        self.error_sample_count = {name: int(near[:, k].sum()) for k, name in enumerate(SURFACES)}
        # how far BladeFace.closest_points stopped short of the minimum on these points (for the record)
        self.exact_method_excess = float(np.abs(raw - ref)[near].max(initial=0.0))
        # float32 storage: half an ulp of the largest stored value within the band
        quantum = float(np.spacing(np.float32(ACCURATE_WITHIN + 1.0))) / 2
        self.error_bound = 1.5 * max(self.measured_max_error.values()) + quantum

    # -- cache -------------------------------------------------------------------
    def _cache_path(self, cache_dir, cache_key):
        if cache_dir is None or not cache_key:
            return None
        key = str(cache_key)
        if not re.fullmatch(r"[A-Za-z0-9_.\-]{1,100}", key):
            key = hashlib.sha256(key.encode()).hexdigest()
        return pathlib.Path(cache_dir) / f"{key}.fast_field.s{self.spacing:g}.npz"

    _ARRAYS = ("_fp", "_ip", "_grid", "_hs", "_line_uv", "_coarse_uv", "_kind", "_line_theta", "_line_inside")

    def _save(self, path):
        meta = {"version": CACHE_VERSION, "fingerprint": self._fingerprint,
                "error_bound": self.error_bound, "measured_max_error": self.measured_max_error,
                "exact_method_excess": self.exact_method_excess, "far_error_bound": self.far_error_bound,
                "error_sample_count": self.error_sample_count, "stats": self.stats,
                "build_seconds": self.build_seconds}
        tmp = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
            with os.fdopen(fd, "wb") as f:
                np.savez(f, meta=np.array(json.dumps(meta)),
                         **{name.lstrip("_"): getattr(self, name) for name in self._ARRAYS})
            os.replace(tmp, path)          # atomic: a reader sees the old file or the new one
            tmp = None
        except OSError as exc:
            _log.warning("fast field: cannot write the cache %s: %s", path, exc)
        finally:
            if tmp is not None and os.path.exists(tmp):
                os.unlink(tmp)

    def _load(self, path):
        """Load the arrays from ``path``; False (and a rebuild) if missing, stale or corrupt."""
        if not path.is_file():
            return False
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
            if meta.get("version") != CACHE_VERSION or meta.get("fingerprint") != self._fingerprint:
                _log.info("fast field: cache %s is for another geometry or version; rebuilding", path)
                return False
            # mapped, not read: pages shared by every process that loads the field, read when touched
            mapped = map_npz(path, [name.lstrip("_") for name in self._ARRAYS])
            arrays = {name: mapped[name.lstrip("_")] for name in self._ARRAYS}
            fp, ip = arrays["_fp"], arrays["_ip"]
            if fp.shape != (_NPAR,) or ip.shape != (_NIPAR,) or ip.dtype != np.int64:
                raise ValueError("parameter vectors")
            nx, nr, nt = (int(v) for v in ip[[_NX, _NR, _NT]])
            ncx, ncr, nct = (int(v) for v in ip[[_NCX, _NCR, _NCT]])
            expect = {"_grid": ((nx, nr, nt, 2), np.float32), "_hs": ((int(ip[_NHX]), int(ip[_NHR]), 2), np.float32),
                      "_line_uv": ((nx, nr, 2, 2), np.float64), "_coarse_uv": ((ncx, ncr, nct, 2, 2), np.float64),
                      "_kind": ((ncx - 1, ncr - 1, nct - 1, 2), np.uint8),
                      "_line_theta": ((nx, nr, 2), np.float64), "_line_inside": ((nx, nr, 2), np.bool_)}
            for name, (shape, dtype) in expect.items():
                if arrays[name].shape != shape or arrays[name].dtype != dtype:
                    raise ValueError(f"{name}: {arrays[name].shape} {arrays[name].dtype}, expected {shape}")
            ref_fp, ref_ip = self._layout()
            if not (np.array_equal(ip, ref_ip) and np.allclose(fp, ref_fp, rtol=0, atol=1e-9)):
                raise ValueError("grid layout differs")
            error_bound = float(meta["error_bound"])
            measured = {k: float(meta["measured_max_error"][k]) for k in SURFACES}
            if not (np.isfinite(error_bound) and error_bound >= 0):
                raise ValueError("error bound")
        except Exception as exc:     # noqa: BLE001 -- any unreadable cache means: rebuild
            _log.warning("fast field: cache %s unusable (%s); rebuilding", path, exc)
            return False
        for name, value in arrays.items():
            setattr(self, name, np.ascontiguousarray(value))
        self.error_bound = error_bound
        self.measured_max_error = measured
        self.error_sample_count = meta.get("error_sample_count", {})
        self.exact_method_excess = float(meta.get("exact_method_excess", float("nan")))
        self.far_error_bound = float(meta.get("far_error_bound", float("nan")))
        self.stats = dict(meta.get("stats", {}), loaded_from=str(path))
        return True
