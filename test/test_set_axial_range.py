"""The electrodes' axial range in a set: as close to the closed channel's ends as the walls let an electrode be designed.

Where a blade's walls stop covering the span a little inside its sections' extent, the coarse insets of
``EDGE_INSETS`` would jump from one that fails to 0.5 % of the channel length, and the electrode would leave
end strips of stock that long; the designer bisects between the two (``EDGE_INSET_RESOLUTION``).

The faceted mesh blade and the measured Rotor 37 sections seemed to be such blades (their electrodes stopped
0.26 % and 0.31 % short of the ends): in fact the footprint test's Newton cycled between two parameters at
their trailing edges and called points of the walls outside them (``spline_kernels.uv_at``). Units: mm.
"""

from dataclasses import replace

import numpy as np
import pytest

from edm_planner.errors import EdmError
from edm_planner.geometry.electrode import design_electrodes
from edm_planner.geometry.loader import load_geometry
from edm_planner.machining.electrode_set import EDGE_INSETS, SetDesigner

from conftest import CONFIG


def _designs(blisk, base, share):
    fx0, fx1 = blisk.full_span_axial_range
    length = fx1 - fx0
    try:
        design_electrodes(blisk, replace(base, axial_range=(fx0 + share * length, fx1 - share * length)), only="main")
        return True
    except EdmError:
        return False


def _share(blisk, axial_range):
    fx0, fx1 = blisk.full_span_axial_range
    return (axial_range[0] - fx0) / (fx1 - fx0)


def test_the_mesh_blisks_electrodes_reach_the_thinnest_inset_its_trailing_edge_no_longer_stops_them():
    g = load_geometry(CONFIG / "mesh_blisk.yaml")
    face = g.blisk.pressure_face
    # where plain Newton stepped between u = 1 and u = 0.97 for ever, on the shroud side of the trailing edge:
    # the face exists there (it does on both sides along x), so the point is inside and its angle continuous
    x = np.linspace(23.60, 23.82, 23)
    theta, inside = face.theta_at(x, np.full_like(x, 120.60768929))
    assert inside.all()
    assert np.all(np.diff(theta) > 0) and np.abs(np.diff(theta, 2)).max() < 1e-4
    designer = SetDesigner(g, None, workers=1)
    assert _share(g.blisk, designer.closed_channel_range()) == pytest.approx(EDGE_INSETS[0], abs=1e-12)


def test_between_an_inset_that_fails_and_one_that_designs_the_thinnest_that_designs_is_found(default_geometry):
    # a negative inset reaches beyond the walls' full span, which the design refuses: a real failure
    designer = SetDesigner(default_geometry, None, workers=1)
    resolution = 1e-5
    share = _share(default_geometry.blisk, designer.closed_channel_range(insets=(-0.001, 0.0005),
                                                                         resolution=resolution))
    assert 0.0 <= share <= resolution
    assert _designs(default_geometry.blisk, designer.base, share)
    assert not _designs(default_geometry.blisk, designer.base, share - resolution)


def test_a_blisk_whose_walls_cover_the_span_keeps_the_thinnest_coarse_inset(default_geometry):
    designer = SetDesigner(default_geometry, None, workers=1)
    assert _share(default_geometry.blisk, designer.closed_channel_range()) == pytest.approx(EDGE_INSETS[0], abs=1e-12)


def test_rotor37s_electrodes_reach_the_thinnest_inset_too():
    # its measured sections' trailing edge made the same Newton cycle: its electrodes stopped 0.31 % short
    g = load_geometry(CONFIG / "rotor37.yaml")
    designer = SetDesigner(g, None, workers=1)
    assert _share(g.blisk, designer.closed_channel_range()) == pytest.approx(EDGE_INSETS[0], abs=1e-12)


def _uv_at_all_steps(net, x0, r0, u, v):
    """``spline_kernels.uv_at`` without its 2-cycle shortcut: all 30 plain Newton steps, then the descending
    Newton where they end off the position; the loop in Python around the compiled step functions, so that its
    arithmetic is the kernel's. (u, v, inside, cycled)."""
    from edm_planner.geometry import spline_kernels as K

    cp, tu, tv = net
    work = K.new_work()
    ev = work[2]
    u_start, v_start, cycled = u, v, True
    for _ in range(30):
        K.surface_eval(cp, tu, tv, u, v, work)
        du, dv, _ = K._meridional_step(ev, x0, r0)
        un, vn = min(max(u - du, 0.0), 1.0), min(max(v - dv, 0.0), 1.0)
        stalled = un == u and vn == v
        u, v = un, vn
        if max(abs(du), abs(dv)) < 1e-11 or stalled:
            cycled = False
            break
    K.surface_eval(cp, tu, tv, u, v, work)
    resid = float(np.hypot(ev[0, 0] - x0, np.hypot(ev[0, 1], ev[0, 2]) - r0))
    if resid >= 1e-7 and cycled:
        u2, v2, resid2 = K._uv_at_descending(cp, tu, tv, x0, r0, u_start, v_start, work)
        if resid2 < 1e-7:
            u, v, resid = u2, v2, resid2
    return u, v, resid < 1e-7, cycled


def test_the_footprint_newtons_cycle_shortcut_gives_the_bits_of_all_its_steps():
    # uv_at ends an exact 2-cycle at once on the state its 30 steps would end on: near the mesh blisk's
    # trailing edge, where plain Newton cycles, every answer is the same bits as running all the steps
    from edm_planner.geometry.spline_kernels import uv_at_many

    g = load_geometry(CONFIG / "mesh_blisk.yaml")
    face = g.blisk.pressure_face
    x, r = np.meshgrid(np.linspace(23.55, 23.95, 41), np.linspace(119.0, 121.0, 21))
    x, r = x.ravel(), r.ravel()
    _, idx = face._xr_tree.query(np.column_stack([x, r]) / face._xr_scale)
    starts = np.ascontiguousarray(face._seed_uv[idx])
    uv, inside = uv_at_many(*face._net, x, r, starts)
    reference = [_uv_at_all_steps(face._net, a, b, *s) for a, b, s in zip(x, r, starts)]
    assert sum(c for *_, c in reference) >= 20, "the grid must hold points where plain Newton cycles"
    assert np.array_equal(uv, np.array([(u, v) for u, v, *_ in reference]))
    assert np.array_equal(inside, np.array([i for _, _, i, _ in reference]))
