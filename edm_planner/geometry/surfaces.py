"""Queries on one reconstructed blade face: theta(x, r), closest points.

A blade face is the bicubic surface of Liu 2024 (``nurbs.interpolate_surface``)
through its S x C section points. Two questions recur everywhere:

* where is the face at a given meridional position (x, r)? -- solve
  ``x(u, v) = x0, r(u, v) = r0`` by Newton's method (the map (u, v) -> (x, r)
  is one to one over the blade: stations run monotonically along the chord
  and sections monotonically along the span);
* which face point is closest to a point in space? -- Gauss-Newton on
  ``|S(u, v) - p|^2``, started from the (x, r) inversion.
"""

import numpy as np
from scipy.spatial import cKDTree

from .nurbs import interpolate_surface

_NEWTON_ITERATIONS = 30
_NEWTON_TOL = 1e-11


class BladeFace:
    """One face of blade 0 as a smooth surface with (x, r) and closest-point queries.

    Parameters
    ----------
    points : (S, C, 3) float
        The face's section points in W [mm] (``BladeSections.face_points``).
    name : str
        For error messages.
    knot_rule : {'chord', 'paper'}
        Knot placement of the reconstruction (see ``nurbs.KNOT_RULES``).
    """

    def __init__(self, points, name="blade face", knot_rule="chord"):
        self.name = name
        self.surface = interpolate_surface(np.asanyarray(points, dtype=np.float64), name=name, knot_rule=knot_rule)
        # a dense (u, v) sampling gives the Newton iterations their start
        n = 64
        uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
        self._seed_uv = np.column_stack([uu.ravel(), vv.ravel()])
        pts = self.surface.evaluate(uu, vv).reshape(-1, 3)
        self._seed_xr = np.column_stack([pts[:, 0], np.hypot(pts[:, 1], pts[:, 2])])
        self._xr_scale = np.ptp(self._seed_xr, axis=0) + 1e-9
        self._xr_tree = cKDTree(self._seed_xr / self._xr_scale)
        # closest-point seeds: finer than the (x, r) seeds, the distance minimum is sharp
        m = 128
        uu, vv = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m))
        self._dense_uv = np.column_stack([uu.ravel(), vv.ravel()])
        self._dense_tree = cKDTree(self.surface.evaluate(uu, vv).reshape(-1, 3))

    # -- meridional position ------------------------------------------------
    def _xr_and_jacobian(self, u, v):
        s = self.surface.evaluate(u, v)
        s_u, s_v = self.surface.derivatives(u, v)
        r = np.hypot(s[..., 1], s[..., 2])
        r_u = (s[..., 1] * s_u[..., 1] + s[..., 2] * s_u[..., 2]) / r
        r_v = (s[..., 1] * s_v[..., 1] + s[..., 2] * s_v[..., 2]) / r
        return s, r, np.stack([np.stack([s_u[..., 0], s_v[..., 0]], -1), np.stack([r_u, r_v], -1)], -2), s_u, s_v

    def uv_at(self, x, r):
        """Face parameters at meridional positions (x, r).

        Parameters
        ----------
        x, r : (n,) float
            [mm]

        Returns
        -------
        u, v : (n,) float
        inside : (n,) bool
            False where (x, r) lies outside the face's meridional footprint
            (the parameters then sit on the nearest boundary).
        """
        x = np.atleast_1d(np.asanyarray(x, dtype=np.float64))
        r = np.atleast_1d(np.asanyarray(r, dtype=np.float64))
        target = np.column_stack([x, r])
        _, idx = self._xr_tree.query(target / self._xr_scale)
        uv = self._seed_uv[idx].copy()
        for _ in range(_NEWTON_ITERATIONS):
            s, rr, jac, _, _ = self._xr_and_jacobian(uv[:, 0], uv[:, 1])
            res = np.column_stack([s[:, 0], rr]) - target
            det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
            det = np.where(np.abs(det) < 1e-300, 1e-300, det)
            du = (jac[:, 1, 1] * res[:, 0] - jac[:, 0, 1] * res[:, 1]) / det
            dv = (-jac[:, 1, 0] * res[:, 0] + jac[:, 0, 0] * res[:, 1]) / det
            step = np.column_stack([du, dv])
            # damp big steps: the footprint's edges bend
            big = np.abs(step).max(axis=1) > 0.25
            step[big] *= (0.25 / np.abs(step[big]).max(axis=1))[:, None]
            uv = np.clip(uv - step, 0.0, 1.0)
            if np.abs(step).max() < _NEWTON_TOL:
                break
        s, rr, _, _, _ = self._xr_and_jacobian(uv[:, 0], uv[:, 1])
        resid = np.hypot(s[:, 0] - x, rr - r)
        return uv[:, 0], uv[:, 1], resid < 1e-7

    def theta_at(self, x, r, with_gradient=False):
        """Angle of the face at (x, r) [rad], optionally with (d theta/dx, d theta/dr) [rad/mm].

        Returns
        -------
        theta : (n,) float
        inside : (n,) bool
        gradient : (n, 2) float, only if ``with_gradient``
        """
        u, v, inside = self.uv_at(x, r)
        s, rr, jac, s_u, s_v = self._xr_and_jacobian(u, v)
        theta = np.arctan2(s[:, 2], s[:, 1])
        if not with_gradient:
            return theta, inside
        r2 = rr**2
        th_u = (s[:, 1] * s_u[:, 2] - s[:, 2] * s_u[:, 1]) / r2
        th_v = (s[:, 1] * s_v[:, 2] - s[:, 2] * s_v[:, 1]) / r2
        # [theta_x, theta_r] = [theta_u, theta_v] J^-1
        grad = np.linalg.solve(np.swapaxes(jac, 1, 2), np.column_stack([th_u, th_v])[..., None])[..., 0]
        return theta, inside, grad

    # -- closest points -------------------------------------------------------
    def closest_points(self, points, iterations=60):
        """Closest points on the face (boundary included) and their distances.

        Gauss-Newton on ``|S(u, v) - p|^2`` with backtracking: a step is kept
        only where it lowers the distance (halved up to 12 times otherwise), so
        the iteration cannot oscillate for points farther from the face than
        its radius of curvature; it starts from the nearest of 128 x 128
        surface samples, so it settles in the global minimum's basin.

        Parameters
        ----------
        points : (n, 3) float
            Query points in W [mm], in blade 0's angular position.

        Returns
        -------
        closest : (n, 3) float
        distance : (n,) float
            Unsigned [mm].
        uv : (n, 2) float
        """
        p = np.atleast_2d(np.asanyarray(points, dtype=np.float64))
        _, idx = self._dense_tree.query(p)
        uv = self._dense_uv[idx].copy()
        s = self.surface.evaluate(uv[:, 0], uv[:, 1])
        f = np.einsum("ij,ij->i", s - p, s - p)
        active = np.ones(len(p), dtype=bool)
        for _ in range(iterations):
            if not active.any():
                break
            a = np.where(active)[0]
            ua = uv[a]
            s_u, s_v = self.surface.derivatives(ua[:, 0], ua[:, 1])
            d = s[a] - p[a]
            a11 = np.einsum("ij,ij->i", s_u, s_u)
            a12 = np.einsum("ij,ij->i", s_u, s_v)
            a22 = np.einsum("ij,ij->i", s_v, s_v)
            b1 = np.einsum("ij,ij->i", s_u, d)
            b2 = np.einsum("ij,ij->i", s_v, d)
            det = a11 * a22 - a12**2
            det = np.where(det < 1e-300, 1e-300, det)
            step = np.column_stack([(a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det])
            big = np.abs(step).max(axis=1) > 0.1
            step[big] *= (0.1 / np.abs(step[big]).max(axis=1))[:, None]
            scale = np.ones(len(a))
            pending = np.ones(len(a), dtype=bool)
            new_uv, new_s, new_f = ua.copy(), s[a].copy(), f[a].copy()
            for _ in range(12):                     # backtracking: accept only descent
                k = np.where(pending)[0]
                cand = np.clip(ua[k] - scale[k, None] * step[k], 0.0, 1.0)
                cs = self.surface.evaluate(cand[:, 0], cand[:, 1])
                cf = np.einsum("ij,ij->i", cs - p[a[k]], cs - p[a[k]])
                ok = cf <= f[a[k]]
                new_uv[k[ok]], new_s[k[ok]], new_f[k[ok]] = cand[ok], cs[ok], cf[ok]
                pending[k[ok]] = False
                scale[k[~ok]] *= 0.5
                if not pending.any():
                    break
            moved = np.abs(new_uv - ua).max(axis=1)
            uv[a], s[a], f[a] = new_uv, new_s, new_f
            active[a] = moved > 1e-13
        return s, np.sqrt(f), uv
