"""Checks that a triangle mesh is one closed, consistently wound blade in millimetres.

* :func:`count_open_edges` counts the edges a single face uses (the holes).
* :func:`count_bodies` counts the face-connected bodies.
* :func:`check_blade_solid` rejects a mesh that is not one closed solid of a
  plausible size for a blade in millimetres, and turns an inside-out one
  outwards.

Units: millimetres.
"""

import logging

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..errors import GeometryError

_log = logging.getLogger(__name__)

#: plausible bounding-box diagonal of a blade in millimetres [mm]
MIN_DIAGONAL = 1.0
MAX_DIAGONAL = 10000.0


def count_open_edges(mesh):
    """Number of edges used by exactly one face."""
    if len(mesh.faces) == 0:
        return 0
    return len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1))


def count_bodies(mesh):
    """Number of separate bodies (sets of faces connected through shared edges)."""
    return connected_components(
        coo_matrix((np.ones(len(mesh.face_adjacency)),
                    (mesh.face_adjacency[:, 0], mesh.face_adjacency[:, 1])),
                   shape=(len(mesh.faces),) * 2),
        directed=False)[0]


def check_blade_solid(mesh, where):
    """Reject a mesh that is not one closed blade in millimetres; fix inverted normals in place.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Non-empty, finite vertices, coincident vertices merged [mm].
    where : str
        Names the mesh in error messages, e.g. ``"blade mesh 'blade.stl'"``.

    Returns
    -------
    mesh : trimesh.Trimesh
        The same object, outward-wound (``trimesh.repair.fix_normals`` applied,
        with a warning logged, when its volume was not positive).

    Raises
    ------
    GeometryError
        Implausible size (not millimetres), open (not watertight),
        inconsistent winding, several bodies, or non-positive volume even
        after fixing the normals.
    """
    diagonal = float(np.linalg.norm(mesh.extents))
    if diagonal < MIN_DIAGONAL:
        raise GeometryError(
            f"{where}: bounding-box diagonal is {diagonal:.4g}, too small for a blade in "
            "millimetres; is the file in metres? (meshes must be in mm)")
    if diagonal > MAX_DIAGONAL:
        raise GeometryError(
            f"{where}: bounding-box diagonal is {diagonal:.4g}, too large for a blade in "
            "millimetres; is the file in micrometres or another unit? (meshes must be in mm)")

    if not mesh.is_watertight:
        n_open = count_open_edges(mesh)
        detail = f"{n_open} open edges" if n_open else "edges shared by more than two faces"
        raise GeometryError(f"{where}: not watertight ({detail}); a closed solid is required")
    if not mesh.is_winding_consistent:
        raise GeometryError(f"{where}: inconsistent winding (face orientations disagree)")
    bodies = count_bodies(mesh)
    if bodies != 1:
        raise GeometryError(f"{where}: {bodies} separate bodies, expected exactly one blade")
    if not mesh.volume > 0:
        _log.warning("%s: non-positive volume %.6g (inverted normals), fixing the winding",
                     where, mesh.volume)
        trimesh.repair.fix_normals(mesh)
        if not mesh.volume > 0:
            raise GeometryError(
                f"{where}: volume {mesh.volume:.6g} mm^3 is not positive, even after fixing normals")
    return mesh
