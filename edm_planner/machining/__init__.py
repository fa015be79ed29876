"""Machining a channel: the full cycle (copy processing), the automatic electrode set, the removal proof."""

from .cycle import PHASES, CycleBuilder, CycleOptions, Leg, MachiningCycle, ProcessReach
from .electrode_set import Candidate, ElectrodeSet, Piece, SetDesigner, SetOptions, write_set
from .removal import (RemovalReport, Sweep, SurfaceStock, WallSamples, plot_stock_maps, simulate_removal,
                      stock_at_points, stock_vertex_colours, wall_samples)

__all__ = ["PHASES", "CycleBuilder", "CycleOptions", "Leg", "MachiningCycle", "ProcessReach",
           "Candidate", "ElectrodeSet", "Piece", "SetDesigner", "SetOptions", "write_set",
           "RemovalReport", "Sweep", "SurfaceStock", "WallSamples", "plot_stock_maps", "simulate_removal",
           "stock_at_points", "stock_vertex_colours", "wall_samples"]
