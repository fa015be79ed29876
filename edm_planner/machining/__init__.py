"""Machining: the removal simulation (what a channel becomes after EDM)."""

from .removal import (RemovalReport, Sweep, SurfaceStock, WallSamples, plot_stock_maps, simulate_removal,
                      stock_at_points, stock_vertex_colours, wall_samples)

__all__ = ["RemovalReport", "Sweep", "SurfaceStock", "WallSamples", "plot_stock_maps", "simulate_removal",
           "stock_at_points", "stock_vertex_colours", "wall_samples"]
