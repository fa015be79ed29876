"""Removed volume per cut (edm_planner.process.volume) against closed forms.

Every case checks that the exact volume lies in the certified bracket, that the
voxel estimate is within a stated relative error, and (where cheap) that the
bracket narrows when the resolution is halved. Dimensions are chosen so the
grown electrode's flat faces fall on voxel faces of the lattice anchored at the
origin (the estimate is then limited by the rounded edges only).
"""

import math

import numpy as np
import pytest
import trimesh
from scipy.integrate import quad

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.process.volume import (AnnulusBlank, Cut, MeshBlank, channel_cavity_volume, pose_travel_of,
                                        removed_volumes)


def shifted(x=0.0, y=0.0, z=0.0):
    m = np.eye(4)
    m[:3, 3] = [x, y, z]
    return m


def box_mesh(extents, centre=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(centre)
    return m


def block(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = box_mesh(hi - lo, (lo + hi) / 2)
    return MeshBlank(m.vertices, m.faces)


def plunge_volume(a, b, g, depth):
    """Part below the top face z = 0 of an a x b box (grown by g) plunged until its bottom is ``depth`` below.

    Slices at height z of the swept grown box: a rounded rectangle (a x b grown by g, area
    ab + 2g(a+b) + pi g^2) from z = -depth to 0, and below the bottom, at s = -depth - z in
    [0, g], a rounded rectangle grown by sqrt(g^2 - s^2); integrating the latter over s gives
    ab g + (a+b) pi g^2 / 2 + 2 pi g^3 / 3.
    """
    return depth * (a * b + 2 * g * (a + b) + math.pi * g * g) + a * b * g + (a + b) * math.pi * g * g / 2 \
        + 2 * math.pi * g ** 3 / 3


def box_grown_volume(a, b, c, g):
    """Steiner formula: volume of an a x b x c box grown by a ball of radius g."""
    return a * b * c + 2 * g * (a * b + b * c + c * a) + math.pi * g * g * (a + b + c) + 4 * math.pi * g ** 3 / 3


def check(cut, exact, rel):
    assert cut.lower <= exact <= cut.upper, (cut, exact)
    assert cut.volume == pytest.approx(exact, rel=rel), (cut, exact)


# a 100 x 100 x 60 block with its top face at z = 0
BLOCK = block((-50, -50, -60), (50, 50, 0))
A, B, C, GAP = 9.6, 5.6, 20.0, 0.2  # grown footprint 10 x 6 mm


def plunge_cut(label, x=0.0, depth=7.8, n=40):
    el = box_mesh((A, B, C))
    poses = np.array([shifted(x, 0, C / 2 + 1 - t) for t in np.linspace(0, 1 + depth, n)])
    return Cut(label, el.vertices, el.faces, poses, GAP)


def test_plunge_into_block():
    exact = plunge_volume(A, B, GAP, 7.8)
    coarse = removed_volumes(BLOCK, [plunge_cut("plunge")], resolution=0.5)
    fine = removed_volumes(BLOCK, [plunge_cut("plunge")], resolution=0.25)
    for r in (coarse, fine):
        check(r.cuts[0], exact, 0.01)
        assert r.total_lower <= exact <= r.total_upper
        assert r.total == r.cuts[0].volume
    assert fine.cuts[0].upper - fine.cuts[0].lower < coarse.cuts[0].upper - coarse.cuts[0].lower
    d = fine.to_dict()
    assert d["cuts"][0]["volume_mm3"] == fine.cuts[0].volume and "accuracy" in d and d["voxels"] == fine.voxels


def test_translation_through_block_is_a_prism():
    # a 4 x 5.6 x 7.6 box crosses the block x in [0, 40] from side to side: removed = 40 * (rounded 5.6 x 7.6)
    b, c, g = 5.6, 7.6, 0.2
    el = box_mesh((4.0, b, c))
    poses = np.array([shifted(x, 0, 0) for x in np.linspace(-10, 50, 121)])
    blank = block((0, -20, -20), (40, 20, 20))
    exact = 40.0 * (b * c + 2 * g * (b + c) + math.pi * g * g)
    widths = []
    for res in (0.5, 0.25):
        r = removed_volumes(blank, [Cut("slot", el.vertices, el.faces, poses, g)], resolution=res)
        check(r.cuts[0], exact, 0.01)
        widths.append(r.cuts[0].upper - r.cuts[0].lower)
    assert widths[1] < widths[0]


def test_translation_inside_annulus_matches_mesh_blank_and_nothing_outside():
    ring = AnnulusBlank(np.array([0.0, 60.0]), np.array([100.0, 100.0]), np.array([0.0, 60.0]),
                        np.array([150.0, 150.0]), 0.0, 60.0)
    el = box_mesh((9.6, 3.6, 5.6))
    a, b, c, g = 9.6 + 20.0, 3.6, 5.6, 0.2  # swept box: the electrode's x extent plus the 20 mm travel
    poses = np.array([shifted(x, 125.0, 0) for x in np.linspace(20, 40, 81)])
    cut = Cut("inside", el.vertices, el.faces, poses, g)
    exact = box_grown_volume(a, b, c, g)
    in_ring = removed_volumes(ring, [cut], resolution=0.5)
    in_block = removed_volumes(block((-10, 80, -30), (70, 170, 30)), [cut], resolution=0.5)
    check(in_ring.cuts[0], exact, 0.01)
    assert in_ring.cuts[0] == in_block.cuts[0]
    beyond = np.array([shifted(x, 125.0, 0) for x in np.linspace(120, 140, 81)])  # past x1 = 60
    away = Cut("away", el.vertices, el.faces, beyond, g)
    r = removed_volumes(ring, [away], resolution=0.5)
    assert (r.cuts[0].volume, r.cuts[0].lower, r.cuts[0].upper) == (0.0, 0.0, 0.0)


def test_rotation_sweep_is_an_annular_sector():
    # box x in [R1, R2], |y| <= w/2, z in [-H, 0] turned by phi about Z; gap 1e-3 mm (nearly the box's sweep)
    R1, R2, w, H, phi, g = 20.0, 30.0, 6.0, 10.0, math.radians(60), 1e-3
    el = box_mesh((R2 - R1, w, H), ((R1 + R2) / 2, 0, -H / 2))

    def rot(t):
        m = np.eye(4)
        m[:2, :2] = [[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]]
        return m

    poses = np.array([rot(t) for t in np.linspace(0, phi, 241)])
    # at radius rho the box spans angles [-beta, beta] (with a hole for rho > R2 that the sweep fills,
    # as phi exceeds the box's angular width): the swept section is [-beta, beta + phi]
    r_max = math.hypot(R2, w / 2)
    beta = lambda rho: math.asin(min(w / 2, math.sqrt(max(rho * rho - R1 * R1, 0.0))) / rho)  # noqa: E731
    area = phi * (r_max ** 2 - R1 ** 2) / 2 + quad(lambda rho: 2 * rho * beta(rho), R1, r_max, limit=200)[0]
    sweep = H * area  # the gap's contribution is below H * g * (2 area / H + perimeter) < 0.1 % here
    perimeter = phi * (R1 + r_max) + 4 * (R2 - R1) + 4 * w
    grown = (H + 2 * g) * (area + g * perimeter + math.pi * g * g)  # bounds the grown sweep from above
    blank = block((-40, -40, -20), (40, 40, 0))
    widths = []
    for res in (0.5, 0.25):
        r = removed_volumes(blank, [Cut("turn", el.vertices, el.faces, poses, g)], resolution=res)
        c = r.cuts[0]
        assert c.lower <= sweep and grown <= c.upper
        assert c.volume == pytest.approx(sweep, rel=0.02)
        widths.append(c.upper - c.lower)
    assert widths[1] < widths[0]


def test_overlapping_cuts_count_material_once():
    # the second plunge is shifted by 4 mm along x: the two grown sweeps overlap in a
    # (A - 4) x B box grown by GAP (both are rounded boxes and the shift exceeds the gap)
    first, second = plunge_cut("first"), plunge_cut("second", x=4.0)
    depth = 7.8
    one = plunge_volume(A, B, GAP, depth)
    overlap = plunge_volume(A - 4.0, B, GAP, depth)
    r = removed_volumes(BLOCK, [first, second], resolution=0.5)
    check(r.cuts[0], one, 0.01)
    check(r.cuts[1], one - overlap, 0.02)
    assert r.total_lower <= 2 * one - overlap <= r.total_upper
    assert r.total == pytest.approx(2 * one - overlap, rel=0.01)
    # the same cuts the other way round: the first one takes everything it reaches
    back = removed_volumes(BLOCK, [second, first], resolution=0.5)
    assert back.cuts[0].volume == r.cuts[0].volume and back.cuts[1].volume == r.cuts[1].volume


def test_pose_travel():
    el = box_mesh((2.0, 2.0, 2.0))
    poses = np.array([shifted(0, 0, z) for z in (0.0, 0.5, 0.75)])
    assert pose_travel_of(el.vertices, poses) == pytest.approx(0.5)
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # 90 degrees about Z: corner (1, 1) moves by 2, x 1/cos(22.5 deg)
    assert pose_travel_of(el.vertices, np.array([np.eye(4), turn])) == pytest.approx(2 / math.cos(math.pi / 8))


def test_the_hull_points_stand_for_the_electrode_bit_for_bit(default_geometry):
    """removed_volumes thins and bounds each cut's poses over its mesh's hull points (computed once per mesh):
    the same moves, to the bit, as over every vertex."""
    from edm_planner.process.volume import hull_points, thin_poses

    V = np.asarray(default_geometry.electrodes[0].mesh.vertices)
    hull = hull_points(V)
    assert 3 < len(hull) < len(V) // 10
    rng = np.random.default_rng(5)
    poses = []
    for k in range(60):                                  # a feed with a little turning, as a cycle's leg
        a = 0.002 * k + 1e-4 * rng.standard_normal()
        pose = shifted(0.05 * k, 0.01 * rng.standard_normal(), 0.0)
        pose[1:3, 1:3] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
        poses.append(pose)
    poses = np.array(poses)
    assert pose_travel_of(hull, poses) == pose_travel_of(V, poses)
    assert np.array_equal(thin_poses(hull, poses, 0.2), thin_poses(V, poses, 0.2))
    # hull points passed as such are not hulled again: still the same moves
    assert pose_travel_of(hull, poses, on_hull=True) == pose_travel_of(V, poses)
    assert np.array_equal(thin_poses(hull, poses, 0.2, on_hull=True), thin_poses(V, poses, 0.2))


def test_bad_input():
    good = plunge_cut("ok", n=3)
    scaled = good.poses.copy()
    scaled[1, :3, :3] *= 1.01
    nan = good.vertices.copy()
    nan[0, 0] = np.nan
    cases = [
        dict(cuts=[]),
        dict(cuts=[good], resolution=0.0),
        dict(cuts=[good], resolution=float("nan")),
        dict(cuts=[Cut("g", good.vertices, good.faces, good.poses, 0.0)]),
        dict(cuts=[Cut("s", good.vertices, good.faces, scaled, GAP)]),
        dict(cuts=[Cut("n", nan, good.faces, good.poses, GAP)]),
        dict(cuts=[Cut("f", good.vertices, good.faces + 100, good.poses, GAP)]),
        dict(cuts=[good], blank=AnnulusBlank(np.array([0.0, 1.0]), np.array([1.0, np.inf]), np.array([0.0, 1.0]),
                                             np.array([2.0, 2.0]), 0.0, 1.0)),
        dict(cuts=[good], blank="block"),
    ]
    for kw in cases:
        blank = kw.pop("blank", BLOCK)
        with pytest.raises(EdmError) as err:
            removed_volumes(blank, **kw)
        assert err.value.code == ErrorCode.INVALID_REQUEST


@pytest.fixture(scope="module")
def default_blisk(default_geometry):
    return default_geometry.blisk


def test_channel_cavity_volume(default_blisk):
    coarse = channel_cavity_volume(default_blisk, step=0.25)
    fine = channel_cavity_volume(default_blisk, step=0.0625)
    assert coarse == pytest.approx(fine, rel=0.005)
    # the channel holds less than the whole pitch sector between hub and shroud
    x0, x1 = default_blisk.axial_range
    xs = np.linspace(x0, x1, 201)
    ring = np.trapezoid(default_blisk.shroud.radius_at(xs) ** 2 - default_blisk.hub.radius_at(xs) ** 2, xs) / 2
    assert 0.3 * ring * default_blisk.pitch < fine < ring * default_blisk.pitch


def test_annulus_from_blisk(default_blisk):
    # the blades' axial range: ahead of and behind the blades the flow path is turned, not eroded
    ring = AnnulusBlank.from_blisk(default_blisk)
    assert (ring.x0, ring.x1) == default_blisk.axial_range
    whole = AnnulusBlank.from_blisk(default_blisk, whole_profiles=True)
    assert whole.x0 == -4.0 and whole.x1 == 29.0
    xs = np.linspace(ring.x0, ring.x1, 37)
    assert np.allclose(np.interp(xs, ring.hub_x, ring.hub_r), default_blisk.hub.radius_at(xs), atol=1e-3)
    assert np.allclose(np.interp(xs, ring.shroud_x, ring.shroud_r), default_blisk.shroud.radius_at(xs), atol=1e-3)


def test_thinned_poses_keep_the_ends_the_travel_and_the_volume():
    from edm_planner.process.volume import thin_poses

    # the slot of the prism test, sampled every 0.05 mm as a certificate would
    b, c, g = 5.6, 7.6, 0.2
    el = box_mesh((4.0, b, c))
    poses = np.array([shifted(x, 0, 0) for x in np.linspace(-10, 50, 1201)])
    keep = thin_poses(el.vertices, poses, 0.125)
    assert keep[0] == 0 and keep[-1] == len(poses) - 1 and np.all(np.diff(keep) > 0)
    assert pose_travel_of(el.vertices, poses[keep]) <= 0.125 + 0.05 + 1e-9
    assert len(keep) <= len(poses) // 2 + 1          # 0.05 mm steps: every second pose (0.1 mm)
    blank = block((0, -20, -20), (40, 20, 20))
    exact = 40.0 * (b * c + 2 * g * (b + c) + math.pi * g * g)
    full = removed_volumes(blank, [Cut("slot", el.vertices, el.faces, poses, g)], resolution=0.5)
    thin = removed_volumes(blank, [Cut("slot", el.vertices, el.faces, poses, g)], resolution=0.5, max_travel=0.125)
    assert thin.total == pytest.approx(full.total, rel=0.002)
    check(thin.cuts[0], exact, 0.01)
