"""Continuous certification of motion segments."""

import numpy as np
import pytest

from edm_planner.interference.segment import certify_segment, screw_motion


def wall_clearance(wall_y, half_width=1.0):
    """A box electrode of half-width 1 mm along Y, a wall at y = wall_y: clearance of its +Y face."""
    def clearance(poses):
        return wall_y - (poses[:, 1, 3] + half_width)
    return clearance


def translation(y):
    m = np.eye(4)
    m[1, 3] = y
    return m


def test_straight_motion_clear_of_a_wall_is_certified():
    pose_at, lip = screw_motion(translation(0.0), translation(1.0), np.array([[0, 1.0, 0]]))
    res = certify_segment(wall_clearance(3.0), pose_at, lip, threshold=0.1)
    assert res.certified and np.isnan(res.first_contact) and res.clearance_lower_bound >= 0.1


def test_collision_between_two_clear_waypoints_is_caught():
    """Both ends are far clear, but the straight path crosses an obstacle in its middle."""
    def clearance(poses):
        return np.hypot(poses[:, 0, 3] - 5.0, poses[:, 1, 3] - 0.3) - 0.5    # disc of radius 0.5 at (5, 0.3)

    a, b = np.eye(4), np.eye(4)
    b[0, 3] = 10.0
    pose_at, lip = screw_motion(a, b, np.zeros((1, 3)))
    assert (clearance(np.stack([a, b])) > 4).all()              # a discrete check at the waypoints passes
    res = certify_segment(clearance, pose_at, lip, threshold=0.0)
    assert not res.certified
    assert res.first_contact == pytest.approx((5.0 - 0.4) / 10.0, abs=1e-4)


def test_first_contact_parameter_and_depth():
    """Line y = 0 from x = 0 to 10 through a disc of radius 1 centred (6, 0.5)."""
    def clearance(poses):
        return np.hypot(poses[:, 0, 3] - 6.0, poses[:, 1, 3] - 0.5) - 1.0

    a, b = np.eye(4), np.eye(4)
    b[0, 3] = 10.0
    pose_at, lip = screw_motion(a, b, np.zeros((1, 3)))
    res = certify_segment(clearance, pose_at, lip, threshold=0.0, min_interval=1e-7)
    assert not res.certified
    entry = (6.0 - np.sqrt(1 - 0.25)) / 10.0                    # first parameter inside the disc
    assert entry - 1e-5 <= res.first_contact <= entry + 1e-5
    assert res.penetration_bound >= 0


def test_rotation_uses_the_lever_arm():
    """A 1 mm-clear electrode rotated by 0.2 rad with a 10 mm lever arm: the bound must see 2 mm of travel."""
    r1 = np.eye(4)
    c, s = np.cos(0.2), np.sin(0.2)
    r1[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    pts = np.array([[0, 10.0, 0]])
    pose_at, lip = screw_motion(np.eye(4), r1, pts)
    assert lip == pytest.approx(0.2 * 10.0)
    # the tip at (0, 10 cos, 10 sin) approaches a wall z = 1.5 (reached at sin^-1(0.15) < 0.2 rad)
    def clearance(poses):
        tip = poses[:, :3, :3] @ pts[0] + poses[:, :3, 3]
        return 1.5 - tip[:, 2]
    res = certify_segment(clearance, pose_at, lip)
    assert not res.certified
    assert res.first_contact == pytest.approx(np.arcsin(0.15) / 0.2, abs=1e-4)


def test_start_in_collision_is_reported_at_zero():
    pose_at, lip = screw_motion(translation(0.0), translation(1.0), np.zeros((1, 3)))
    res = certify_segment(wall_clearance(0.5), pose_at, lip)
    assert not res.certified and res.first_contact == 0.0 and res.penetration_bound == pytest.approx(0.5)


def test_budget_exhaustion_is_not_a_certificate():
    """A path that grazes the threshold cannot be certified within a tiny budget: reported, not passed."""
    pose_at, lip = screw_motion(translation(0.0), translation(1.0), np.zeros((1, 3)))
    res = certify_segment(lambda p: np.full(len(p), 0.1000001), pose_at, lip * 100 + 1, threshold=0.1,
                          max_evaluations=8)
    assert not res.certified and res.penetration_bound > 0
