"""Five-axis kinematics (Huang eq. 2): forward/inverse round trips and channel selection."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from edm_planner.geometry.frames import rotation_about_x
from edm_planner.cnc.kinematics import FiveAxisKinematics

PITCH = 2 * np.pi / 60


def machine(c_pivot=(1.0, -2.0, 30.0), a_zero=0.0):
    final = np.eye(4)
    final[:3, :3] = Rotation.from_euler("xyz", [0.05, -0.1, 0.2]).as_matrix()
    final[:3, 3] = [12.0, 109.0, 4.0]
    return FiveAxisKinematics(final, PITCH, c_pivot=c_pivot, a_zero=a_zero)


def test_zero_axes_are_the_final_pose_and_a_selects_the_channel():
    k = machine()
    np.testing.assert_allclose(k.forward(np.zeros(5))[0], k.final_pose, atol=1e-12)
    for ch in (1, 7, 59):
        pose = k.forward([0, 0, 0, ch * PITCH, 0])[0]
        np.testing.assert_allclose(pose, rotation_about_x(ch * PITCH) @ k.final_pose, atol=1e-12)


def test_c_rotates_about_its_pivot():
    k = machine()
    pivot_world = k.final_pose[:3, :3] @ np.asarray(k.c_pivot) + k.final_pose[:3, 3]
    pose = k.forward([0, 0, 0, 0, 0.3])[0]
    np.testing.assert_allclose(pose[:3, :3] @ np.asarray(k.c_pivot) + pose[:3, 3], pivot_world, atol=1e-12)


def test_linear_axes_translate_in_w():
    k = machine()
    pose = k.forward([1.5, -2.0, 0.25, 0, 0])[0]
    np.testing.assert_allclose(pose[:3, 3] - k.final_pose[:3, 3], [1.5, -2.0, 0.25], atol=1e-12)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(q=st.lists(st.floats(-50, 50), min_size=3, max_size=3),
       a=st.floats(-3.0, 3.0), c=st.floats(-1.4, 1.4), a_zero=st.floats(-1, 1))
def test_round_trip_pose_axes_pose_is_exact(q, a, c, a_zero):
    k = machine(a_zero=a_zero)
    axes = np.array([*q, a, c])
    pose = k.forward(axes)
    back, residual = k.inverse(pose)
    assert residual[0] < 1e-9
    np.testing.assert_allclose(k.forward(back), pose, atol=1e-9)


def test_unreachable_orientation_is_reported():
    k = machine()
    pose = k.forward(np.zeros(5))[0]
    pose[:3, :3] = Rotation.from_euler("y", 0.3).as_matrix() @ pose[:3, :3]    # a tilt no axis gives
    _, residual = k.inverse(pose[None])
    assert residual[0] > 0.1
