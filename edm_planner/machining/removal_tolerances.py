"""Settings and numerical tolerances of the material-removal simulation, in one place.

Used by the signed distance (:mod:`.mesh_distance`), the stock of electrode sweeps (:mod:`.swept_stock`),
the wall samples (:mod:`.wall_samples`, :mod:`.corner_rounding`) and the report (:mod:`.removal`).
Units: mm.
"""

from dataclasses import dataclass


#: depths [mm] of the extra sample rows inside every surface edge (see wall_samples)
REMOVAL_EDGE_DEPTHS = (0.005, 0.01, 0.02, 0.03, 0.045, 0.07, 0.1)


@dataclass(frozen=True)
class RemovalTolerances:
    """Settings and numerical tolerances of the removal simulation [mm]."""

    #: stock above this is "not done" [mm]
    stock: float = 0.02
    #: wall sample spacing, the largest distance between neighbouring samples [mm]
    spacing: float = 0.2
    #: samples on a hub/shroud radius are evaluated this far inside the channel for the
    #: wall angles, whose spline footprint may report "outside" exactly on its edge [mm]
    wall_inset: float = 1e-6
    #: barycentric coordinate below which a closest point is on an edge or vertex
    #: (selects the pseudonormal; looser than igl's 1e-12, safe for any dihedral < 180 deg)
    barycentric: float = 1e-9
    #: added to every travel bound so that rounding never prunes a pair that ties [mm]
    travel_safety: float = 1e-9
    #: (point, pose) pairs per distance query batch (memory ~50 bytes each)
    batch: int = 250_000
    #: coarse grid per sample direction used to size the wall grids
    pilot: int = 161
    #: most sample rows or columns of one surface (the grid stops refining there; its spacing is reported)
    max_grid: int = 3000


REMOVAL = RemovalTolerances()
