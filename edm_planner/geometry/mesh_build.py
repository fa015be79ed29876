"""Building blade triangle meshes from grids of points.

* :func:`closed_blade_mesh` closes the two faces of a blade (sampled on one
  (S, C) grid) into a watertight, outward-wound solid, every triangle
  labelled with the :class:`MeshFaceLabel` of the part of the blade it
  belongs to.
* :func:`face_grid_mesh` triangulates one (S, C) grid as an open surface.

Units: millimetres. Frame W: X is the blisk axis, ``theta = atan2(z, y)``.
"""

import logging
from enum import IntEnum

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import GeometryError
from .mesh_validate import count_open_edges

_log = logging.getLogger(__name__)

#: key of the per-face :class:`MeshFaceLabel` codes in ``mesh.face_attributes``
FACE_LABELS = "blade_face"

#: relative tolerance for merging coincident vertices (times the bbox diagonal)
MERGE_REL = 1e-9


class MeshFaceLabel(IntEnum):
    """Which part of a closed blade mesh a triangle belongs to (``mesh.face_attributes['blade_face']``).

    Not to be confused with :class:`~.surfaces.BladeFace`, the spline surface
    of one face of a blade; this enum was called ``BladeFace`` before.
    """

    MINUS = 0  #: the face looking towards -theta (pressure face)
    PLUS = 1  #: the face looking towards +theta (suction face)
    HUB = 2  #: end cap at section 0 (hub end)
    TIP = 3  #: end cap at section S-1 (tip / shroud end)
    EDGE = 4  #: closure of a leading or trailing edge with non-zero thickness


def _check_grid(points, name):
    p = np.array(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 3:
        raise GeometryError(f"{name}: expected an (S, C, 3) array of points, got shape {p.shape}")
    if p.shape[0] < 2 or p.shape[1] < 2:
        raise GeometryError(f"{name}: need at least a 2 x 2 grid of points, got {p.shape[0]} x {p.shape[1]}")
    if not np.all(np.isfinite(p)):
        raise GeometryError(f"{name}: points contain NaN or infinite values")
    return p


def _grid_quads(S, C, offset=0):
    """Vertex indices of the cells of an (S, C) grid, corners (s,c), (s+1,c), (s+1,c+1), (s,c+1).

    Returns
    -------
    quads : ((S-1)*(C-1), 4) int
    """
    idx = np.arange(S * C).reshape(S, C) + offset
    return np.stack(
        [idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)


def _split_quads(quads, flip=False):
    """Two triangles per quad (a, b, c, d), split along a-c, wound a->b->c (or reversed).

    Returns
    -------
    faces : (2 n, 3) int
        Triangles of quad k at rows 2k and 2k+1.
    """
    a, b, c, d = quads.T
    tri = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=1).reshape(-1, 3)
    return tri[:, ::-1].copy() if flip else tri


def face_grid_mesh(points, flip=False):
    """Open triangle mesh of one grid of points, two triangles per cell.

    Parameters
    ----------
    points : (S, C, 3) float
        Grid of Cartesian points [mm] (e.g. a blade face, a hub or shroud
        patch of a channel), S, C >= 2.
    flip : bool
        Normal side. With ``flip=False`` the face normals point along
        ``dP/ds x dP/dc`` (s: first grid index, c: second); ``flip=True``
        reverses every triangle.

    Returns
    -------
    mesh : trimesh.Trimesh
        ``2 (S-1)(C-1)`` triangles; vertex ``s*C + c`` is ``points[s, c]``
        (vertices are not merged), cell (s, c) gives faces
        ``2 (s (C-1) + c)`` and ``2 (s (C-1) + c) + 1``.
    """
    p = _check_grid(points, "face grid")
    S, C, _ = p.shape
    faces = _split_quads(_grid_quads(S, C), flip=flip)
    return trimesh.Trimesh(vertices=p.reshape(-1, 3), faces=faces, process=False)


def _merge_close_vertices(vertices, tol):
    """Map every vertex to one representative of its cluster of points closer than ``tol``.

    Returns
    -------
    unique : (m, 3) float
    inverse : (n,) int
        ``vertices[i]`` becomes ``unique[inverse[i]]``.
    """
    n = len(vertices)
    pairs = cKDTree(vertices).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return vertices, np.arange(n)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    # first vertex of each cluster is its representative, clusters numbered in order
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return vertices[np.sort(first)], rank[inverse]


def closed_blade_mesh(minus, plus):
    """Close the two faces of a blade into a watertight, outward-wound solid.

    Parameters
    ----------
    minus, plus : (S, C, 3) float
        The blade's -theta and +theta faces sampled on the same grid [mm]:
        section 0 at the hub end, S-1 at the tip end, station 0 the leading
        and C-1 the trailing edge. The faces may touch along station 0 and/or
        C-1 (zero edge thickness), fully or only at some sections.

    Returns
    -------
    mesh : trimesh.Trimesh
        Closed triangle mesh (``is_watertight``, ``is_winding_consistent``,
        ``volume > 0``): the two faces, the edge closures where the thickness
        is non-zero and the hub and tip caps (the strip between the minus and
        plus rows of section 0 and S-1). Coincident vertices (closer than
        1e-9 of the bounding-box diagonal) are merged and the triangles that
        collapse are dropped. ``mesh.face_attributes['blade_face']`` holds one
        :class:`MeshFaceLabel` code per face (int8, (F,)).

    Raises
    ------
    GeometryError
        Bad shapes or values, or faces that do not bound a solid (crossing
        faces, zero volume, ...).
    """
    m = _check_grid(minus, "blade minus face")
    p = _check_grid(plus, "blade plus face")
    if m.shape != p.shape:
        raise GeometryError(f"blade faces: minus {m.shape} and plus {p.shape} grids differ in shape")
    S, C, _ = m.shape
    n = S * C
    vertices = np.concatenate([m.reshape(-1, 3), p.reshape(-1, 3)])

    def vid(t, s, c):
        # vertex index of face t (0 minus, 1 plus) at section s, station c
        return t * n + np.asarray(s) * C + np.asarray(c)

    # Orientation by construction on the parameter box (s, c, t): outward
    # normals -t (minus), +t (plus), -s (hub), +s (tip), -c (LE), +c (TE).
    # A triangle a->b->c over the (u, v) quad has normal e_u x e_v; the cyclic
    # order (s, c, t) gives e_s x e_c = e_t, e_c x e_t = e_s, e_t x e_s = e_c.
    blocks, labels = [], []

    def add(quads, flip, label):
        tri = _split_quads(quads, flip=flip)
        blocks.append(tri)
        labels.append(np.full(len(tri), label, dtype=np.int8))

    add(_grid_quads(S, C, 0), True, MeshFaceLabel.MINUS)  # -t
    add(_grid_quads(S, C, n), False, MeshFaceLabel.PLUS)  # +t
    c = np.arange(C - 1)
    for s, flip, label in ((0, True, MeshFaceLabel.HUB), (S - 1, False, MeshFaceLabel.TIP)):
        # quads over (c, t): (c,0) (c+1,0) (c+1,1) (c,1); normal e_c x e_t = +s
        quads = np.stack([vid(0, s, c), vid(0, s, c + 1), vid(1, s, c + 1), vid(1, s, c)], -1)
        add(quads, flip, label)
    s = np.arange(S - 1)
    for cc, flip in ((0, False), (C - 1, True)):
        # quads over (s, t): (s,0) (s+1,0) (s+1,1) (s,1); normal e_s x e_t = -c
        quads = np.stack([vid(0, s, cc), vid(0, s + 1, cc), vid(1, s + 1, cc), vid(1, s, cc)], -1)
        add(quads, flip, MeshFaceLabel.EDGE)
    faces = np.concatenate(blocks)
    labels = np.concatenate(labels)

    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    if diagonal <= 0:
        raise GeometryError("blade faces: all points coincide")
    unique, inverse = _merge_close_vertices(vertices, MERGE_REL * diagonal)
    faces = inverse[faces]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    faces, labels = faces[keep], labels[keep]

    mesh = trimesh.Trimesh(vertices=unique, faces=faces, process=False)
    mesh.face_attributes[FACE_LABELS] = labels
    if not mesh.is_watertight:
        raise GeometryError(
            f"blade faces: the closed blade mesh is not watertight ({count_open_edges(mesh)} open edges); "
            "do the faces touch or cross away from the edges?")
    if not mesh.is_winding_consistent:
        raise GeometryError("blade faces: the closed blade mesh is not consistently wound (faces cross?)")
    volume = mesh.volume
    if abs(volume) <= 1e-12 * diagonal ** 3:
        raise GeometryError("blade faces: the minus and plus faces enclose no volume")
    if volume < 0:
        mesh.invert()
    _log.debug("closed blade mesh: %d vertices, %d faces, volume %.6g mm^3",
               len(mesh.vertices), len(mesh.faces), mesh.volume)
    return mesh
