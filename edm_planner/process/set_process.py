"""The EDM process of a designed set: roughing twins, their proof, removed volume, erosion time and wear.

Runs once on the delivered candidate, after its finishing proof: :func:`add_process` is the ``process_step``
that whoever builds a :class:`~edm_planner.machining.electrode_set.SetDesigner` with a process model passes
in (the designer, a layer below, imports nothing of this), and the designer calls it at the end of
:meth:`~edm_planner.machining.electrode_set.SetDesigner.design`, before it moves the plans to their channel:

1. with ``rough_and_finish`` (the default): a roughing twin of every piece
   (:mod:`edm_planner.machining.rough_finish`), its own
   certified cycle, and the roughing proof (the removal simulation with the rough spark gap) with the
   allowance it leaves; the twins become pieces of the set, machined first (``rough-<label>``);
2. the removed volume of every leg of every electrode in machining order, written onto the legs with
   their regime (so the bridge erosion-times them), and the process report (:mod:`.report`);
3. with ``wear_compensation``: every electrode's compensation by feed depth (:func:`add_wear_compensation`).

A piece whose twin cannot be made (its finishing electrode is thinner somewhere than twice the twin's extra
offset) or certified gets none and erodes its region alone at the finish regime; with no twin at all, or a
roughing proof that overcuts, the set runs single-regime (the finishing electrodes erode everything at the
finish regime). The notes say why.
No rclpy.
"""

import copy
import logging
from dataclasses import replace

import numpy as np

from ..errors import EdmError
from ..machining.corner_rounding import corner_rounding_stock
from ..machining.electrode_set import Piece
from ..machining.removal import simulate_removal
from ..machining.rough_finish import allowance_figures, axial_extent, rough_piece, rough_sweeps
from ..planning.planner import plan_id_for
from .report import ProcessRun, compensation_schedule, leg_direction, plan_process

_log = logging.getLogger(__name__)

#: where each step of :func:`add_process` ends, as a share of the process step's progress: roughly its share of
#: the time on the default blisk (twins 1.3 s, their proof 2.3 s, removed volume 2.8 s of 6.4 s on an AMD EPYC
#: Zen 4, 2026-11-29)
_SHARES = {"twins": 0.2, "proof": 0.55, "volume": 0.98}


def _rough_plan(piece, rp):
    """The roughing twin's Plan: the finishing plan's feed with the twin's electrode, id and feed certificate."""
    plan = copy.copy(piece.plan)
    plan.plan_id = plan_id_for(plan.geometry_id, 0, plan.electrode_id, plan.options, rp.design)
    plan.electrode_mesh = rp.electrode.mesh
    # its own feed certificate; the exact re-check of every vertex at every sample (tens of seconds) is the
    # finishing plan's only: NaN here, "not computed"
    plan.metrics = replace(plan.metrics, clearance_lower_bound=tuple(float(v) for v in rp.feed_clearance),
                           clearance_exact=(float("nan"),) * 4)
    plan.message = (f"roughing twin of plan {piece.plan.plan_id}: its feed re-certified with the twin, clearance "
                    f"lower bound {min(rp.feed_clearance):.4f} mm (certified)")
    plan.cycle = rp.cycle
    return plan


def add_roughing(designer, candidate):
    """Roughing twins of the candidate's pieces, proven: (twin pieces, notes).

    A piece whose twin cannot be made (the finishing electrode is thinner than twice the extra offset
    somewhere: the twin's design leaves no electrode) or certified gets none: it erodes its own region
    alone, at the finish regime, and a note says why. No twin at all, or a roughing proof that overcuts:
    ([], notes).
    """
    process = designer.process
    twins, notes, twinned = [], [], []
    for i, p in enumerate(candidate.pieces):
        designer.process_progress(_SHARES["twins"] * i / len(candidate.pieces),
                                  f"{candidate.name}: the roughing twin of {p.label} and its certified cycle")
        try:
            rp = rough_piece(designer.blisk, designer.field, p, process, designer.cycle_options, designer._walls)
        except EdmError as e:                         # e.g. an offset that leaves no electrode
            notes.append(f"no roughing twin for {p.label}: {e.code.name}: {e.message}")
            continue
        if not rp.certified:
            notes.append(f"no roughing twin for {p.label}: {rp.cycle.message}")
            continue
        extra = process.rough_electrode_gap - float(p.design.discharge_gap)
        if rp.inset < extra - process.allowance_band:
            notes.append(f"the roughing twin of {p.label} lies only {rp.inset:.3f} mm inside its finishing electrode "
                         f"somewhere (its extra offset {extra:.3f} mm less the allowance band "
                         f"{process.allowance_band:g} mm): the allowance may thin there (never below zero: its feed "
                         f"is certified)")
        twins.append(rp)
        twinned.append(i)
    if not twins:
        return [], notes
    designer.process_progress(_SHARES["twins"], f"{candidate.name}: the roughing proof of "
                                                f"{len(twins)} twin(s) (material removal at the rough spark gap)")
    pool = designer._workers_pool()              # the sizing workers share out the wall samples, as in prove()
    report = simulate_removal(designer.blisk, rough_sweeps(twins), process.rough.spark_gap,
                              tolerance=designer.options.tolerance, samples=designer._wall_samples,
                              executor=pool, parts=designer.workers if pool is not None else 1)
    corner = corner_rounding_stock(designer.blisk, designer._wall_samples, process.rough_electrode_gap)
    ends = [x for rp in twins for x in (axial_extent(rp.design, rp.electrode_id) or ())]
    allowance = allowance_figures(report, candidate.removal, process, designer.options.tolerance, twinned, corner,
                                  ends, designer._wall_samples)
    allowance["twin_inset_mm"] = {rp.label: round(rp.inset, 4) for rp in twins}
    candidate.rough_removal, candidate.allowance = report, allowance
    if report.overcut_max > 0:
        return [], notes + [f"the roughing proof overcuts by {report.overcut_max:.4f} mm"]
    pieces = []
    for i, rp in zip(twinned, twins):
        p = candidate.pieces[i]
        twin = Piece(rp.label, p.electrode_id, rp.design, _rough_plan(p, rp), rp.cycle,
                     volume=float(rp.electrode.mesh.volume))
        twin.regime = "rough"
        pieces.append(twin)
    return pieces, notes


def add_process(designer, candidate, resolution=0.5):
    """The process of the delivered candidate: roughing twins first (when configured), then the report.

    The designer's ``process_step``: ``designer`` is the
    :class:`~edm_planner.machining.electrode_set.SetDesigner` (its ``process`` model, blisk, field, wall
    samples and workers are used), ``candidate`` the delivered
    :class:`~edm_planner.machining.electrode_set.Candidate`.

    Sets ``candidate.pieces`` (twins first), ``candidate.process`` (ProcessReport) and, with twins,
    ``candidate.rough_removal`` and ``candidate.allowance``; returns the report.
    """
    process = designer.process
    candidate.single_regime_reason = "" if process.rough_and_finish else "rough_and_finish is off"
    for p in candidate.pieces:
        p.regime = "finish"
    if process.rough_and_finish:
        twins, notes = add_roughing(designer, candidate)
        candidate.roughing_notes = notes
        for note in notes:
            _log.warning("%s", note)
        if twins:
            candidate.pieces = twins + candidate.pieces
        else:
            candidate.single_regime_reason = "; ".join(notes) or "no roughing twin"
    designer.process_progress(_SHARES["proof"], f"{candidate.name}: removed volume, erosion time and wear of "
                                                f"{len(candidate.pieces)} electrode(s)")
    runs = [ProcessRun(p.label, p.regime, np.asarray(p.plan.electrode_mesh.vertices),
                         np.asarray(p.plan.electrode_mesh.faces), np.asarray(p.plan.final_pose),
                         tuple(p.plan.axis_names), p.cycle) for p in candidate.pieces]
    candidate.process = plan_process(designer.blisk, runs, process, resolution=resolution,
                                     stock_mesh=getattr(designer, "stock_mesh", None))
    if process.wear_compensation:
        designer.process_progress(_SHARES["volume"], f"{candidate.name}: wear compensation")
        add_wear_compensation(designer, candidate, runs)
    return candidate.process


def add_wear_compensation(designer, candidate, runs):
    """Wear compensation by feed depth on every electrode of the candidate's process report.

    Per electrode: the front is the feed's last direction (electrode frame), the schedule follows from the
    wear per face (:func:`~.report.compensation_schedule`), and the cycle's
    ``reach.compensation_front`` / ``compensation_depths`` let the program run the j-th channel of an
    electrode's life moved that deep along the front
    (:meth:`~edm_planner.machining.cycle.MachiningCycle.with_compensation_depth`:
    certified by inclusion in the unworn electrode, no new certificate). The stored cycle is the first
    channel's, a fresh electrode's, at depth 0.
    """
    process = designer.process
    for p, run, e in zip(candidate.pieces, runs, candidate.process.electrodes):
        feed = next(leg for leg in p.cycle.legs if leg.phase == "feed")
        front = leg_direction(run, feed)
        depths = compensation_schedule(e, process.max_compensated_wear, designer.blisk.blade_count,
                                       front is not None and feed.removed_volume > 0)
        if not depths:
            _log.warning("%s: no wear compensation: %s", p.label, e.compensation["note"])
            continue
        e.compensation["front_direction"] = [round(float(v), 6) for v in front]
        p.cycle.reach.compensation_front = tuple(float(v) for v in front)
        p.cycle.reach.compensation_depths = tuple(float(d) for d in depths)
