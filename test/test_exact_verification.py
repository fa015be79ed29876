"""Exact verification of poses with the field's numba solvers (FastChannelField.exact_pose_clearances).

The numba solvers must agree with ExactChannelDistance (same spline faces, same
profiles, same sign rule), and the field's branch and bound must give exactly
the minimum of the exact distances over every electrode vertex. Units: mm, rad.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from edm_planner.geometry.frames import rotation_about_x
from edm_planner.interference.checker import ChannelChecker, Method, per_distinct_pose
from edm_planner.interference.exact_points import ExactChannelDistance, transform_points


GAP = 0.1


@pytest.fixture(scope="module")
def default(default_geometry):
    return default_geometry


@pytest.fixture(scope="module")
def field(default_field):
    return default_field


def near(pose, n, seed, shift=0.02, turn=2e-4):
    rng = np.random.default_rng(seed)
    out = np.repeat(pose[None], n, axis=0)
    out[:, :3, :3] = Rotation.from_rotvec(rng.normal(scale=turn, size=(n, 3))).as_matrix() @ pose[:3, :3]
    out[:, :3, 3] += rng.normal(scale=shift, size=(n, 3))
    return out


def shifted(pose, by):
    out = pose.copy()
    out[:3, 3] += by
    return out


def brute_force(field, poses, points, channel=0):
    """Exact distances of every vertex under every pose by the numba solvers: (min, argmin) per surface."""
    world = transform_points(poses, points)
    d = np.concatenate([field.exact_blade_distances(world.reshape(-1, 3), channel),
                        field.exact_profile_distances(world.reshape(-1, 3))], axis=1)
    d = d.reshape(len(poses), len(points), 4)
    return d.min(axis=1), d


def test_numba_solvers_agree_with_the_exact_method_on_the_electrode(default, field):
    e = default.electrodes[0]
    world = transform_points(near(e.final_pose, 2, seed=3, shift=0.05), e.mesh.vertices[::5]).reshape(-1, 3)
    ref = ExactChannelDistance(default.blisk).clearances(world)
    mine = np.concatenate([field.exact_blade_distances(world), field.exact_profile_distances(world)], axis=1)
    assert np.array_equal(np.sign(mine), np.sign(ref))
    diff = np.abs(mine - ref)
    # same surfaces: equal to 1e-6 mm, except where BladeFace.closest_points stops short of the
    # minimum (closest point near an edge of the face): there the numba solver is closer
    assert diff[:, 2:].max() < 1e-6
    assert (np.abs(mine) <= np.abs(ref) + 1e-8).all()
    assert (np.mean(diff[:, :2] < 1e-6, axis=0) > 0.75).all()
    assert diff.max() < 0.005


def test_branch_and_bound_is_the_exact_minimum_over_all_vertices(default, field):
    e = default.electrodes[0]
    pts = np.asarray(e.mesh.vertices)
    poses = np.concatenate([
        e.final_pose[None],
        near(e.final_pose, 3, seed=1),
        near(e.final_pose, 2, seed=2, shift=0.15),                       # some of these penetrate
        shifted(e.final_pose, [-25.0, 0, 0])[None],                     # partly out of the grid axially
    ])
    got, arg, solved = field.exact_pose_clearances(poses, pts)
    want, every = brute_force(field, poses, pts)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)          # same vertex transform up to rounding
    np.testing.assert_allclose(every[np.arange(len(poses))[:, None], arg, np.arange(4)], got, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[0], GAP, atol=3e-6)
    assert (got[4:6].min(axis=1) < 0).any()                              # the test sees penetration
    # the pruning pays: far fewer exact solves than 4 per vertex (final pose: the faces parallel the walls)
    assert (solved[1:4] < pts.shape[0]).all()
    assert solved[-1] < 0.2 * pts.shape[0]


def test_other_channel_is_channel_zero_turned(default, field):
    e = default.electrodes[0]
    pts = np.asarray(e.mesh.vertices)[::3]
    poses = near(e.final_pose, 2, seed=4)
    k = 7
    turned = rotation_about_x(k * default.blisk.pitch)[None] @ poses
    a, _, _ = field.exact_pose_clearances(poses, pts, 0)
    b, _, _ = field.exact_pose_clearances(turned, pts, k)
    np.testing.assert_allclose(a, b, atol=1e-9)
    np.testing.assert_allclose(b, brute_force(field, turned, pts, k)[0], rtol=0, atol=1e-12)


def test_checker_exact_method_with_the_field_and_its_closest_points(default, field):
    e = default.electrodes[0]
    checker = ChannelChecker(default.blisk, {"main": (e.mesh, e.final_pose)}, default.geometry_id)
    poses = near(e.final_pose, 2, seed=5)
    without = checker.check(poses, method=Method.EXACT, closest=True)      # ExactChannelDistance on every vertex
    checker._fast = field
    with_field = checker.check(poses, method=Method.EXACT, closest=True)
    np.testing.assert_allclose(with_field.clearances, brute_force(field, poses, e.mesh.vertices)[0], rtol=0, atol=1e-12)
    # the Python solver stops short by a few micrometres at most, never the other way
    assert (with_field.clearances <= without.clearances + 1e-9).all()
    np.testing.assert_allclose(with_field.clearances, without.clearances, atol=5e-3)
    pairs = with_field.closest
    np.testing.assert_allclose(np.linalg.norm(pairs[:, :, 0] - pairs[:, :, 1], axis=2),
                               np.abs(with_field.clearances), atol=1e-9)


def test_a_path_that_comes_back_is_checked_once_per_distinct_pose_and_answered_for_every_pose(default, field):
    """A cycle's return leg retraces its feed: the checker computes each distinct pose once (the same bytes; 0.0
    and -0.0 differ) and answers every pose bit for bit what the field gives for the whole list."""
    e = default.electrodes[0]
    checker = ChannelChecker(default.blisk, {"main": (e.mesh, e.final_pose)}, default.geometry_id)
    checker._fast = field
    feed = near(e.final_pose, 30, seed=8, shift=0.3, turn=2e-3)
    signed = np.eye(4)                                                   # the final pose's place, unturned
    signed[:3, 3] = e.final_pose[:3, 3]
    zero = signed.copy()
    zero[0, 1] = -0.0                                                    # equal as a number, other bytes
    poses = np.concatenate([feed, feed[::-1], feed[7:9], [signed, zero]])
    asked = []

    def counted(p, points, channel):
        asked.append(len(p))
        return field.pose_clearances(p, points, channel)

    checker._fast = type("Counted", (), {"pose_clearances": staticmethod(counted), "error_bound": field.error_bound})()
    got = checker.check(poses, method=Method.FAST, threshold=0.05)
    assert asked == [32]                                                  # 30 + the two signed-zero poses
    whole, _ = field.pose_clearances(poses, e.mesh.vertices, 0)
    np.testing.assert_array_equal(got.clearances, whole)
    np.testing.assert_array_equal(got.colliding, whole.min(axis=1) < 0.05 + field.error_bound)
    np.testing.assert_array_equal(got.clearances[30:60], got.clearances[29::-1])


def test_per_distinct_pose_gives_each_pose_the_values_of_its_own_and_keeps_the_first_order():
    rng = np.random.default_rng(3)
    distinct = np.repeat(np.eye(4)[None], 4, axis=0)
    distinct[:, :3, 3] = rng.normal(size=(4, 3))
    poses = distinct[[2, 0, 2, 3, 0, 1, 3]]
    seen = []

    def evaluate(p):                                     # per-pose values of two shapes, as the methods return
        seen.append(p.copy())
        return p[:, :3, 3].sum(axis=1), np.repeat(p[:, None, :3, :], 2, axis=1)

    sums, pairs = per_distinct_pose(poses, evaluate)
    np.testing.assert_array_equal(seen[0], distinct[[2, 0, 3, 1]])                  # each once, first order
    np.testing.assert_array_equal(sums, poses[:, :3, 3].sum(axis=1))
    np.testing.assert_array_equal(pairs, np.repeat(poses[:, None, :3, :], 2, axis=1))
    assert per_distinct_pose(poses[:1], evaluate)[0].shape == (1,)


def test_side_test_is_the_sign_of_the_exact_wall_distance(default, field):
    e = default.electrodes[0]
    pts = np.concatenate([field.error_sample_points(300, seed=7),           # -0.5 ... 2 mm from the walls, edges
                          transform_points(near(e.final_pose, 1, seed=6, shift=0.3), e.mesh.vertices[::7])[0]])
    behind = field.behind_walls(pts)
    d = field.exact_blade_distances(pts)
    np.testing.assert_array_equal(behind, np.signbit(d))
    assert behind.any(axis=0).all() and (~behind).any(axis=0).all()
    k = 5
    turned = pts @ rotation_about_x(k * default.blisk.pitch)[:3, :3].T
    np.testing.assert_array_equal(field.behind_walls(turned, k), behind)


def test_verify_poses_is_the_minimum_over_every_pose_and_vertex(default, field):
    from edm_planner.interference.pose_check import verify_poses

    e = default.electrodes[0]
    pts = np.asarray(e.mesh.vertices)
    poses = np.concatenate([e.final_pose[None], near(e.final_pose, 3, seed=1),
                            near(e.final_pose, 2, seed=2, shift=0.15), shifted(e.final_pose, [-25.0, 0, 0])[None]])
    check = verify_poses(poses, pts, 0, default.blisk, field)
    per_pose, arg, _ = field.exact_pose_clearances(poses, pts)        # exact per pose (tested against brute force)
    got = np.array([check.clearance_exact[s] for s in ("suction", "pressure", "hub", "shroud")])
    np.testing.assert_allclose(got, per_pose.min(axis=0), rtol=0, atol=1e-12)
    for j, s in enumerate(("suction", "pressure", "hub", "shroud")):
        t, k = check.argmin[s]
        assert per_pose[t, j] == pytest.approx(got[j], abs=1e-12)
    assert not check.passed and "hub clearance" in check.message        # the shifted pose is in the hub
    assert check.exact_evaluations < 0.5 * len(poses) * len(pts)         # pruned, even where faces parallel walls


def test_verify_poses_searches_halves_of_the_vertices_with_the_answer_of_one_search(default, field):
    """Each surface is searched as two halves of the vertex tree sharing their best value: the minimum and
    its (sample, vertex) are those of one search over every vertex, on one thread or two."""
    from edm_planner.interference.pose_check import search_trees, surface_minimum, verify_poses

    e = default.electrodes[0]
    V = np.ascontiguousarray(e.mesh.vertices)
    P = np.ascontiguousarray(np.concatenate([e.final_pose[None], near(e.final_pose, 6, seed=3, shift=0.1)]))
    full = field._plain_args(0)
    exact_args = (full.channel_angle, full.params, full.shape, full.tables)
    trees = search_trees(P, V)
    checks = [verify_poses(P, V, 0, default.blisk, field, threads=n) for n in (1, 2)]
    for s, name in enumerate(("suction", "pressure", "hub", "shroud")):
        best, t, k, _, _ = surface_minimum(s, P, V, trees, exact_args)
        for check in checks:
            assert check.clearance_exact[name] == best and check.argmin[name] == (t, k)
    # a value shared by another search prunes: given one just below the minimum, a half solves fewer pairs
    # and finds nothing below it
    def half(shared):
        return surface_minimum(0, P, V, trees, exact_args, root=trees.halves[0], shared=np.full(1, shared))

    alone, told = half(np.inf), half(checks[0].clearance_exact["suction"] - 1e-3)
    assert told[3] < alone[3] and told[0] >= checks[0].clearance_exact["suction"]


def test_the_halves_results_join_as_one_search():
    from edm_planner.interference.pose_check import _joined

    m = 6
    got = _joined([(0.5, 3, 1, 1, np.array([19])), (0.5, 2, 4, 2, np.array([16, 3]))], m)
    assert got[:4] == (0.5, 2, 4, 3) and sorted(got[4]) == [3, 16, 19]      # a tie: the lower key 2 * 6 + 4
    got = _joined([(np.inf, -1, 5, 0, np.zeros(0, np.int64)), (0.7, 0, 1, 4, np.array([1]))], m)
    assert got[:4] == (0.7, 0, 1, 4)
    assert _joined([(np.inf, -1, 5, 0, np.zeros(0, np.int64))] * 2, m)[0] == np.inf     # nothing: inf, no error


def test_distinct_count_is_the_number_of_distinct_keys():
    from edm_planner.interference.pose_check import _distinct_count

    rng = np.random.default_rng(7)
    for keys in (rng.integers(0, 1000, 5000), rng.permutation(300) * 7, np.array([5]), np.zeros(0, np.int64)):
        assert _distinct_count(keys) == len(np.unique(keys))
