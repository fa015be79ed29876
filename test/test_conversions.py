"""The ROS message conversions of poses: one vectorised conversion, the same numbers as one matrix at a time."""

import numpy as np
from scipy.spatial.transform import Rotation

from edm_planner.ros.conversions import matrices_to_poses, matrix_to_pose, pose_to_matrix


def _transforms(n, seed):
    rng = np.random.default_rng(seed)
    m = np.repeat(np.eye(4)[None], n, axis=0)
    m[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    m[:, :3, 3] = rng.uniform(-300.0, 300.0, (n, 3))
    return m


def _fields(pose):
    return (pose.position.x, pose.position.y, pose.position.z,
            pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w)


def test_matrices_to_poses_gives_each_matrix_its_own_quaternion_and_position():
    m = _transforms(500, seed=3)
    m[0, :3, :3] = np.diag([1.0, -1.0, -1.0])              # a half turn: the quaternion's sign convention
    poses = matrices_to_poses(m)
    assert len(poses) == 500
    for k, pose in enumerate(poses):
        q = Rotation.from_matrix(m[k, :3, :3]).as_quat()     # one matrix at a time, as before
        assert _fields(pose) == (*m[k, :3, 3], *q)
        assert _fields(matrix_to_pose(m[k])) == _fields(pose)
        np.testing.assert_allclose(pose_to_matrix(pose), m[k], rtol=0, atol=1e-12)


def test_matrices_to_poses_takes_none_and_lists():
    assert matrices_to_poses(np.empty((0, 4, 4))) == []
    assert _fields(matrices_to_poses([np.eye(4)])[0]) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
