"""Tests of edm_planner.interference.criteria: Huang & Liu's eq. 3 and neighbour-angle test.

* eq. 3 (torus test) against closed-form radii, its safety factor, and its
  relation to the exact normal distance on a sloped (conical) wall;
* Huang's Fig. 3 argument reproduced numerically on a strongly curved and
  twisted analytic sheet: a clear point behind the tangent plane of its
  nearest shape point, which the 90-degree test rejects and the
  neighbour-angle test accepts;
* the neighbour-angle test is itself only an approximation: on a cylinder the
  band of misjudged points is measured against the sagitta of the shape-point
  spacing h, ``R (1 - cos(h / 2R)) ~ h^2 / 8R``;
* on the default blisk (channels 0 and 3): the designed electrode at its
  final pose is feasible, shifted 1 mm into the suction wall it is not, and
  the decisions agree with the sign of the exact signed distance
  (``ExactChannelDistance``) except inside the discretisation band.

Units: mm, rad. Frame W: X the blisk axis, theta = atan2(z, y).
"""

import pathlib
import types

import numpy as np
import pytest
from scipy.optimize import minimize

from edm_planner.geometry.frames import cylindrical_to_cartesian, rotation_about_x
from edm_planner.geometry.profiles import RevolutionProfile
from edm_planner.interference import SURFACES
from edm_planner.interference.criteria import (
    BLADE_TESTS, PaperCriteria, face_shape_points, neighbour_angle_test, normal_test, torus_test)
from edm_planner.interference.exact_points import ExactChannelDistance, ProfileDistance

DEFAULT_YAML = pathlib.Path(__file__).resolve().parent.parent / "config" / "default_blisk.yaml"
#: accuracy the discharge-gap offset is achieved to [mm] (constants.TOL.offset)
OFFSET_TOL = 2e-3
#: worst misjudged depth of the neighbour-angle test over the sagitta of the
#: spacing, square grid on a cylinder: the diagonal neighbour's chord slope is
#: applied up to 22.5 deg off the diagonal; at the Voronoi corner in the
#: direction 67.5 deg off the curved one this gives 0.170 h^2/R = 1.36 sagittas
NEIGHBOUR_BAND = 1.4


# ----------------------------------------------------------------- eq. 3: hub and shroud

def _walls(hub_points, shroud_points):
    """The part of a Blisk that torus_test reads."""
    return types.SimpleNamespace(hub=RevolutionProfile(hub_points, "hub_profile"),
                                 shroud=RevolutionProfile(shroud_points, "shroud_profile"))


@pytest.mark.parametrize("delta1", [0.0, 0.3])
def test_torus_test_on_cylinders_against_closed_form_radii(delta1):
    walls = _walls([[-10.0, 100.0], [40.0, 100.0]], [[-10.0, 120.0], [40.0, 120.0]])
    rng = np.random.default_rng(3)
    n = 200
    x = rng.uniform(-20, 50, n)                 # also beyond the profiles: continued as cylinders
    th = rng.uniform(-np.pi, np.pi, n)
    eps = 1e-6
    for rho, hub_expect, shroud_expect in (
            (100.0 + delta1 - eps, False, True), (100.0 + delta1 + eps, True, True),
            (120.0 - delta1 - eps, True, True), (120.0 - delta1 + eps, True, False),
            (99.0, False, True), (121.0, True, False), (110.0, True, True)):
        p = cylindrical_to_cartesian(x, np.full(n, rho), th)
        hub_ok, shroud_ok, hub_m, shroud_m = torus_test(p, walls, delta1, with_margin=True)
        assert np.all(hub_ok == hub_expect) and np.all(shroud_ok == shroud_expect)
        np.testing.assert_allclose(hub_m, rho - 100.0 - delta1, atol=1e-9)
        np.testing.assert_allclose(shroud_m, 120.0 - delta1 - rho, atol=1e-9)
        assert np.all((hub_m > 0) == hub_ok) and np.all((shroud_m > 0) == shroud_ok)
    # the radius is about X (y^2 + z^2), not x^2 + y^2 as the paper's text writes
    p = np.array([[30.0, 0.0, 110.0], [-30.0, 110.0, 0.0]])
    assert all(np.all(ok) for ok in torus_test(p, walls, delta1))


def test_torus_test_on_a_sloped_wall_is_radial_not_normal():
    """Cone hub r = 100 + 0.1 x: radial margin x cos(slope angle) = exact normal distance."""
    walls = _walls([[0.0, 100.0], [40.0, 104.0]], [[0.0, 120.0], [40.0, 124.0]])
    rng = np.random.default_rng(4)
    x = rng.uniform(10, 30, 500)
    rho = walls.hub.radius_at(x) + rng.uniform(-1, 1, 500)
    p = cylindrical_to_cartesian(x, rho, rng.uniform(-np.pi, np.pi, 500))
    hub_ok, _, hub_m, _ = torus_test(p, walls, 0.0, with_margin=True)
    exact, _, _ = ProfileDistance(walls.hub, material_below=True).signed(x, rho)
    cos = 1.0 / np.hypot(1.0, 0.1)
    np.testing.assert_allclose(hub_m * cos, exact, atol=1e-9)
    assert np.all(hub_ok == (exact > 0))
    assert np.all(np.abs(hub_m) >= np.abs(exact))      # the radial test reads the clearance larger


# ----------------------------------------------------------------- analytic sheets

def twisted_sheet(radius, twist):
    """A cylinder-bent sheet twisted about its span: S(u, v), unit normals N(u, v).

    u is the arc length along the section (convex towards the +normal side,
    radius ``radius``), v the span; the section at v is rotated about the
    span axis by ``twist * v``. Normals point to the convex (channel) side.
    """
    def surface(u, v):
        u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
        a, c = radius * np.sin(u / radius), radius * np.cos(u / radius) - radius
        phi = twist * v
        return np.stack([a * np.cos(phi) + c * np.sin(phi), v, -a * np.sin(phi) + c * np.cos(phi)], axis=-1)

    def normal(u, v, e=1e-6):
        s_u = (surface(u + e, v) - surface(u - e, v)) / (2 * e)
        s_v = (surface(u, v + e) - surface(u, v - e)) / (2 * e)
        n = np.cross(s_u, s_v)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        phi = twist * np.asarray(v, dtype=float)
        up = np.stack(np.broadcast_arrays(np.sin(phi), 0.0, np.cos(phi)), axis=-1)
        return np.where((np.einsum("...i,...i->...", n, up) < 0)[..., None], -n, n)

    return surface, normal


def dense_signed_distance(surface, normal, point, u0, v0, window=2.0):
    """Signed distance of a point to S: dense (u, v) sampling, then Nelder-Mead from its best sample."""
    gu, gv = np.meshgrid(np.linspace(u0 - window, u0 + window, 801), np.linspace(v0 - window, v0 + window, 801))
    k = np.argmin(np.sum((surface(gu, gv) - point) ** 2, axis=-1))
    res = minimize(lambda q: np.sum((surface(q[0], q[1]) - point) ** 2), [gu.ravel()[k], gv.ravel()[k]],
                   method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-18, "maxiter": 4000})
    foot = surface(*res.x)
    return float(np.sign(np.dot(point - foot, normal(*res.x))) * np.linalg.norm(point - foot))


def test_fig3_twisted_sheet_90_degree_test_misjudges_neighbour_angle_does_not():
    """Huang's E1: clear of a convex, twisted wall, yet more than 90 deg off N at its nearest shape point."""
    surface, normal = twisted_sheet(radius=3.0, twist=0.25)        # 0.25 rad/mm: 1.5 rad over the sheet
    h = 1.0
    uu, vv = np.meshgrid(np.arange(-4, 4.01, h), np.arange(-3, 3.01, h))
    shape, normals = surface(uu, vv), normal(uu, vv)
    # E1: 0.02 mm off the wall, 0.45 h along the convex direction from the shape point (0, 0)
    u1, v1 = 0.45, 0.3
    e1 = surface(u1, v1) + 0.02 * normal(u1, v1)
    exact = dense_signed_distance(surface, normal, e1, u1, v1)
    assert exact == pytest.approx(0.02, abs=1e-6)                    # not interfering
    ok90, alpha90 = normal_test(e1, shape, normals)
    ok, alpha, theta, idx = neighbour_angle_test(e1, shape, normals, with_index=True)
    assert np.allclose(shape.reshape(-1, 3)[idx[0]], surface(0.0, 0.0))   # M1 = the shape point at (0, 0)
    assert np.degrees(alpha90[0]) > 95.0                              # measured 95.05 deg
    assert not ok90[0]                                                # the 90-degree test misjudges E1
    assert ok[0] and np.degrees(theta[0]) > np.degrees(alpha[0]) + 10  # theta 106.6 deg > alpha 95.05 deg
    # a patch of such points, all 0.01 mm clear of the wall. Where the twist bends the sheet away
    # from N1 (v > 0 here) the 90-degree test rejects them all and the angles accept them all ...
    us, vs = np.meshgrid(np.linspace(0.3, 0.45, 4), np.linspace(0.0, 0.4, 5))
    pts = (surface(us, vs) + 0.01 * normal(us, vs)).reshape(-1, 3)
    assert not normal_test(pts, shape, normals)[0].any()
    assert neighbour_angle_test(pts, shape, normals)[0].all()
    # ... but where it bends the sheet towards N1 (v < 0: the diagonal neighbour M(1, -1) lies
    # above M1's tangent plane, theta < 90 deg) it is the other way round: the neighbour-angle
    # test rejects clear points that the 90-degree test gets right
    us, vs = np.meshgrid(np.linspace(0.3, 0.45, 4), np.linspace(-0.4, -0.3, 3))
    pts = (surface(us, vs) + 0.01 * normal(us, vs)).reshape(-1, 3)
    assert normal_test(pts, shape, normals)[0].all()
    assert not neighbour_angle_test(pts, shape, normals)[0].any()
    # the safety margin Delta2 turns E1 infeasible once it exceeds theta - alpha
    margin = theta[0] - alpha[0]
    assert neighbour_angle_test(e1, shape, normals, delta2=margin - 1e-6)[0][0]
    assert not neighbour_angle_test(e1, shape, normals, delta2=margin + 1e-6)[0][0]


def _cylinder(radius, h, convex, nu=41, nv=21):
    """Shape points of a cylinder (axis Y), arc spacing h along u, h along v; normals to the channel side."""
    u = (np.arange(nu) - nu // 2) * h
    v = (np.arange(nv) - nv // 2) * h
    uu, vv = np.meshgrid(u, v)
    phi = uu / radius
    pts = np.stack([radius * np.sin(phi), vv, radius * np.cos(phi)], axis=-1)
    out = np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], axis=-1)
    return pts, (out if convex else -out)


def test_neighbour_angle_examples_of_misjudgement():
    """Convex wall: a point inside is accepted; concave wall: a clear point is rejected."""
    radius, h = 3.0, 0.5
    sag = radius * (1 - np.cos(h / (2 * radius)))       # 0.0104 mm
    phi = 0.45 * h / radius
    for convex in (True, False):
        shape, normals = _cylinder(radius, h, convex)
        d = -0.5 * sag if convex else 0.5 * sag          # signed distance, positive in the channel
        rho = radius + d if convex else radius - d
        e = np.array([rho * np.sin(phi), 0.0, rho * np.cos(phi)])
        ok, _, _ = neighbour_angle_test(e, shape, normals)
        assert ok[0] == convex                           # judged clear iff convex: wrong both times
        assert (d > 0) != convex


@pytest.mark.parametrize("h", [0.5, 0.25])
def test_misjudgement_band_against_shape_point_spacing(h):
    """Misjudged points lie within ~1.4 sagittas of the wall; the 90-degree test's within one."""
    radius = 3.0
    sag = radius * (1 - np.cos(h / (2 * radius)))
    rng = np.random.default_rng(5)
    n = 100_000
    phi = rng.uniform(-5 * h, 5 * h, n) / radius
    y = rng.uniform(-3 * h, 3 * h, n)
    d = rng.uniform(-2 * sag, 2 * sag, n)                # exact signed distance, + in the channel
    for convex in (True, False):
        shape, normals = _cylinder(radius, h, convex)
        rho = radius + d if convex else radius - d
        e = np.column_stack([rho * np.sin(phi), y, rho * np.cos(phi)])
        ok, _, _ = neighbour_angle_test(e, shape, normals)
        ok90, _ = normal_test(e, shape, normals)
        wrong, wrong90 = ok != (d > 0), ok90 != (d > 0)
        band, band90 = np.abs(d[wrong]).max() / sag, np.abs(d[wrong90]).max() / sag
        # measured 1.31-1.35 (h = 0.5, 0.25): O(h^2 / R), attained
        assert 1.2 < band <= NEIGHBOUR_BAND
        assert 0.95 < band90 <= 1.0 / np.cos(h / (2 * radius)) + 1e-9
        # the 90-degree test errs on the safe side of a convex wall and the unsafe side of a
        # concave one; the neighbour-angle test mostly the other way round
        inside_accepted, clear_rejected = (wrong & ok).sum(), (wrong & ~ok).sum()
        if convex:
            assert not (wrong90 & ok90).any() and inside_accepted > 20 * clear_rejected
        else:
            assert not (wrong90 & ~ok90).any() and clear_rejected > 20 * inside_accepted
        # and misjudges about twice as many points (chord vs tangent: h^3/12 vs h^3/24 in 2-D)
        assert wrong.mean() > 1.5 * wrong90.mean()


# ----------------------------------------------------------------- the default blisk

@pytest.fixture(scope="module")
def default(default_geometry):
    return default_geometry


@pytest.fixture(scope="module")
def criteria(default):
    return {t: PaperCriteria(default.blisk, blade_test=t) for t in BLADE_TESTS}


@pytest.fixture(scope="module")
def exact(default):
    return ExactChannelDistance(default.blisk)


def _electrode_points(electrode):
    return np.vstack([electrode.samples[s] for s in ("left", "right", "upper", "lower")])


def _shifted(pose, distance):
    """The pose turned about X towards -theta by ``distance`` mm at the radius of its origin.

    A turn keeps every point's radius (a straight translation would also move the
    ends of the strongly swept electrode radially, here into the shroud).
    """
    return rotation_about_x(-distance / np.hypot(pose[1, 3], pose[2, 3])) @ pose


def test_invalid_arguments(default):
    with pytest.raises(ValueError):
        PaperCriteria(default.blisk, blade_test="dot")
    with pytest.raises(ValueError):
        PaperCriteria(default.blisk, resolution=0.0)


@pytest.mark.parametrize("channel", [0, 3])
def test_final_pose_feasible_and_margins(default, criteria, channel):
    b = default.blisk
    e = default.electrodes[0]
    pts = _electrode_points(e)
    pose = e.pose_in_channel(channel, b.pitch)[None]
    gap = default.design.discharge_gap
    for blade_test, crit in criteria.items():
        ok, margin = crit.pose_feasible(pose, pts, channel, with_margin=True)
        assert ok.all(), blade_test
        # hub and shroud: the discharge gap, read radially (gap / cos(slope) >= gap)
        assert np.all(margin[0, 2:] >= gap - OFFSET_TOL) and np.all(margin[0, 2:] <= gap + OFFSET_TOL)
        assert np.all(margin[0, :2] > 0.2)               # angles [rad]; measured 0.58 / 0.62 rad
    # the safety factors are respected: just within the margins feasible, just beyond not
    within = PaperCriteria(b, delta1=margin[0, 2:].min() - 1e-6, delta2=margin[0, :2].min() - 1e-6,
                           blade_test=blade_test)
    beyond = PaperCriteria(b, delta1=margin[0, 2:].max() + 1e-6, delta2=margin[0, :2].max() + 1e-6,
                           blade_test=blade_test)
    assert within.pose_feasible(pose, pts, channel).all()
    assert not beyond.pose_feasible(pose, pts, channel).any()


@pytest.mark.parametrize("channel", [0, 3])
def test_electrode_shifted_into_the_suction_wall_is_infeasible(default, criteria, exact, channel):
    b = default.blisk
    e = default.electrodes[0]
    pts = _electrode_points(e)[::2]                     # every face, 0.5 mm -> ~0.7 mm apart
    final = e.pose_in_channel(channel, b.pitch)
    poses = np.stack([_shifted(final, 1.0), _shifted(final, 0.05)])
    for crit in criteria.values():
        ok = crit.pose_feasible(poses, pts, channel)
        np.testing.assert_array_equal(ok[0], [False, True, True, True])
        np.testing.assert_array_equal(ok[1], [True, True, True, True])   # 0.05 mm < the 0.1 mm gap
    # a batch of poses = one pose at a time
    crit = criteria["neighbour_angle"]
    np.testing.assert_array_equal(crit.pose_feasible(poses[:1], pts, channel)[0], [False, True, True, True])
    left = e.samples["left"][::5]                       # the face towards the suction wall
    world = (left @ poses[0, :3, :3].T) + poses[0, :3, 3]
    assert exact.clearances(world, channel)[:, 0].min() < -0.8


def test_channel_k_is_channel_0_rotated(default, criteria):
    b = default.blisk
    rng = np.random.default_rng(6)
    p = cylindrical_to_cartesian(rng.uniform(0, 25, 2000), rng.uniform(101, 119, 2000), rng.uniform(-0.1, 0.2, 2000))
    rot = rotation_about_x(3 * b.pitch)[:3, :3]
    for crit in criteria.values():
        r0, r3 = crit.evaluate(p, 0), crit.evaluate(p @ rot.T, 3)
        for s in SURFACES + ("feasible",):
            np.testing.assert_array_equal(r0[s], r3[s])
        np.testing.assert_allclose(r0["margin"], r3["margin"], atol=1e-9)


def test_shape_point_normals_point_into_the_channel(criteria, exact):
    crit = criteria["neighbour_angle"]
    for col, surface in enumerate(("suction", "pressure")):
        pts, nrm = crit.shape_points(surface, channel=3)
        nv, nu = pts.shape[:2]
        inner = (slice(nv // 5, 4 * nv // 5, 3), slice(nu // 5, 4 * nu // 5, 3))   # away from edges and walls
        p, n = pts[inner].reshape(-1, 3), nrm[inner].reshape(-1, 3)
        np.testing.assert_allclose(exact.clearances(p + 0.05 * n, 3)[:, col], 0.05, atol=2e-3)
        np.testing.assert_allclose(exact.clearances(p - 0.05 * n, 3)[:, col], -0.05, atol=2e-3)


def test_face_shape_points_spacing(default):
    pts, nrm = face_shape_points(default.blisk.suction_face.surface, 0.5, +1)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=-1), 1.0, atol=1e-12)
    assert np.linalg.norm(np.diff(pts, axis=0), axis=-1).max() <= 0.5 + 1e-9    # span: uniform enough
    assert np.linalg.norm(np.diff(pts, axis=1), axis=-1).max() <= 0.65          # chord: measured 0.61


def _min_curvature_radius(blisk):
    """Smallest radius of curvature of the blade faces along the chord [mm] (at the edges).

    From the turning of the normals over 4000 steps along u, on 41 sections.
    """
    u, v = np.meshgrid(np.linspace(0, 1, 4001), np.linspace(0, 1, 41))
    radii = []
    for face in (blisk.suction_face, blisk.pressure_face):
        pts, nrm = face.surface.evaluate(u, v), face.surface.normals(u, v)
        ds = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
        dn = np.linalg.norm(np.diff(nrm, axis=1), axis=-1)
        radii.append((ds / np.maximum(dn, 1e-300)).min())
    return min(radii)


@pytest.mark.parametrize("channel", [0, 3])
def test_agreement_with_exact_signed_distance(default, criteria, exact, channel):
    """Random points within 0.5 mm of the blade walls: sign of the exact distance vs the decision.

    Points are kept on this side of the blade: a point pushed through a thin
    edge into the neighbouring channel is behind the wall for the criteria,
    but clear of the face for the exact reference (its sign says "inside the
    blade", and the point is not).
    """
    b = default.blisk
    rng = np.random.default_rng(10 + channel)
    n = 5000
    x0, x1 = b.axial_range
    x = rng.uniform(x0, x1, n)
    r = rng.uniform(b.hub.radius_at(x) + 0.3, b.shroud.radius_at(x) - 0.3)
    th_s, th_p, inside = b.wall_angles(x, r)
    th_minus, _ = b.pressure_face.theta_at(x, r)
    th_plus, _ = b.suction_face.theta_at(x, r)
    thickness = (th_plus - th_minus) * r
    which = rng.integers(0, 2, n)                       # 0: near the suction wall, 1: the pressure wall
    s = rng.uniform(-1, 1, n)
    offset = np.where(s < 0, s * np.minimum(0.5, 0.9 * thickness), 0.5 * s)   # < 0: into the blade
    th = np.where(which == 0, th_s + offset / r, th_p - offset / r)
    keep = inside
    p = cylindrical_to_cartesian(x, r, th + channel * b.pitch)[keep]
    which = which[keep]
    d = exact.clearances(p, channel)
    h = criteria["neighbour_angle"].spacing
    rho_min = _min_curvature_radius(b)                   # measured 0.236 mm, at the trailing edge
    band = NEIGHBOUR_BAND * h**2 / (8 * rho_min)        # 0.069 mm for h = 0.305 mm
    for name, crit in criteria.items():
        res = crit.evaluate(p, channel)
        wrong = np.zeros(len(p), dtype=bool)
        for col, surface in enumerate(("suction", "pressure")):
            sel = which == col
            wrong[sel] = res[surface][sel] != (d[sel, col] > 0)
            assert np.all(np.abs(d[sel & wrong, col]) <= band)
        # measured misjudged (channel 0 / 3): 0.09 / 0.06 % neighbour-angle (at most 0.019 mm
        # from the wall), 0 / 0.04 % 90-degree, of ~4700 points
        assert wrong.mean() < 0.005, (name, wrong.mean())
