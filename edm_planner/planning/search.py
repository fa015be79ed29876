"""Backward exit search (Huang III.A-B, Liu 4.1-4.2).

Start at the electrode's final machining pose, step outwards along a
reference direction (the machine X axis, or the channel centerline) and at
every node choose the free motions -- lateral translation, A, C (and B on a
six-axis machine) -- that keep every electrode sample point inside the
channel with the margins and minimise the method's objective. Stop when the
electrode is clear of the blisk by the exit distance; the reversed node list
is the feed path. Where no step of the current length is feasible the step is
halved (Liu 4.2: shorten the step adaptively); below the smallest step the
channel is reported infeasible with the furthest node, the blocking surface
and its clearance.

Methods: ``default`` (sequential linear programming from the previous
increments: raise the smallest slack up to a cushion, then stay closest to the
previous node's increments, Huang's Objfun1), ``ga`` (Huang's binary GA on
Huang's objective), ``max_min_distance`` (Ayesta 2016: the same LP maximising
the smallest clearance) and ``max_free_distance`` (Kang 2018: pattern search
for the longest free travel along the reference direction).
"""

import logging
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..budget import budget_clock
from ..errors import ErrorCode
from ..geometry.frames import hull_points
from ..interference import SURFACES
from ..interference.wall_features import triangle_grid
from ..cnc.kinematics import state_poses
from .ga import GAOptions, NoFeasibleStart, minimize_ga
from .lp import DenseLp
from .objective import Weights, margin, smoothness

_log = logging.getLogger(__name__)

METHODS = ("default", "ga", "max_min_distance", "max_free_distance")
REFERENCES = ("x_axis", "centerline")
#: free variables per machine: lateral translation (2), then A, C (, B)
FREE_AXES = {4: ("u1", "u2", "C"), 5: ("u1", "u2", "A", "C"), 6: ("u1", "u2", "A", "C", "B")}


class SearchStatus(IntEnum):
    """Outcome of a search (mapped onto ErrorCode by the planner)."""

    SUCCESS = 0
    START_IN_COLLISION = 1
    INFEASIBLE = 2
    TIMEOUT = 3

    @property
    def error_code(self):
        return {0: ErrorCode.SUCCESS, 1: ErrorCode.ELECTRODE_IN_COLLISION,
                2: ErrorCode.INFEASIBLE, 3: ErrorCode.TIMEOUT}[int(self)]


@dataclass(frozen=True)
class SearchOptions:
    """Settings of the exit search (mm, rad, s)."""

    method: str = "default"
    reference: str = "x_axis"
    axes: int = 5
    step: float = 0.1
    min_step: float = 0.0125
    margin_hub_shroud: float = 0.02          # Delta1
    margin_blade: float = 0.02               # Delta2
    exit_distance: float = 2.0
    exit_side: str = "auto"                  # "downstream" (+X), "upstream" (-X) or "auto"
    lateral_ratio: float = 3.0               # largest lateral move per unit step
    angle_step: float = 0.02                 # largest C/B change per node [rad]
    a_step: float = 0.004                    # largest A change per node [rad]: A turns the whole blisk, at a
                                             # radius of ~100 mm its step equals a lateral step of ~0.4 mm
    weights: Weights = field(default_factory=Weights)
    seed: int = 0
    time_budget: float = 60.0                # [s] of work: numba's one-time compilation not counted (budget.py)
    max_nodes: int = 5000
    search_points: int = 1500                # electrode sample points used while searching
    cushion_extra: float = 0.2              # mm of slack beyond the start's that the default method seeks
    search_allowance: float = 0.01           # mm added to the margins while searching: the vertices
                                             # between the search points may come a little closer

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.reference not in REFERENCES:
            raise ValueError(f"reference must be one of {REFERENCES}, got {self.reference!r}")
        if self.axes not in FREE_AXES:
            raise ValueError(f"axes must be 4, 5 or 6, got {self.axes!r}")
        for name in ("step", "min_step", "exit_distance", "lateral_ratio", "angle_step", "a_step",
                     "time_budget"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        for name in ("margin_hub_shroud", "margin_blade", "search_allowance", "cushion_extra"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be >= 0 mm, got {v!r}")
        if self.exit_side not in ("auto", "upstream", "downstream"):
            raise ValueError(f"exit_side must be auto, upstream or downstream, got {self.exit_side!r}")


@dataclass
class SearchResult:
    """Nodes of the exit path (exit order: final pose first) or why there are none."""

    status: SearchStatus
    message: str
    states: np.ndarray                       # (n, 3 + k): position (3), A, C(, B)
    clearances: np.ndarray                   # (n, 4) fast clearances at the nodes
    objfun1: float = 0.0
    objfun2: float = 0.0
    evaluations: int = 0
    direction: int = 1
    blocking_surface: str = ""
    blocking_clearance_lower_bound: float = float("nan")
    furthest_reference: float = 0.0
    elapsed: float = 0.0
    reference: np.ndarray = None             # (n,) distance along the reference at each node [mm]


def _row_minima(rows):
    """(m,) minimum of each row of (m, 4) values: column by column (numpy's min along a short axis is ten
    times slower; the same values)."""
    return np.minimum(np.minimum(rows[:, 0], rows[:, 1]), np.minimum(rows[:, 2], rows[:, 3]))


def _column_minima(rows):
    """(4,) minimum of each column of (m, 4) values, from a transposed copy (the same values, ten times
    sooner than numpy's strided reduction)."""
    return np.ascontiguousarray(rows.T).min(axis=1)


def _feature_vertices(mesh, angle=0.5, limit=3000):
    """Vertices on the mesh's sharp edges (dihedral angle above ``angle`` rad), at most ``limit``."""
    sharp = mesh.face_adjacency_edges[mesh.face_adjacency_angles > angle]
    idx = np.unique(sharp)
    if len(idx) > limit:
        idx = idx[np.linspace(0, len(idx) - 1, limit).astype(int)]
    return np.asarray(mesh.vertices)[idx]


class ExitSearch:
    """Backward search of one electrode out of channel 0.

    Parameters
    ----------
    blisk : Blisk
    electrode : Electrode
        Its mesh vertices and labelled samples (electrode frame).
    field : FastChannelField-like
        ``clearances(points (n, 3), channel) -> (n, 4)`` and ``error_bound``.
    options : SearchOptions
    centerline : Centerline, optional
        Needed for ``reference='centerline'``.
    """

    def __init__(self, blisk, electrode, field, options=None, centerline=None):
        self.blisk = blisk
        self.electrode = electrode
        self.field = field
        self.options = options or SearchOptions()
        self.centerline = centerline
        o = self.options
        self.k = len(FREE_AXES[o.axes])
        rng = np.random.default_rng(o.seed)
        samples = electrode.samples
        total = sum(len(v) for v in samples.values())
        self.points, self.labels = [], []
        for i, label in enumerate(("left", "right", "upper", "lower")):
            pts = samples[label]
            keep = max(16, int(round(o.search_points * len(pts) / total)))
            idx = np.sort(rng.choice(len(pts), size=min(keep, len(pts)), replace=False))
            self.points.append(pts[idx])
            self.labels.append(np.full(len(idx), i))
        # the electrode's edges and corners: where a turning electrode first comes close to a wall
        edges = _feature_vertices(electrode.mesh)
        self.points.append(edges)
        self.labels.append(np.full(len(edges), 4))
        self.points = np.vstack(self.points)
        # the walls' sharp features (blade edges, blunt end caps) against the electrode's triangles: one more
        # column of the clearances (label 5, blade surfaces only), which a vertex sample cannot stand for
        self.features, self.triangles = getattr(field, "wall_features", None), None
        if self.features is not None:
            self.triangles = triangle_grid(electrode.mesh.vertices, electrode.mesh.faces)
            self.labels.append(np.array([5]))
        self.labels = np.concatenate(self.labels)
        self.required = np.array([o.margin_blade, o.margin_blade, o.margin_hub_shroud, o.margin_hub_shroud])
        self.margins = self.required + o.search_allowance
        self.bound = float(getattr(field, "error_bound", 0.0))
        self.evaluations = 0
        x0, x1 = blisk.axial_range
        self.blisk_x = (x0, x1)
        # free-variable step bounds: lateral [mm] (per unit step), angles [rad]
        angles = {4: [o.angle_step], 5: [o.a_step, o.angle_step], 6: [o.a_step, o.angle_step, o.angle_step]}
        self.scale = np.array([o.lateral_ratio, o.lateral_ratio] + angles[o.axes])
        self.cushion = np.inf
        self._evaluated = None                   # (increments, clearances) the last node solve evaluated
        self.reach = float(np.linalg.norm(self.points, axis=1).max())    # lever of the rotations [mm]
        self.mesh_radius = float(np.linalg.norm(electrode.mesh.vertices, axis=1).max())
        self._feature_known = None               # (pose, feature clearance) of the last pose measured
        # Objfun2's points (left / right faces), and the vertices that bound the electrode's axial extent:
        # a linear function's extremes over a mesh lie on its convex hull
        self._left, self._right = np.flatnonzero(self.labels == 0), np.flatnonzero(self.labels == 1)
        self._extent = hull_points(electrode.mesh.vertices)

    # -- evaluation of candidate states ---------------------------------------------
    def _poses(self, states):
        b = states[:, 5] if self.k == 5 else None
        a = states[:, 3] if self.options.axes >= 5 else np.zeros(len(states))
        c = states[:, 4] if self.options.axes >= 5 else states[:, 3]
        return state_poses(self.electrode.final_pose, states[:, :3], a, c, b)

    #: solve the LP at every node, even where the warm start keeps the cushion (for comparisons: same steps)
    lp_at_every_node = False

    #: the feature column's clearances are searched this far [mm] (beyond: reported as this, less the cover)
    FEATURE_REACH = 0.4

    def _distances(self, states, points=None, features=None):
        """(n, m, 4) fast clearances of the search points (or of ``points``) for candidate states.

        With the walls' features (``self.features``), a last column holds their clearance to the electrode's
        triangles (blade surfaces; the hub and shroud entries are the reach): always with the search points,
        with ``points`` only where ``features`` is true; searched only up to what the last pose measured
        allows (``_feature_bound``).
        """
        with_features = self.features is not None and (points is None or bool(features))
        points = self.points if points is None else points
        poses = self._poses(states)
        self.evaluations += len(poses)
        if not len(points):                                 # the feature column alone
            d = np.zeros((len(poses), 0, 4))
        elif hasattr(self.field, "posed_clearances"):      # the fast field: transform and lookup in one loop
            d = self.field.posed_clearances(poses, points, 0)
        else:
            world = np.einsum("pij,mj->pmi", poses[:, :3, :3], points) + poses[:, None, :3, 3]
            d = self.field.clearances(world.reshape(-1, 3), 0).reshape(len(poses), len(points), 4)
        if not with_features:
            return d
        column = np.full((len(poses), 1, 4), self.FEATURE_REACH)
        column[:, 0, :2] = self.features.clearances(poses, self.triangles, upper=self._feature_bound(poses),
                                                    reach=self.FEATURE_REACH)
        self._feature_known = (poses[-1].copy(), column[-1, 0, :2].copy())
        return np.concatenate([d, column], axis=1)

    def _assess(self, states):
        """Per candidate: minimum clearance per surface (n, 4) and feasibility (n,)."""
        d = self._distances(states)
        mins = d.min(axis=1)
        ok = (mins - self.bound >= self.margins).all(axis=1)
        return d, mins, ok

    def _exit_reached(self, states, direction):
        poses = self._poses(states)
        xs = np.einsum("pj,mj->pm", poses[:, 0, :3], self._extent) + poses[:, 0, 3][:, None]
        if direction > 0:
            return xs.min(axis=1) > self.blisk_x[1] + self.options.exit_distance
        return xs.max(axis=1) < self.blisk_x[0] - self.options.exit_distance

    # -- the reference direction ----------------------------------------------------
    def _frame(self, position, direction):
        """Unit reference direction and two normal directions at an electrode position."""
        if self.options.reference == "x_axis" or self.centerline is None:
            t = np.array([float(direction), 0.0, 0.0])
        else:
            pts = self.centerline.sample(400)
            i = int(np.argmin(np.linalg.norm(pts - position, axis=1)))
            if (direction > 0 and i == len(pts) - 1) or (direction < 0 and i == 0):
                j = len(pts) - 1 if direction > 0 else 0          # beyond the ends: the end tangent
                t = (pts[j] - pts[j - direction]) * direction
            else:
                t = (pts[min(i + 1, len(pts) - 1)] - pts[max(i - 1, 0)]) * direction
            t /= np.linalg.norm(t)
        # normals: the circumferential and the radial direction, made orthogonal to t
        e_r = np.array([0.0, position[1], position[2]]) / np.hypot(position[1], position[2])
        e_t = np.array([0.0, -e_r[2], e_r[1]])
        n1 = e_t - t * (t @ e_t)
        n1 /= np.linalg.norm(n1)
        # t x n1, written out (np.cross costs more than the rest of the frame)
        n2 = np.array([t[1] * n1[2] - t[2] * n1[1], t[2] * n1[0] - t[0] * n1[2], t[0] * n1[1] - t[1] * n1[0]])
        return t, n1, n2

    def _candidates(self, state, incr, step, frame):
        """States reached from ``state`` by free increments ``incr`` (n, k) and a reference step."""
        t, n1, n2 = frame
        incr = np.atleast_2d(incr)
        out = np.repeat(state[None], len(incr), axis=0)
        out[:, :3] += step * (t + incr[:, :1] * n1 + incr[:, 1:2] * n2)
        out[:, 3:3 + self.k - 2] += incr[:, 2:]
        return out

    # -- the per-node objective ------------------------------------------------------
    def _objective(self, d, incr, prev_incr):
        """Huang's Objfun (eq. 6) and its terms Objfun1 (eq. 4), Objfun2 (eq. 5) per candidate."""
        w = self.options.weights
        sw = np.array(list(w.smoothness[:2]) + [w.smoothness[2] / (self.k - 2)] * (self.k - 2))
        f1 = smoothness(incr, prev_incr, 2 * self.scale, sw)
        f2 = margin(d[:, self._left, 0], d[:, self._right, 1], w.margin)
        total = w.total[0] * f1 + w.total[1] * f2
        return total, f1, f2

    def _free_travel(self, states, step, frame, limit=40):
        """Kang's free distance: how many further reference steps each candidate can take unchanged."""
        t = frame[0]
        travel = np.zeros(len(states))
        alive = np.ones(len(states), dtype=bool)
        for j in range(1, limit + 1):
            moved = states[alive].copy()
            moved[:, :3] += j * step * t
            _, _, ok = self._assess(moved)
            idx = np.where(alive)[0]
            travel[idx[ok]] = j * step
            alive[idx[~ok]] = False
            if not alive.any():
                break
        return travel

    # -- one node ------------------------------------------------------------------------
    def _solve_node(self, state, prev_incr, step, frame):
        o = self.options
        if o.method == "ga":
            return self._solve_node_ga(state, prev_incr, step, frame)
        if o.method in ("default", "max_min_distance"):
            return self._solve_node_lp(state, prev_incr, step, frame)
        return self._solve_node_pattern(state, prev_incr, step, frame)

    def _slack(self, states, points=None, features=None):
        """(n, m, 4) slack of every search point to every surface: clearance - margin - field bound."""
        return self._distances(states, points, features) - self.margins - self.bound

    def _feature_bound(self, poses):
        """(n, 2) [mm]: bounds of the feature clearance at ``poses`` from the last one measured (None: none yet).

        The features' distance to the electrode is 1-Lipschitz in how far any electrode point moves, and no
        point moves more than ``|R' - R|_F r + |t' - t|`` (r: the mesh's largest vertex radius). The last
        value is exact below the reach, or the reach itself (then so is the bound); with 1e-9 mm for
        rounding, the search finds the same values as without the bound, sooner (the LP's finite
        differences are a few micrometres away from its base).
        """
        if self._feature_known is None:
            return None
        p0, value = self._feature_known
        shift = (np.linalg.norm(poses[:, :3, :3] - p0[:3, :3], axis=(1, 2)) * self.mesh_radius
                 + np.linalg.norm(poses[:, :3, 3] - p0[:3, 3], axis=1))
        return value[None, :] + shift[:, None] + 1e-9

    def _solve_node_lp(self, state, prev_incr, step, frame, iterations=5):
        """Sequential linear programming on the free increments.

        Linearise every near-critical point clearance in the free increments
        (forward differences on the fast field), then one LP (HiGHS): raise the
        smallest slack up to the cushion -- the slack the electrode has at its
        machining pose plus ``cushion_extra`` -- and, among those increments, take the one closest to
        the previous node's (Huang's Objfun1). ``max_min_distance`` raises the
        smallest slack without a cap (Ayesta 2016). Re-linearise at the
        solution until the fast field confirms it feasible.
        """
        o = self.options
        k = self.k
        x0 = np.clip(prev_incr, -self.scale, self.scale)
        cap = np.inf if o.method == "max_min_distance" else self.cushion
        rho = 0.5 * self.scale
        sw = np.array(list(o.weights.smoothness[:2]) + [o.weights.smoothness[2] / (k - 2)] * (k - 2))
        cost_f1 = sw / (2 * self.scale)
        eps = 1e-3 * self.scale
        feasible = []                                      # (x, smallest slack)
        predicted = np.inf                                 # the LP's smallest slack at its step
        # no point moves more than this within the trust region (a slack is 1-Lipschitz in the move)
        move = step * 2 * rho[0] + rho[2:].sum() * self.reach
        for it in range(iterations + 1):
            rows = self._slack(self._candidates(state, x0[None], step, frame))[0]             # (m, 4)
            s0 = rows.reshape(-1)
            if s0.min() >= 0:
                feasible.append((x0, float(s0.min()), s0))
                if it > 0 and o.method != "max_min_distance" and s0.min() >= min(cap, predicted) - 0.002:
                    break                                  # the LP's step, confirmed by the field
                if it == 0 and s0.min() >= cap and not self.lp_at_every_node:
                    # the warm start keeps the cushion: the LP's one optimum is not to move (t = cap, and any
                    # move costs smoothness), so no linearisation is needed; the same step as with it
                    break
            if it == iterations:
                break
            # only points that can come near the smallest slack need a gradient
            near = np.nonzero(_row_minima(rows) <= s0.min() + 2 * move + 1e-3)[0]
            # forward differences: the field is trilinear, its cell gradient is what a step sees
            real = near[near < len(self.points)]              # the feature column comes last, if near
            moved = self._slack(self._candidates(state, x0 + np.diag(eps), step, frame), self.points[real],
                                len(real) < len(near))
            base = s0.reshape(-1, 4)[near].reshape(-1)
            jac = ((moved.reshape(k, -1) - base) / eps[:, None]).T                              # (a, k)
            # near-critical constraints: those a move within the trust region can bring down to the minimum
            reach = np.abs(jac) @ (2.0 * rho)
            active = np.nonzero(base - reach <= s0.min() + 1e-3)[0]
            if len(active) > 800:
                active = active[np.argsort(base[active] - reach[active])[:800]]
            step_lp = self._lp_step(base[active], jac[active], x0, prev_incr, rho, cap, cost_f1, o.method)
            x, predicted = step_lp if step_lp is not None else (None, -np.inf)
            if x is None or np.allclose(x, x0, rtol=0, atol=1e-7):
                break
            x0 = x
        if not feasible:
            return None
        # most slack up to the cushion, then the smoothest
        f1 = [float(cost_f1 @ np.abs(x - prev_incr)) for x, _, _ in feasible]
        i = min(range(len(feasible)), key=lambda j: (-round(min(feasible[j][1], cap), 4), f1[j]))
        x, _, slack = feasible[i]
        self._evaluated = (x, slack.reshape(-1, 4) + self.margins + self.bound)     # its clearances, for the caller
        return x

    def _lp_step(self, s0, jac, x0, prev, rho, cap, cost_f1, method):
        """One LP: variables [dx (k), p (k), q (k), t]; x = x0 + dx, x - prev = p - q, s0 + J dx >= t."""
        k = self.k
        lo = np.maximum(-rho, -self.scale - x0)
        hi = np.minimum(rho, self.scale - x0)
        c = np.zeros(3 * k + 1)
        if method == "max_min_distance":
            c[k:3 * k] = 1e-6 * np.tile(cost_f1, 2)
            c[-1] = -1.0
        else:
            c[k:3 * k] = np.tile(cost_f1, 2)
            c[-1] = -100.0                                 # clearance up to the cushion first
        a_ub = np.zeros((len(s0), 3 * k + 1))
        a_ub[:, :k] = -jac
        a_ub[:, -1] = 1.0
        a_eq = np.zeros((k, 3 * k + 1))
        a_eq[:, :k] = np.eye(k)
        a_eq[:, k:2 * k] = -np.eye(k)
        a_eq[:, 2 * k:3 * k] = np.eye(k)
        col_lo = np.concatenate([lo, np.zeros(2 * k), [-np.inf]])
        col_hi = np.concatenate([hi, np.full(2 * k, np.inf), [cap]])
        if getattr(self, "_lp", None) is None:
            self._lp = DenseLp()                           # one HiGHS instance for all the search's LPs
        x = self._lp.solve(c, a_ub, s0, a_eq, prev - x0, col_lo, col_hi)
        if x is None:
            return None
        return x0 + x[:k], float(x[-1])

    def _solve_node_ga(self, state, prev_incr, step, frame):
        rng = self._rng
        lower, upper = -self.scale, self.scale
        precision = np.full(self.k, 1e-3) * np.maximum(self.scale, 1e-3) / np.maximum(self.scale.max(), 1e-9)

        def feasible(x):
            return self._assess(self._candidates(state, x, step, frame))[2]

        def objective(x):
            d = self._distances(self._candidates(state, x, step, frame))
            return self._objective(d, x, prev_incr)[0]

        try:
            res = minimize_ga(objective, feasible, lower, upper, precision,
                              GAOptions(population_size=24, generations=20, seed=int(rng.integers(1 << 31)),
                                        max_init_attempts=600),
                              seeds=[np.clip(prev_incr, lower, upper)])
        except NoFeasibleStart:
            return None
        return res.x

    def _solve_node_pattern(self, state, prev_incr, step, frame):
        """Kang's max_free_distance: vectorised pattern search around the warm start for the longest free travel."""
        rng = self._rng
        best = np.clip(prev_incr, -self.scale, self.scale)
        spread = 0.25 * self.scale
        best_val, best_ok = None, False
        for _ in range(6):
            trial = np.vstack([best, best + np.diag(spread), best - np.diag(spread),
                               best + rng.normal(size=(4 * self.k, self.k)) * spread])
            trial = np.clip(trial, -self.scale, self.scale)
            states = self._candidates(state, trial, step, frame)
            d, mins, ok = self._assess(states)
            val = np.full(len(trial), np.inf)
            if ok.any():
                val[ok] = -self._free_travel(states[ok], step, frame) - 1e-3 * (mins[ok] - self.margins).min(axis=1)
            if np.isfinite(val).any():
                i = int(np.argmin(val))
                if best_val is None or val[i] < best_val:
                    best, best_val, best_ok = trial[i], val[i], True
                spread *= 0.5
            else:
                # nothing feasible: push towards the largest clearance and widen the search
                slack = (mins - self.margins).min(axis=1)
                best = trial[int(np.argmax(slack))]
                spread = np.minimum(spread * 2.0, self.scale)
        return best if best_ok else None

    # -- the search ----------------------------------------------------------------------
    def run(self, progress=None):
        """Search the exit path; ``progress(fraction, nodes, reference_mm)`` is called now and then."""
        o = self.options
        t0 = budget_clock()
        self._rng = np.random.default_rng(o.seed)
        start = np.zeros(3 + (self.k - 2))
        start[:3] = self.electrode.final_pose[:3, 3]
        d0, m0, _ = self._assess(start[None])
        if not (m0[0] - self.bound >= self.required).all():
            j = int(np.argmin(m0[0] - self.required))
            return SearchResult(SearchStatus.START_IN_COLLISION,
                                f"the electrode at its final pose is {m0[0, j]:.4f} mm from the {SURFACES[j]} "
                                f"surface, below the margin {self.required[j]:.4f} mm (+ field bound "
                                f"{self.bound * 1e3:.1f} um)", start[None], m0, evaluations=self.evaluations,
                                blocking_surface=SURFACES[j],
                                blocking_clearance_lower_bound=float(m0[0, j] - self.bound),
                                elapsed=budget_clock() - t0)
        # the default method keeps, where the channel allows, a little more slack than the electrode has at its
        # machining pose (where every method starts): smooth where there is room, never closer than it starts
        self.cushion = float(min((m0[0] - self.margins - self.bound).min() + self.options.cushion_extra, 0.5))
        sides = {"downstream": [1], "upstream": [-1], "auto": [1, -1]}[o.exit_side]
        results = [self._run_side(start, m0[0], side, t0, progress) for side in sides]
        done = [r for r in results if r.status == SearchStatus.SUCCESS]
        if done:
            best = min(done, key=lambda r: r.objfun1 + r.objfun2)
        else:
            best = max(results, key=lambda r: r.furthest_reference)
        best.evaluations = self.evaluations
        best.elapsed = budget_clock() - t0
        return best

    def _run_side(self, start, clear0, direction, t0, progress):
        o = self.options
        states, clears, refs = [start], [clear0], [0.0]
        prev_incr = np.zeros(self.k)
        step = o.step
        f1_sum = f2_sum = 0.0
        travelled = 0.0
        expected = (self.blisk_x[1] - self.blisk_x[0]) + 2 * o.exit_distance + 30.0
        last_block = (SURFACES[0], float("nan"))
        while True:
            if budget_clock() - t0 > o.time_budget:
                return self._fail(SearchStatus.TIMEOUT, f"time budget of {o.time_budget:g} s used up",
                                  states, clears, direction, travelled, last_block)
            if len(states) > o.max_nodes:
                return self._fail(SearchStatus.INFEASIBLE, f"no exit within {o.max_nodes} nodes",
                                  states, clears, direction, travelled, last_block)
            state = states[-1]
            frame = self._frame(state[:3], direction)
            incr = self._solve_node(state, prev_incr, step, frame)
            if incr is None:
                # record what blocks, then shorten the step (Liu 4.2)
                d, mins, _ = self._assess(self._candidates(state, prev_incr[None], step, frame))
                j = int(np.argmin(mins[0] - self.margins))
                last_block = (SURFACES[j], float(mins[0, j] - self.bound))     # a lower bound over the search points
                step *= 0.5
                if step < o.min_step:
                    return self._fail(SearchStatus.INFEASIBLE,
                                      f"no feasible step after {travelled:.3f} mm along the reference: blocked by the "
                                      f"{last_block[0]} surface (clearance lower bound {last_block[1]:.4f} mm)",
                                      states, clears, direction, travelled, last_block)
                continue
            new = self._candidates(state, incr[None], step, frame)
            known = self._evaluated
            if known is not None and known[0] is incr:
                d = known[1][None]                                    # evaluated by the node's solver
                mins = _column_minima(known[1])[None]
            else:
                d, mins, _ = self._assess(new)
            self._evaluated = None
            _, f1, f2 = self._objective(d, incr[None], prev_incr)       # Huang's terms, for every method
            f1_sum += float(f1[0])
            f2_sum += float(f2[0])
            states.append(new[0])
            clears.append(mins[0])
            prev_incr = incr
            travelled += step
            refs.append(travelled)
            step = min(o.step, step * 1.25)                    # recover the nominal step gently (X stays smooth)
            if progress is not None and len(states) % 25 == 0:
                progress(min(travelled / expected, 0.99), len(states), travelled)
            if self._exit_reached(new, direction)[0]:
                return SearchResult(SearchStatus.SUCCESS, f"exit found after {travelled:.2f} mm, {len(states)} nodes",
                                    np.array(states), np.array(clears), f1_sum, f2_sum, direction=direction,
                                    furthest_reference=travelled, reference=np.array(refs))

    def _fail(self, status, message, states, clears, direction, travelled, block):
        return SearchResult(status, message, np.array(states), np.array(clears), direction=direction,
                            blocking_surface=block[0], blocking_clearance_lower_bound=block[1],
                            furthest_reference=travelled)
