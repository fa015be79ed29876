"""Tool pose optimisation: minimum one-sided Hausdorff distance (Chen & Dong eq. 1-2, 9; section 3.2).

The flat tool bottom is discretised into points b_i (tool frame, z = 0); a
pose x = (alpha, beta, t) moves them to

    p_i(x) = T0 . T_z(t) . R_x(alpha) . R_y(beta) . b_i

with T0 the initial pose (tool frame -> W; origin at the centre of the flat
bottom, z = tool axis from the bottom up the shank): alpha, beta turn the
tool about its own x and y axes through the bottom centre, t moves it along
its initial axis (positive = away from the surface). The paper's gamma (about
the tool axis) is left out: a flat-bottomed tool is symmetric about its axis,
so every d_i has zero sensitivity to it (it would only make the LP's
increment arbitrary in that component). Units: mm, rad.

The model (eq. 2) minimises h = max_i d_i(x), d_i the distance of p_i(x) to
the target surface (eq. 4-8, :class:`~.distance.RevolutionDistance`). With
e_i the signed distance (d_i = |e_i|), the constraint d_i <= h is the pair
-h <= e_i <= h, each side smooth, which is the exact linearisation of d_i
also where a point crosses the surface (there |e_i| has a kink).

Three stages, each reported separately:

1. :func:`paper_iteration` -- eq. 9 as written: at x_k linearise
   e_i(x_k + dx) ~ e_i + grad e_i . dx, solve min h s.t. the linearised
   constraints with slack variables s_i >= 0 (equalities
   ``+-(e_i + grad e_i dx) + s_i = h``) and the rotation/translation ranges, as a
   linear programme (scipy ``linprog``, HiGHS), update x_{k+1} = x_k + eta dx,
   stop when the increment (rotations weighted by the tool radius, so in mm
   at the rim) or the change of h falls below its tolerance, or after N_max
   iterations.
2. :func:`optimise_pose` runs the paper's secondary optimisation (section
   3.2) where stage 1 made a position worse than its initial pose: the same
   iteration again from the initial pose with the tightened rotation range.
3. Our addition, because the plain iteration (a fixed fraction eta of an LP
   step bounded only by the parameter ranges) zig-zags around the minimax
   optimum instead of settling in it: :func:`trust_region_polish`, the same
   linearised LP inside a trust region that grows or shrinks with the ratio
   of actual to predicted decrease and accepts only decreasing steps (the
   sequential LP of Madsen 1975 for minimax problems), to a first-order
   stationary point of the minimax problem within the first-round ranges.

:func:`brute_force_optimum` is an independent global check (grid over the
rotations with the exact 1-D optimum in t, Nelder-Mead restarts, an SLSQP
epigraph polish); the tests and the benchmark compare it with stage 3.
"""

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, linprog, minimize

_LP_OPTIONS = {"presolve": True, "primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


def bottom_points(radius, rings=3, outer_points=24):
    """Discretised flat tool bottom: its centre and ``rings`` concentric rings.

    Ring j (1..rings) has radius ``radius * j / rings`` and a number of points
    proportional to j (a multiple of 4, so every ring has points on the tool
    frame's x and y axes), ``outer_points`` on the rim.

    Returns
    -------
    (m, 3) float
        Points in the tool frame (z = 0) [mm].
    """
    pts = [np.zeros((1, 3))]
    for j in range(1, rings + 1):
        n = 4 * int(np.ceil(outer_points * j / (4.0 * rings)))
        phi = 2 * np.pi * np.arange(n) / n
        rho = radius * j / rings
        pts.append(np.column_stack([rho * np.cos(phi), rho * np.sin(phi), np.zeros(n)]))
    return np.vstack(pts)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _ry(b):
    c, s = np.cos(b), np.sin(b)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _drx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[0.0, 0, 0], [0, -s, -c], [0, c, -s]])


def _dry(b):
    c, s = np.cos(b), np.sin(b)
    return np.array([[-s, 0, c], [0, 0.0, 0], [-c, 0, -s]])


class ToolPoseModel:
    """Signed distances of the tool-bottom points to the target and their sensitivities.

    Parameters
    ----------
    distance : RevolutionDistance
        The target surface.
    initial_pose : (4, 4) float
        T0, tool frame -> W (z = tool axis, origin at the bottom centre).
    bottom : (m, 3) float
        Tool-bottom points in the tool frame [mm] (:func:`bottom_points`).
    scale : float
        Length that converts the rotations to mm in norms and trust regions
        (the tool radius) [mm].
    """

    def __init__(self, distance, initial_pose, bottom, scale):
        self.distance = distance
        self.T0 = np.asarray(initial_pose, dtype=np.float64)
        self.bottom = np.asarray(bottom, dtype=np.float64)
        self.scale = float(scale)
        self.evaluations = 0

    def pose(self, x):
        """Tool pose (4, 4) in W for parameters x = (alpha, beta, t)."""
        a, b, t = x
        local = np.eye(4)
        local[:3, :3] = _rx(a) @ _ry(b)
        local[2, 3] = t
        return self.T0 @ local

    def points(self, x):
        """Tool-bottom points in W at x, (m, 3) [mm]."""
        T = self.pose(x)
        return self.bottom @ T[:3, :3].T + T[:3, 3]

    def errors(self, x):
        """Signed distances e_i(x) [mm]."""
        self.evaluations += 1
        return self.distance.signed_distance(self.points(x))

    def evaluate(self, x):
        """e_i(x) (m,) and the Jacobian d e_i / d(alpha, beta, t) (m, 3)."""
        self.evaluations += 1
        a, b, _ = x
        R0 = self.T0[:3, :3]
        p = self.points(x)
        e, grad, _ = self.distance.closest(p)
        dpa = self.bottom @ (R0 @ _drx(a) @ _ry(b)).T
        dpb = self.bottom @ (R0 @ _rx(a) @ _dry(b)).T
        jac = np.column_stack([np.einsum("ij,ij->i", grad, dpa), np.einsum("ij,ij->i", grad, dpb),
                               grad @ R0[:, 2]])
        return e, jac

    def objective(self, x):
        """h(x) = max_i |e_i(x)|, the one-sided Hausdorff distance of the discretised bottom [mm]."""
        return float(np.max(np.abs(self.errors(x))))

    def norm(self, dx):
        """Size of an increment in mm: rotations times the tool radius, t as it is."""
        return float(np.linalg.norm([dx[0] * self.scale, dx[1] * self.scale, dx[2]]))


def linearised_step(e, jac, lower, upper):
    """One LP of eq. 9: min h over (dx, h, s) with +-(e + J dx) + s = h, s >= 0, lower <= dx <= upper.

    Parameters
    ----------
    e : (m,) float
        Signed distances at the current pose [mm].
    jac : (m, k) float
        Their sensitivities.
    lower, upper : (k,) float
        Bounds of the increment.

    Returns
    -------
    dx : (k,) float
    h_lin : float
        The linearised objective at dx [mm].
    """
    m, k = jac.shape
    n_var = k + 1 + 2 * m
    c = np.zeros(n_var)
    c[k] = 1.0
    a_eq = np.zeros((2 * m, n_var))
    a_eq[:m, :k] = jac
    a_eq[m:, :k] = -jac
    a_eq[:, k] = -1.0
    a_eq[np.arange(2 * m), k + 1 + np.arange(2 * m)] = 1.0
    b_eq = np.concatenate([-e, e])
    bounds = [(lo, hi) for lo, hi in zip(lower, upper)] + [(0.0, None)] + [(0.0, None)] * (2 * m)
    res = linprog(c, A_eq=a_eq, b_eq=b_eq, bounds=bounds, method="highs", options=_LP_OPTIONS)
    if res.status != 0:
        # a degenerate LP (never seen); the zero step is feasible and safe
        return np.zeros(k), float(np.max(np.abs(e)))
    return res.x[:k], float(res.x[k])


@dataclass
class IterationResult:
    """Outcome of one optimisation stage.

    Attributes
    ----------
    x : (3,) float
        alpha, beta [rad], t [mm].
    h : float
        max |e_i| at x [mm].
    iterations : int
        LPs solved.
    history : list of float
        h after every iteration [mm].
    """

    x: np.ndarray
    h: float
    iterations: int
    history: list


def paper_iteration(model, x0, lower, upper, eta=0.5, increment_tolerance=1e-6, objective_tolerance=1e-7,
                    max_iterations=50):
    """Eq. 9 as the paper states it: x_{k+1} = x_k + eta dx_k until ||eta dx|| < eps or |h_{k+1} - h_k| < eps.

    Parameters
    ----------
    model : ToolPoseModel
    x0 : (3,) float
    lower, upper : (3,) float
        The rotation and translation ranges (the paper's [-0.1 pi, 0.1 pi] and [0, 2 mm]).
    eta : float
        Step factor in (0, 1].
    increment_tolerance : float
        On the increment's size (:meth:`ToolPoseModel.norm`) [mm].
    objective_tolerance : float
        On the change of h [mm].
    max_iterations : int
        N_max.

    Returns
    -------
    IterationResult
        The last iterate (as the paper's iteration ends), not necessarily the best one.
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    x = np.clip(np.asarray(x0, dtype=np.float64), lower, upper)
    e, jac = model.evaluate(x)
    h = float(np.max(np.abs(e)))
    history = []
    k = 0
    for k in range(1, max_iterations + 1):
        dx, _ = linearised_step(e, jac, lower - x, upper - x)
        step = eta * dx
        x = np.clip(x + step, lower, upper)
        e, jac = model.evaluate(x)
        h_new = float(np.max(np.abs(e)))
        history.append(h_new)
        converged = model.norm(step) < increment_tolerance or abs(h_new - h) < objective_tolerance
        h = h_new
        if converged:
            break
    return IterationResult(x=x, h=h, iterations=k, history=history)


def trust_region_polish(model, x0, lower, upper, radius=None, tolerance=1e-12, max_iterations=200):
    """Minimax SLP with a trust region (Madsen 1975) from x0, within [lower, upper].

    Each iteration solves the LP of eq. 9 with the increment also bounded by
    the trust radius (rotations times the tool radius, in mm); a step is taken
    only if it lowers h by at least 1 % of the LP's predicted decrease; the
    radius doubles after a good prediction at the boundary and shrinks to a
    quarter after a poor one. Stops when the predicted decrease or the radius
    falls below ``tolerance`` [mm]: a stationary point of max |e_i|.

    Returns
    -------
    IterationResult
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    x = np.clip(np.asarray(x0, dtype=np.float64), lower, upper)
    e, jac = model.evaluate(x)
    h = float(np.max(np.abs(e)))
    lam = 0.05 * model.scale if radius is None else float(radius)
    w = np.array([model.scale, model.scale, 1.0])
    history = []
    k = 0
    for k in range(1, max_iterations + 1):
        lo = np.maximum(lower - x, -lam / w)
        hi = np.minimum(upper - x, lam / w)
        dx, h_lin = linearised_step(e, jac, lo, hi)
        predicted = h - h_lin
        if predicted <= tolerance:
            break
        x_new = np.clip(x + dx, lower, upper)
        e_new, jac_new = model.evaluate(x_new)
        h_new = float(np.max(np.abs(e_new)))
        ratio = (h - h_new) / predicted
        if ratio > 0.01:
            x, e, jac, h = x_new, e_new, jac_new, h_new
        history.append(h)
        at_boundary = np.max(np.abs(dx) * w) >= 0.99 * lam
        if ratio > 0.75 and at_boundary:
            lam *= 2.0
        elif ratio < 0.25:
            lam = 0.25 * min(lam, np.max(np.abs(dx) * w))
        if lam < tolerance:
            break
    return IterationResult(x=x, h=h, iterations=k, history=history)


@dataclass
class PoseOptimum:
    """One position's optimisation.

    Attributes
    ----------
    x : (3,) float
        Final alpha, beta [rad], t [mm].
    pose : (4, 4) float
        Final tool pose in W.
    h_initial, h_paper, h : float
        max |e_i| at the initial pose, after the paper's iteration (with the
        secondary optimisation where it applied), and final [mm].
    x_paper : (3,) float
    iterations : int
        LPs of the paper's iteration (both rounds where the secondary ran).
    polish_iterations : int
        LPs of the trust-region polish (0 without it).
    secondary : bool
        The paper's secondary optimisation ran (round 1 made the position worse).
    """

    x: np.ndarray
    pose: np.ndarray
    h_initial: float
    h_paper: float
    h: float
    x_paper: np.ndarray
    iterations: int
    polish_iterations: int
    secondary: bool


def parameter_bounds(rotation_range, translation_range):
    """(lower, upper) of (alpha, beta, t) for a rotation range +-rotation_range [rad] and a t range (lo, hi) [mm]."""
    lo_t, hi_t = translation_range
    return (np.array([-rotation_range, -rotation_range, lo_t]), np.array([rotation_range, rotation_range, hi_t]))


def optimise_pose(model, rotation_range, translation_range, secondary_rotation_range, eta=0.5,
                  increment_tolerance=1e-6, objective_tolerance=1e-7, max_iterations=50, polish=True):
    """Paper iteration, secondary optimisation where it applies, then the trust-region polish.

    The polish starts from the better of the paper's result and the initial
    pose and works within the first-round ranges, so the final h is never
    above either.

    Returns
    -------
    PoseOptimum
    """
    lower, upper = parameter_bounds(rotation_range, translation_range)
    x0 = np.clip(np.zeros(3), lower, upper)
    h0 = model.objective(np.zeros(3))
    first = paper_iteration(model, x0, lower, upper, eta, increment_tolerance, objective_tolerance, max_iterations)
    best, iterations, secondary = first, first.iterations, False
    if first.h > h0:
        secondary = True
        lo2, hi2 = parameter_bounds(secondary_rotation_range, translation_range)
        second = paper_iteration(model, np.clip(np.zeros(3), lo2, hi2), lo2, hi2, eta, increment_tolerance,
                                 objective_tolerance, max_iterations)
        iterations += second.iterations
        if second.h < first.h:
            best = second
    x, h, polish_iterations = best.x, best.h, 0
    if polish:
        start = best.x if best.h <= h0 else x0
        fin = trust_region_polish(model, start, lower, upper)
        x, h, polish_iterations = fin.x, fin.h, fin.iterations
    return PoseOptimum(x=x, pose=model.pose(x), h_initial=h0, h_paper=best.h, h=h, x_paper=best.x,
                       iterations=iterations, polish_iterations=polish_iterations, secondary=secondary)


def _best_t(model, a, b, t_lo, t_hi):
    """For fixed rotations the exact optimum in t: the root of max e + min e (both rise with t)."""
    def f(t):
        e = model.errors((a, b, t))
        return float(e.max() + e.min())

    f_lo, f_hi = f(t_lo), f(t_hi)
    if f_lo >= 0:
        t = t_lo
    elif f_hi <= 0:
        t = t_hi
    else:
        t = brentq(f, t_lo, t_hi, xtol=1e-14, maxiter=200)
    return t, model.objective((a, b, t))


def brute_force_optimum(model, rotation_range, translation_range, grid=11, starts=2):
    """Global minimum of max |e_i| over the ranges by search, independent of the LP machinery.

    For fixed rotations (alpha, beta) every e_i rises with t (the tool axis is
    close to the surface normal), so the best t is the root of
    max e + min e, found exactly (Brent). The rotations are searched on a
    ``grid`` x ``grid`` lattice, the ``starts`` best lattice points are refined
    by Nelder-Mead, and the best of those by SLSQP on the smooth epigraph form
    (min h s.t. -h <= e_i(x) <= h over all three parameters).

    Returns
    -------
    x : (3,) float
    h : float
        [mm]
    """
    lower, upper = parameter_bounds(rotation_range, translation_range)
    t_lo, t_hi = translation_range

    def phi(ab):
        a, b = np.clip(ab, lower[:2], upper[:2])
        return _best_t(model, a, b, t_lo, t_hi)[1]

    g = np.linspace(-rotation_range, rotation_range, grid)
    vals = [(phi((a, b)), a, b) for a in g for b in g]
    vals.sort()
    best_x, best_h = None, np.inf
    for _, a, b in vals[:starts]:
        res = minimize(phi, np.array([a, b]), method="Nelder-Mead",
                       options={"xatol": 1e-9, "fatol": 1e-13, "maxiter": 1000, "maxfev": 1000,
                                "initial_simplex": [[a, b], [a + 0.02, b], [a, b + 0.02]]})
        a1, b1 = np.clip(res.x, lower[:2], upper[:2])
        t1, h1 = _best_t(model, a1, b1, t_lo, t_hi)
        if h1 < best_h:
            best_x, best_h = np.array([a1, b1, t1]), h1
    # epigraph polish (smooth constraints): variables (alpha, beta, t, h)
    z0 = np.concatenate([best_x, [best_h]])
    cons = [{"type": "ineq", "fun": lambda z: z[3] - model.errors(z[:3]),
             "jac": lambda z: np.column_stack([-model.evaluate(z[:3])[1], np.ones(len(model.bottom))])},
            {"type": "ineq", "fun": lambda z: z[3] + model.errors(z[:3]),
             "jac": lambda z: np.column_stack([model.evaluate(z[:3])[1], np.ones(len(model.bottom))])}]
    res = minimize(lambda z: z[3], z0, jac=lambda z: np.array([0, 0, 0, 1.0]), method="SLSQP", constraints=cons,
                   bounds=list(zip(lower, upper)) + [(0, None)], options={"ftol": 1e-15, "maxiter": 300})
    if res.success:
        x = np.clip(res.x[:3], lower, upper)
        h = model.objective(x)
        if h < best_h:
            best_x, best_h = x, h
    return best_x, float(best_h)
