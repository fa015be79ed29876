"""Queries on one reconstructed blade face: theta(x, r), closest points.

A blade face is the bicubic surface of Liu 2024 (``nurbs.interpolate_surface``)
through its S x C section points. Two questions recur everywhere:

* where is the face at a given meridional position (x, r)? -- solve
  ``x(u, v) = x0, r(u, v) = r0`` by Newton's method (the map (u, v) -> (x, r)
  is one to one over the blade: stations run monotonically along the chord
  and sections monotonically along the span);
* which face point is closest to a point in space? -- Newton on
  ``|S(u, v) - p|^2`` with backtracking, started from the nearest of a dense
  set of face samples.

Both run in the numba kernels of :mod:`.spline_kernels` (the same surface,
evaluated from its control net and knots); numpy only finds the starts.
"""

import numpy as np
from scipy.spatial import cKDTree

from .nurbs import interpolate_surface
from .spline_kernels import closest_points_many, eval_many, kernel_net, uv_at_many

#: closest points: Newton stops when a step moves the foot by less than this [mm]
_PROJECT_TOL = 1e-9
_PROJECT_ITERATIONS = 100


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
        self._net = kernel_net(self.surface)

    def __getstate__(self):                       # the kernel net is rebuilt, not pickled twice
        state = dict(self.__dict__)
        state.pop("_net", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._net = kernel_net(self.surface)

    def _derivatives(self, u, v):
        """S, S_u, S_v at (u, v), each (n, 3)."""
        ev = eval_many(*self._net, np.ascontiguousarray(u, dtype=np.float64), np.ascontiguousarray(v, dtype=np.float64))
        return ev[:, 0], ev[:, 1], ev[:, 2]

    # -- meridional position ------------------------------------------------
    def _xr_and_jacobian(self, u, v):
        s, s_u, s_v = self._derivatives(u, v)
        r = np.hypot(s[..., 1], s[..., 2])
        r_u = (s[..., 1] * s_u[..., 1] + s[..., 2] * s_u[..., 2]) / r
        r_v = (s[..., 1] * s_v[..., 1] + s[..., 2] * s_v[..., 2]) / r
        return s, r, np.stack([np.stack([s_u[..., 0], s_v[..., 0]], -1), np.stack([r_u, r_v], -1)], -2), s_u, s_v

    def uv_at(self, x, r):
        """Face parameters at meridional positions (x, r).

        Newton on ``(x(u, v), r(u, v)) = (x, r)`` from the nearest of 64 x 64
        face samples in scaled (x, r), steps damped to 0.25 and clipped to
        [0, 1], down to steps of 1e-11.

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
        uv, inside = uv_at_many(*self._net, np.ascontiguousarray(x), np.ascontiguousarray(r),
                                np.ascontiguousarray(self._seed_uv[idx]))
        return uv[:, 0], uv[:, 1], inside

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
    def closest_points(self, points):
        """Closest points on the face (boundary included) and their distances.

        Newton on ``|S(u, v) - p|^2`` (Gauss-Newton where the Hessian is not
        positive definite) with backtracking, so a step is kept only where it
        lowers the distance; it starts from the nearest of 128 x 128 surface
        samples, so it settles in the global minimum's basin, and a foot that
        ends on the face's boundary is tried again from inside
        (``spline_kernels.project_edge``).

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
        p = np.ascontiguousarray(np.atleast_2d(np.asanyarray(points, dtype=np.float64)))
        _, idx = self._dense_tree.query(p)
        feet, f, uv = closest_points_many(*self._net, p, np.ascontiguousarray(self._dense_uv[idx]),
                                          _PROJECT_TOL, _PROJECT_ITERATIONS)
        return feet, np.sqrt(f), uv
