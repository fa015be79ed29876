"""Machining a channel: the full cycle (copy processing), the automatic electrode set, the removal proof."""

from .. import deprecation
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
_MOVED_TO_RECORDS = ("plot_stock_maps", "stock_vertex_colours", "write_set")


def __getattr__(name):
    # PEP 562, a deprecated alias only: this import runs when an old name is asked for (machining imports no
    # records module at load time)
    if name in _MOVED_TO_RECORDS:
        from ..records import set_files, stock_maps
        value = globals()[name] = deprecation.moved_name(__name__, name, stock_maps, set_files)
        return value                      # kept: ``from edm_planner.machining import name`` asks twice, warns once
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
