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
