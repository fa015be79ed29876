"""The ROS message conversions of poses: one vectorised conversion, the same numbers as one matrix at a time."""

import numpy as np
import pytest
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


def test_a_mesh_goes_into_its_message_and_back_bit_for_bit_and_a_broken_one_is_refused():
    import trimesh
    from edm_planner_msgs.msg import TriangleMesh

    from edm_planner.ros.conversions import mesh_to_msg, msg_to_mesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=7.25)
    mesh.vertices += [0.1 + 1e-12, -3.0, 120.0]
    msg = mesh_to_msg(mesh)
    assert len(msg.vertices) == 3 * len(mesh.vertices) and len(msg.triangles) == 3 * len(mesh.faces)
    back = msg_to_mesh(msg)
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    # through the message's serialization, as a subscriber receives it
    from rclpy.serialization import deserialize_message, serialize_message
    received = msg_to_mesh(deserialize_message(serialize_message(msg), TriangleMesh))
    np.testing.assert_array_equal(received.vertices, mesh.vertices)
    np.testing.assert_array_equal(received.faces, mesh.faces)
    cut = TriangleMesh(vertices=list(msg.vertices)[:-1], triangles=list(msg.triangles))
    with pytest.raises(ValueError, match="3 values per vertex"):
        msg_to_mesh(cut)
    beyond = TriangleMesh(vertices=list(msg.vertices), triangles=[0, 1, len(mesh.vertices)])
    with pytest.raises(ValueError, match="beyond the"):
        msg_to_mesh(beyond)
