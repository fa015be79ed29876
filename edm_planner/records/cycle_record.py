"""A machining cycle as a plan-store record's ``meta`` and ``arrays``: every leg's samples verbatim, stacked.

The store (:mod:`.store`) keeps a cycle this way and the certificate digest (:mod:`.certificate`) is computed
from the cycle read back from it. Units: mm, rad. No rclpy.
"""

import numpy as np

from ..machining.cycle import ClearZone, Leg, MachiningCycle, ProcessReach


def cycle_to_record(cycle):
    """A MachiningCycle as (meta, arrays) of a record: every leg's samples verbatim, stacked ({}, {} for None)."""
    if cycle is None:
        return {}, {}
    legs = cycle.legs
    meta = {"cycle": {"axis_names": list(cycle.axis_names), "phases": [leg.phase for leg in legs],
                      "labels": [leg.label for leg in legs], "reach": cycle.reach.to_dict(),
                      "margin": float(cycle.margin), "certified": bool(cycle.certified), "message": cycle.message,
                      "clear_zone": cycle.clear_zone.to_dict() if cycle.clear_zone is not None else None,
                      "regimes": [leg.regime for leg in legs],
                      "removed_volume_mm3": [None if not np.isfinite(leg.removed_volume) else float(leg.removed_volume)
                                             for leg in legs]}}
    arrays = {"cycle_leg_samples": np.vstack([np.asarray(leg.samples, dtype=np.float64) for leg in legs]),
              "cycle_leg_lengths": np.array([len(leg.samples) for leg in legs], dtype=np.int64),
              "cycle_min_clearance": np.vstack([np.asarray(leg.clearance_lower_bound, dtype=np.float64).reshape(4)
                                                for leg in legs])}
    return meta, arrays


def cycle_from_record(meta, arrays):
    """The MachiningCycle of a record's meta and arrays, legs bit for bit; None when it has none."""
    c = meta.get("cycle")
    if not c:
        return None
    samples, lengths = arrays["cycle_leg_samples"], arrays["cycle_leg_lengths"]
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    regimes = c.get("regimes") or [""] * len(c["phases"])              # records before the process model: none
    volumes = c.get("removed_volume_mm3") or [None] * len(c["phases"])
    legs = [Leg(phase, label, samples[a:b].copy(), arrays["cycle_min_clearance"][i].copy(), regimes[i],
                float("nan") if volumes[i] is None else float(volumes[i]))
            for i, (phase, label, a, b) in enumerate(zip(c["phases"], c["labels"], bounds[:-1], bounds[1:]))]
    return MachiningCycle(tuple(c["axis_names"]), legs, ProcessReach.from_dict(c["reach"]), c["margin"],
                          c["certified"], c["message"], ClearZone.from_dict(c.get("clear_zone")))
