"""Tests of edm_planner.geometry.blade_mesh (closed blade meshes, loading, exact slicing)."""

import logging
import time

import numpy as np
import pytest
import trimesh

from edm_planner.errors import ErrorCode, GeometryError, GeometryFileError
from edm_planner.geometry.blade_mesh import (
    FACE_LABELS,
    BladeFace,
    closed_blade_mesh,
    face_grid_mesh,
    load_blade_mesh,
    mesh_to_sections,
)
from edm_planner.geometry.frames import cylindrical_to_cartesian, rotation_about_x
from edm_planner.geometry.sections import BladeSections

# --------------------------------------------------------------------------
# an analytic blade: chord parameter c in [0, 1] (LE -> TE), span s in [0, 1]
# (hub -> tip), mounted at r 100..120 mm, x 0..25 mm; cambered and twisted,
# optionally swept and on a conical hub.
# --------------------------------------------------------------------------

R_HUB, SPAN, CHORD = 100.0, 20.0, 25.0
SWEEP, CONE = 4.0, 2.0  # axial shift of the tip, radial rise of the TE [mm]


def _xr(c, s, swept):
    if swept:
        return CHORD * c + SWEEP * s, R_HUB + SPAN * s + CONE * c
    return CHORD * c, R_HUB + SPAN * s


def _cs(x, r, swept):
    """Inverse of _xr."""
    if swept:
        m = np.array([[CHORD, SWEEP], [CONE, SPAN]])
        cs = np.linalg.solve(m, np.stack([x, r - R_HUB], -1)[..., None])[..., 0]
        return cs[..., 0], cs[..., 1]
    return x / CHORD, (r - R_HUB) / SPAN


def _thetas(x, r, swept=False, edge=0.0, theta0=0.6):
    """theta_minus, theta_plus [rad] at (x, r); thickness ``edge + 8 c (1 - c)`` mm."""
    c, s = _cs(x, r, swept)
    mean = theta0 + (0.3 + 0.15 * s) * (c - 0.5) + 0.2 * (c - 0.5) ** 2
    t = edge + 8.0 * c * (1 - c)
    return mean - t / (2 * r), mean + t / (2 * r)


def _blade(S, C, swept=False, edge=0.0, theta0=0.6):
    """minus, plus faces (S, C, 3) on a uniform (c, s) grid."""
    s, c = np.meshgrid(np.linspace(0, 1, S), np.linspace(0, 1, C), indexing="ij")
    x, r = _xr(c, s, swept)
    tm, tp = _thetas(x, r, swept, edge, theta0)
    return cylindrical_to_cartesian(x, r, tm), cylindrical_to_cartesian(x, r, tp)


def _volume(edge):
    # thickness (tangential) integrated over the meridional footprint; the
    # (c, s) -> (x, r) map has Jacobian CHORD * SPAN (minus the sweep term)
    return (edge + 8.0 / 6.0) * CHORD * SPAN


def _faceting_bound(S, C, swept, edge, theta0=0.6):
    """Bound on the tangential error r*dtheta of the faceted faces [mm].

    Linear interpolation of g = r*theta(x, r) on a triangle with edge vectors
    up to h long is off by at most 0.5 * max|D^2 g| * h^2; the straight
    Cartesian chords add at most r * dtheta^2 / 8 per cell.
    """
    x, r = _xr(*np.meshgrid(np.linspace(0, 1, 41), np.linspace(0, 1, 41)), swept)
    x, r = x.ravel(), r.ravel()
    e = 1e-3
    hess = []
    for face in (0, 1):
        def g(xx, rr):
            return rr * _thetas(xx, rr, swept, edge, theta0)[face]
        gxx = (g(x + e, r) - 2 * g(x, r) + g(x - e, r)) / e ** 2
        grr = (g(x, r + e) - 2 * g(x, r) + g(x, r - e)) / e ** 2
        gxr = (g(x + e, r + e) - g(x + e, r - e) - g(x - e, r + e) + g(x - e, r - e)) / (4 * e ** 2)
        hess.append(np.abs(0.5 * (gxx + grr)) + np.hypot(0.5 * (gxx - grr), gxr))  # spectral norm
    d_c = np.subtract(_xr(1.0 / (C - 1), 0.0, swept), _xr(0.0, 0.0, swept))
    d_s = np.subtract(_xr(0.0, 1.0 / (S - 1), swept), _xr(0.0, 0.0, swept))
    h2 = max(np.sum((d_c + d_s) ** 2), np.sum(d_c ** 2), np.sum(d_s ** 2))
    dtheta = 0.45 / (C - 1) + 0.15 / (S - 1)  # largest change of theta across a cell
    return 0.5 * float(np.max(hess)) * h2 + (R_HUB + SPAN) * dtheta ** 2 / 8


@pytest.fixture(scope="module")
def fine_blade():
    return closed_blade_mesh(*_blade(61, 161))


# --------------------------------------------------------------------------
# closed_blade_mesh
# --------------------------------------------------------------------------

def _e_theta(points):
    theta = np.arctan2(points[:, 2], points[:, 1])
    return np.column_stack([np.zeros_like(theta), -np.sin(theta), np.cos(theta)])


@pytest.mark.parametrize("swept", [False, True])
def test_closed_mesh_zero_edge_thickness(swept):
    S, C = 9, 21
    mesh = closed_blade_mesh(*_blade(S, C, swept))
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert mesh.volume == pytest.approx(_volume(0.0), rel=0.02)
    labels = mesh.face_attributes[FACE_LABELS]
    assert len(labels) == len(mesh.faces)
    counts = np.bincount(labels, minlength=len(BladeFace))
    # faces touch at both edges: the edge closures vanish, each cap loses one
    # triangle at either end, and the 2 S edge vertex pairs are merged
    assert counts[BladeFace.MINUS] == counts[BladeFace.PLUS] == 2 * (S - 1) * (C - 1)
    assert counts[BladeFace.HUB] == counts[BladeFace.TIP] == 2 * (C - 1) - 2
    assert counts[BladeFace.EDGE] == 0
    assert len(mesh.vertices) == 2 * S * C - 2 * S
    # outward: the minus face looks towards -theta, the plus face towards +theta
    normals, centres = mesh.face_normals, mesh.triangles_center
    for face, sign in ((BladeFace.MINUS, -1), (BladeFace.PLUS, 1)):
        sel = labels == face
        assert np.all(sign * np.einsum("ij,ij->i", normals[sel], _e_theta(centres[sel])) > 0)


def test_closed_mesh_cap_normals_point_out_radially():
    mesh = closed_blade_mesh(*_blade(9, 21))
    labels = mesh.face_attributes[FACE_LABELS]
    centres, normals = mesh.triangles_center, mesh.face_normals
    e_r = centres[:, 1:] / np.linalg.norm(centres[:, 1:], axis=1)[:, None]
    n_r = np.einsum("ij,ij->i", normals[:, 1:], e_r)
    assert np.all(n_r[labels == BladeFace.HUB] < -0.9)
    assert np.all(n_r[labels == BladeFace.TIP] > 0.9)


def test_closed_mesh_non_zero_edge_thickness():
    S, C = 7, 15
    mesh = closed_blade_mesh(*_blade(S, C, edge=0.4))
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.volume == pytest.approx(_volume(0.4), rel=0.02)
    counts = np.bincount(mesh.face_attributes[FACE_LABELS], minlength=len(BladeFace))
    assert counts[BladeFace.HUB] == counts[BladeFace.TIP] == 2 * (C - 1)
    assert counts[BladeFace.EDGE] == 2 * 2 * (S - 1)
    assert len(mesh.vertices) == 2 * S * C


def test_closed_mesh_thickness_zero_at_one_edge_and_some_sections():
    S, C = 6, 12
    minus, plus = _blade(S, C, edge=0.3)
    plus[:, 0] = minus[:, 0]  # sharp leading edge
    plus[::2, -1] = minus[::2, -1]  # trailing edge sharp only at sections 0, 2, 4
    mesh = closed_blade_mesh(minus, plus)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    counts = np.bincount(mesh.face_attributes[FACE_LABELS], minlength=len(BladeFace))
    assert counts[BladeFace.EDGE] == S - 1  # one triangle per trailing-edge quad


@pytest.mark.parametrize("reverse", ["sections", "stations", "both"])
def test_closed_mesh_is_outward_for_any_grid_order(reverse):
    minus, plus = _blade(6, 12, edge=0.2)
    axes = {"sections": (0,), "stations": (1,), "both": (0, 1)}[reverse]
    mesh = closed_blade_mesh(np.flip(minus, axes), np.flip(plus, axes))
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(_volume(0.2), rel=0.05)


def test_closed_mesh_rejects_bad_input():
    minus, plus = _blade(5, 8)
    with pytest.raises(GeometryError, match="same|differ"):
        closed_blade_mesh(minus, plus[:, :-1])
    with pytest.raises(GeometryError, match=r"\(S, C, 3\)"):
        closed_blade_mesh(minus[..., :2], plus[..., :2])
    bad = minus.copy()
    bad[2, 3, 1] = np.nan
    with pytest.raises(GeometryError, match="NaN"):
        closed_blade_mesh(bad, plus)
    with pytest.raises(GeometryError, match="no volume|watertight"):
        closed_blade_mesh(minus, minus)


# --------------------------------------------------------------------------
# face_grid_mesh
# --------------------------------------------------------------------------

def test_face_grid_mesh_layout_and_flip():
    S, C = 4, 6
    s, c = np.meshgrid(np.arange(S, dtype=float), np.arange(C, dtype=float), indexing="ij")
    points = np.stack([c, s, np.zeros_like(s)], -1)  # dP/ds = +y, dP/dc = +x
    mesh = face_grid_mesh(points)
    assert len(mesh.faces) == 2 * (S - 1) * (C - 1)
    assert len(mesh.vertices) == S * C
    np.testing.assert_array_equal(mesh.vertices, points.reshape(-1, 3))
    np.testing.assert_allclose(mesh.face_normals, np.tile([0, 0, -1.0], (len(mesh.faces), 1)))  # y x x = -z
    assert mesh.area == pytest.approx((S - 1) * (C - 1))
    flipped = face_grid_mesh(points, flip=True)
    np.testing.assert_allclose(flipped.face_normals, -mesh.face_normals)
    assert mesh.is_winding_consistent and not mesh.is_watertight
    # cell (s, c) gives faces 2 (s (C-1) + c) and +1
    s0, c0 = 2, 3
    k = 2 * (s0 * (C - 1) + c0)
    np.testing.assert_allclose(mesh.triangles[k:k + 2].reshape(-1, 3).mean(0), [c0 + 0.5, s0 + 0.5, 0], atol=0.2)


def test_face_grid_mesh_of_a_blade_face_matches_the_closed_mesh_side():
    minus, plus = _blade(6, 10)
    open_plus = face_grid_mesh(plus)
    closed = closed_blade_mesh(minus, plus)
    labels = closed.face_attributes[FACE_LABELS]
    n_open = np.mean(open_plus.face_normals, axis=0)
    n_closed = np.mean(closed.face_normals[labels == BladeFace.PLUS], axis=0)
    flip = np.dot(n_open, n_closed) < 0
    assert np.dot(face_grid_mesh(plus, flip=flip).face_normals.mean(0), n_closed) > 0


def test_face_grid_mesh_rejects_bad_grids():
    with pytest.raises(GeometryError):
        face_grid_mesh(np.zeros((1, 5, 3)))
    with pytest.raises(GeometryError):
        face_grid_mesh(np.zeros((3, 5)))


# --------------------------------------------------------------------------
# load_blade_mesh
# --------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".stl", ".obj", ".ply"])
def test_load_round_trip(tmp_path, suffix):
    mesh = closed_blade_mesh(*_blade(11, 31, edge=0.2))
    path = tmp_path / f"blade{suffix}"
    mesh.export(path)
    loaded = load_blade_mesh(path)
    assert loaded.is_watertight and loaded.is_winding_consistent
    assert len(loaded.faces) == len(mesh.faces)
    assert loaded.volume == pytest.approx(mesh.volume, rel=1e-5)


def test_load_fixes_inverted_normals(tmp_path, caplog):
    mesh = closed_blade_mesh(*_blade(11, 31))
    mesh.invert()
    path = tmp_path / "inverted.stl"
    mesh.export(path)
    with caplog.at_level(logging.WARNING, logger="edm_planner.geometry.blade_mesh"):
        loaded = load_blade_mesh(path)
    assert loaded.volume == pytest.approx(-mesh.volume, rel=1e-5)
    assert "inverted" in caplog.text


def test_load_open_mesh_names_open_edges(tmp_path):
    box = trimesh.creation.box(extents=(10, 20, 30))
    # remove one side of the box: the two triangles with normal +x
    keep = ~np.isclose(box.face_normals[:, 0], 1.0)
    box.update_faces(keep)
    path = tmp_path / "open_box.stl"
    box.export(path)
    with pytest.raises(GeometryError, match=r"not watertight \(4 open edges\)") as err:
        load_blade_mesh(path)
    assert "open_box.stl" in str(err.value)
    assert err.value.code == ErrorCode.INVALID_GEOMETRY


def test_load_missing_file(tmp_path):
    with pytest.raises(GeometryFileError, match="not found") as err:
        load_blade_mesh(tmp_path / "nope.stl")
    assert "nope.stl" in str(err.value)
    assert err.value.code == ErrorCode.FILE_ERROR


@pytest.mark.parametrize("name, content", [
    ("garbage.stl", b"this is not a mesh\n"),
    ("garbage.ply", b"junk junk junk"),
    ("garbage.obj", b"hello world\n"),
    ("blade.txt", b"v 0 0 0\n"),
])
def test_load_not_a_mesh(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(GeometryFileError) as err:
        load_blade_mesh(path)
    assert name in str(err.value)


def test_load_directory_is_a_file_error(tmp_path):
    with pytest.raises(GeometryFileError):
        load_blade_mesh(tmp_path)


def test_load_empty_stl_is_a_geometry_error(tmp_path):
    path = tmp_path / "empty.stl"
    path.write_bytes(b"\0" * 80 + np.uint32(0).tobytes())
    with pytest.raises(GeometryError, match="empty") as err:
        load_blade_mesh(path)
    assert not isinstance(err.value, GeometryFileError)


def test_load_mesh_in_metres(tmp_path):
    mesh = closed_blade_mesh(*_blade(7, 15))
    mesh.apply_scale(0.001)
    path = tmp_path / "metres.stl"
    mesh.export(path)
    with pytest.raises(GeometryError, match="metres"):
        load_blade_mesh(path)


def test_load_mesh_in_micrometres(tmp_path):
    mesh = closed_blade_mesh(*_blade(7, 15))
    mesh.apply_scale(1000.0)
    path = tmp_path / "um.stl"
    mesh.export(path)
    with pytest.raises(GeometryError, match="too large"):
        load_blade_mesh(path)


def test_load_nan_vertices(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv nan 0 0\nv 0 10 0\nv 0 0 10\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    with pytest.raises(GeometryError, match="NaN") as err:
        load_blade_mesh(path)
    assert "nan.obj" in str(err.value)


def test_load_inconsistent_winding(tmp_path):
    box = trimesh.creation.box(extents=(10, 20, 30))
    faces = box.faces.copy()
    faces[0] = faces[0, ::-1]
    path = tmp_path / "flipped_face.obj"
    trimesh.Trimesh(box.vertices, faces, process=False).export(path)
    with pytest.raises(GeometryError, match="winding"):
        load_blade_mesh(path)


def _two_blades(angle=0.4):
    one = closed_blade_mesh(*_blade(11, 31))
    other = one.copy()
    other.apply_transform(rotation_about_x(angle))
    return trimesh.util.concatenate([one, other])


def test_load_two_blades(tmp_path):
    path = tmp_path / "two.stl"
    _two_blades().export(path)
    with pytest.raises(GeometryError, match="2 separate bodies"):
        load_blade_mesh(path)


# --------------------------------------------------------------------------
# mesh_to_sections
# --------------------------------------------------------------------------

def _check_against_analytic(sections, swept, edge, theta0=0.6):
    tm, tp = _thetas(sections.x, sections.r, swept, edge, theta0)
    err = np.maximum(np.abs(sections.r * (sections.theta_minus - tm)),
                     np.abs(sections.r * (sections.theta_plus - tp)))
    return float(err.max())


def test_mesh_to_sections_reproduces_the_analytic_blade(fine_blade):
    sections = mesh_to_sections(fine_blade, n_sections=25, n_stations=81)
    assert isinstance(sections, BladeSections)
    assert sections.shape == (25, 81)
    c, s = _cs(sections.x, sections.r, False)
    # the station grid fills the footprint: just inside the hub, tip and edges
    assert 0 < s.min() < 0.01 and 0.99 < s.max() < 1
    assert 0 < c.min() < 1e-3 and 1 - 1e-3 < c.max() < 1
    assert np.all(np.diff(sections.x, axis=1) > 0)  # leading -> trailing edge
    assert np.all(np.diff(sections.r, axis=0) > 0)  # hub -> tip
    bound = _faceting_bound(61, 161, False, 0.0)
    assert bound < 0.01
    assert _check_against_analytic(sections, False, 0.0) < bound
    # zero thickness at the edges: the first/last station is very thin
    thickness = sections.r * (sections.theta_plus - sections.theta_minus)
    assert np.all(thickness[:, [0, -1]] < 0.01)
    assert np.all(thickness[:, 1:-1] > 0)


@pytest.mark.parametrize("edge", [0.0, 0.3])
def test_mesh_to_sections_swept_blade_on_a_cone(edge):
    S, C = 61, 161
    mesh = closed_blade_mesh(*_blade(S, C, swept=True, edge=edge))
    sections = mesh_to_sections(mesh, n_sections=15, n_stations=41)
    c, s = _cs(sections.x, sections.r, True)
    assert 0 < s.min() < 0.01 and 0.99 < s.max() < 1
    assert 0 < c.min() < 1e-3 and 1 - 1e-3 < c.max() < 1
    # sections follow the hub and tip: constant span fraction along each section
    np.testing.assert_allclose(s - s[:, :1], 0, atol=2e-3)
    bound = _faceting_bound(S, C, True, edge)
    assert bound < 0.01
    assert _check_against_analytic(sections, True, edge) < bound
    thickness = sections.r * (sections.theta_plus - sections.theta_minus)
    assert np.all(thickness[:, [0, -1]] > edge - 0.01)


def test_mesh_to_sections_across_the_angle_wrap():
    theta0 = np.pi - 0.05  # the blade straddles theta = +-pi
    mesh = closed_blade_mesh(*_blade(31, 81, theta0=theta0))
    sections = mesh_to_sections(mesh, n_sections=9, n_stations=21)
    assert np.all(sections.theta_plus >= sections.theta_minus)
    assert np.ptp(sections.theta_plus) < 0.5
    assert _check_against_analytic(sections, False, 0.0, theta0) < _faceting_bound(31, 81, False, 0.0, theta0)


def test_mesh_to_sections_is_fast():
    mesh = closed_blade_mesh(*_blade(51, 101))  # ~20k faces
    assert 19000 < len(mesh.faces) < 21000
    mesh_to_sections(mesh, n_sections=5, n_stations=9)  # warm-up
    start = time.process_time()         # CPU time: the same on a shared, loaded machine
    mesh_to_sections(mesh, n_sections=25, n_stations=81)
    assert time.process_time() - start < 2.0


def test_mesh_to_sections_of_a_loaded_stl(tmp_path, fine_blade):
    path = tmp_path / "blade.stl"
    fine_blade.export(path)
    sections = mesh_to_sections(load_blade_mesh(path), n_sections=9, n_stations=31)
    # float32 STL adds ~1e-5 mm to the faceting error
    assert _check_against_analytic(sections, False, 0.0) < _faceting_bound(61, 161, False, 0.0) + 1e-4


def test_mesh_to_sections_rejects_two_blades():
    with pytest.raises(GeometryError, match="separate intervals"):
        mesh_to_sections(_two_blades(0.4), n_sections=5, n_stations=9)


def test_mesh_to_sections_rejects_a_whole_ring():
    with pytest.raises(GeometryError, match="90 deg"):
        mesh_to_sections(_two_blades(np.pi), n_sections=5, n_stations=9)


def test_mesh_to_sections_rejects_open_meshes():
    mesh = closed_blade_mesh(*_blade(7, 15))
    mesh.update_faces(np.arange(1, len(mesh.faces)))
    with pytest.raises(GeometryError, match="open edges"):
        mesh_to_sections(mesh)


def test_mesh_to_sections_is_rotation_equivariant(fine_blade):
    base = mesh_to_sections(fine_blade, n_sections=5, n_stations=11)
    turned = fine_blade.copy()
    turned.apply_transform(rotation_about_x(-1.3))
    other = mesh_to_sections(turned, n_sections=5, n_stations=11)
    np.testing.assert_allclose(other.x, base.x, atol=1e-9)
    np.testing.assert_allclose(other.r, base.r, atol=1e-9)
    np.testing.assert_allclose(other.theta_minus, base.theta_minus - 1.3, atol=1e-9)
    np.testing.assert_allclose(other.theta_plus, base.theta_plus - 1.3, atol=1e-9)
