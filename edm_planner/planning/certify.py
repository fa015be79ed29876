"""Continuous certification of a fitted axis path (Huang IV.A, Liu 4.2, issue 4 item 6).

The path is a C2 spline q(s) in machine-axis space, interpolated by the
machine exactly as it is certified here. Any electrode vertex moves, per unit
path parameter, by at most

    |o'| + |A'| |u| + |C'| L_C (+ |B'| L_B)

(o the electrode origin's path, u a vertex about the origin, L_C / L_B the
levers of the C / B axes), bounded on each knot interval from the spline's
first and second derivatives (``displacement_bounds``). Certification starts
from the knots and halves every interval whose Lipschitz bound -- with slack
lower bounds c_a, c_b at its ends and displacement bound D over it, the slack
inside is at least ``(c_a + c_b - D) / 2`` per surface -- does not stay above
the margins; a sample below its margin, or an interval that cannot be
certified below the smallest length, is reported with its path parameter,
the surface and the penetration bound. The plan's samples are placed
separately (``sample``) so that no vertex moves more than the sample spacing
(the plan export's 0.05 mm promise) between consecutive samples.

Slack lower bounds come from the fast field (its value less its error bound);
where that is not enough the vertices that can attain the minimum are solved
exactly. The walls' sharp features -- the blade faces' edges at the leading
and trailing edges and blunt end caps, which can pass between two electrode
vertices -- are measured the other way round, feature samples against the
electrode's triangles (:mod:`..interference.wall_features`), and the smaller
of the two is the clearance. Written by hand: no library certifies a spline
motion against a clearance oracle.
"""

from dataclasses import dataclass

import numpy as np

from ..interference import SURFACES
from ..interference.wall_features import triangle_grid

#: how far an exact measurement (the plan's exact re-check, the removal proof) may lie below the certificate's
#: bound before the two disagree [mm]: the exact solvers' and the wall samples' accuracy (1e-6 mm each), with
#: room for rounding. A sound bound is never above a distance measured at a pose of the certified path.
AGREEMENT_ACCURACY = 1e-5


@dataclass
class Certificate:
    """Outcome of a path certification.

    Attributes
    ----------
    certified : bool
    params : (N,) float
        Path parameters of the samples (increasing).
    axes : (N, k) float
    poses : (N, 4, 4) float
    clearances : (N, 4) float
        Lower bounds of the per-surface clearance at the samples [mm].
    lower_bound : (4,) float
        Certified lower bound of the per-surface clearance over the whole
        continuous path (samples and every interval between them, by the
        Lipschitz bound) [mm]; NaN when the path is not certified.
    max_step : float
        Largest bound on any vertex's move between consecutive samples [mm].
    first_failure : float
        Path parameter of the first interval that could not be certified (NaN if certified).
    failure_surface : str
    penetration_bound : float
        [mm] how far below its margin the clearance may go there.
    exact_checks : int
        Samples where vertices were solved exactly.
    """

    certified: bool
    params: np.ndarray
    axes: np.ndarray
    poses: np.ndarray
    clearances: np.ndarray
    max_step: float
    first_failure: float = float("nan")
    failure_surface: str = ""
    penetration_bound: float = 0.0
    exact_checks: int = 0
    lower_bound: np.ndarray = None


def _axis_columns(axis_names):
    idx = {n: i for i, n in enumerate(axis_names)}
    return [idx["X"], idx["Y"], idx["Z"]], idx.get("A"), [idx[n] for n in ("C", "B") if n in idx]


def displacement_bounds(spline, a, b, axis_names, final_offset, vertices):
    """Per interval [a_i, b_i]: a bound on how far any electrode vertex moves along the spline [mm].

    A vertex is at ``p = R_x(A) (w + u)`` with ``w = (X, Y, Z) + t_final`` the
    electrode origin and ``u`` the vertex rotated by C (and B) about it, so
    ``|p'| <= |o'| + |A'| |u| + |C'| L_C (+ |B'| L_B)`` with ``o = R_x(A) w``
    the origin's path. Bounding |o'| by the axes' own speeds would count the
    radius (about 110 mm) times |A'| although A's turn about the blisk axis
    and the compensating Y, Z motion cancel at the origin, so |o'| is taken
    exactly at the interval ends and bounded inside by its second derivative.
    On each interval q'' is linear (samples include every knot), so
    ``max |q'| <= (|q'(a)| + |q'(b)| + (b - a) max(|q''(a)|, |q''(b)|)) / 2``.
    """
    lin, ia, rot = _axis_columns(axis_names)
    h = b - a
    qa, qb = spline(a), spline(b)
    d1a, d1b = spline(a, 1), spline(b, 1)
    d2 = np.maximum(np.abs(spline(a, 2)), np.abs(spline(b, 2)))
    speed = 0.5 * (np.abs(d1a) + np.abs(d1b) + h[:, None] * d2)          # per axis
    reach = float(np.linalg.norm(vertices, axis=1).max())
    lever_c = float(np.hypot(vertices[:, 0], vertices[:, 1]).max())

    def origin_speed(q, d1):
        w = q[:, lin] + final_offset
        v = d1[:, lin].copy()
        if ia is not None:                                 # d/ds R_x(A) w = R_x(A) (w' + A' e_x x w)
            v[:, 1] -= d1[:, ia] * w[:, 2]
            v[:, 2] += d1[:, ia] * w[:, 1]
        return np.linalg.norm(v, axis=1)

    lin_speed = np.linalg.norm(speed[:, lin], axis=1)
    lin_acc = np.linalg.norm(d2[:, lin], axis=1)
    w_max = np.maximum(np.linalg.norm(qa[:, lin] + final_offset, axis=1),
                       np.linalg.norm(qb[:, lin] + final_offset, axis=1)) + h * lin_speed
    if ia is not None:
        sa, acc_a = speed[:, ia], d2[:, ia]
        acc = lin_acc + 2 * sa * lin_speed + (acc_a + sa ** 2) * w_max
    else:
        sa, acc = np.zeros_like(h), lin_acc
    o_speed = 0.5 * (origin_speed(qa, d1a) + origin_speed(qb, d1b) + h * acc)
    total = o_speed + sa * reach
    for j in rot:
        total = total + speed[:, j] * (lever_c if axis_names[j] == "C" and "B" not in axis_names else reach)
    return total * h


class PathCertifier:
    """Samples and certifies spline paths of one electrode in one channel.

    Parameters
    ----------
    field : FastChannelField
    vertices : (M, 3) float
        The electrode mesh's vertices in its frame [mm].
    pose_of : callable
        ``(n, k) axis values -> (n, 4, 4)`` electrode poses in W (channel 0).
    axis_names : sequence of str
    margins : (4,) float
        Required clearance per surface [mm] (order of SURFACES).
    final_offset : (3,) float
        The electrode origin's position at the final pose (t_final) [mm].
    allowance : float
        Subtracted from vertex clearances for the electrode's flat triangles
        (their deviation from the exact offset faces, the electrode's chord
        tolerance) [mm].
    faces : (F, 3) int, optional
        The electrode mesh's triangles: with them the walls' sharp features
        (``field.wall_features``) are measured against the triangles too. Without,
        only vertices are (a bound that a blade edge between two vertices escapes).
    """

    def __init__(self, field, vertices, pose_of, axis_names, margins, final_offset, allowance=0.0, faces=None):
        self.field = field
        self.features, self.triangles = None, None
        if faces is not None:
            self.features = field.wall_features
            self.triangles = triangle_grid(vertices, faces)
        self.final_offset = np.asarray(final_offset, dtype=np.float64)
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.pose_of = pose_of
        self.axis_names = tuple(axis_names)
        self.margins = np.asarray(margins, dtype=np.float64)
        self.allowance = float(allowance)
        self.bound = float(field.error_bound)
        self.exact_checks = 0

    # -- clearance lower bounds -----------------------------------------------------------
    def clearances(self, poses):
        """(n, 4) lower bounds of per-surface clearances of the electrode vertices [mm]."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        low = self.field.pose_clearances(poses, self.vertices, 0)[0] - self.bound
        unsure = np.nonzero((low - self.margins < 0).any(axis=1))[0]
        for i in unsure:                                  # inside the band: solve the candidates exactly
            low[i] = self._exact(poses[i])
            self.exact_checks += 1
        low -= self.allowance
        if self.features is not None:
            low[:, :2] = self.features.clearances(poses, self.triangles, upper=low[:, :2])
        return low

    def _exact(self, pose):
        world = self.vertices @ pose[:3, :3].T + pose[:3, 3]
        fast = self.field.clearances(world, 0)
        out = np.empty(4)
        for j in range(4):
            cand = np.nonzero(fast[:, j] <= fast[:, j].min() + 2 * self.bound)[0]
            if j < 2:
                out[j] = self.field.exact_blade_distances(world[cand], 0)[:, j].min()
            else:
                out[j] = self.field.exact_profile_distances(world[cand])[:, j - 2].min()
        return out

    def slack(self, poses):
        """(n,) smallest slack over the surfaces: clearance lower bound less the margin [mm]."""
        return (self.clearances(poses) - self.margins).min(axis=1)

    # -- sampling and certification --------------------------------------------------------
    def _bounds(self, spline, a, b):
        return displacement_bounds(spline, np.asarray(a, float), np.asarray(b, float), self.axis_names,
                                   self.final_offset, self.vertices)

    def sample(self, spline, s0, s1, spacing=0.05):
        """Parameters on [s0, s1], every knot included, with no vertex moving more than ``spacing`` between them."""
        knots = np.asarray(spline.x)
        params = np.unique(np.concatenate([[s0, s1], knots[(knots > s0) & (knots < s1)]]))
        for _ in range(60):
            move = self._bounds(spline, params[:-1], params[1:])
            if move.max() <= spacing:
                return params, move
            parts = np.maximum(1, np.ceil(1.05 * move / spacing)).astype(int)
            params = np.unique(np.concatenate(
                [np.linspace(lo, hi, n + 1) for lo, hi, n in zip(params[:-1], params[1:], parts)]))
        raise RuntimeError("sampling did not converge")            # only with a non-finite spline

    def certify(self, spline, s0, s1, min_interval=1e-6, max_levels=40):
        """Certify ``spline`` on [s0, s1]: every electrode vertex keeps its margins all along.

        Adaptive: intervals from knot to knot, halved where the Lipschitz bound
        ``(c_a + c_b - D) / 2`` (per surface) does not stay above the margin;
        clearance evaluations only where needed.

        Returns
        -------
        Certificate
            ``params``/``poses``/``clearances`` are the evaluated samples.
        """
        knots = np.asarray(spline.x)
        params = np.unique(np.concatenate([[s0, s1], knots[(knots > s0) & (knots < s1)]]))
        clear = self.clearances(self.pose_of(spline(params)))
        seen_p, seen_c = [params], [clear]
        lo, hi, ca, cb = params[:-1], params[1:], clear[:-1], clear[1:]
        worst_move = 0.0
        failure = None
        for _ in range(max_levels):
            move = self._bounds(spline, lo, hi)
            worst_move = max(worst_move, float(move.max(initial=0.0)))
            sa, sb = ca - self.margins, cb - self.margins
            inside = 0.5 * (sa + sb - move[:, None])
            bad = (inside < 0).any(axis=1)
            at_sample = (sa < 0).any(axis=1) | (sb < 0).any(axis=1)
            tiny = bad & ((hi - lo) < min_interval)
            stop = bad & (at_sample | tiny)
            if stop.any():
                i = int(np.argmax(stop))                   # the earliest along the path
                low = np.where((sa[i] < 0).any(), sa[i], np.where((sb[i] < 0).any(), sb[i], inside[i]))
                j = int(np.argmin(low))
                where = lo[i] if (sa[i] < 0).any() else (hi[i] if (sb[i] < 0).any() else 0.5 * (lo[i] + hi[i]))
                failure = (float(where), SURFACES[j], float(-low[j]))
                break
            if not bad.any():
                break
            lo, hi, ca, cb = lo[bad], hi[bad], ca[bad], cb[bad]
            mid = 0.5 * (lo + hi)
            cm = self.clearances(self.pose_of(spline(mid)))
            seen_p.append(mid)
            seen_c.append(cm)
            lo, hi = np.concatenate([lo, mid]), np.concatenate([mid, hi])
            ca, cb = np.concatenate([ca, cm]), np.concatenate([cm, cb])
            order = np.argsort(lo)
            lo, hi, ca, cb = lo[order], hi[order], ca[order], cb[order]
        else:
            failure = (float(lo[0]), SURFACES[0], float("nan"))
        p = np.concatenate(seen_p)
        c = np.concatenate(seen_c)
        order = np.argsort(p)
        axes = spline(p[order])
        cert = Certificate(failure is None, p[order], axes, self.pose_of(axes), c[order], worst_move,
                           exact_checks=self.exact_checks, lower_bound=np.full(len(SURFACES), np.nan))
        if failure is not None:
            cert.first_failure, cert.failure_surface, cert.penetration_bound = failure
        else:
            cert.lower_bound = self._path_lower_bound(spline, cert.params, cert.clearances)
        return cert

    def _path_lower_bound(self, spline, params, clear):
        """(4,) lower bound of each surface's clearance over the whole path [mm].

        The evaluated samples of a finished certification partition the path
        into the intervals it certified; inside each, every vertex is at least
        ``(c_a + c_b - D) / 2`` clear (``D`` the interval's displacement bound).
        """
        if len(params) < 2:
            return clear.min(axis=0)
        move = self._bounds(spline, params[:-1], params[1:])
        inside = 0.5 * (clear[:-1] + clear[1:] - move[:, None])
        return np.minimum(clear.min(axis=0), inside.min(axis=0))
