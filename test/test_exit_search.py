"""Backward exit search on the default blisk (planner core, work in progress for issue 4)."""

import numpy as np
import pytest

from edm_planner.geometry.electrode import ElectrodeDesign, design_electrodes
from edm_planner.interference.exact_points import ExactChannelDistance, transform_points
from edm_planner.cnc.kinematics import state_axes
from edm_planner.planning.search import ExitSearch, SearchOptions, SearchStatus, _column_minima, _row_minima



@pytest.fixture(scope="module")
def setup(default_geometry, default_field):
    return default_geometry, default_field


def test_options_are_validated():
    for bad in ({"method": "simplex"}, {"axes": 3}, {"step": 0.0}, {"margin_blade": -1.0},
                {"reference": "y_axis"}, {"exit_side": "left"}):
        with pytest.raises(ValueError):
            SearchOptions(**bad)


def test_electrode_in_collision_at_its_final_pose_is_reported(setup):
    g, field = setup
    # margins larger than the 0.1 mm discharge gap: the final pose itself violates them
    res = ExitSearch(g.blisk, g.electrodes[0], field, SearchOptions(margin_blade=0.2)).run()
    assert res.status == SearchStatus.START_IN_COLLISION
    assert res.blocking_surface in ("suction", "pressure") and res.blocking_clearance_lower_bound == pytest.approx(0.1, abs=0.02)


def test_full_size_electrode_cannot_leave_the_curved_channel(setup):
    g, field = setup
    res = ExitSearch(g.blisk, g.electrodes[0], field, SearchOptions(exit_side="downstream", step=0.2)).run()
    assert res.status == SearchStatus.INFEASIBLE
    assert res.furthest_reference < 1.0 and res.blocking_surface
    assert "blocked by the" in res.message


@pytest.mark.slow
def test_reduced_rear_electrode_exits_downstream_with_its_margins(setup):
    g, field = setup
    rear = design_electrodes(g.blisk, ElectrodeDesign(circumferential_reduction=0.045, radial_reduction=1.5,
                                                      split="front_rear", split_overlap=1.0))[1]
    opts = SearchOptions(method="max_min_distance", exit_side="downstream", step=0.2)
    res = ExitSearch(g.blisk, rear, field, opts).run()
    assert res.status == SearchStatus.SUCCESS, res.message
    assert res.direction == 1 and len(res.states) > 20
    # every node keeps the margins by the exact distance of all electrode vertices
    exact = ExactChannelDistance(g.blisk)
    a, c = res.states[:, 3], res.states[:, 4]
    from edm_planner.cnc.kinematics import state_poses
    poses = state_poses(rear.final_pose, res.states[:, :3], a, c)
    worst = min(exact.clearances(transform_points(p[None], rear.mesh.vertices)[0]).min() for p in poses[::5])
    assert worst >= 0.02 - 0.005        # margin, less the field bound the search accounts for on sampled points
    # the last node is clear of the blisk downstream
    last = transform_points(poses[-1:], rear.mesh.vertices)[0]
    assert last[:, 0].min() > g.blisk.axial_range[1] + opts.exit_distance
    # the axis values start at zero (the final pose) and X increases along the exit
    q = state_axes(rear.final_pose, res.states[:, :3], a, c)
    np.testing.assert_allclose(q[0], 0.0, atol=1e-9)
    assert q[-1, 0] > 10.0


def test_warm_start_that_keeps_the_cushion_is_the_lp_step(setup, monkeypatch):
    """Where the previous node's increments keep the cushion, the node takes them without an LP: the same nodes
    as the full sequential LP at every node, from far fewer pose evaluations."""
    g, field = setup
    rear = design_electrodes(g.blisk, ElectrodeDesign(circumferential_reduction=0.03, radial_reduction=3.0,
                                                      split="front_rear", split_overlap=1.0))[1]
    opts = SearchOptions(method="default", exit_side="downstream", step=0.1)
    fast = ExitSearch(g.blisk, rear, field, opts).run()
    monkeypatch.setattr(ExitSearch, "lp_at_every_node", True)
    full = ExitSearch(g.blisk, rear, field, opts).run()
    assert fast.status == full.status == SearchStatus.SUCCESS
    assert len(full.states) > 150
    np.testing.assert_array_equal(fast.states, full.states)
    assert fast.objfun1 == full.objfun1
    # most nodes of this channel keep the cushion: about half the evaluations (585 against 1121 on this blisk)
    assert fast.evaluations < 0.7 * full.evaluations


def test_row_and_column_minima_are_numpys():
    """The search's minima of (m, 4) slack rows, written for speed, give numpy's values (NaN and inf included)."""
    rows = np.random.default_rng(3).normal(size=(1981, 4))
    rows[5, 2], rows[7, 0], rows[9] = np.inf, -np.inf, np.nan
    np.testing.assert_array_equal(_row_minima(rows), rows.min(axis=1))
    np.testing.assert_array_equal(_column_minima(rows), rows.min(axis=0))
    np.testing.assert_array_equal(_column_minima(rows[:9]), rows[:9].min(axis=0))
