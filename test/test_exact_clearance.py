"""Exact clearances against closed forms, and the triangle-exact mesh method.

A synthetic blisk whose blade faces are half-planes through the axis
(theta = const) between cylindrical (or conical) hub and shroud has
closed-form distances: to the face theta = a, rho * sin(theta - a); to a
cylinder of radius R, |rho - R|; to a cone r = r0 + k x, the distance to a
line in the (x, r) half-plane.
"""

import numpy as np
import pytest
import trimesh

from edm_planner.geometry.blisk import Blisk
from edm_planner.geometry.frames import cylindrical_to_cartesian
from edm_planner.geometry.profiles import RevolutionProfile
from edm_planner.geometry.sections import BladeSections
from edm_planner.interference.exact_points import ExactChannelDistance, pose_clearances, transform_points
from edm_planner.interference.mesh_exact import MeshChannelChecker

A = 0.05          # blade half-thickness [rad]
N = 12


def flat_blade_blisk(hub_slope=0.0):
    x, r = np.meshgrid(np.linspace(0, 20, 21), np.linspace(90, 130, 9))
    blade = BladeSections(x, r, np.full_like(x, -A), np.full_like(x, A))
    hub = RevolutionProfile([[-10, 100 - 10 * hub_slope], [30, 100 + 30 * hub_slope]], "hub_profile")
    shroud = RevolutionProfile([[-10, 120.0], [30, 120.0]], "shroud_profile")
    return Blisk(N, hub, shroud, blade)


@pytest.fixture(scope="module")
def flat():
    return flat_blade_blisk()


@pytest.fixture(scope="module")
def flat_exact(flat):
    return ExactChannelDistance(flat)


def test_points_against_closed_forms(flat, flat_exact):
    rng = np.random.default_rng(1)
    n = 400
    x = rng.uniform(2, 18, n)
    rho = rng.uniform(101, 119, n)
    pitch = 2 * np.pi / N
    th = rng.uniform(A + 0.01, pitch - A - 0.01, n)
    for channel in (0, 5):
        p = cylindrical_to_cartesian(x, rho, th + channel * pitch)
        d, feet = flat_exact.clearances(p, channel=channel, closest=True)
        np.testing.assert_allclose(d[:, 0], rho * np.sin(th - A), atol=1e-9)
        np.testing.assert_allclose(d[:, 1], rho * np.sin(pitch - A - th), atol=1e-9)
        np.testing.assert_allclose(d[:, 2], rho - 100, atol=1e-9)
        np.testing.assert_allclose(d[:, 3], 120 - rho, atol=1e-9)
        # the feet lie on their surfaces at the stated distances
        np.testing.assert_allclose(np.linalg.norm(feet - p[:, None, :], axis=2), np.abs(d), atol=1e-8)


def test_penetration_is_negative(flat, flat_exact):
    pts = cylindrical_to_cartesian([10, 10, 10, 10], [110, 110, 99.5, 120.7], [A - 0.01, 2 * np.pi / N - A + 0.01, 0.2, 0.2])
    d = flat_exact.clearances(pts)
    assert d[0, 0] == pytest.approx(-110 * np.sin(0.01), abs=1e-9)      # inside blade 0
    assert d[1, 1] == pytest.approx(-110 * np.sin(0.01), abs=1e-9)      # inside blade 1
    assert d[2, 2] == pytest.approx(-0.5, abs=1e-9)                     # below the hub
    assert d[3, 3] == pytest.approx(-0.7, abs=1e-9)                     # above the shroud


def test_conical_hub_is_the_distance_to_a_line_in_the_meridional_plane():
    k = 0.2
    blisk = flat_blade_blisk(hub_slope=k)
    exact = ExactChannelDistance(blisk)
    x, rho = np.array([5.0, 10.0, 15.0]), np.array([104.0, 105.0, 108.0])
    p = cylindrical_to_cartesian(x, rho, np.full(3, 0.2))
    d = exact.clearances(p)[:, 2]
    # line r = 100 + k x: distance (rho - 100 - k x) / sqrt(1 + k^2)
    np.testing.assert_allclose(d, (rho - 100 - k * x) / np.hypot(1, k), atol=1e-9)


def test_pose_clearances_take_the_minimum_over_points(flat, flat_exact):
    box = trimesh.creation.box(extents=[4.0, 2.0, 2.0])
    pose = np.eye(4)
    pose[:3, 3] = cylindrical_to_cartesian(10.0, 110.0, np.pi / N)      # mid channel
    m, arg = pose_clearances(flat_exact.clearances, pose[None], box.vertices)
    d_all = flat_exact.clearances(transform_points(pose[None], box.vertices)[0])
    np.testing.assert_allclose(m[0], d_all.min(axis=0))
    assert (arg[0] == d_all.argmin(axis=0)).all()
    # hub clearance of the box: its vertex nearest the axis, closed form
    world = transform_points(pose[None], box.vertices)[0]
    assert m[0, 2] == pytest.approx(np.hypot(world[:, 1], world[:, 2]).min() - 100, abs=1e-9)


def test_mesh_method_matches_closed_form_for_a_box(flat):
    checker = MeshChannelChecker(flat, resolution=0.5)
    assert checker.faceting_bound < 0.01      # planes exact, cylinders sag ~ l^2 / (8 R)
    box = trimesh.creation.box(extents=[4.0, 2.0, 2.0])
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 110.0, 0.0]           # theta = 0: the box sits wholly inside blade 0 (|theta| < A)
    d = checker.clearances(box, pose[None])
    # deepest vertex: theta = 1/109 rad from the face at theta = +A ... closed form
    world = transform_points(pose[None], box.vertices)[0]
    th = np.arctan2(world[:, 2], world[:, 1])
    expected = (np.hypot(world[:, 1], world[:, 2]) * np.sin(th - A)).min()
    assert d[0, 0] == pytest.approx(expected, abs=1e-6) and d[0, 0] < -4
    assert d[0, 1] > 0
    pose[:3, 3] = cylindrical_to_cartesian(10.0, 110.0, np.pi / N)
    d, pairs = checker.clearances(box, pose[None], closest=True)
    exact = ExactChannelDistance(flat).clearances(transform_points(pose[None], box.vertices)[0]).min(axis=0)
    # a box's closest feature to a plane or a cylinder is a vertex: both methods agree
    np.testing.assert_allclose(d[0], exact, atol=checker.faceting_bound + 1e-6)
    np.testing.assert_allclose(np.linalg.norm(pairs[0, :, 0] - pairs[0, :, 1], axis=1), d[0], atol=1e-6)


def test_mesh_method_sees_contact_between_sample_points(flat):
    """A flat plate above the convex hub: clear at its corners, cutting the hub in its middle."""
    checker = MeshChannelChecker(flat, resolution=0.25)
    plate = trimesh.creation.box(extents=[4.0, 0.5, 10.0])   # bottom face 10 mm across the hub
    sag = 100.1 - np.sqrt(100.1**2 - 25.0)                   # 0.1249 mm: chord of the r = 100.1 circle
    rot = trimesh.transformations.rotation_matrix(np.pi / N, [1, 0, 0])
    pose = rot.copy()
    pose[:3, 3] = rot[:3, :3] @ [10.0, np.sqrt(100.1**2 - 25.0) + 0.25, 0.0]
    corners = ExactChannelDistance(flat).clearances(transform_points(pose[None], plate.vertices)[0])[:, 2].min()
    assert corners == pytest.approx(0.1, abs=1e-9)          # every vertex is 0.1 mm clear of the hub
    d = checker.clearances(plate, pose[None])[0, 2]
    # the plate's middle is 0.1 - sag = -0.025 mm inside the hub (to the hub mesh's faceting)
    assert d == pytest.approx(0.1 - sag, abs=checker.faceting_bound + 1e-4)
