"""The material-removal simulation against closed forms, brute force and the default blisk."""

import json
import pickle
from pathlib import Path

import igl
import numpy as np
import pytest
import trimesh

from edm_planner.geometry.frames import cartesian_to_cylindrical, rotation_about_x
from edm_planner.machining.removal import MeshDistance, Sweep, simulate_removal, stock_at_points, wall_samples
from edm_planner.machining.swept_stock import _clusters, _inverse, _PoseTree
from edm_planner.records.stock_maps import plot_stock_maps, stock_vertex_colours

CONFIG = Path(__file__).resolve().parents[1] / "config"
GAP = 0.1
EXACT = 1e-9   # float precision of the distances [mm]


def box(lx, wy, wz):
    """Box electrode with half sizes (lx, wy, wz) centred at its frame's origin."""
    return trimesh.creation.box((2 * lx, 2 * wy, 2 * wz))


def translation(x=0.0, y=0.0, z=0.0):
    t = np.eye(4)
    t[:3, 3] = x, y, z
    return t


def rigid(seed):
    """A random rigid transform (to show the results do not depend on where the setup sits in W)."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    t = np.eye(4)
    t[:3, :3] = q * np.sign(np.linalg.det(q))
    t[:3, 3] = rng.uniform(-50, 50, 3)
    return t


def moved(points, t):
    return points @ t[:3, :3].T + t[:3, 3]


def test_signed_distance_equals_libigl_pseudonormal(monkeypatch):
    # trimesh's contains() casts a second ray in a direction from an unseeded generator where its first rays
    # disagree (points 1e-3 from a vertex): seeded here, so the reference is the same in every run
    monkeypatch.setattr(trimesh.util, "random_generator", lambda seed=None: np.random.default_rng(0))
    rng = np.random.default_rng(0)
    for mesh in (box(1.0, 1.5, 2.0), trimesh.creation.icosphere(2), trimesh.creation.capsule(2.0, 0.5)):
        points = np.vstack([rng.uniform(-3, 3, (300, 3)),
                            mesh.vertices[:200] + rng.normal(0, 1e-3, (min(200, len(mesh.vertices)), 3)),   # vertex regions
                            mesh.sample(300) + rng.normal(0, 0.05, (300, 3))])
        ours = MeshDistance(mesh.vertices, mesh.faces)(points)
        ref = igl.signed_distance(points, np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64))[0]
        np.testing.assert_allclose(ours, ref, atol=EXACT)
        assert np.array_equal(ours < 0, mesh.contains(points))


def _libigl_unsigned(points, V, F):
    return np.asarray(igl.signed_distance(points, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_UNSIGNED)[0],
                      dtype=np.float64).ravel()


def test_the_tree_gives_libigls_distances_bit_for_bit_and_survives_a_pickle():
    """MeshDistance's own bounding-box tree (written here: 1.8x faster than libigl's on one thread) finds the
    distances of libigl's, bit for bit: far, near, at vertices, inside; on a sphere, a capsule and a twisted,
    finely meshed blade-like slab (long thin triangles, many near ties). Pickled (to a worker), the same."""
    rng = np.random.default_rng(1)
    slab = trimesh.creation.box((30.0, 6.0, 0.8))
    slab = slab.subdivide_to_size(0.4)
    twist = np.radians(25.0) * slab.vertices[:, 0] / 30.0                    # about the X axis along the slab
    v = slab.vertices.copy()
    v[:, 1], v[:, 2] = (np.cos(twist) * slab.vertices[:, 1] - np.sin(twist) * slab.vertices[:, 2],
                        np.sin(twist) * slab.vertices[:, 1] + np.cos(twist) * slab.vertices[:, 2])
    meshes = [trimesh.creation.icosphere(3), trimesh.creation.capsule(2.0, 0.5), trimesh.Trimesh(v, slab.faces)]
    for mesh in meshes:
        V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
        lo, hi = V.min(axis=0) - 1.0, V.max(axis=0) + 1.0
        points = np.vstack([rng.uniform(lo, hi, (2000, 3)),
                            V[rng.integers(0, len(V), 300)],                              # on vertices
                            mesh.sample(2000) + rng.normal(0, 0.1, (2000, 3)),          # near, both sides
                            rng.uniform(lo - 40.0, hi + 40.0, (300, 3))])               # far
        dist = MeshDistance(V, F)
        ours = dist(points)
        assert np.abs(ours).tobytes() == _libigl_unsigned(points, V, F).tobytes()
        again = pickle.loads(pickle.dumps(dist))
        assert again(points).tobytes() == ours.tobytes()
    assert dist(np.zeros((0, 3))).shape == (0,)


def test_a_point_that_is_not_finite_has_no_distance_and_an_empty_mesh_is_refused():
    mesh = trimesh.creation.icosphere(2)
    dist = MeshDistance(mesh.vertices, mesh.faces)
    out = dist(np.array([[np.nan, 0.0, 0.0], [0.0, 0.0, 3.0], [np.inf, 1.0, 1.0]]))
    assert np.isnan(out[0]) and np.isnan(out[2]) and out[1] == pytest.approx(2.0, abs=0.02)
    with pytest.raises(ValueError, match="faces"):
        MeshDistance(mesh.vertices, np.zeros((0, 3), dtype=np.int64))


def test_box_in_box_channel_at_one_pose():
    """Every wall's stock over the electrode face's footprint is wall distance - face offset - gap."""
    lx, wy, wz = 5.0, 2.0, 1.5
    walls_y, walls_z = 2.4, 1.7
    place = rigid(1)
    e = box(lx, wy, wz)
    u = np.linspace(-0.95, 0.95, 9)
    xs, ss = np.meshgrid(lx * u, u)
    on_y = np.column_stack([xs.ravel(), walls_y * np.ones(xs.size), wz * ss.ravel()])
    on_z = np.column_stack([xs.ravel(), wy * ss.ravel(), walls_z * np.ones(xs.size)])
    points = np.vstack([on_y, on_y * [1, -1, 1], on_z, on_z * [1, 1, -1]])
    stock, which = stock_at_points(moved(points, place), [(e.vertices, e.faces, place[None])], GAP)
    expected = np.repeat([walls_y - wy - GAP, walls_y - wy - GAP, walls_z - wz - GAP, walls_z - wz - GAP], xs.size)
    np.testing.assert_allclose(stock, expected, atol=EXACT)
    assert (which == 0).all()
    # beyond the face's edge the nearest feature is the edge: sqrt(d^2 + h^2) - gap
    corner = np.array([[1.0, walls_y, wz + 0.3]])
    stock, _ = stock_at_points(moved(corner, place), [(e.vertices, e.faces, place)], GAP)
    assert stock[0] == pytest.approx(np.hypot(walls_y - wy, 0.3) - GAP, abs=EXACT)


def test_translation_sweep_along_a_parallel_wall():
    lx, wy, wz, wall, length = 2.0, 1.0, 1.0, 1.3, 6.0
    e = box(lx, wy, wz)
    poses = np.array([translation(x) for x in np.linspace(0.0, length, 25)])
    x = np.linspace(-lx + 0.01, length + lx + 1.5, 200)
    points = np.column_stack([x, np.full_like(x, wall), np.linspace(-0.9, 0.9, len(x))])
    place = rigid(2)
    stock, which = stock_at_points(moved(points, place), [Sweep(e.vertices, e.faces, place @ poses)], GAP)
    beyond = np.maximum(x - (length + lx), 0.0)
    np.testing.assert_allclose(stock, np.hypot(beyond, wall - wy) - GAP, atol=EXACT)
    assert (which[beyond > 0, 1] == len(poses) - 1).all()   # the end of the travel attains them


def test_rotation_sweep_farthest_corner_on_a_cylinder():
    """A box turned about X: on a cylinder around X the corners' radius leaves rho_wall - rho_corner."""
    lx, w, r0, turn = 3.0, 1.0, 10.0, 0.4
    e = box(lx, w, w)
    angles = np.linspace(0.0, turn, 41)
    poses = np.array([rotation_about_x(a) @ translation(z=r0) for a in angles])
    rho_c = np.hypot(w, r0 + w)
    rho_w = rho_c + 0.35
    theta_c = np.arctan2(r0 + w, w)          # the corner (y, z) = (w, r0 + w) at angle 0
    theta_c2 = np.arctan2(r0 + w, -w)        # the other outer corner
    # points radially outside a corner at one of the poses: exactly rho_w - rho_c - gap
    x = np.linspace(-0.9 * lx, 0.9 * lx, len(angles))
    under = np.column_stack([x, rho_w * np.cos(theta_c + angles), rho_w * np.sin(theta_c + angles)])
    stock, _ = stock_at_points(under, [(e.vertices, e.faces, poses)], GAP)
    np.testing.assert_allclose(stock, rho_w - rho_c - GAP, atol=EXACT)
    # anywhere between the outer corners' extreme angles: no less, and no more than to the nearest corner
    psi = np.linspace(theta_c, theta_c2 + turn, 300)
    between = np.column_stack([np.zeros_like(psi), rho_w * np.cos(psi), rho_w * np.sin(psi)])
    stock, _ = stock_at_points(between, [(e.vertices, e.faces, poses)], GAP)
    corners = np.concatenate([theta_c + angles, theta_c2 + angles])
    chord = np.sqrt(rho_w**2 + rho_c**2 - 2 * rho_w * rho_c * np.cos(psi[:, None] - corners[None]))
    assert (stock >= rho_w - rho_c - GAP - EXACT).all()
    assert (stock <= chord.min(axis=1) - GAP + EXACT).all()


def test_overcut_of_an_electrode_pushed_into_the_wall():
    push, wall = 0.07, 2.0
    e = box(3.0, 1.0, 1.0)
    points = np.column_stack([np.linspace(-2.5, 2.5, 30), np.full(30, wall), np.zeros(30)])
    pose = translation(y=wall - 1.0 + push)
    stock, _ = stock_at_points(points, [(e.vertices, e.faces, pose)], GAP)
    np.testing.assert_allclose(stock, -(push + GAP), atol=EXACT)
    assert max(0.0, -stock.min()) == pytest.approx(push + GAP)


def random_sweep(rng, mesh, k):
    """A smooth random rigid motion of k poses near the origin."""
    rot = np.cumsum(rng.normal(0, 0.04, (k, 3)), axis=0)
    pos = np.cumsum(rng.normal(0, 0.08, (k, 3)), axis=0)
    poses = np.repeat(np.eye(4)[None], k, axis=0)
    for i in range(k):
        poses[i, :3, :3] = trimesh.transformations.euler_matrix(*rot[i])[:3, :3]
        poses[i, :3, 3] = pos[i]
    return Sweep(np.asarray(mesh.vertices), np.asarray(mesh.faces), poses)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pruned_minimum_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    shapes = [box(1.5, 0.6, 0.4), trimesh.creation.icosphere(2, radius=0.8),
              trimesh.creation.cylinder(0.5, 2.0, sections=24)]
    sweeps = [random_sweep(rng, shapes[j], k) for j, k in enumerate((60, 1, 35))]
    gaps = [0.1, 0.05, 0.2]
    points = rng.uniform(-2.5, 2.5, (400, 3))
    stats = {}
    stock, which = stock_at_points(points, sweeps, gaps, stats=stats)
    brute = np.full(len(points), np.inf)
    for sw, g in zip(sweeps, gaps):
        for pose in sw.poses:
            q = moved(points, np.linalg.inv(pose))
            brute = np.minimum(brute, igl.signed_distance(q, sw.vertices, sw.faces.astype(np.int64))[0] - g)
    np.testing.assert_allclose(stock, brute, atol=EXACT)
    # the reported pose attains the minimum
    for j, sw in enumerate(sweeps):
        m = which[:, 0] == j
        if not m.any():
            continue
        q = np.einsum("nij,nj->ni", np.linalg.inv(sw.poses[which[m, 1]])[:, :3, :3], points[m]) \
            + np.linalg.inv(sw.poses[which[m, 1]])[:, :3, 3]
        sd = igl.signed_distance(q, sw.vertices, sw.faces.astype(np.int64))[0]
        np.testing.assert_allclose(sd - gaps[j], stock[m], atol=EXACT)
    assert stats["queries"] < stats["pairs"]


def test_each_part_of_the_points_bounds_its_travel_from_its_own_centre():
    # the pruning's bound, per pose-tree node and part: ||R_s^T - R_a^T|| |p - c_k| + |travel of c_k| must
    # cover every point's true travel between the node's middle pose (and its parent's) and each of its poses
    rng = np.random.default_rng(5)
    sweep = random_sweep(rng, box(1.0, 0.5, 0.3), 40)
    points = rng.uniform(-30.0, 30.0, (3000, 3))
    centres, part = _clusters(points)
    assert len(centres) == 64 and np.bincount(part).min() >= 3000 // 64
    inv_r, inv_t = _inverse(sweep.poses)
    tree = _PoseTree(inv_r, inv_t, centres, 0, len(sweep.poses) - 2)
    d = np.linalg.norm(points - centres[part], axis=1)
    assert d.max() < 0.5 * np.linalg.norm(points - points.mean(axis=0), axis=1).max()   # nearer than one centre
    for node in range(len(tree.lo)):
        for anchor, alpha, beta in ((tree.mid[node], tree.alpha, tree.beta),
                                    (tree.mid[max(tree.parent[node], 0)], tree.alpha_par, tree.beta_par)):
            q_a = points @ inv_r[anchor].T + inv_t[anchor]
            bound = alpha[node] * d + beta[node, part]
            for s in range(tree.lo[node], tree.hi[node] + 1):
                travel = np.linalg.norm(points @ inv_r[s].T + inv_t[s] - q_a, axis=1)
                assert np.all(travel <= bound + 1e-9)


# -- the default blisk --------------------------------------------------------------
@pytest.fixture(scope="module")
def blisk_setup():
    from edm_planner.geometry.loader import load_geometry

    g = load_geometry(str(CONFIG / "default_blisk.yaml"))
    samples = wall_samples(g.blisk)
    e = g.electrodes[0]
    report = simulate_removal(g.blisk, [Sweep.from_electrode(e, e.final_pose)], g.design.discharge_gap,
                              samples=samples)
    return g, samples, report


def test_wall_samples_lie_on_the_walls_and_cover_their_area(blisk_setup):
    g, samples, _ = blisk_setup
    b = g.blisk
    x0, x1 = b.full_span_axial_range
    for name, s in samples.items():
        assert s.valid.all() and s.spacing <= 0.2 + 1e-9
        x, r, th = cartesian_to_cylindrical(s.points)
        assert x.min() == pytest.approx(x0) and x.max() == pytest.approx(x1)
        th_s, th_p, inside = b.wall_angles(x, np.clip(r, b.hub.radius_at(x) + 1e-6, b.shroud.radius_at(x) - 1e-6))
        assert inside.all()
        if name in ("suction", "pressure"):
            np.testing.assert_allclose(th, th_s if name == "suction" else th_p, atol=1e-12)
            assert (r >= b.hub.radius_at(x)).all() and (r <= b.shroud.radius_at(x)).all()
        else:
            np.testing.assert_allclose(r, (b.hub if name == "hub" else b.shroud).radius_at(x), atol=1e-12)
            assert (th >= th_s - 1e-12).all() and (th <= th_p + 1e-12).all()
    # areas against the channel meshes restricted to the closed channel (triangle centres inside)
    meshes = b.channel_meshes(resolution=0.25)
    for name, mesh in meshes.items():
        x, r, th = cartesian_to_cylindrical(mesh.triangles_center)
        keep = (x > x0) & (x < x1)
        if name in ("hub", "shroud"):
            radius = b.hub.radius_at(x) + 1e-6 if name == "hub" else b.shroud.radius_at(x) - 1e-6
            th_s, th_p, _ = b.wall_angles(x, radius)
            keep &= (th > th_s) & (th < th_p)
        else:
            keep &= (r > b.hub.radius_at(x)) & (r < b.shroud.radius_at(x))
        assert samples[name].area == pytest.approx(mesh.area_faces[keep].sum(), rel=0.01), name


def test_primitive_electrode_leaves_only_the_corners_and_ends(blisk_setup):
    """The channel less the gap, at its final pose: zero stock but at the corners and the axial ends."""
    g, samples, report = blisk_setup
    b, chord = g.blisk, g.design.chord_tolerance
    gap = g.design.discharge_gap
    x0, x1 = b.full_span_axial_range
    # the electrode's flat triangles lie within the chord tolerance of the exact offset faces
    assert report.overcut_max <= chord
    assert report.continuous_bound == 0.0 and report.pose_count == 1
    for name in ("suction", "pressure"):
        s = report.surfaces[name]
        x, r, stock = s.u, s.v, s.stock
        away = (x > x0 + 1) & (x < x1 - 1)
        inner = away & (r > b.hub.radius_at(x) + 2 * gap) & (r < b.shroud.radius_at(x) - 2 * gap)
        assert np.abs(stock[inner]).max() <= chord
        # the wall sample at a corner is g / sin(phi / 2) - g from the electrode's corner edge
        # (phi the channel's corner angle; a right angle leaves g (sqrt(2) - 1))
        for row, profile, side in ((0, b.hub, 1.0), (-1, b.shroud, -1.0)):
            xs, rs = x[row][away[row]], r[row][away[row]]
            _, _, _, grads = b.wall_angles(xs, rs, with_gradient=True)
            grad = grads[0] if name == "suction" else grads[1]
            wall = np.column_stack([-rs * grad[:, 0], -rs * grad[:, 1], np.ones_like(rs)])
            wall *= (1.0 if name == "suction" else -1.0) / np.linalg.norm(wall, axis=1, keepdims=True)
            slope = profile.slope_at(xs)
            ring = side * np.column_stack([-slope, np.ones_like(slope), np.zeros_like(slope)])
            ring /= np.linalg.norm(ring, axis=1, keepdims=True)
            phi = np.pi - np.arccos(np.einsum("ij,ij->i", wall, ring))
            np.testing.assert_allclose(stock[row][away[row]], gap * (1 / np.sin(phi / 2) - 1), atol=chord)
        # the electrode stops 0.5 % inside the closed channel: stock at both ends
        assert (stock[:, 0] > 0).all() and (stock[:, -1] > 0).all()
    for name in ("hub", "shroud"):
        s = report.surfaces[name]
        # 0.4 mm and more from the blade walls (the rows are graded towards the walls)
        inner = (s.u > x0 + 1) & (s.u < x1 - 1) & (np.abs(s.v - s.v[:1]) > 0.4) & (np.abs(s.v - s.v[-1:]) > 0.4)
        assert np.abs(s.stock[inner]).max() <= chord
    for s in report.surfaces.values():
        assert s.stock_mean < chord and s.area_fraction_above_tolerance < 0.05
        assert s.stock_max > report.tolerance      # a gap-offset electrode cannot finish a sharp corner
    assert not report.every_sample_within_tolerance, \
        "the strict flag (every sample within the tolerance of sharp corners) fails on the corner rounding alone"
    data = json.loads(json.dumps(report.to_dict()))
    assert data["accuracy"]["sample_spacing_mm"] <= 0.2 and data["surfaces"]["hub"]["overcut_max_mm"] <= chord


def test_continuous_bound_is_half_the_largest_step(blisk_setup):
    g, samples, _ = blisk_setup
    e = g.electrodes[0]
    poses = np.array([translation(x=0.01) @ e.final_pose, e.final_pose])
    report = simulate_removal(g.blisk, [Sweep.from_electrode(e, poses)], g.design.discharge_gap, samples=samples)
    assert report.continuous_bound == pytest.approx(0.005, rel=1e-6)
    assert report.pose_count == 2


def test_the_proof_shared_out_among_processes_is_the_proof_of_one(blisk_setup):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    g, samples, _ = blisk_setup
    e = g.electrodes[0]
    poses = np.array([translation(x=0.3 * k, y=0.02 * k) @ e.final_pose for k in range(6, -1, -1)])
    sweeps = [Sweep.from_electrode(e, poses)]
    one = simulate_removal(g.blisk, sweeps, g.design.discharge_gap, samples=samples)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        shared = simulate_removal(g.blisk, sweeps, g.design.discharge_gap, samples=samples, executor=pool, parts=2)
    for name, s in one.surfaces.items():
        np.testing.assert_array_equal(shared.surfaces[name].stock, s.stock)
        assert shared.surfaces[name].area_fraction_above_tolerance == s.area_fraction_above_tolerance
    assert shared.queries > 0


def test_stock_maps_and_vertex_colours(blisk_setup, tmp_path):
    g, _, report = blisk_setup
    path = plot_stock_maps(report, tmp_path / "stock.png")
    assert Path(path).stat().st_size > 50_000
    from matplotlib.image import imread

    assert imread(path).shape[:2] == (1100, 1430)
    mesh = g.blisk.channel_meshes()["hub"]
    colours = stock_vertex_colours(mesh, report, "hub")
    assert colours.shape == (len(mesh.vertices), 4) and colours.dtype == np.uint8
    x = mesh.vertices[:, 0]
    x0, x1 = g.blisk.full_span_axial_range
    outside = (x < x0 - 1) | (x > x1 + 1)
    assert (colours[outside, :3] == colours[outside][0, :3]).all()   # unsampled: one grey
    # channel k: the samples turned with the mesh give the same colours
    turned = stock_vertex_colours(g.blisk.channel_meshes(2)["hub"], report, "hub",
                                  transform=g.blisk.channel_transform(2))
    assert np.array_equal(turned, colours)
