"""Interference checking: clearance of electrode poses to the channel surfaces.

* :mod:`.exact_points` -- exact signed distance of points to the model
  surfaces (reconstructed spline blade faces; hub and shroud reduced to the
  (x, r) half-plane, Chen & Dong eq. 4-8). The reference for everything else.
* :mod:`.mesh_exact` -- exact triangle-mesh clearance of the electrode mesh
  (python-fcl), which also sees contact between sample points.
* :mod:`.fast` -- a precomputed distance field for search, with a measured
  error bound (:class:`~.fast.FastChannelField`). Its parts live by concern:
  :mod:`.field_params` (the kernels' named arguments), :mod:`.field_layout`
  (the grid's extents and the solvers' start samples), :mod:`.field_build`
  (the grid fill), :mod:`.field_query` (per point and per pose),
  :mod:`.exact_solvers` (the exact blade and profile solvers),
  :mod:`.min_search` (the exact minimum over a pose sequence),
  :mod:`.field_error` (the measured error bound), :mod:`.field_cache` (the
  disk cache) and :mod:`.field_lock` (one build at a time).
* :mod:`.wall_features` -- the walls' sharp features (blade edges, blunt
  ends) against the electrode's triangles.
* :mod:`.pose_check` -- the exact re-check of a pose sequence: every electrode
  vertex at every pose (``verify_poses``; an exported plan's re-check is
  :mod:`edm_planner.records.plan_check`).
* :mod:`.criteria` -- the papers' criteria (Huang eq. 3 and the
  neighbour-angle test).
* :mod:`.segment` -- continuous certification of a motion segment.
"""

#: order of the four channel surfaces in every array of clearances
SURFACES = ("suction", "pressure", "hub", "shroud")
