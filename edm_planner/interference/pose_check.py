"""The exact re-check of a pose sequence: every electrode vertex at every pose, exactly.

:func:`verify_poses` gives the exact minimum signed clearance per surface
over all samples and vertices of a pose sequence (the field's branch and
bound of :mod:`.min_search` with the numba exact solvers, and the
side-of-wall test for vertices behind a wall). The planner fills a plan's
exact clearance with it; :func:`edm_planner.records.plan_check.verify_exported_plan`
applies it to an exported plan directory. Units: mm, rad.
"""

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from ..constants import EXACT_TOLERANCE, RIGID_TOLERANCE
from ..geometry.frames import hull_points, rotation_about_x
from . import SURFACES
from . import fast as _fast
from . import min_search as _search
from .exact_points import transform_points
from .wall_features import triangle_grid

_log = logging.getLogger(__name__)


def box_error(pa, pb, box):
    """Largest distance between box corners under two pose batches (bounds every point inside)."""
    return float(np.linalg.norm(transform_points(pa, box) - transform_points(pb, box), axis=2).max())


def _behind_pairs(P, V, anchors, args, chunk_bytes=32_000_000):
    """(sample, vertex, wall) of the vertex positions found behind a wall by the side tests.

    Every vertex at the anchors; where a vertex is behind a wall at either of two consecutive anchors or
    its side differs, every sample between them. Anchors in chunks (their flags take anchors x M x 2 bytes).
    """
    step = max(2, chunk_bytes // (2 * len(V)))
    found = []
    for i in range(0, max(len(anchors) - 1, 1), step - 1):
        part = anchors[i:i + step]
        sides = _search._anchor_sides(P, V, part, *args)                 # (anchors, M, 2)
        at, ak, af = np.nonzero(sides if i == 0 else sides[1:])          # each anchor once
        found.append((part[at + (i > 0)], ak, af))
        gap, k, face = np.nonzero(sides[:-1] | sides[1:] | (sides[:-1] != sides[1:]))
        first, last = part[gap] + 1, part[gap + 1]
        flags, start = _search._sweep_sides(P, V, face.astype(np.int64), k.astype(np.int64), first, last, *args)
        pos = np.flatnonzero(flags)
        run = np.searchsorted(start, pos, side="right") - 1
        found.append((first[run] + pos - start[run], k[run], face[run]))
    return tuple(np.concatenate([f[j] for f in found]).astype(np.int64) for j in range(3))


def _vertex_moves(P, V):
    """(N - 1,) largest move of any vertex between consecutive poses [mm].

    A vertex's move |(R_b - R_a) v + T_b - T_a| is convex in v, so its largest
    value over the vertices is attained at a vertex of their convex hull.
    """
    if len(P) < 2:
        return np.zeros(0)
    return _search._vertex_steps(P, hull_points(V))


def _anchors(moves, stride, travel):
    """First and last sample, and between them as far apart as no vertex travels more than ``travel`` mm
    (bounded by the sum of the largest moves) and no more than ``stride`` samples."""
    N = len(moves) + 1
    path = np.concatenate([[0.0], np.cumsum(moves)])
    out = [0]
    while out[-1] < N - 1:
        a = out[-1]
        far = int(np.searchsorted(path, path[a] + travel, side="right")) - 1
        out.append(max(a + 1, min(far, a + stride, N - 1)))
    return np.array(out, dtype=np.int64)


@dataclass
class PoseCheck:
    """The exact clearance of an electrode along a sequence of poses (:func:`verify_poses`).

    Attributes
    ----------
    passed : bool
        Every surface's minimum at least ``threshold``.
    clearance_exact : dict
        Surface -> the smallest exact signed clearance over all samples and vertices [mm]; with
        ``faces``, the smaller of that and the walls' feature lower bound (``feature_cover``).
    argmin : dict
        Surface -> (sample, vertex) attaining it; vertex -1 where a wall feature does.
    max_vertex_step : float
        Largest move of any vertex between consecutive samples [mm].
    samples, vertices : int
    anchor_samples : int
        Samples at which every vertex's side of both walls was tested.
    exact_evaluations : int
        (sample, vertex) pairs evaluated exactly on at least one surface.
    exact_by_surface : dict
        Surface -> exact point-to-surface solves.
    behind_pairs : int
        (sample, vertex, wall) triples found behind a wall by the side tests.
    threshold : float
    elapsed : float
        [s], without building or loading the distance field.
    message : str
    vertex_clearance : dict
        Surface -> the vertices' exact minimum alone [mm].
    feature_cover : float
        Covering radius of the wall-feature samples [mm] (NaN: features not checked).
    """

    passed: bool
    clearance_exact: dict
    argmin: dict
    max_vertex_step: float
    samples: int
    vertices: int
    anchor_samples: int
    exact_evaluations: int
    exact_by_surface: dict
    behind_pairs: int
    threshold: float
    elapsed: float
    message: str = ""
    vertex_clearance: dict = None
    feature_cover: float = float("nan")


def _rigid_or_raise(poses):
    R = poses[:, :3, :3]
    ortho = np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)).max()
    if ortho > RIGID_TOLERANCE or np.abs(np.linalg.det(R) - 1.0).max() > RIGID_TOLERANCE:
        raise ValueError(f"verify_poses: poses must be rigid motions (|R^T R - I| = {ortho:.3g})")


def verify_poses(poses, vertices, channel, blisk, field=None, *, threshold=0.0, anchor_travel=0.5,
                 anchor_stride=256, cache_dir=None, cache_key=None, threads=None, progress=None, faces=None):
    """The exact minimum clearance of every vertex at every pose, per surface of a channel.

    The exact signed distances are those of the numba solvers of
    :class:`~..interference.fast.FastChannelField` (``exact_blade_distances``,
    ``exact_profile_distances``: the surfaces and the sign rule of
    :class:`~..interference.exact_points.ExactChannelDistance`; equal to 1e-6 mm,
    or closer to the surface where ``BladeFace.closest_points`` stops short
    near an edge of a face). The minimum over all poses times vertices is found
    by branch and bound on the 1-Lipschitz distance (``interference.fast``,
    "Exact minimum over a pose sequence"): exact, not sampled, and a few hundred thousand exact
    solves for a plan of 10^4 poses x 10^4 vertices. The bound holds for vertex
    positions in front of the walls; those behind a wall are found by side
    tests (the sign rule alone): every vertex at anchor poses (the first, the
    last, and between them no vertex travels more than ``anchor_travel`` and
    no more than ``anchor_stride`` poses apart), and every pose between two
    anchors where a vertex is behind a wall at either or its side differs;
    each is solved exactly. Not covered: a vertex that goes behind a wall
    around the face's edge (across the footprint's boundary, not through the
    face) and comes back between two anchors (``anchor_stride=1`` tests every
    vertex at every pose); contact between vertices (faces, and motion between
    poses, which a small vertex step bounds).

    Parameters
    ----------
    poses : (N, 4, 4) float
        Electrode frame -> W, rigid motions (to ``RIGID_TOLERANCE``).
    vertices : (M, 3) float
        Electrode points in its frame [mm].
    channel : int
    blisk : Blisk
    field : FastChannelField, optional
        Its exact solvers are used, its tables only to skip side tests more
        than 1 mm in front of a wall. Built, or loaded from ``cache_dir``
        under ``cache_key``, when not given (~6 s to build, ~1 s to load).
    threshold : float
        Smallest clearance accepted [mm].
    anchor_travel : float
        Largest vertex travel between anchors of the side tests [mm].
    anchor_stride : int
        Most poses between anchors.
    threads : int, optional
        Searches run at once (each surface in two halves of the vertex tree, the walls first); numba's
        thread count by default. The result does not depend on it (the counts of exact solves may vary by
        the threads' timing).
    progress : callable, optional
        ``progress(stage, fraction, 0, 0.0, message)``, stage "anchors" then "search".
    faces : (F, 3) int, optional
        The electrode mesh's triangles (``vertices`` its vertices): the walls' sharp
        features (blade edges, blunt end caps; :mod:`.wall_features`) are then measured
        against the triangles at every pose, and a wall's figure is the smaller of its
        vertex minimum and its feature lower bound (exact distances of the feature samples
        less their covering radius, ``PoseCheck.feature_cover``). Without, vertices only.

    Returns
    -------
    PoseCheck

    Raises
    ------
    ValueError
        Malformed or non-rigid poses, no vertices.
    """
    P = np.ascontiguousarray(np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4))
    V = np.ascontiguousarray(np.atleast_2d(np.asanyarray(vertices, dtype=np.float64)))
    if len(P) < 1 or V.ndim != 2 or V.shape[1] != 3 or len(V) < 1:
        raise ValueError(f"verify_poses: need (N >= 1, 4, 4) poses and (M >= 1, 3) vertices, got {P.shape}, "
                         f"{V.shape}")
    if not (np.isfinite(P).all() and np.isfinite(V).all()):
        raise ValueError("verify_poses: poses and vertices must be finite")
    _rigid_or_raise(P)
    if field is None:
        field = _fast.FastChannelField(blisk, spacing=0.1, cache_dir=cache_dir, cache_key=cache_key)
    report = progress or (lambda *a: None)
    t0 = time.perf_counter()
    N, m = len(P), len(V)
    full = field._plain_args(channel)                # plain inner tuples: numba types them in C, fast
    args = (full.channel_angle, full.params, full.shape, full.tables)      # what the exact solvers take

    moves = _vertex_moves(P, V)
    max_vstep = float(moves.max()) if len(moves) else 0.0
    anchors = _anchors(moves, max(1, int(anchor_stride)), float(anchor_travel))
    report("anchors", 0.0, 0, 0.0, f"{N} samples x {m} vertices")
    behind_t, behind_k, behind_f = _behind_pairs(P, V, anchors, full)
    seeds = _search._exact_pairs(P, V, behind_t, behind_k, behind_f, *args)
    report("anchors", 1.0, 0, 0.0, f"{len(behind_t)} vertex positions behind a wall")

    trees = search_trees(P, V)
    # each surface searched as two halves of the vertex tree sharing their best value: the suction wall
    # alone took as long as the three other surfaces together, which left one of two threads idle (the
    # default plan's re-check, Zen 3, 8 alternated runs: 1.03 / 1.22 s min / median whole, 0.94 / 1.09 s halved;
    # four or eight parts per surface gained nothing more)
    halves = trees.halves
    shared = [np.full(1, np.inf) for _ in SURFACES]

    def search(s, half):
        mine = behind_f == s
        return surface_minimum(s, P, V, trees, args, (behind_t[mine], behind_k[mine], seeds[mine]),
                                       half, shared[s])

    workers = max(1, min(len(SURFACES) * len(halves), int(threads or numba.get_num_threads())))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        jobs = [[pool.submit(search, s, half) for half in halves] for s in range(len(SURFACES))]  # walls first
        results = []
        for i, parts in enumerate(jobs):
            results.append(_joined([job.result() for job in parts], m))
            report("search", (i + 1) / len(jobs), 0, 0.0, f"{SURFACES[i]} {results[-1][0]:.4f} mm")

    best = {s: float(r[0]) for s, r in zip(SURFACES, results)}
    argmin = {s: (int(r[1]), int(r[2])) for s, r in zip(SURFACES, results)}
    vertex_best = dict(best)
    cover = float("nan")
    if faces is not None:
        # the features are sampled in channel 0: the poses taken there
        features = field.wall_features
        cover = features.cover
        P0 = _channel_zero(P, channel, blisk.pitch)
        upper = np.broadcast_to([best[SURFACES[0]], best[SURFACES[1]]], (N, 2))
        feat = features.clearances(P0, triangle_grid(V, faces), upper=upper)
        for j in range(2):
            i = int(np.argmin(feat[:, j]))
            if feat[i, j] < best[SURFACES[j]]:
                best[SURFACES[j]], argmin[SURFACES[j]] = float(feat[i, j]), (i, -1)
    evaluated = _distinct_count(np.concatenate([r[4] for r in results]))
    problems = [f"{s} clearance {best[s]:.4f} mm below {threshold} mm at sample {argmin[s][0]}"
                for s in SURFACES if best[s] < threshold]
    elapsed = time.perf_counter() - t0
    return PoseCheck(passed=not problems, clearance_exact=best, argmin=argmin, max_vertex_step=max_vstep,
                     samples=N, vertices=m, anchor_samples=len(anchors), exact_evaluations=evaluated,
                     exact_by_surface={s: int(r[3]) for s, r in zip(SURFACES, results)},
                     behind_pairs=len(behind_t), threshold=float(threshold), elapsed=elapsed,
                     message="; ".join(problems) or "ok", vertex_clearance=vertex_best, feature_cover=cover)


class SearchTrees(NamedTuple):
    """The branch and bound's trees over one pose sequence and vertex set (:func:`search_trees`)."""
    rep: np.ndarray          # the vertex clusters (``_vertex_tree``): representative, radius, children
    radius: np.ndarray
    left: np.ndarray
    right: np.ndarray
    offset: np.ndarray       # |representative - origin|, the origin the sample tree's moves are taken about
    samples: tuple           # ``_sample_tree``: mid, rho, tau, left, right

    @property
    def halves(self):
        """The vertex tree's top clusters to search apart: its two children, or the root of a one-vertex tree."""
        return [int(self.left[0]), int(self.right[0])] if self.left[0] >= 0 else [0]


def search_trees(poses, vertices):
    """The vertex and sample trees of ``surface_minimum`` for (N, 4, 4) poses and (M, 3) vertices (contiguous)."""
    rep, radius, left, right = _search._vertex_tree(vertices)
    origin = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return SearchTrees(rep, radius, left, right, np.linalg.norm(vertices[rep] - origin, axis=1),
                       _search._sample_tree(poses, origin))


_NO_SEEDS = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))


def surface_minimum(surface, poses, vertices, trees, exact_args, seeds=_NO_SEEDS, root=0, shared=None):
    """``_min_search`` of one surface over the vertices of cluster ``root`` (0: all) and every sample.

    ``exact_args``: (channel angle, params, shape, tables) of the field's plain kernel arguments;
    ``seeds``: (sample, vertex, value) arrays of pairs evaluated already; ``shared``: the (1,) array the
    searches of one surface share (a new one when None). Returns (minimum, sample, vertex, exact
    evaluations, keys of the pairs evaluated).
    """
    return _search._min_search(surface, poses, vertices, trees.rep, trees.radius, trees.offset, trees.left,
                               trees.right, *trees.samples, *seeds, EXACT_TOLERANCE, *exact_args, root,
                               np.full(1, np.inf) if shared is None else shared)


def _joined(parts, m):
    """One surface's search result from its parts' (minimum, sample, vertex, evaluations, keys): the smallest
    minimum, the lowest pair key among equal ones (as one search over every vertex gives)."""
    found = [r for r in parts if np.isfinite(r[0])] or parts[:1]      # none finite: inf, as one search gives
    best = min(found, key=lambda r: (r[0], r[1] * m + r[2]))
    return (best[0], best[1], best[2], sum(int(r[3]) for r in parts), np.concatenate([r[4] for r in parts]))


def _distinct_count(keys):
    """How many distinct values an int array holds.

    Sorted, not ``len(np.unique(keys))``: numpy 2.3+ counts a 1-D array's distinct values in a hash table,
    50 times slower here (0.36 s against 0.007 s for the 350 000 keys of a demo plan's re-check, Zen 3).
    """
    s = np.sort(keys)
    return int(s.size and 1 + np.count_nonzero(s[1:] != s[:-1]))


def _channel_zero(poses, channel, pitch):
    """Poses in channel ``channel`` taken to channel 0 (a rotation about X)."""
    if not channel:
        return poses
    return np.ascontiguousarray(rotation_about_x(-channel * pitch)[None] @ poses)
