"""Bench suite ``electrode_set`` (issues 12, 24): the automatic electrode set of channel 0 on four blisks.

For the default blisk, NASA Rotor 37, the mesh blisk and the blisk72 regression
case (``test/cases/blisk72``): the set chosen, every
candidate's outcome, the stock left per surface (largest, mean, share of the
area above the tolerance; exact at the wall samples) and the overcut, the
cycle time per channel and for the whole blisk on ``config/machine.yaml``
(each leg timed rest to rest by the axis bridge's timing; tool changes not
counted), and the time to design the set: the whole (``design_s``), the set itself (``set_s``: sizing,
certified cycles, removal proofs, the choice) and the delivered set's EDM process after it
(``process_step_s``: roughing twins, removed volume, erosion time, wear; issue 25). Targets (issue 12): stock at most
0.02 mm over at least 99 % of every wall's area, no overcut beyond the
tolerance, the set designed in 60 s or less. Per candidate, the certificate's
bound and the removal proof's smallest distance side by side (issue 24). The
distance field is built or loaded before the clock starts.
"""

import logging
import time

from ..cli import DEFAULT_CACHE
from ..errors import EdmError
from ..geometry.loader import load_geometry
from ..interference.fast import FastChannelField
from ..cnc.config import load_machine
from ..cnc.trajectory import time_run
from ..machining.electrode_set import SetDesigner
from ..machining.program import PlanCycle, blisk_program_steps, program_runs
from ..process.set_process import add_process
from .common import BLISKS, CONFIG, DESIGNED

_log = logging.getLogger(__name__)


def cycle_times(plans, blade_count, pitch, machine, labels=None):
    """(per electrode: one channel's cycle [s], whole blisk [s]) on ``machine``.

    ``labels`` names the electrodes (the set's piece labels, in the order of
    ``plans``); without them, the plans' electrode ids, which the pieces of a
    "three axial pieces" set share ("main").
    """

    labels = [p.electrode_id for p in plans] if labels is None else list(labels)
    if len(labels) != len(plans) or len(set(labels)) != len(labels):
        raise ValueError(f"cycle_times: one distinct label per plan, got {labels}")
    cycles = {p.plan_id: PlanCycle.of_plan(p) for p in plans}
    per_channel = {}
    for label, p in zip(labels, plans):
        (run,) = program_runs([(p.plan_id, p.channel)], cycles, pitch)
        per_channel[label] = float(time_run(run.legs, machine).duration)
    cache = {}
    runs = program_runs(blisk_program_steps([p.plan_id for p in plans], blade_count), cycles, pitch)
    whole = sum(float(time_run(run.legs, machine, cache=cache).duration) for run in runs)
    return per_channel, whole


def bench_electrode_set(blisks=BLISKS):
    cache = DEFAULT_CACHE
    machine = load_machine(CONFIG / "machine.yaml")
    out = {"machine": "config/machine.yaml", "tolerance_mm": 0.02, "area_share_target": 0.99, "time_target_s": 60}
    for name in blisks:
        g = load_geometry(BLISKS[name])
        field = FastChannelField(g.blisk, spacing=0.1, cache_dir=cache, cache_key=g.geometry_id)
        t = time.perf_counter()
        process_start = []                           # when the designer turned to the delivered set's process

        def progress(stage, fraction, message):
            if not process_start and "the EDM process" in message:
                process_start.append(time.perf_counter())

        result = SetDesigner(g, field, field_cache=(cache, g.geometry_id), process=machine.process,
                             process_step=add_process, progress=progress).design(0)
        end = time.perf_counter()
        design_s = end - t
        DESIGNED[name] = (g, result)                 # the process suite reuses it when it runs next
        # the set (sizing, certified cycles, removal proofs, the choice) and, after it, the delivered set's EDM
        # process (roughing twins sized, certified and proven; removed volume, erosion time, wear)
        set_s = (process_start[0] if process_start else end) - t
        entry = {"design_s": round(design_s, 1), "set_s": round(set_s, 1), "process_step_s": round(design_s - set_s, 1),
                 "message": result.message[:600],
                 "candidates": {c.name: {"status": c.status, "reason": c.reason[:300],
                                         "certificate_vs_proof": c.truth} for c in result.candidates}}
        if result.delivered is not None:
            chosen = result.delivered
            entry["delivered"] = chosen.name
            entry["meets_tolerance"] = result.success
            entry["electrodes"] = [{"label": p.label, "plan_id": p.plan.plan_id,
                                    "circumferential_reduction_rad": round(p.design.circumferential_reduction, 5),
                                    "radial_reduction_mm": round(p.design.radial_reduction, 3),
                                    "volume_mm3": round(p.volume, 1)} for p in chosen.pieces]
            entry["removal"] = chosen.removal.to_dict()
            entry["process_s"] = round(chosen.process.seconds, 1) if chosen.process is not None else None
            try:
                per_channel, whole = cycle_times(result.plans, g.blisk.blade_count, g.blisk.pitch, machine,
                                                 labels=[p.label for p in chosen.pieces])
                entry["cycle_s_per_channel"] = {k: round(v, 1) for k, v in per_channel.items()}
                entry["whole_blisk_s"] = round(whole, 1)
            except EdmError as e:        # the set's figures stand; the machine cannot run it, and says why
                entry["cycle_error"] = f"{e.code.name}: {e.message}"
                _log.error("electrode set %s: the cycle cannot be timed on config/machine.yaml: %s", name, e)
            entry["meets_targets"] = {
                "stock_strict": all(s.area_fraction_above_tolerance <= 0.01 for s in chosen.removal.surfaces.values()),
                "stock_beyond_corner_rounding": all(s.area_fraction_beyond_inherent <= 0.01
                                                    for s in chosen.removal.surfaces.values()),
                "overcut": chosen.removal.overcut_max <= 0.02, "time": design_s <= 60, "set_time": set_s <= 60}
        else:
            proven = [c for c in result.candidates if c.removal is not None]
            if proven:
                best = min(proven, key=lambda c: max(s.area_fraction_beyond_inherent
                                                     for s in c.removal.surfaces.values()))
                entry["closest_candidate"] = {"name": best.name, "removal": best.removal.to_dict()}
        out[name] = entry
        _log.warning("electrode set %s: %s", name, entry)
    return out
