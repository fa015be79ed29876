"""Roughing twins and the process report's parts (issue 25, points 4 and 5), without designing a set.

The whole chain on the default blisk's set (a twin certified, its proof's allowance uniform, the report over
DDS) is asserted in test_electrode_set_node.py and test_demo.py.
"""

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from edm_planner.geometry.electrode import ElectrodeDesign, design_electrodes
from edm_planner.machining.rough_finish import allowance_figures, axial_extent, in_frame_of, twin_design
from edm_planner.process.model import DEFAULT_PROCESS
from edm_planner.process.report import face_wear, silhouette_area


def test_the_twin_design_lies_the_extra_offset_inside_its_finishing_design():
    d = ElectrodeDesign(discharge_gap=0.1, circumferential_reduction=0.03, split="front_rear", split_overlap=1.0,
                        axial_range=(1.0, 23.0))
    t = twin_design(d, DEFAULT_PROCESS)
    assert t.discharge_gap == pytest.approx(0.35)            # rough gap 0.25 + allowance 0.1
    assert t.axial_range == pytest.approx((1.25, 22.75)) and t.split_overlap == pytest.approx(0.5)
    assert (t.circumferential_reduction, t.reduction_side, t.split) == (0.03, "both", "front_rear")
    # each piece's cut faces come in by 0.25 mm: the split face too
    for eid, (lo, hi) in (("front", (1.25, 12.25)), ("rear", (11.75, 22.75))):
        assert axial_extent(t, eid) == pytest.approx((lo, hi))
    assert axial_extent(d, "front") == pytest.approx((1.0, 12.5))
    whole = twin_design(ElectrodeDesign(split="none", axial_range=(1.0, 23.0), split_overlap=0.7), DEFAULT_PROCESS)
    assert whole.split_overlap == 0.7 and axial_extent(whole, "main") == pytest.approx((1.25, 22.75))


def test_a_twin_expressed_in_the_finishing_frame_is_the_same_solid(default_geometry):
    blisk = default_geometry.blisk
    x0, x1 = blisk.full_span_axial_range
    d = ElectrodeDesign(circumferential_reduction=0.03, split="front_rear", split_overlap=1.0,
                        axial_range=(x0 + 0.5, x1 - 0.5))        # the set designer gives every piece its range
    (fin,) = design_electrodes(blisk, d, only="rear")
    (twin,) = design_electrodes(blisk, twin_design(d, DEFAULT_PROCESS), only="rear")
    moved = in_frame_of(twin, fin.final_pose)
    assert np.array_equal(moved.final_pose, fin.final_pose)
    world = lambda e: np.asarray(e.mesh.vertices) @ e.final_pose[:3, :3].T + e.final_pose[:3, 3]  # noqa: E731
    assert np.abs(world(moved) - world(twin)).max() < 1e-9
    # and it lies 0.25 mm inside the finishing electrode, cut faces included
    from edm_planner.machining.removal import MeshDistance
    inside = MeshDistance(np.asarray(fin.mesh.vertices), np.asarray(fin.mesh.faces))(np.asarray(moved.mesh.vertices))
    assert inside.max() <= -0.25 + 0.005, inside.max()


@pytest.mark.parametrize("eid", ["left", "right"])
def test_a_left_right_twin_lies_the_extra_offset_inside_along_its_inclined_split_face(default_geometry, eid):
    """The split face of a twisted channel is inclined to the arc: drawn in along the arc by 0.25 mm the
    twin lay only 0.085 (left) and 0.13 mm (right) inside; along the face's normal (split_inset) it lies
    0.25 mm inside but for 0.015 mm at the corners of its axial ends, within the allowance band."""
    from edm_planner.machining.removal import MeshDistance

    blisk = default_geometry.blisk
    x0, x1 = blisk.full_span_axial_range
    d = ElectrodeDesign(circumferential_reduction=0.01, split="left_right", split_overlap=1.0,
                        axial_range=(x0 + 0.5, x1 - 0.5))
    t = twin_design(d, DEFAULT_PROCESS)
    assert (t.split_inset, t.split_overlap) == (pytest.approx(0.25), 1.0)
    assert "split_inset" not in d.to_dict() and t.to_dict()["split_inset"] == pytest.approx(0.25)
    (fin,) = design_electrodes(blisk, d, only=eid)
    (twin,) = design_electrodes(blisk, t, only=eid)
    inside = MeshDistance(np.asarray(fin.mesh.vertices), np.asarray(fin.mesh.faces))(
        np.asarray(in_frame_of(twin, fin.final_pose).mesh.vertices))
    assert -inside.max() >= 0.25 - 0.02, -inside.max()
    assert np.percentile(-inside, 1) >= 0.25 - 0.005
    # the same design without the inset: the arc offset of the old twins, measurably less
    (old,) = design_electrodes(blisk, replace(t, split_inset=0.0, split_overlap=0.5), only=eid)
    before = MeshDistance(np.asarray(fin.mesh.vertices), np.asarray(fin.mesh.faces))(
        np.asarray(in_frame_of(old, fin.final_pose).mesh.vertices))
    assert -before.max() < 0.2


def test_a_split_inset_must_leave_a_gap_and_a_sub_electrode(default_geometry):
    from edm_planner.errors import GeometryError

    with pytest.raises(GeometryError, match="split_inset: must lie in 0 .. discharge_gap - 0.01"):
        ElectrodeDesign(discharge_gap=0.1, split="left_right", split_inset=0.1)
    with pytest.raises(GeometryError, match="split_inset: must lie"):
        ElectrodeDesign(split_inset=-0.1)
    blisk = default_geometry.blisk
    with pytest.raises(GeometryError, match="split_inset: the split faces drawn in leave no sub-electrode"):
        design_electrodes(blisk, ElectrodeDesign(discharge_gap=0.5, split="left_right", split_inset=0.45,
                                                 split_fraction=0.05), only="left")


def _report(stock, which=None, u=None):
    out = {}
    for name, s in stock.items():
        s = np.asarray(s, float)
        out[name] = SimpleNamespace(stock=s, which=np.zeros(s.shape + (2,), int) if which is None else which,
                                    u=np.linspace(0.0, 20.0, s.shape[1])[None].repeat(s.shape[0], 0) if u is None
                                    else u)
    return SimpleNamespace(surfaces=out)


def test_the_allowance_is_judged_against_the_ideal_twin_away_from_its_ends():
    shape = (4, 21)
    finish = _report({"suction": np.zeros(shape)})
    a = DEFAULT_PROCESS.finish_allowance
    even = allowance_figures(_report({"suction": np.full(shape, a)}), finish, DEFAULT_PROCESS, 0.02)
    assert even["uniform"] and even["surfaces"]["suction"]["share_within_band"] == 1.0
    # more stock in a corner strip is what the ideal twin leaves there too
    corner = np.zeros(shape)
    corner[0] = 0.12
    rough = np.full(shape, a)
    rough[0] += 0.12
    assert not allowance_figures(_report({"suction": rough}), finish, DEFAULT_PROCESS, 0.02)["uniform"]
    assert allowance_figures(_report({"suction": rough}), finish, DEFAULT_PROCESS, 0.02,
                             corner={"suction": corner.ravel()})["uniform"]
    # thick stock near a twin's end (u = 20 mm) is the finishing electrode's: not judged there
    rough = np.full(shape, a)
    rough[:, -1] = 0.6
    assert not allowance_figures(_report({"suction": rough}), finish, DEFAULT_PROCESS, 0.02)["uniform"]
    assert allowance_figures(_report({"suction": rough}), finish, DEFAULT_PROCESS, 0.02, ends=[20.0])["uniform"]
    # an overcut anywhere is never uniform, and the smallest stock says where it stands
    rough = np.full(shape, a)
    rough[2, 3] = -0.004
    f = allowance_figures(_report({"suction": rough}), finish, DEFAULT_PROCESS, 0.02)
    assert not f["uniform"] and f["surfaces"]["suction"]["smallest_stock_mm"] == pytest.approx(-0.004)
    # where the finishing electrode without a twin (sweep 1) reaches the wall, the allowance is not judged
    which = np.zeros(shape + (2,), int)
    which[:, 10:, 0] = 1
    rough = np.full(shape, a)
    rough[:, 10:] = 0.9
    assert allowance_figures(_report({"suction": rough}), _report({"suction": np.zeros(shape)}, which),
                             DEFAULT_PROCESS, 0.02, twinned=[0])["uniform"]


def test_silhouettes_and_face_wear_of_a_box():
    box = trimesh.creation.box((10.0, 4.0, 6.0))
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    for d, area in (((1, 0, 0), 24.0), ((0, 1, 0), 60.0), ((0, 0, 1), 40.0)):
        assert silhouette_area(V, F, d, pixel=0.02) == pytest.approx(area, rel=0.01)
    # seen along a diagonal of the x-y plane: the projected outline's area, exactly
    d = np.array([1.0, 1.0, 0.0]) / math.sqrt(2)
    assert silhouette_area(V, F, d, pixel=0.02) == pytest.approx(6.0 * (10 + 4) / math.sqrt(2), rel=0.01)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=3.0)
    assert silhouette_area(np.asarray(sphere.vertices), np.asarray(sphere.faces), (0.3, 0.2, 0.9)) == \
        pytest.approx(math.pi * 9.0, rel=0.01)

    # the box fed along +x then moved along -y: each leg's wear on the face that leads it
    from edm_planner.machining.cycle import Leg, MachiningCycle, ProcessReach
    from edm_planner.process.report import ProcessRun

    feed = Leg("feed", "feed", np.array([[-5.0, 0, 0, 0, 0], [0.0, 0, 0, 0, 0]]), regime="finish",
               removed_volume=100.0)
    side = Leg("process", "side", np.array([[0.0, 0, 0, 0, 0], [0.0, -0.2, 0, 0, 0]]), regime="finish",
               removed_volume=30.0)
    idle = Leg("return", "back", np.array([[0.0, -0.2, 0, 0, 0], [-5.0, -0.2, 0, 0, 0]]))
    run = ProcessRun("main", "finish", V, F, np.eye(4), ("X", "Y", "Z", "A", "C"),
                       MachiningCycle(("X", "Y", "Z", "A", "C"), [feed, side, idle], ProcessReach(), 0.08))
    regime = DEFAULT_PROCESS.finish
    depth, areas = face_wear(run, regime)
    assert set(depth) == {"front", "face -y"}
    assert depth["front"] == pytest.approx(100 * 0.15 / 24.0, rel=0.01)
    assert depth["face -y"] == pytest.approx(30 * 0.15 / 60.0, rel=0.01)
    assert areas["front"] == pytest.approx(24.0, rel=0.01)


def test_a_stock_mesh_is_read_checked_and_named_by_its_content(tmp_path):
    from edm_planner.errors import EdmError, ErrorCode
    from edm_planner.process.volume import MeshBlank, load_stock_mesh

    box = trimesh.creation.box((30.0, 20.0, 10.0))
    box.export(tmp_path / "stock.stl")
    blank, digest = load_stock_mesh(tmp_path / "stock.stl")
    assert isinstance(blank, MeshBlank) and len(blank.faces) == 12 and len(digest) == 64
    assert load_stock_mesh(tmp_path / "stock.stl")[1] == digest, "the same file, the same digest (set id)"
    open_box = box.copy()
    open_box.update_faces(np.arange(len(box.faces)) != 0)       # one triangle missing: not a solid
    open_box.export(tmp_path / "open.stl")
    (tmp_path / "junk.stl").write_bytes(b"solid nothing\nthis is not an stl\n")
    for name, code, words in (("missing.stl", ErrorCode.FILE_ERROR, "No such file"),
                              ("open.stl", ErrorCode.INVALID_GEOMETRY, "closed solid"),
                              ("junk.stl", ErrorCode.FILE_ERROR, "")):
        with pytest.raises(EdmError) as exc:
            load_stock_mesh(tmp_path / name)
        assert exc.value.code == code and words in exc.value.message, exc.value.message
