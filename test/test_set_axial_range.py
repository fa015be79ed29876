"""The electrodes' axial range in a set: as close to the closed channel's ends as the walls let an electrode be designed.

Where a blade's walls stop covering the span a little inside its sections' extent (a faceted mesh blade, the
measured Rotor 37 sections), the coarse insets of ``EDGE_INSETS`` jump from one that fails to 0.5 % of the
channel length, and the electrode leaves end strips of stock that long; the designer bisects between the two
(``EDGE_INSET_RESOLUTION``). Units: mm.
"""

from dataclasses import replace

import pytest

from edm_planner.errors import EdmError
from edm_planner.geometry.electrode import design_electrodes
from edm_planner.geometry.loader import load_geometry
from edm_planner.machining.electrode_set import EDGE_INSET_RESOLUTION, EDGE_INSETS, SetDesigner

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


def test_the_mesh_blisks_electrodes_reach_as_far_as_its_walls_let_them():
    g = load_geometry(CONFIG / "mesh_blisk.yaml")
    designer = SetDesigner(g, None, workers=1)
    share = _share(g.blisk, designer.closed_channel_range())
    # between the coarse shares that fail (0.2 %) and design (0.5 %), within the resolution of the thinnest
    assert EDGE_INSETS[2] < share < EDGE_INSETS[3]
    assert _designs(g.blisk, designer.base, share)
    assert not _designs(g.blisk, designer.base, share - EDGE_INSET_RESOLUTION)


def test_a_blisk_whose_walls_cover_the_span_keeps_the_thinnest_coarse_inset(default_geometry):
    designer = SetDesigner(default_geometry, None, workers=1)
    assert _share(default_geometry.blisk, designer.closed_channel_range()) == pytest.approx(EDGE_INSETS[0], abs=1e-12)
