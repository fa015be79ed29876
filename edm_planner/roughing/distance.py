"""Exact distance from points to a surface of revolution about X (Chen & Dong eq. 4-8).

The shroud's inner surface is the profile curve C(u) = (x(u), r(u)) turned
about the blisk axis. For a point p the rotation angle of its mapping point
is the point's own angle (eq. 6: the angle that zeroes the derivative of the
distance in theta), which reduces the distance to a function of one variable,
the profile parameter (eq. 7); its minimiser (eq. 8) gives the mapping point
q = S(u_min, theta_opt). Here the profile is ``r = R(x)`` (a
:class:`~edm_planner.geometry.profiles.RevolutionProfile`, parameter u = x), so
in the (x, r) half-plane

    d(x)^2 = (x - x_p)^2 + (R(x) - r_p)^2,   r_p = hypot(y_p, z_p).

The paper rotates about Z; W's blisk axis is X, so its (x, y, z) roles are
(y, z, x) here. Units: mm.

The 1-D minimisation is global and exact: the nearest of a dense sampling of
the profile (every ``sample_step`` mm, knots included) selects the basin, a
sign change of g(x) = (x - x_p) + (R(x) - r_p) R'(x) (half the derivative of
d^2) is bracketed between that sample and a neighbour, and a safeguarded
Newton iteration (bisection whenever Newton leaves the bracket) converges to
machine precision. Beyond its given points the profile continues as a
cylinder (``RevolutionProfile.radius_at``), so the surface is that too.
"""

import numpy as np
from scipy.spatial import cKDTree

_NEWTON_ITERATIONS = 60
_X_TOL = 1e-13


class RevolutionDistance:
    """Signed distances from points in W to a surface of revolution about X.

    Parameters
    ----------
    profile : RevolutionProfile
        The meridional profile r = R(x) [mm].
    extend : float
        The search covers the profile's x range widened by this much on each
        side (the surface's cylindrical continuation) [mm].
    sample_step : float
        Spacing of the basin-selecting samples [mm]; must be well below the
        profile's radius of curvature plus the points' distances (always true
        for a shroud and tool points a few mm from it).

    Notes
    -----
    Sign: positive on the axis side of the surface (r < R: a tool point short
    of the surface, material left), negative beyond it (r > R: overcut).
    """

    def __init__(self, profile, extend=10.0, sample_step=0.05):
        self.profile = profile
        # the profile's own interpolant (PCHIP) as its piecewise-cubic coefficients: R, R' and R''
        # in one cheap evaluation (RevolutionProfile.slope_at rebuilds the derivative on every call)
        pp = profile._interp
        self._bp, self._coef = np.asarray(pp.x), np.asarray(pp.c)
        lo, hi = profile.x_range
        self.x_lo, self.x_hi = lo - extend, hi + extend
        n = int(np.ceil((self.x_hi - self.x_lo) / sample_step)) + 1
        xs = np.linspace(self.x_lo, self.x_hi, n)
        xs = np.unique(np.concatenate([xs, profile.points[:, 0]]))
        self._xs = xs
        self._rs = profile.radius_at(xs)
        self._tree = cKDTree(np.column_stack([xs, self._rs]))

    def _eval(self, x):
        """R, R', R'' at x: the profile's piecewise cubic evaluated directly (cylinder beyond its ends)."""
        lo, hi = self.profile.x_range
        xc = np.clip(x, lo, hi)
        k = np.clip(np.searchsorted(self._bp, xc, side="right") - 1, 0, self._coef.shape[1] - 1)
        c = self._coef[:, k]
        u = xc - self._bp[k]
        r = ((c[0] * u + c[1]) * u + c[2]) * u + c[3]
        inside = (x >= lo) & (x <= hi)
        d1 = np.where(inside, (3 * c[0] * u + 2 * c[1]) * u + c[2], 0.0)
        d2 = np.where(inside, 6 * c[0] * u + 2 * c[1], 0.0)
        return r, d1, d2

    def _g(self, x, xp, rp):
        r, s, c = self._eval(x)
        return (x - xp) + (r - rp) * s, r, s, c

    def foot_x(self, xp, rp):
        """Axial position of the mapping point for meridional positions (x_p, r_p) (eq. 8).

        Returns
        -------
        (n,) float
            u_min = x of the closest profile point [mm].
        """
        xp = np.atleast_1d(np.asanyarray(xp, dtype=np.float64))
        rp = np.atleast_1d(np.asanyarray(rp, dtype=np.float64))
        _, k = self._tree.query(np.column_stack([xp, rp]))
        xs = self._xs
        last = len(xs) - 1
        gk = self._g(xs[k], xp, rp)[0]
        # the sampled minimum's neighbour on the side g points to brackets the sign change
        left = gk > 0
        lo = np.where(left, xs[np.maximum(k - 1, 0)], xs[k])
        hi = np.where(left, xs[k], xs[np.minimum(k + 1, last)])
        g_lo, r_lo, _, _ = self._g(lo, xp, rp)
        g_hi, r_hi, _, _ = self._g(hi, xp, rp)
        bracketed = (g_lo <= 0) & (g_hi >= 0) & (hi > lo)
        # no sign change: the minimum is an end of the searched range (or a sample exactly)
        d_lo = np.hypot(lo - xp, r_lo - rp)
        d_hi = np.hypot(hi - xp, r_hi - rp)
        x = np.where(bracketed, 0.5 * (lo + hi), np.where(d_lo <= d_hi, lo, hi))
        act = np.flatnonzero(bracketed)
        lo, hi = lo[act], hi[act]
        xa, xpa, rpa = x[act], xp[act], rp[act]
        for _ in range(_NEWTON_ITERATIONS):
            if not len(act):
                break
            g, r, s, curv = self._g(xa, xpa, rpa)
            # keep the bracket: g(lo) <= 0 <= g(hi)
            neg = g <= 0
            lo = np.where(neg, xa, lo)
            hi = np.where(neg, hi, xa)
            dg = 1.0 + s * s + (r - rpa) * curv
            with np.errstate(divide="ignore", invalid="ignore"):
                newton = xa - g / dg
            ok = np.isfinite(newton) & (newton >= lo) & (newton <= hi) & (dg > 0)
            new = np.where(ok, newton, 0.5 * (lo + hi))
            done = (np.abs(new - xa) <= _X_TOL * (1.0 + np.abs(xa))) | (hi - lo <= _X_TOL * (1.0 + np.abs(xa)))
            xa = new
            x[act] = xa
            keep = ~done
            act, lo, hi, xa, xpa, rpa = act[keep], lo[keep], hi[keep], xa[keep], xpa[keep], rpa[keep]
        return x

    def closest(self, points):
        """Mapping points and signed distances of points in W.

        Parameters
        ----------
        points : (n, 3) float
            [mm] in W (X = the surface's axis).

        Returns
        -------
        signed : (n,) float
            Signed distance [mm] (positive towards the axis, see the class notes).
        gradient : (n, 3) float
            d signed / d point: the unit vector from the mapping point to the
            point, times the sign (the surface normal at the mapping point).
        foot : (n, 3) float
            The mapping points q = S(u_min, theta_opt) (eq. 8) [mm].
        """
        p = np.atleast_2d(np.asanyarray(points, dtype=np.float64))
        xp = p[:, 0]
        rp = np.hypot(p[:, 1], p[:, 2])
        theta = np.arctan2(p[:, 2], p[:, 1])                 # eq. 6: theta_opt = the point's angle
        xf = self.foot_x(xp, rp)
        rf, sf, _ = self._eval(xf)
        dx, dr = xp - xf, rp - rf
        dist = np.hypot(dx, dr)
        # inward normal (towards the axis) in (x, r): (R', -1) / sqrt(1 + R'^2)
        nrm = np.hypot(sf, 1.0)
        side = (dx * sf - dr) / nrm
        sign = np.where(side >= 0, 1.0, -1.0)
        signed = sign * dist
        c, s = np.cos(theta), np.sin(theta)
        foot = np.column_stack([xf, rf * c, rf * s])
        tiny = dist < 1e-12
        with np.errstate(invalid="ignore", divide="ignore"):
            ux = np.where(tiny, sf / nrm, sign * dx / np.where(tiny, 1.0, dist))
            ur = np.where(tiny, -1.0 / nrm, sign * dr / np.where(tiny, 1.0, dist))
        grad = np.column_stack([ux, ur * c, ur * s])
        return signed, grad, foot

    def signed_distance(self, points):
        """Signed distances only [mm] (see :meth:`closest`)."""
        return self.closest(points)[0]
