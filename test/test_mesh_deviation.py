"""The workpiece mesh's stated deviation from the true surfaces: an upper bound, by side, checked independently."""

import json

import numpy as np
import pytest
import trimesh

from edm_planner.geometry.blade_mesh import face_grid_mesh
from edm_planner.geometry.frames import cartesian_to_cylindrical, cylindrical_to_cartesian, rotation_about_x
from edm_planner.geometry.mesh_deviation import (RevolutionPatch, channel_mesh_deviation, channel_patches,
                                                 surface_deviation)
from edm_planner.geometry.profiles import RevolutionProfile
from edm_planner.geometry.spline_kernels import eval_many
from edm_planner.interference import SURFACES
from edm_planner.interference.exact_points import ProfileDistance
from edm_planner.records.plan_export import read_plan, write_plan

from plan_samples import failed_box_plan

#: channel of the export: not 0, so the turned meshes and surfaces are what is measured
CHANNEL = 2
#: slack on the exact closest points (converged Newton) and on float32 vertices read back [mm]
SLACK = 1e-7


@pytest.fixture(scope="module")
def exported(tmp_path_factory, default_geometry):
    """A failed plan written for channel 2 (write_plan writes the workpiece of failed plans too)."""
    g = default_geometry
    plan = failed_box_plan(g, CHANNEL, "deviation-1")
    out = tmp_path_factory.mktemp("deviation") / "plan"
    write_plan(plan, out, g.blisk)
    doc = json.loads((out / "plan.json").read_text())
    return g, doc, read_plan(out, require_success=False).workpiece_meshes()


def _bounds(doc):
    return doc["files"]["workpiece"]["deviation"]["surfaces"]


def test_plan_json_states_the_deviation_per_surface_and_side(exported):
    g, doc, parts = exported
    wp = doc["files"]["workpiece"]
    # the keys readers had are unchanged
    assert wp["resolution"] == 0.5 and set(wp["surfaces"]) == set(SURFACES) and set(parts) == set(SURFACES)
    dev = wp["deviation"]
    assert dev["kind"] == "bound" and dev["units"] == "mm" and dev["float32"] is True
    assert {"into_channel", "into_material", "measured"} <= set(dev["definition"]) and "remainder" in dev["method"]
    for s in SURFACES:
        d = dev["surfaces"][s]
        assert d["triangles"] == len(parts[s].faces)
        for side in ("into_channel", "into_material"):
            assert 0.0 <= d[f"measured_{side}"] <= d[side] <= d[f"measured_{side}"] + d["remainder"] + 1e-15
        assert 0.0 < d["remainder"] < 0.05 * max(d["into_channel"], d["into_material"])
        assert d["sample_spacing"] < 0.1
    b = _bounds(doc)
    # the signs: the pressure face is concave seen from the channel (its chords lie in the channel), the
    # suction face convex (its chords lie in the material); the hub is convex, the shroud concave
    assert b["pressure"]["measured_into_channel"] > 5 * b["suction"]["into_channel"]
    assert b["suction"]["measured_into_material"] > 10 * b["suction"]["into_channel"]
    assert b["hub"]["measured_into_material"] > 5 * b["hub"]["into_channel"]
    assert b["shroud"]["measured_into_channel"] > 1.5 * b["shroud"]["into_material"]
    # the pressure wall's worst sag into the channel is on its concave middle, not at an edge
    x, r, _ = cartesian_to_cylindrical(np.array(b["pressure"]["at_into_channel"]))
    assert g.blisk.axial_range[0] + 5 < x < g.blisk.axial_range[1] - 5
    assert doc["files"]["electrode"]["deviation"]["kind"] == "exact"
    assert doc["files"]["electrode"]["deviation"]["deviation"] == 0.0


def _blade_signed(face, turn, points, normals):
    """Exact signed distance of points in W to a blade face turned by ``turn`` (positive along ``normals``)."""
    R = rotation_about_x(turn)[:3, :3]
    local = points @ R
    feet, dist, _ = face.closest_points(local)
    side = np.sign(np.einsum("ij,ij->i", local - feet, normals @ R))
    return side * dist


def _mesh_samples(mesh, count, seed):
    """Random points on a mesh, its triangles' centroids and edge midpoints (where chords sag most), and
    the triangle of each."""
    pts, tri = trimesh.sample.sample_surface(mesh, count, seed=seed)
    c = mesh.triangles
    mids = [c.mean(axis=1)] + [(c[:, i] + c[:, (i + 1) % 3]) / 2 for i in range(3)]
    every = np.arange(len(c))
    return np.vstack([pts] + mids), np.concatenate([tri] + [every] * 4)


def test_independent_points_never_exceed_the_stated_bounds(exported):
    """Both ways, by means the bound does not use: points on the mesh (float32, read back from workpiece.stl)
    against the exact closest points of the true surfaces, and random true-surface points against the
    mesh's closest points (trimesh)."""
    g, doc, parts = exported
    b, bl = _bounds(doc), g.blisk
    rng = np.random.default_rng(26)
    found = {}
    for s in SURFACES:
        mesh, bound = parts[s], b[s]
        # mesh -> true surface: positive where the mesh lies on the channel side
        pts, tri = _mesh_samples(mesh, 6000, seed=4)
        if s in ("suction", "pressure"):
            face = bl.suction_face if s == "suction" else bl.pressure_face
            turn = (CHANNEL + (s == "pressure")) * bl.pitch
            d = _blade_signed(face, turn, pts, mesh.face_normals[tri])
        else:
            x, rho, _ = cartesian_to_cylindrical(pts)
            d = ProfileDistance(bl.hub if s == "hub" else bl.shroud, material_below=s == "hub").signed(x, rho)[0]
        assert d.max() <= bound["into_channel"] + SLACK, s
        assert -d.min() <= bound["into_material"] + SLACK, s
        # true surface -> mesh: positive where the surface lies on the channel side (the mesh in the material)
        n = 8000
        if s in ("suction", "pressure"):
            uv = rng.random((n, 2))
            sp = face.surface.evaluate(uv[:, 0], uv[:, 1]) @ rotation_about_x(turn)[:3, :3].T
        else:
            params = bl.channel_mesh_parameters(0.5)[s].reshape(-1, 2)
            xs = rng.uniform(params[:, 0].min(), params[:, 0].max(), n)
            th = rng.uniform(params[:, 1].min(), params[:, 1].max(), n) + CHANNEL * bl.pitch
            profile = bl.hub if s == "hub" else bl.shroud
            sp = cylindrical_to_cartesian(xs, profile.radius_at(xs), th)
        foot, dist, tid = trimesh.proximity.closest_point(mesh, sp)
        sigma = np.sign(np.einsum("ij,ij->i", sp - foot, mesh.face_normals[tid])) * dist
        assert sigma.max() <= bound["into_material"] + SLACK, s
        assert -sigma.min() <= bound["into_channel"] + SLACK, s
        found[s] = max(d.max(), -sigma.min()), max(-d.min(), sigma.max())
    # the bound is not loose where it matters: the pressure face's concave sag into the channel, which a
    # CAM check against the mesh reads as clearance lost, is attained to within 10 %, and is of the order
    # kappa h^2 / 8 of 0.5 mm triangles (thousandths of a mm)
    assert found["pressure"][0] >= 0.9 * b["pressure"]["into_channel"] > 0.002
    assert found["suction"][1] >= 0.9 * b["suction"]["into_material"]
    assert found["pressure"][1] >= 0.9 * b["pressure"]["into_material"]


def test_finer_resolution_gives_smaller_bounds(exported):
    g, doc, _ = exported
    at_half = _bounds(doc)
    coarse = channel_mesh_deviation(g.blisk, CHANNEL, 1.0)
    fine = channel_mesh_deviation(g.blisk, CHANNEL, 0.25)
    for s in SURFACES:
        for side in ("into_channel", "into_material"):
            assert getattr(fine[s], side) < at_half[s][side] < getattr(coarse[s], side), (s, side)
    # chord sag goes as h^2: halving the edges divides the dominant figures by about 4
    for s, side in (("pressure", "into_channel"), ("pressure", "into_material"), ("suction", "into_material")):
        assert 3.0 < at_half[s][side] / getattr(fine[s], side) < 5.0, (s, side)


@pytest.mark.parametrize("channel_side", ["outside", "inside"])
def test_a_cylinder_gives_its_chord_sag_on_the_right_side(channel_side):
    """A cylinder of radius R meshed with angular step dt: the chords sag R (1 - cos(dt / 2)) into the
    material when the channel is outside it (a hub), into the channel when it is inside (a shroud)."""
    R, dt = 100.0, 0.01
    profile = RevolutionProfile([[0.0, R], [10.0, R]])
    x, th = np.linspace(0.0, 10.0, 21), np.arange(11) * dt
    mesh = face_grid_mesh(cylindrical_to_cartesian(x[None, :], R, th[:, None]))
    outward = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center * [0, 1, 1]).mean() > 0
    if outward != (channel_side == "outside"):
        mesh.invert()                              # normals into the channel
    params = np.stack(np.meshgrid(x, th), axis=-1)
    dev = surface_deviation(mesh, params, RevolutionPatch(profile), float32=False)
    sag = R * (1.0 - np.cos(dt / 2))              # 1.25e-3 mm
    deep, shallow = ((dev.into_material, dev.into_channel) if channel_side == "outside"
                     else (dev.into_channel, dev.into_material))
    assert sag - 1e-12 <= deep <= sag + dev.remainder + 1e-12
    assert shallow <= dev.remainder + 1e-12 and dev.remainder < 0.02 * sag
    # r'' = r' = 0, |n . H_thetatheta| <= R over lattice cells of dt / 8: the remainder is R (dt / 8)^2 / 8
    assert dev.remainder == pytest.approx(R * (dt / 8) ** 2 / 8, rel=1e-9)


def test_the_remainder_alone_bounds_what_the_lattice_measures(exported):
    """With the vertices as the only samples (one lattice cell per triangle) the bound is the remainder term
    alone; it must still cover the deviations the dense lattice attains."""
    g, doc, _ = exported
    dense = _bounds(doc)
    sparse = channel_mesh_deviation(g.blisk, CHANNEL, 0.5, subdivisions=1)
    for s in SURFACES:
        for side in ("into_channel", "into_material"):
            assert getattr(sparse[s], side) >= dense[s][f"measured_{side}"], (s, side)


def test_second_derivative_bounds_hold_inside_every_triangle(default_geometry):
    """The hull bounds A, B, C are at least |n . S_uu|, |n . S_uv|, |n . S_vv| at random points of every
    triangle's preimage, also for triangles across several knot spans (3 mm)."""
    bl = default_geometry.blisk
    rng = np.random.default_rng(7)
    for res in (0.5, 3.0):
        params, meshes, patches = bl.channel_mesh_parameters(res), bl.channel_meshes(1, res), channel_patches(bl, 1)
        for s in SURFACES:
            pre = params[s].reshape(-1, 2)[meshes[s].faces]
            if s in ("hub", "shroud"):
                pre = pre + [0.0, bl.pitch]
                if res == 3.0:             # and triangles across the profile's cubic pieces
                    pre[:, 1, 0] = np.minimum(pre[:, 1, 0] + rng.uniform(0.0, 10.0, len(pre)), pre[:, :, 0].max())
            bounds = patches[s].hessian_bound(pre, meshes[s].face_normals)
            q = np.einsum("tjk,tkd->tjd", rng.dirichlet([1, 1, 1], size=(len(pre), 4)), pre).reshape(-1, 2)
            n = np.repeat(meshes[s].face_normals, 4, axis=0)
            if s in ("suction", "pressure"):
                ev = eval_many(*patches[s]._net, q[:, 0].copy(), q[:, 1].copy())
                second = [np.abs(np.einsum("ij,ij->i", ev[:, k], n @ patches[s].rotation)) for k in (3, 4, 5)]
            else:
                interp = (bl.hub if s == "hub" else bl.shroud)._interp
                second = [np.abs(interp.derivative(2)(q[:, 0])), np.abs(interp.derivative(1)(q[:, 0])),
                          interp(q[:, 0])]
            for value, bound in zip(second, bounds):
                assert (value.reshape(-1, 4).max(axis=1) <= bound * (1 + 1e-9) + 1e-12).all(), (res, s)
