"""A set's piece whose feed plans but whose cycle does not certify takes more radial reduction (issue 24).

On the mesh blisk the front piece of three axial pieces plans with 1.05 mm of radial reduction, but its
cycle's clear leg (X alone, out of the part) is not certified: the annulus ahead of the blades narrows (the
hub rises, the shroud falls). Before, that rejected the candidate, and the three, four and five axial pieces
with it; now the designer bisects for the smallest larger radial reduction whose plan and cycle both
certify. Units: mm, rad.
"""

import time
from dataclasses import replace

import pytest

from edm_planner.geometry.loader import load_geometry
from edm_planner.interference.fast import FastChannelField
from edm_planner.machining.electrode_set import Piece, SetDesigner, candidate_sets

from conftest import CONFIG


@pytest.mark.slow
def test_a_piece_whose_cycle_fails_takes_the_smallest_radial_reduction_that_certifies_it(field_cache):
    g = load_geometry(CONFIG / "mesh_blisk.yaml")
    field = FastChannelField(g.blisk, spacing=0.1, cache_dir=field_cache, cache_key=g.geometry_id)
    designer = SetDesigner(g, field, workers=1)
    designer.base = replace(designer.base, axial_range=designer.closed_channel_range())
    designer.t0 = time.perf_counter()
    (label, eid, design), *_ = dict(candidate_sets(g.blisk, designer.base, designer.options))["three axial pieces"]
    piece = Piece(label, eid, design)
    assert label == "front" and designer.size_piece(piece)
    assert piece.cycle.certified, piece.cycle.message
    h, r = piece.design.circumferential_reduction, piece.design.radial_reduction
    # the sizing's own smallest radial reduction at this h planned, but its cycle was not certified
    planned = [rr for hh, rr, res in piece.tried if hh == h and res.startswith("certified")]
    smallest = min(planned)
    assert smallest < r <= smallest + designer.options.radial_resolution + 1e-9
    plan, small = designer._plan(piece, h, smallest)
    assert plan is not None
    failing = designer._cycle(piece, plan, small)
    assert not failing.certified and "clear position" in failing.message
    # every trial of the cycle is recorded, and the piece's plan is the one of its design
    assert any("cycle certified" in res for _, _, res in piece.tried)
    assert min(piece.plan.metrics.clearance_exact) >= min(piece.plan.metrics.clearance_lower_bound) - 1e-6
    assert piece.volume > 0
