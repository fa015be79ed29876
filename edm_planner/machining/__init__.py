"""Machining a channel: the full cycle (copy processing), the automatic electrode set, the removal proof."""

import warnings

from .cycle import PHASES, CycleBuilder, CycleOptions, Leg, MachiningCycle, ProcessReach
from .electrode_set import Candidate, ElectrodeSet, Piece, SetDesigner, SetOptions
from .removal import RemovalReport, SurfaceStock, simulate_removal
from .swept_stock import Sweep, stock_at_points
from .wall_samples import WallSamples, wall_samples

__all__ = ["PHASES", "CycleBuilder", "CycleOptions", "Leg", "MachiningCycle", "ProcessReach",
           "Candidate", "ElectrodeSet", "Piece", "SetDesigner", "SetOptions",
           "RemovalReport", "Sweep", "SurfaceStock", "WallSamples", "simulate_removal",
           "stock_at_points", "wall_samples"]

#: names that moved up to the records layer (files and pictures): deprecated aliases here, for one release
_MOVED_TO_RECORDS = {"plot_stock_maps": "stock_maps", "stock_vertex_colours": "stock_maps", "write_set": "set_files"}


def __getattr__(name):
    # PEP 562: a lazy import keeps the old names working, with a warning (machining must not import records)
    if name in _MOVED_TO_RECORDS:
        module = _MOVED_TO_RECORDS[name]
        warnings.warn(f"edm_planner.machining.{name} moved to edm_planner.records.{module}.{name}",
                      DeprecationWarning, stacklevel=2)
        if module == "stock_maps":
            from ..records import stock_maps as moved
        else:
            from ..records import set_files as moved
        value = globals()[name] = getattr(moved, name)   # warned once: ``from`` asks twice
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
