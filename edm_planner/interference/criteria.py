"""The papers' interference criteria, as written (Huang & Liu, section III.B.2).

Huang judges an electrode pose point by point ("point-to-surface"): every
sample point of the electrode must lie in the region bounded by the two blade
walls, the hub and the shroud.

* Hub and shroud, eq. 3: tori of radii R_h and R_c; a point is feasible iff
  ``(R_h + Delta1)^2 < rho^2 < (R_c - Delta1)^2`` (:func:`torus_test`).
* Blade walls, the neighbour-angle test of Fig. 3: the wall is a grid of
  ordered shape points M with normals N into the channel. For an electrode
  point E0 let M1 be the nearest shape point, N1 its normal and M5 the grid
  neighbour of M1 on E0's side; with ``theta = angle(M1M5, N1)`` and
  ``alpha = angle(M1E0, N1)`` the point is feasible iff
  ``theta - alpha - Delta2 > 0`` (:func:`neighbour_angle_test`).
* The "traditional" 90-degree test Huang compares against:
  ``dot(M1E0, N1) > 0`` (:func:`normal_test`).

Both blade tests are approximations of the exact signed distance of
:mod:`.exact_points`. The neighbour-angle test replaces the wall near M1 by
the cone of half-angle theta about N1, whose generator in E0's direction is
the chord M1M5; the 90-degree test replaces it by the tangent plane at M1.
With shape-point spacing h and wall curvature kappa each misjudges the
points in a band about ``h^2 * kappa / 8`` deep (the chord's sagitta;
measured 1.0x that for the 90-degree test and up to 1.35x for the
neighbour-angle test on a square grid, where the cone spreads a diagonal
chord's slope over 45 deg of directions; ``test/test_criteria.py``):

* convex towards the channel (Huang's Fig. 3): the 90-degree test rejects
  clear points behind the tangent plane (his E1), the neighbour-angle test
  accepts points inside the wall, between chord and wall;
* concave towards the channel, or on the rising side of a twisted wall: the
  other way round, the neighbour-angle test rejecting clear points.

The chord lies farther from the wall than the tangent plane near M1, so
the neighbour-angle test misjudges about twice as many points as the
90-degree test, and on the unsafe side of convex walls. Neither test knows
how far a point is from the wall, only on which side.

Units: mm, rad. Frame W: X is the blisk axis, ``theta = atan2(z, y)``.
"""

import numpy as np
from scipy.spatial import cKDTree

from . import SURFACES
from ..geometry.frames import rotation_about_x
from .exact_points import transform_points

#: the blade-wall tests :class:`PaperCriteria` can apply
BLADE_TESTS = ("neighbour_angle", "normal")

#: grid offsets (dv, du) of the 8 neighbours of a shape point
_NEIGHBOURS = np.array([(0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)])


def _points(points):
    return np.atleast_2d(np.asanyarray(points, dtype=np.float64))


# ---------------------------------------------------------------- hub and shroud

def torus_test(points, blisk, delta1=0.0, with_margin=False):
    """Huang eq. 3: is each point between the hub and the shroud?

    Huang treats hub and shroud as tori of constant radii R_h and R_c. Here
    they are taken at the point's own axial position, ``R_h = hub(x_p)``,
    ``R_c = shroud(x_p)``: exact for cylindrical walls. For a sloped profile
    (dr/dx = tan(phi)) the radial clearance tested here is the normal
    distance to the wall divided by cos(phi) (to first order), i.e. slightly
    larger than the true clearance.

    Parameters
    ----------
    points : (n, 3) float
        [mm], in W.
    blisk : Blisk
    delta1 : float
        Safety factor Delta1 [mm].
    with_margin : bool
        Also return the radial margins.

    Returns
    -------
    hub_ok, shroud_ok : (n,) bool
        ``(R_h + Delta1)^2 < rho^2`` and ``rho^2 < (R_c - Delta1)^2``.
    hub_margin, shroud_margin : (n,) float, only with ``with_margin``
        ``rho - R_h - Delta1`` and ``R_c - Delta1 - rho`` [mm]; positive iff feasible.
    """
    p = _points(points)
    # Huang writes x_p^2 + y_p^2 for the squared radius, but his blisk axis is X:
    # the radius about it is sqrt(y^2 + z^2).
    rho2 = p[:, 1] ** 2 + p[:, 2] ** 2
    r_h = blisk.hub.radius_at(p[:, 0])
    r_c = blisk.shroud.radius_at(p[:, 0])
    hub_ok = (r_h + delta1) ** 2 < rho2
    shroud_ok = rho2 < (r_c - delta1) ** 2
    if not with_margin:
        return hub_ok, shroud_ok
    rho = np.sqrt(rho2)
    return hub_ok, shroud_ok, rho - r_h - delta1, r_c - delta1 - rho


# ---------------------------------------------------------------- blade walls

def _nearest(points, shape_points, normals, tree):
    """Flat index of M1 (the nearest shape point), M1, N1 and E0 - M1."""
    flat = shape_points.reshape(-1, 3)
    if tree is None:
        tree = cKDTree(flat)
    _, idx = tree.query(points)
    m1 = flat[idx]
    n1 = normals.reshape(-1, 3)[idx]
    return idx, m1, n1, points - m1


def _angle_to(vectors, unit_normals):
    """Angle [rad] between vectors and unit normals; pi/2 for zero vectors."""
    length = np.linalg.norm(vectors, axis=-1)
    dot = np.einsum("...i,...i->...", vectors, unit_normals)
    cos = np.divide(dot, length, out=np.zeros_like(dot), where=length > 0)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def neighbour_angle_test(points, shape_points, normals, delta2=0.0, tree=None, with_index=False):
    """Huang's neighbour-angle criterion (Fig. 3) for one channel surface.

    M1 is the shape point nearest to E0, N1 its normal. M5 is the grid
    neighbour of M1 (8-neighbourhood) on E0's side: the one whose direction
    ``M5 - M1`` is best aligned with the tangential part of ``E0 - M1``
    (largest cosine; the largest raw projection would prefer the longer
    diagonal neighbours, which on a twisted surface run along the twist).
    Then
    ``theta = angle(M1M5, N1)``, ``alpha = angle(M1E0, N1)``, and E0 is
    feasible iff ``theta - alpha - Delta2 > 0``.

    If no neighbour lies on E0's side (M1 on the grid's boundary and E0
    beyond it) or E0 lies on M1's normal, ``theta = pi/2``: the tangent
    plane, i.e. the 90-degree test. If E0 coincides with M1, ``alpha = pi/2``.

    Parameters
    ----------
    points : (n, 3) float
        Electrode points E0 [mm].
    shape_points : (nv, nu, 3) float
        The ordered shape points M of the surface [mm].
    normals : (nv, nu, 3) float
        Unit normals at the shape points, pointing into the flow channel.
    delta2 : float
        Angular safety margin Delta2 [rad].
    tree : scipy.spatial.cKDTree, optional
        Of ``shape_points.reshape(-1, 3)`` (built if not given).
    with_index : bool
        Also return the flat index of M1 in ``shape_points.reshape(-1, 3)``.

    Returns
    -------
    ok : (n,) bool
        ``theta - alpha - delta2 > 0``.
    alpha : (n,) float
        Angle between M1E0 and N1 [rad].
    theta : (n,) float
        Angle between M1M5 and N1 [rad].
    index : (n,) int, only with ``with_index``

    Notes
    -----
    The paper's text says "only if alpha is smaller than theta, E0 is judged
    non-interfering", but its constraint formula writes ``con_i = 1 if
    alpha_i - theta_i - Delta2 > 0``. The two contradict each other; the
    formula is a typo (it would accept every point behind a flat wall), so
    the geometrically consistent form ``theta - alpha - Delta2 > 0`` is used.
    """
    p = _points(points)
    shape_points = np.asanyarray(shape_points, dtype=np.float64)
    normals = np.asanyarray(normals, dtype=np.float64)
    nv, nu = shape_points.shape[:2]
    idx, m1, n1, d = _nearest(p, shape_points, normals, tree)
    alpha = _angle_to(d, n1)
    alpha = np.where(np.linalg.norm(d, axis=1) > 0, alpha, 0.5 * np.pi)
    tangential = d - np.einsum("ij,ij->i", d, n1)[:, None] * n1
    # the neighbours of M1 on the grid, (n, 8)
    j, i = np.divmod(idx, nu)
    jj = j[:, None] + _NEIGHBOURS[:, 0]
    ii = i[:, None] + _NEIGHBOURS[:, 1]
    valid = (jj >= 0) & (jj < nv) & (ii >= 0) & (ii < nu)
    nb = np.where(valid, jj * nu + ii, idx[:, None])
    chords = shape_points.reshape(-1, 3)[nb] - m1[:, None, :]          # (n, 8, 3)
    # direction cosines: raw projections would favour the longer diagonals
    length = np.linalg.norm(chords, axis=2) * np.linalg.norm(tangential, axis=1)[:, None]
    proj = np.einsum("nkc,nc->nk", chords, tangential)
    cos = np.divide(proj, length, out=np.zeros_like(proj), where=length > 0)
    cos = np.where(valid, cos, -np.inf)
    best = np.argmax(cos, axis=1)
    rows = np.arange(len(p))
    same_side = cos[rows, best] > 0
    theta = np.where(same_side, _angle_to(chords[rows, best], n1), 0.5 * np.pi)
    ok = theta - alpha - delta2 > 0
    if with_index:
        return ok, alpha, theta, idx
    return ok, alpha, theta


def normal_test(points, shape_points, normals, delta2=0.0, tree=None):
    """The "traditional" 90-degree criterion Huang compares against.

    E0 is feasible iff ``dot(M1E0, N1) > 0`` (with ``delta2 = 0``), M1 the
    nearest shape point: the wall is replaced by its tangent plane at M1.

    Parameters
    ----------
    points : (n, 3) float
        Electrode points E0 [mm].
    shape_points : (nv, nu, 3) float
    normals : (nv, nu, 3) float
        Unit normals pointing into the flow channel.
    delta2 : float
        Angular safety margin [rad]: feasible iff ``pi/2 - alpha - delta2 > 0``.
    tree : scipy.spatial.cKDTree, optional

    Returns
    -------
    ok : (n,) bool
    alpha : (n,) float
        Angle between M1E0 and N1 [rad].
    """
    p = _points(points)
    shape_points = np.asanyarray(shape_points, dtype=np.float64)
    normals = np.asanyarray(normals, dtype=np.float64)
    _, _, n1, d = _nearest(p, shape_points, normals, tree)
    alpha = _angle_to(d, n1)
    alpha = np.where(np.linalg.norm(d, axis=1) > 0, alpha, 0.5 * np.pi)
    return 0.5 * np.pi - alpha - delta2 > 0, alpha


# ---------------------------------------------------------------- shape points of a blade face

def face_shape_points(surface, resolution, into):
    """Ordered shape points of a spline face with normals oriented into a side.

    Parameters
    ----------
    surface : SplineSurface
    resolution : float
        Target spacing of the shape points along both parameter directions [mm]
        (the grid is uniform in the parameters; its largest spacing is
        reported by :func:`grid_spacing`).
    into : {+1, -1}
        +1: the normals point towards +theta, -1: towards -theta (by majority:
        at the leading and trailing edge they point along the axis).

    Returns
    -------
    points : (nv, nu, 3) float
    normals : (nv, nu, 3) float
        Unit normals.
    """
    coarse = surface.grid(201, 41)
    along_u = np.linalg.norm(np.diff(coarse, axis=1), axis=2).sum(axis=1).max()
    along_v = np.linalg.norm(np.diff(coarse, axis=0), axis=2).sum(axis=0).max()
    nu = max(3, int(np.ceil(along_u / resolution)) + 1)
    nv = max(3, int(np.ceil(along_v / resolution)) + 1)
    u, v = np.meshgrid(np.linspace(0.0, 1.0, nu), np.linspace(0.0, 1.0, nv))
    pts = surface.evaluate(u, v)
    nrm = surface.normals(u, v)
    th = np.arctan2(pts[..., 2], pts[..., 1])
    e_theta = np.stack([np.zeros_like(th), -np.sin(th), np.cos(th)], axis=-1)
    if into * np.einsum("...i,...i->...", nrm, e_theta).mean() < 0:
        nrm = -nrm
    return pts, nrm


def grid_spacing(shape_points):
    """Largest distance between grid neighbours along u and along v [mm].

    Parameters
    ----------
    shape_points : (nv, nu, 3) float

    Returns
    -------
    h_u, h_v : float
    """
    s = np.asanyarray(shape_points, dtype=np.float64)
    return (float(np.linalg.norm(np.diff(s, axis=1), axis=2).max()),
            float(np.linalg.norm(np.diff(s, axis=0), axis=2).max()))


# ---------------------------------------------------------------- the criteria on a blisk

class PaperCriteria:
    """Huang's constraints on channel k of a blisk: eq. 3 and a blade-wall test.

    Parameters
    ----------
    blisk : Blisk
    delta1 : float
        Radial safety factor of eq. 3 [mm].
    delta2 : float
        Angular safety margin of the blade-wall test [rad].
    resolution : float
        Spacing of the blade walls' shape points [mm].
    blade_test : {'neighbour_angle', 'normal'}
        Huang's neighbour-angle test or the traditional 90-degree test.

    Attributes
    ----------
    spacing : float
        Largest grid-neighbour spacing of the shape points over both walls [mm].
    """

    def __init__(self, blisk, delta1=0.0, delta2=0.0, resolution=0.25, blade_test="neighbour_angle"):
        for name, value in (("delta1", delta1), ("delta2", delta2), ("resolution", resolution)):
            if not np.isfinite(value):
                raise ValueError(f"PaperCriteria: {name} must be finite, got {value!r}")
        if resolution <= 0:
            raise ValueError(f"PaperCriteria: resolution must be > 0 mm, got {resolution!r}")
        if blade_test not in BLADE_TESTS:
            raise ValueError(f"PaperCriteria: blade_test must be one of {BLADE_TESTS}, got {blade_test!r}")
        self.blisk = blisk
        self.delta1 = float(delta1)
        self.delta2 = float(delta2)
        self.resolution = float(resolution)
        self.blade_test = blade_test
        # blade 0's faces: the suction face bounds the channel on its +theta
        # side, the pressure face (of blade k+1) on its -theta side
        self._faces = {
            "suction": face_shape_points(blisk.suction_face.surface, resolution, +1),
            "pressure": face_shape_points(blisk.pressure_face.surface, resolution, -1),
        }
        self._trees = {k: cKDTree(v[0].reshape(-1, 3)) for k, v in self._faces.items()}
        self.spacing = max(max(grid_spacing(v[0])) for v in self._faces.values())

    def _blade_index(self, surface, channel):
        """Which blade carries this wall of channel k."""
        return channel if surface == "suction" else channel + 1

    def shape_points(self, surface, channel=0):
        """The shape points of a blade wall of channel k, in W.

        Parameters
        ----------
        surface : {'suction', 'pressure'}
        channel : int

        Returns
        -------
        points, normals : (nv, nu, 3) float
            Normals point into channel k.
        """
        pts, nrm = self._faces[surface]
        rot = rotation_about_x(self._blade_index(surface, channel) * self.blisk.pitch)[:3, :3]
        return pts @ rot.T, nrm @ rot.T

    def evaluate(self, points, channel=0):
        """Per point and surface: Huang's decision and its margin.

        The nearest shape point is an exact k-d tree query; for points
        millimetres away from a wall it visits many shape points (about
        20 us per point and wall at the default resolution).

        Parameters
        ----------
        points : (n, 3) float
            [mm], in W.
        channel : int

        Returns
        -------
        dict
            ``'suction', 'pressure', 'hub', 'shroud'`` -> (n,) bool, feasible
            w.r.t. that surface; ``'feasible'`` -> (n,) bool, all four;
            ``'margin'`` -> (n, 4) float in the order of ``SURFACES``:
            ``theta - alpha - delta2`` [rad] (or ``pi/2 - alpha - delta2``)
            for the blade walls, the radial margins of :func:`torus_test` [mm]
            for hub and shroud; positive iff feasible.
        """
        p = _points(points)
        out = {}
        margin = np.empty((len(p), len(SURFACES)))
        for col, surface in enumerate(SURFACES[:2]):
            # rotate the points into blade 0's position instead of the wall into blade k's
            rot = rotation_about_x(-self._blade_index(surface, channel) * self.blisk.pitch)[:3, :3]
            local = p @ rot.T
            pts, nrm = self._faces[surface]
            if self.blade_test == "neighbour_angle":
                ok, alpha, theta = neighbour_angle_test(local, pts, nrm, self.delta2, self._trees[surface])
                margin[:, col] = theta - alpha - self.delta2
            else:
                ok, alpha = normal_test(local, pts, nrm, self.delta2, self._trees[surface])
                margin[:, col] = 0.5 * np.pi - alpha - self.delta2
            out[surface] = ok
        hub_ok, shroud_ok, margin[:, 2], margin[:, 3] = torus_test(p, self.blisk, self.delta1, with_margin=True)
        out["hub"], out["shroud"] = hub_ok, shroud_ok
        out["feasible"] = out["suction"] & out["pressure"] & hub_ok & shroud_ok
        out["margin"] = margin
        return out

    def pose_feasible(self, poses, points, channel=0, with_margin=False):
        """Huang's Con_L, Con_R, Con_U, Con_D per pose: all points feasible per surface.

        Parameters
        ----------
        poses : (P, 4, 4) float
            Electrode frame -> W.
        points : (M, 3) float
            Electrode sample points in the electrode frame [mm].
        channel : int
        with_margin : bool
            Also return the smallest margin over the points.

        Returns
        -------
        feasible : (P, 4) bool
            Columns in the order of ``SURFACES``.
        margin : (P, 4) float, only with ``with_margin``
            [rad] for the blade walls, [mm] for hub and shroud.
        """
        world = transform_points(poses, points)
        P, M, _ = world.shape
        res = self.evaluate(world.reshape(-1, 3), channel)
        ok = np.stack([res[s] for s in SURFACES], axis=1).reshape(P, M, len(SURFACES)).all(axis=1)
        if with_margin:
            return ok, res["margin"].reshape(P, M, len(SURFACES)).min(axis=1)
        return ok
