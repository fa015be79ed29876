"""Tests of the blade mesh modules of edm_planner.geometry (closed blade meshes, loading, exact slicing)."""

import logging
import re
import time

import numpy as np
import pytest
import trimesh

from edm_planner.errors import ErrorCode, GeometryError, GeometryFileError
from edm_planner.geometry import blade_mesh
from edm_planner.geometry.mesh_build import FACE_LABELS, MeshFaceLabel, closed_blade_mesh, face_grid_mesh
from edm_planner.geometry.mesh_read import load_blade_mesh
from edm_planner.geometry.mesh_sections import mesh_to_sections, mesh_to_sections_with_report
from edm_planner.geometry.blisk import Blisk, mesh_slice_overlap
from edm_planner.geometry.frames import cylindrical_to_cartesian, rotation_about_x
from edm_planner.geometry.loader import load_geometry
from edm_planner.geometry.profiles import RevolutionProfile
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
    counts = np.bincount(labels, minlength=len(MeshFaceLabel))
    # faces touch at both edges: the edge closures vanish, each cap loses one
    # triangle at either end, and the 2 S edge vertex pairs are merged
    assert counts[MeshFaceLabel.MINUS] == counts[MeshFaceLabel.PLUS] == 2 * (S - 1) * (C - 1)
    assert counts[MeshFaceLabel.HUB] == counts[MeshFaceLabel.TIP] == 2 * (C - 1) - 2
    assert counts[MeshFaceLabel.EDGE] == 0
    assert len(mesh.vertices) == 2 * S * C - 2 * S
    # outward: the minus face looks towards -theta, the plus face towards +theta
    normals, centres = mesh.face_normals, mesh.triangles_center
    for face, sign in ((MeshFaceLabel.MINUS, -1), (MeshFaceLabel.PLUS, 1)):
        sel = labels == face
        assert np.all(sign * np.einsum("ij,ij->i", normals[sel], _e_theta(centres[sel])) > 0)


def test_closed_mesh_cap_normals_point_out_radially():
    mesh = closed_blade_mesh(*_blade(9, 21))
    labels = mesh.face_attributes[FACE_LABELS]
    centres, normals = mesh.triangles_center, mesh.face_normals
    e_r = centres[:, 1:] / np.linalg.norm(centres[:, 1:], axis=1)[:, None]
    n_r = np.einsum("ij,ij->i", normals[:, 1:], e_r)
    assert np.all(n_r[labels == MeshFaceLabel.HUB] < -0.9)
    assert np.all(n_r[labels == MeshFaceLabel.TIP] > 0.9)


def test_closed_mesh_non_zero_edge_thickness():
    S, C = 7, 15
    mesh = closed_blade_mesh(*_blade(S, C, edge=0.4))
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.volume == pytest.approx(_volume(0.4), rel=0.02)
    counts = np.bincount(mesh.face_attributes[FACE_LABELS], minlength=len(MeshFaceLabel))
    assert counts[MeshFaceLabel.HUB] == counts[MeshFaceLabel.TIP] == 2 * (C - 1)
    assert counts[MeshFaceLabel.EDGE] == 2 * 2 * (S - 1)
    assert len(mesh.vertices) == 2 * S * C


def test_closed_mesh_thickness_zero_at_one_edge_and_some_sections():
    S, C = 6, 12
    minus, plus = _blade(S, C, edge=0.3)
    plus[:, 0] = minus[:, 0]  # sharp leading edge
    plus[::2, -1] = minus[::2, -1]  # trailing edge sharp only at sections 0, 2, 4
    mesh = closed_blade_mesh(minus, plus)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    counts = np.bincount(mesh.face_attributes[FACE_LABELS], minlength=len(MeshFaceLabel))
    assert counts[MeshFaceLabel.EDGE] == S - 1  # one triangle per trailing-edge quad


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
    n_closed = np.mean(closed.face_normals[labels == MeshFaceLabel.PLUS], axis=0)
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
    with caplog.at_level(logging.WARNING, logger="edm_planner.geometry.mesh_validate"):
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



# --------------------------------------------------------------------------
# CAD blades as they come: run past the hub and the shroud, closed by caps of
# any shape. The swept blade on its cone stands between a conical hub
# r = 100 + 0.08 x (its s = 0 line) and a conical shroud 19.68 mm above (its
# s = 1 line); a mesh is sliced up to 3 % of that height past them, 0.5904 mm.
# --------------------------------------------------------------------------

SLOPE = CONE / CHORD                        # dr/dx of the hub and the shroud
HEIGHT = SPAN - SLOPE * SWEEP               # radial distance from hub to shroud [mm]
FINE = (61, 161)                            # span sections x chord stations of the test meshes


def _walls():
    """Hub and shroud of the swept blade: cones through its s = 0 and s = 1 lines."""
    x = [-10.0, 45.0]
    hub = RevolutionProfile([[xx, R_HUB + SLOPE * xx] for xx in x], "hub_profile")
    shroud = RevolutionProfile([[xx, R_HUB + HEIGHT + SLOPE * xx] for xx in x], "shroud_profile")
    return hub, shroud


def _past_walls(extension):
    """Span parameters of a blade reaching ``extension`` mm (radially) beyond hub and shroud."""
    return -extension / HEIGHT, 1 + extension / HEIGHT


def _swept_faces(s, c, taper=None):
    """minus, plus faces of the swept blade (edge thickness 0) at span and chord parameters s, c (S, C).

    ``taper`` (S, 1) scales the thickness (rounded ends).
    """
    x, r = _xr(c, s, True)
    tm, tp = _thetas(x, r, True)
    if taper is not None:
        mean, half = 0.5 * (tm + tp), 0.5 * (tp - tm) * taper
        tm, tp = mean - half, mean + half
    return cylindrical_to_cartesian(x, r, tm), cylindrical_to_cartesian(x, r, tp)


def _swept_grid(s_lo, s_hi):
    """(s, c) parameter grid over [s_lo, s_hi] x [0, 1]: FINE's spacing, 1/60 in s and 1/160 in c."""
    S = 1 + int(round((FINE[0] - 1) * (s_hi - s_lo)))
    return np.meshgrid(np.linspace(s_lo, s_hi, S), np.linspace(0, 1, FINE[1]), indexing="ij")


def _grid_faceting_bound(s, c):
    """:func:`_faceting_bound` of the swept blade for any (S, C) grid of parameters [mm].

    0.5 max|D^2 g| h^2 (g = r theta, h the longest cell edge or diagonal in
    (x, r)) plus r dtheta^2 / 8 (dtheta the largest change of theta across a
    cell edge or diagonal), for either face.
    """
    x, r = _xr(c, s, True)
    e = 1e-3
    xs, rs = x.ravel(), r.ravel()
    hess, dtheta = [], 0.0
    for face in (0, 1):
        def g(xx, rr):
            return rr * _thetas(xx, rr, True)[face]
        gxx = (g(xs + e, rs) - 2 * g(xs, rs) + g(xs - e, rs)) / e ** 2
        grr = (g(xs, rs + e) - 2 * g(xs, rs) + g(xs, rs - e)) / e ** 2
        gxr = (g(xs + e, rs + e) - g(xs + e, rs - e) - g(xs - e, rs + e) + g(xs - e, rs - e)) / (4 * e ** 2)
        hess.append(np.abs(0.5 * (gxx + grr)) + np.hypot(0.5 * (gxx - grr), gxr))
        th = _thetas(x, r, True)[face]
        for d in (th[1:, :-1] - th[:-1, :-1], th[:-1, 1:] - th[:-1, :-1], th[1:, 1:] - th[:-1, :-1]):
            dtheta = max(dtheta, float(np.abs(d).max()))
    h2 = 0.0
    for dx, dr in ((x[1:, :-1] - x[:-1, :-1], r[1:, :-1] - r[:-1, :-1]),
                   (x[:-1, 1:] - x[:-1, :-1], r[:-1, 1:] - r[:-1, :-1]),
                   (x[1:, 1:] - x[:-1, :-1], r[1:, 1:] - r[:-1, :-1])):
        h2 = max(h2, float((dx ** 2 + dr ** 2).max()))
    return 0.5 * float(np.max(hess)) * h2 + float(r.max()) * dtheta ** 2 / 8


def _solid(triangles):
    """Closed, outward-wound mesh of a triangle soup (vertices merged by position, coincident triangles dropped)."""
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    mesh = trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=np.arange(3 * len(tri)).reshape(-1, 3), process=False)
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    # a triangle both faces share (where they meet at an edge and an end) encloses nothing: drop both
    _, inverse, counts = np.unique(np.sort(mesh.faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    mesh.update_faces(counts[inverse.ravel()] == 1)
    mesh.remove_unreferenced_vertices()
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)          # slow (a Python loop over the faces): soups built wound
    if mesh.volume < 0:
        mesh.invert()
    assert mesh.is_watertight and mesh.is_winding_consistent
    return mesh


def _sides(minus, plus):
    """Triangles of the closed blade's faces and edge closures, without its end caps."""
    mesh = closed_blade_mesh(minus, plus)
    labels = mesh.face_attributes[FACE_LABELS]
    return mesh.triangles[(labels != MeshFaceLabel.HUB) & (labels != MeshFaceLabel.TIP)]


def _fan_capped(minus, plus, window):
    """Closed blade whose flat end caps are fans across ``window`` chord stations.

    Each window of the end section (minus row a..e, plus row a..e) is split
    along the chord minus[a] - plus[e] and fanned from its two ends: the
    triangles span up to ``window`` stations and dip below the end section
    between its points.
    """
    tris = [_sides(minus, plus)]
    C = minus.shape[1]
    for s in (0, -1):
        m, p = minus[s], plus[s]
        for a in range(0, C - 1, window):
            e = min(a + window, C - 1)
            j = np.arange(a, e)
            # wound as the sides closed_blade_mesh makes of these faces (else _solid repairs it, slowly)
            fan = np.concatenate([np.stack([np.broadcast_to(m[a], (len(j), 3)), p[j + 1], p[j]], 1),
                                  np.stack([np.broadcast_to(p[e], (len(j), 3)), m[j], m[j + 1]], 1)])
            tris.append(fan[:, ::-1] if s else fan)
    return _solid(np.concatenate(tris))


def _interior_xr(n=30):
    """Points of the channel between hub and shroud, inside the blade's chord."""
    c, s = np.meshgrid(np.linspace(0.02, 0.98, n), np.linspace(0.01, 0.99, n))
    return _xr(c.ravel(), s.ravel(), True)


def _wall_error(blisk, x, r):
    """Largest tangential distance [mm] of the blisk's channel walls from the analytic blade faces at (x, r)."""
    th_s, th_p, inside = blisk.wall_angles(x, r)
    assert inside.all()
    tm, tp = _thetas(x, r, True)
    return float(max(np.abs(r * (th_s - tp)).max(), np.abs(r * (th_p - blisk.pitch - tm)).max()))


@pytest.fixture(scope="module")
def exact_blisk():
    """The blisk of the analytic swept blade (25 x 81 exact sections from hub to shroud)."""
    hub, shroud = _walls()
    s, c = np.meshgrid(np.linspace(0, 1, 25), 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, 81)), indexing="ij")
    x, r = _xr(c, s, True)
    blisk = Blisk(60, hub, shroud, BladeSections(x, r, *_thetas(x, r, True)))
    # the splines' own interpolation error, two orders below the faceting bounds used below
    assert _wall_error(blisk, *_interior_xr()) < 1e-4
    return blisk


def _check_past_walls(mesh, bound, extension, exact_blisk):
    """Slice ``mesh`` between the walls; the sections and the blisk match the exact blade within ``bound``.

    ``extension``: how far [mm] the mesh reaches past the walls, at least (up to 0.1 mm more), or
    a (min, max) pair.
    """
    reach = (extension - 0.01, extension + 0.1) if np.isscalar(extension) else extension
    extension = reach[0]
    hub, shroud = _walls()
    overlap = mesh_slice_overlap(hub, shroud)
    assert overlap == pytest.approx(0.03 * HEIGHT)
    sections, report = mesh_to_sections_with_report(mesh, 25, 81, hub=hub, shroud=shroud)
    assert _check_against_analytic(sections, True, 0.0) < bound
    hub_r, shroud_r = hub.radius_at(sections.x[0]), shroud.radius_at(sections.x[-1])
    assert report["wall_overlap_mm"] == overlap
    if extension > overlap:
        # sliced exactly over the span the channel needs, never near the mesh's ends
        assert report["clipped_to_hub"] == report["clipped_to_shroud"] == "all"
        np.testing.assert_allclose(sections.r[0], hub_r - overlap, atol=1e-9)
        np.testing.assert_allclose(sections.r[-1], shroud_r + overlap, atol=1e-9)
        for wall in ("hub", "shroud"):
            lo, hi = report[f"beyond_{wall}_mm"]
            assert reach[0] < lo <= hi < reach[1], wall
    blisk = Blisk(60, hub, shroud, sections)
    if extension > overlap:
        assert blisk.blade.shape == (25, 81)            # reaches the walls' overlap: nothing extended
    x, r = _interior_xr()
    assert _wall_error(blisk, x, r) < bound
    th_s, th_p, _ = blisk.wall_angles(x, r)
    ex_s, ex_p, _ = exact_blisk.wall_angles(x, r)
    assert max(np.abs(r * (th_s - ex_s)).max(), np.abs(r * (th_p - ex_p)).max()) < bound
    return sections, report


def test_flat_fan_caps_dip_into_the_blade_between_its_points():
    """The test caps are the reported kind: a few hundredths of a mm inside the end cylinder."""
    s, c = _swept_grid(*_past_walls(0.0))
    minus, plus = _swept_faces(s, c)
    mesh = _fan_capped(minus, plus, 16)
    # tip cap: the triangles with every vertex on the end section (the s = 1 cone); their
    # centres lie below that cone
    tri = mesh.triangles
    on_cone = np.abs(np.hypot(tri[..., 1], tri[..., 2]) - (R_HUB + HEIGHT + SLOPE * tri[..., 0])) < 1e-9
    cap = tri[on_cone.all(axis=1)].mean(axis=1)
    assert len(cap) > 200
    dip = float((R_HUB + HEIGHT + SLOPE * cap[:, 0] - np.hypot(cap[:, 1], cap[:, 2])).max())
    assert 0.02 < dip < 0.1
    with pytest.raises(GeometryError, match=r"circle x=[-\d.]+ mm, r=[\d.]+ mm .* meets the mesh 4 times"):
        mesh_to_sections(mesh, 25, 81, span_margin=0.0)   # sliced to its ends, the cap's dip is in the way


@pytest.mark.parametrize("extension", [0.0, 0.5, 1.5, 5.0])
def test_blade_with_flat_fan_caps_past_the_walls_gives_the_exact_channel(extension, exact_blisk):
    """Flat fan caps, blade ending at the walls or 0.5 / 1.5 / 5 mm past them: the exact channel.

    Tolerance: the faceting bound of the 61 x 161 mesh (:func:`_grid_faceting_bound`,
    0.5 max|D^2 (r theta)| h^2 + r dtheta^2 / 8, about 0.009-0.011 mm), for the
    sections, the blisk's walls against the analytic faces and against the
    exact blade's blisk (whose own spline error is below 1e-4 mm).
    """
    s, c = _swept_grid(*_past_walls(extension))
    mesh = _fan_capped(*_swept_faces(s, c), 16)
    bound = _grid_faceting_bound(s, c)
    assert bound < 0.012
    _, report = _check_past_walls(mesh, bound, extension, exact_blisk)
    if extension == 0.0:
        # a blade ending at the walls is sliced to its own ends (inside the caps) and extended
        assert report["clipped_to_hub"] == report["clipped_to_shroud"] == "none"


def test_yaml_mesh_file_short_form_loads_a_blade_past_the_walls(tmp_path, exact_blisk):
    """``mesh: FILE``: a CAD blade 1.5 mm past hub and shroud with flat fan caps, as binary STL."""
    s, c = _swept_grid(*_past_walls(1.5))
    _fan_capped(*_swept_faces(s, c), 16).export(tmp_path / "blade.stl")
    hub, shroud = _walls()
    text = (f"name: CAD blade past the walls\nblade_count: 60\n"
            f"hub_profile: {hub.points.tolist()}\nshroud_profile: {shroud.points.tolist()}\n"
            "blade:\n  mesh: blade.stl\n")
    (tmp_path / "blisk.yaml").write_text(text)
    geometry = load_geometry(tmp_path / "blisk.yaml")
    blisk = geometry.blisk
    assert blisk.source == "mesh" and blisk.blade.shape == (25, 81)
    # float32 STL vertices add ~1e-5 mm to the faceting error
    bound = _grid_faceting_bound(s, c) + 1e-4
    assert _wall_error(blisk, *_interior_xr()) < bound
    info = geometry.info()
    assert set(geometry.summary()) < set(info)              # the summary stays the message's fields
    assert info["input_mesh_clipped_to_hub"] == info["input_mesh_clipped_to_shroud"] == "all"
    assert info["input_mesh_wall_overlap_mm"] == pytest.approx(0.03 * HEIGHT)
    assert 1.49 < info["input_mesh_beyond_hub_mm"][0] and 1.49 < info["input_mesh_beyond_shroud_mm"][0]
    lo, hi = info["input_mesh_radial_extent_mm"]
    assert lo < info["input_mesh_sliced_hub_side_radius_mm"][0] - 0.8      # 1.5 mm past, sliced 0.59 mm past
    assert hi > info["input_mesh_sliced_tip_side_radius_mm"][1] + 0.8
    # the long form gives the same geometry; neither a list nor a number is a mesh file
    long_form = load_geometry(text=text.replace("mesh: blade.stl", "mesh: {file: blade.stl}"), base_dir=tmp_path)
    np.testing.assert_array_equal(long_form.blisk.blade.theta_plus, blisk.blade.theta_plus)
    with pytest.raises(GeometryError, match="blade.mesh: expected a file name or a mapping"):
        load_geometry(text=text.replace("mesh: blade.stl", "mesh: [blade.stl]"), base_dir=tmp_path)


def test_rounded_caps_past_the_walls_are_accepted(exact_blisk):
    """A blade 1.5 mm past the walls whose last 0.9 mm are rounded off (quarter ellipses) to an edge."""
    s0, s1 = _past_walls(1.5)
    r0, r1 = _past_walls(0.6)                      # the rounding starts 0.6 mm past the walls
    angle = 0.5 * np.pi * np.linspace(0, 1, 9)[1:]
    s, c = _swept_grid(r0, r1)
    k, S = len(angle), s.shape[0]
    span = np.concatenate([r0 - (r0 - s0) * np.sin(angle[::-1]), s[:, 0], r1 + (s1 - r1) * np.sin(angle)])
    taper = np.concatenate([np.cos(angle[::-1]), np.ones(S), np.cos(angle)])
    taper[[0, -1]] = 0.0                           # an edge: the faces meet along the end sections
    s, c = np.meshgrid(span, c[0], indexing="ij")
    minus, plus = _swept_faces(s, c, taper[:, None])
    mesh = _solid(np.concatenate([face_grid_mesh(minus, flip=True).triangles, face_grid_mesh(plus).triangles]))
    main = slice(k, k + S)
    _check_past_walls(mesh, _grid_faceting_bound(s[main], c[main]), 1.5, exact_blisk)


def test_caps_trimmed_by_a_cylinder_are_accepted(exact_blisk):
    """A blade trimmed by the cylinders r = 98 and r = 124 mm (1.7 .. 4.3 mm past the walls)."""
    r_lo, r_hi = 98.0, 124.0
    i, c = np.meshgrid(np.linspace(0, 1, FINE[0]), np.linspace(0, 1, FINE[1]), indexing="ij")
    r = r_lo + i * (r_hi - r_lo)
    s = (r - R_HUB - CONE * c) / SPAN
    minus, plus = _swept_faces(s, c)
    mesh = closed_blade_mesh(minus, plus)
    radius = np.hypot(mesh.vertices[:, 1], mesh.vertices[:, 2])
    assert radius.min() == pytest.approx(r_lo) and radius.max() == pytest.approx(r_hi)
    # past the hub by 98 .. 100 + 0.08 x and the shroud by 124 - (119.68 + 0.08 x) mm
    _, report = _check_past_walls(mesh, _grid_faceting_bound(s, c), (1.7, 4.4), exact_blisk)
    assert report["radial_extent_mm"][1] == pytest.approx(r_hi)


def test_a_cap_reaching_into_the_span_is_refused():
    """A flat cap fanned from the leading edge dips ~3 mm: 1.5 mm past the walls it cuts the channel."""
    s, c = _swept_grid(*_past_walls(1.5))
    mesh = _fan_capped(*_swept_faces(s, c), FINE[1] - 1)
    hub, shroud = _walls()
    with pytest.raises(GeometryError, match=r"the circle x=[-\d.]+ mm, r=[\d.]+ mm .* meets the mesh 4 times"):
        mesh_to_sections(mesh, 25, 81, hub=hub, shroud=shroud)
    # 5 mm past the walls the same cap lies outside the span
    s, c = _swept_grid(*_past_walls(5.0))
    mesh = _fan_capped(*_swept_faces(s, c), FINE[1] - 1)
    sections = mesh_to_sections(mesh, 25, 81, hub=hub, shroud=shroud)
    assert _check_against_analytic(sections, True, 0.0) < _grid_faceting_bound(s, c)


def _slotted(s, c, s_cut, c_cut):
    """The blade with a slot through it (minus to plus face) over the parameter cells s_cut x c_cut."""
    minus, plus = _swept_faces(s, c)
    S, C = s.shape
    cells = np.zeros((S - 1, C - 1), dtype=bool)
    cells[s_cut, c_cut] = True
    keep = np.repeat(~cells.ravel(), 2)          # cell (s, c) -> faces 2 (s (C-1) + c), +1
    # the faces wound as closed_blade_mesh winds them before it turns a negative volume outwards
    own = [face_grid_mesh(minus, flip=True).triangles[keep], face_grid_mesh(plus).triangles[keep]]
    # the slot's walls: one quad from minus to plus along every edge of the cut's border,
    # wound against the face cell beyond that edge
    a0, a1 = s_cut.start, s_cut.stop
    b0, b1 = c_cut.start, c_cut.stop
    borders = ([((a0, b), (a0, b + 1)) for b in range(b0, b1)] + [((a, b1), (a + 1, b1)) for a in range(a0, a1)]
               + [((a1, b + 1), (a1, b)) for b in range(b0, b1)] + [((a + 1, b0), (a, b0)) for a in range(a0, a1)])
    for p, q in borders:
        own.append(np.array([[minus[p], minus[q], plus[q]], [minus[p], plus[q], plus[p]]]))
    own = np.concatenate(own)
    closed = closed_blade_mesh(minus, plus)
    labels = closed.face_attributes[FACE_LABELS]
    if np.dot(closed.face_normals[labels == MeshFaceLabel.MINUS].mean(0),
              face_grid_mesh(minus, flip=True).face_normals.mean(0)) < 0:
        own = own[:, ::-1]                        # closed_blade_mesh turned it
    ends = closed.triangles[(labels != MeshFaceLabel.MINUS) & (labels != MeshFaceLabel.PLUS)]
    return _solid(np.concatenate([own, ends]))


def _split_chordwise(s, c):
    """Two bodies: the blade's front (c < 0.45) and rear (c > 0.5) parts."""
    front = closed_blade_mesh(*_swept_faces(s * 1.0, c * 0.45))
    rear = closed_blade_mesh(*_swept_faces(s * 1.0, 0.5 + c * 0.5))
    return trimesh.util.concatenate([front, rear])


def _self_intersecting(s, c):
    """The minus face pushed 0.5 mm through the plus face over part of the span and chord."""
    minus, plus = _swept_faces(s, c)
    x, r = _xr(c, s, True)
    tm, tp = _thetas(x, r, True)
    patch = (s > 0.4) & (s < 0.6) & (c > 0.3) & (c < 0.6)
    tm = np.where(patch, tp + 0.5 / r, tm)
    return closed_blade_mesh(cylindrical_to_cartesian(x, r, tm), plus)


@pytest.mark.parametrize("defect, message", [
    ("slot", "meets the mesh 0 time"),                 # the circle through the slot
    ("two bodies", "meets the mesh [04] time"),         # in the cut, or across both bodies' edges
    ("self-intersecting", "faces cross"),               # twice, but entering through the plus face
])
def test_a_split_or_self_intersecting_blade_past_the_walls_is_refused(defect, message):
    """Inside the span a slot, a cut into two bodies or crossing faces are refused, the circle named."""
    s, c = _swept_grid(*_past_walls(1.5))
    if defect == "slot":
        mesh = _slotted(s, c, slice(25, 35), slice(60, 100))
        assert mesh.euler_number == 0                  # a body with a hole through it
    elif defect == "two bodies":
        mesh = _split_chordwise(s, c)
    else:
        mesh = _self_intersecting(s, c)
    hub, shroud = _walls()
    with pytest.raises(GeometryError, match=r"the circle x=[-\d.]+ mm, r=[\d.]+ mm \(section \d+, station \d+\)") \
            as err:
        mesh_to_sections(mesh, 25, 81, hub=hub, shroud=shroud)
    assert re.search(message, str(err.value))
    x, r = (float(v) for v in re.search(r"x=([-\d.]+) mm, r=([\d.]+) mm", str(err.value)).groups())
    overlap = mesh_slice_overlap(hub, shroud)
    assert hub.radius_at(x) - overlap - 1e-3 <= r <= shroud.radius_at(x) + overlap + 1e-3


# --------------------------------------------------------------------------
# the old module, blade_mesh: its names import, the renamed and the deprecated warn
# --------------------------------------------------------------------------

def test_the_old_module_still_exports_its_names():
    for name in ("FACE_LABELS", "MESH_SUFFIXES", "closed_blade_mesh", "face_grid_mesh", "load_blade_mesh",
                 "mesh_to_sections"):
        assert getattr(blade_mesh, name) is not None
    assert blade_mesh.closed_blade_mesh is closed_blade_mesh and blade_mesh.mesh_to_sections is mesh_to_sections


def test_blade_face_of_the_old_module_is_the_mesh_face_label_with_a_warning():
    with pytest.warns(DeprecationWarning, match="MeshFaceLabel"):
        from edm_planner.geometry.blade_mesh import BladeFace
    assert BladeFace is MeshFaceLabel
    with pytest.raises(AttributeError):
        blade_mesh.NoSuchName


def test_with_report_flag_still_works_with_a_warning(fine_blade):
    sections, report = mesh_to_sections_with_report(fine_blade, 5, 9)
    plain = mesh_to_sections(fine_blade, 5, 9)
    with pytest.warns(DeprecationWarning, match="mesh_to_sections_with_report"):
        old_sections, old_report = mesh_to_sections(fine_blade, 5, 9, with_report=True)
    with pytest.warns(DeprecationWarning, match="mesh_to_sections_with_report"):
        old_plain = mesh_to_sections(fine_blade, 5, 9, with_report=False)
    assert old_report == report and "axial_extent_mm" in report
    for s in (plain, old_sections, old_plain):
        for key in ("x", "r", "theta_minus", "theta_plus"):
            np.testing.assert_array_equal(getattr(s, key), getattr(sections, key))
