"""Blade triangle meshes: build, load, validate and slice into sections.

* :func:`closed_blade_mesh` closes the two faces of a blade (sampled on one
  (S, C) grid) into a watertight, outward-wound solid with per-face labels.
* :func:`face_grid_mesh` triangulates one (S, C) grid as an open surface.
* :func:`load_blade_mesh` reads a CAD mesh (STL/OBJ/PLY, millimetres) and
  rejects anything that is not one closed, consistently wound body.
* :func:`mesh_to_sections` converts a closed blade mesh into the internal
  :class:`~edm_planner.geometry.sections.BladeSections` form by exact slicing:
  every station (x0, r0) is the circle ``{(x0, r0 cos t, r0 sin t)}``, cut with
  the mesh's cross-section in the plane ``x = x0``.

Units: millimetres and radians. Frame W: X is the blisk axis,
``theta = atan2(z, y)``.
"""

import logging
import os
from enum import IntEnum

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import GeometryError, GeometryFileError
from .sections import BladeSections

_log = logging.getLogger(__name__)

#: key of the per-face :class:`BladeFace` labels in ``mesh.face_attributes``
FACE_LABELS = "blade_face"

#: mesh file formats :func:`load_blade_mesh` accepts
MESH_SUFFIXES = (".stl", ".obj", ".ply")

#: plausible bounding-box diagonal of a blade in millimetres [mm]
_MIN_DIAGONAL = 1.0
_MAX_DIAGONAL = 10000.0

#: relative tolerance for merging coincident vertices (times the bbox diagonal)
_MERGE_REL = 1e-9


class BladeFace(IntEnum):
    """Label of a face of a closed blade mesh (``mesh.face_attributes['blade_face']``)."""

    MINUS = 0  #: the face looking towards -theta (pressure face)
    PLUS = 1  #: the face looking towards +theta (suction face)
    HUB = 2  #: end cap at section 0 (hub end)
    TIP = 3  #: end cap at section S-1 (tip / shroud end)
    EDGE = 4  #: closure of a leading or trailing edge with non-zero thickness


# --------------------------------------------------------------------------
# building meshes
# --------------------------------------------------------------------------

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
        :class:`BladeFace` code per face (int8, (F,)).

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

    add(_grid_quads(S, C, 0), True, BladeFace.MINUS)  # -t
    add(_grid_quads(S, C, n), False, BladeFace.PLUS)  # +t
    c = np.arange(C - 1)
    for s, flip, label in ((0, True, BladeFace.HUB), (S - 1, False, BladeFace.TIP)):
        # quads over (c, t): (c,0) (c+1,0) (c+1,1) (c,1); normal e_c x e_t = +s
        quads = np.stack([vid(0, s, c), vid(0, s, c + 1), vid(1, s, c + 1), vid(1, s, c)], -1)
        add(quads, flip, label)
    s = np.arange(S - 1)
    for cc, flip in ((0, False), (C - 1, True)):
        # quads over (s, t): (s,0) (s+1,0) (s+1,1) (s,1); normal e_s x e_t = -c
        quads = np.stack([vid(0, s, cc), vid(0, s + 1, cc), vid(1, s + 1, cc), vid(1, s, cc)], -1)
        add(quads, flip, BladeFace.EDGE)
    faces = np.concatenate(blocks)
    labels = np.concatenate(labels)

    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    if diagonal <= 0:
        raise GeometryError("blade faces: all points coincide")
    unique, inverse = _merge_close_vertices(vertices, _MERGE_REL * diagonal)
    faces = inverse[faces]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    faces, labels = faces[keep], labels[keep]

    mesh = trimesh.Trimesh(vertices=unique, faces=faces, process=False)
    mesh.face_attributes[FACE_LABELS] = labels
    if not mesh.is_watertight:
        raise GeometryError(
            f"blade faces: the closed blade mesh is not watertight ({_count_open_edges(mesh)} open edges); "
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


# --------------------------------------------------------------------------
# loading and validation
# --------------------------------------------------------------------------

def _count_open_edges(mesh):
    """Number of edges used by exactly one face."""
    if len(mesh.faces) == 0:
        return 0
    return len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1))


def _looks_like_stl(path):
    """True if the file is an ASCII STL or a binary STL of consistent size."""
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        head = fh.read(84)
    if head[:5].lower() == b"solid":
        return True
    if len(head) < 84:
        return False
    count = int(np.frombuffer(head[80:84], dtype="<u4")[0])
    return size == 84 + 50 * count


def load_blade_mesh(path):
    """Read and validate a closed blade mesh in millimetres.

    Parameters
    ----------
    path : str or os.PathLike
        STL, OBJ or PLY file of one blade.

    Returns
    -------
    mesh : trimesh.Trimesh
        One closed, consistently outward-wound body (vertices merged) [mm].
        Inverted normals are fixed with ``trimesh.repair.fix_normals`` (a
        warning is logged).

    Raises
    ------
    GeometryFileError
        Missing file, unsupported format, unreadable file or not a mesh.
    GeometryError
        Empty mesh, NaN/infinite vertices, implausible size (not
        millimetres), open (not watertight), inconsistent winding,
        non-positive volume or several bodies.
    """
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise GeometryFileError(f"blade mesh '{name}': file not found")
    suffix = os.path.splitext(name)[1].lower()
    if suffix not in MESH_SUFFIXES:
        raise GeometryFileError(
            f"blade mesh '{name}': unsupported format '{suffix}' (expected one of {', '.join(MESH_SUFFIXES)})")
    try:
        mesh = trimesh.load(name, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for bad files
        raise GeometryFileError(f"blade mesh '{name}': cannot be read as {suffix[1:].upper()} ({exc})") from exc
    if not isinstance(mesh, trimesh.Trimesh):
        raise GeometryFileError(f"blade mesh '{name}': not a triangle mesh ({type(mesh).__name__})")
    if len(mesh.faces) == 0:
        valid_empty = _looks_like_stl(name) if suffix == ".stl" else len(mesh.vertices) > 0
        if not valid_empty:
            raise GeometryFileError(f"blade mesh '{name}': no geometry could be read, not a {suffix[1:].upper()} mesh")
        raise GeometryError(f"blade mesh '{name}': the mesh is empty (no triangles)")
    vertices = np.asarray(mesh.vertices)
    if not np.all(np.isfinite(vertices)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(vertices), axis=1)))
        raise GeometryError(f"blade mesh '{name}': {bad} vertices are NaN or infinite")

    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise GeometryError(f"blade mesh '{name}': the mesh is empty (all triangles are degenerate)")

    diagonal = float(np.linalg.norm(mesh.extents))
    if diagonal < _MIN_DIAGONAL:
        raise GeometryError(
            f"blade mesh '{name}': bounding-box diagonal is {diagonal:.4g}, too small for a blade in "
            "millimetres; is the file in metres? (meshes must be in mm)")
    if diagonal > _MAX_DIAGONAL:
        raise GeometryError(
            f"blade mesh '{name}': bounding-box diagonal is {diagonal:.4g}, too large for a blade in "
            "millimetres; is the file in micrometres or another unit? (meshes must be in mm)")

    if not mesh.is_watertight:
        n_open = _count_open_edges(mesh)
        detail = f"{n_open} open edges" if n_open else "edges shared by more than two faces"
        raise GeometryError(f"blade mesh '{name}': not watertight ({detail}); a closed solid is required")
    if not mesh.is_winding_consistent:
        raise GeometryError(f"blade mesh '{name}': inconsistent winding (face orientations disagree)")
    bodies = connected_components(
        coo_matrix((np.ones(len(mesh.face_adjacency)),
                    (mesh.face_adjacency[:, 0], mesh.face_adjacency[:, 1])),
                   shape=(len(mesh.faces),) * 2),
        directed=False)[0]
    if bodies != 1:
        raise GeometryError(f"blade mesh '{name}': {bodies} separate bodies, expected exactly one blade")
    if not mesh.volume > 0:
        _log.warning("blade mesh '%s': non-positive volume %.6g (inverted normals), fixing the winding",
                     name, mesh.volume)
        trimesh.repair.fix_normals(mesh)
        if not mesh.volume > 0:
            raise GeometryError(
                f"blade mesh '{name}': volume {mesh.volume:.6g} mm^3 is not positive, even after fixing normals")
    return mesh


# --------------------------------------------------------------------------
# exact slicing into sections
# --------------------------------------------------------------------------

class _Slicer:
    """Cross-sections of a closed mesh by many planes ``x = x0`` at once.

    The mesh is rotated by ``-theta0`` about X so that the blade lies around
    angle 0 and ``atan2`` needs no unwrapping.
    """

    def __init__(self, mesh, theta0):
        v = np.asarray(mesh.vertices, dtype=np.float64)
        c, s = np.cos(theta0), np.sin(theta0)
        rot = np.column_stack([v[:, 0], c * v[:, 1] + s * v[:, 2], -s * v[:, 1] + c * v[:, 2]])
        tri = rot[np.asarray(mesh.faces)]  # (F, 3, 3)
        self.tri = np.ascontiguousarray(tri)
        self.xmin = tri[:, :, 0].min(axis=1)
        self.xmax = tri[:, :, 0].max(axis=1)

    def slice(self, x0):
        """Segments of the cross-sections at the planes ``x = x0``.

        Parameters
        ----------
        x0 : (P,) float

        Returns
        -------
        plane : (N,) int
            Plane index of each segment.
        a, b : (N, 2) float
            End points of each segment in the rotated (y, z) plane [mm].
        """
        x0 = np.asarray(x0, dtype=np.float64)
        order = np.argsort(x0, kind="stable")
        xs = x0[order]
        # a face crosses the plane when some vertex is below (d < 0) and some
        # is on or above (d >= 0): x0 in (xmin, xmax]
        lo = np.searchsorted(xs, self.xmin, side="right")
        hi = np.searchsorted(xs, self.xmax, side="right")
        count = hi - lo
        total = int(count.sum())
        face = np.repeat(np.arange(len(count)), count)
        start = np.cumsum(count) - count
        plane = order[lo[face] + np.arange(total) - start[face]]
        tri = self.tri[face]  # (N, 3, 3)
        d = tri[:, :, 0] - x0[plane, None]  # (N, 3)
        above = d >= 0
        # the lone vertex on its side of the plane, and the other two
        lone = np.where(above.sum(axis=1) == 1, np.argmax(above, axis=1), np.argmin(above, axis=1))
        k1, k2 = (lone + 1) % 3, (lone + 2) % 3
        rows = np.arange(len(face))
        d0, d1, d2 = d[rows, lone], d[rows, k1], d[rows, k2]
        p0, p1, p2 = tri[rows, lone, 1:], tri[rows, k1, 1:], tri[rows, k2, 1:]
        a = p0 + (d0 / (d0 - d1))[:, None] * (p1 - p0)
        b = p0 + (d0 / (d0 - d2))[:, None] * (p2 - p0)
        return plane, a, b

    def radial_range(self, x0):
        """Exact radial extent of the cross-sections.

        Returns
        -------
        r_lo, r_hi : (P,) float
            Smallest distance from the axis to the section and largest one
            (``inf``/``-inf`` where the plane misses the mesh) [mm].
        dip : (P,) float
            Largest amount by which a segment comes closer to the axis than
            both its end points (chords across a cap) [mm].
        """
        x0 = np.asarray(x0, dtype=np.float64)
        plane, a, b = self.slice(x0)
        ab = b - a
        length2 = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(-np.einsum("ij,ij->i", a, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        closest = np.linalg.norm(a + t[:, None] * ab, axis=1)
        ra, rb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        far = np.maximum(ra, rb)
        r_lo = np.full(len(x0), np.inf)
        r_hi = np.full(len(x0), -np.inf)
        dip = np.zeros(len(x0))
        np.minimum.at(r_lo, plane, closest)
        np.maximum.at(r_hi, plane, far)
        np.maximum.at(dip, plane, np.minimum(ra, rb) - closest)
        return r_lo, r_hi, dip

    def hits(self, x0, r0):
        """Does the circle (x0, r0) meet the mesh? (P,) bool."""
        r_lo, r_hi, _ = self.radial_range(x0)
        return (r_lo <= r0) & (r0 <= r_hi)

    def circle_angles(self, x0, r0, merge_tol):
        """Angles where the circles (x0, r0) cross the cross-sections.

        Parameters
        ----------
        x0, r0 : (P,) float
        merge_tol : float
            Crossings closer than this [mm] are one crossing (shared segment
            end points, tangency).

        Returns
        -------
        count : (P,) int
            Number of distinct crossings.
        t_min, t_max : (P,) float
            Smallest and largest crossing angle (rotated frame) [rad], NaN
            where there is no crossing.
        """
        x0 = np.asarray(x0, dtype=np.float64)
        r0 = np.asarray(r0, dtype=np.float64)
        P = len(x0)
        plane, a, b = self.slice(x0)
        ab = b - a
        qa = np.einsum("ij,ij->i", ab, ab)
        qb = 2.0 * np.einsum("ij,ij->i", a, ab)
        qc = np.einsum("ij,ij->i", a, a) - r0[plane] ** 2
        disc = qb * qb - 4.0 * qa * qc
        ok = (disc >= 0) & (qa > 0)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        q = -0.5 * (qb + np.copysign(sq, qb))
        safe_q = np.where(q != 0, q, 1.0)
        t1 = np.where(ok, q / np.where(qa > 0, qa, 1.0), np.nan)
        t2 = np.where(ok & (q != 0), qc / safe_q, t1)
        t = np.stack([t1, t2], axis=1)  # (N, 2)
        valid = ok[:, None] & (t >= 0.0) & (t <= 1.0)
        seg_idx, root = np.nonzero(valid)
        pts = a[seg_idx] + t[seg_idx, root, None] * ab[seg_idx]
        pl = plane[seg_idx]
        ang = np.arctan2(pts[:, 1], pts[:, 0])
        count = np.zeros(P, dtype=np.int64)
        t_min = np.full(P, np.nan)
        t_max = np.full(P, np.nan)
        if len(ang) == 0:
            return count, t_min, t_max
        o = np.lexsort((ang, pl))
        pl, ang = pl[o], ang[o]
        new = np.ones(len(ang), dtype=bool)
        new[1:] = (pl[1:] != pl[:-1]) | (np.diff(ang) * r0[pl[1:]] > merge_tol)
        np.add.at(count, pl[new], 1)
        first = np.ones(len(ang), dtype=bool)
        first[1:] = pl[1:] != pl[:-1]
        last = np.ones(len(ang), dtype=bool)
        last[:-1] = pl[1:] != pl[:-1]
        t_min[pl[first]] = ang[first]
        t_max[pl[last]] = ang[last]
        return count, t_min, t_max


def _mean_angle(mesh):
    """Circular mean of the vertex angles about X [rad]."""
    v = np.asarray(mesh.vertices)
    theta = np.arctan2(v[:, 2], v[:, 1])
    return float(np.arctan2(np.sin(theta).sum(), np.cos(theta).sum()))


def mesh_to_sections(mesh, n_sections=25, n_stations=81, *, span_margin=1e-3, edge_margin=1e-4,
                     n_footprint=256, n_scan=81):
    """Convert a closed blade mesh into :class:`BladeSections` by exact slicing.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        One closed blade of a blisk in W [mm] (X the rotation axis, the blade
        spanning radially, covering a small range of theta).
    n_sections : int
        S, number of sections from the hub-side to the tip-side bound (>= 2).
    n_stations : int
        C, number of chord stations per section, leading to trailing edge
        (>= 4), cosine-clustered towards both edges.
    span_margin : float
        Inset of the first and last section from the footprint's inner and
        outer radial bounds, as a fraction of the span (on top of the
        depth of chords across the caps).
    edge_margin : float
        Inset of the first and last station from the leading and trailing
        edge, as a fraction of the section's chord.
    n_footprint : int
        Number of planes used to find the meridional footprint.
    n_scan : int
        Samples along each section line used to bracket the edges (then
        refined by bisection).

    Returns
    -------
    sections : BladeSections
        (S, C) stations; ``theta_minus``/``theta_plus`` are the smallest and
        largest angle at which the station's circle meets the mesh, unwrapped
        around the blade's mean angle.

    Raises
    ------
    GeometryError
        Not a closed mesh, not a single blade (a circle meets the mesh in two
        separate intervals), or no usable footprint.

    Notes
    -----
    The footprint (the blade's projection on the (x, r) half-plane) is found
    from the exact radial extent ``[r_lo(x), r_hi(x)]`` of cross-sections at
    ``n_footprint`` planes. Its four corners (leading/trailing edge at
    hub/tip) split the lower bound into the hub-side curve and the upper
    bound into the tip-side curve. Section j is the curve
    ``(1 - f_j) H(u) + f_j T(u)`` between them (u the chord fraction along
    each curve), extended linearly beyond u in [0, 1]; its leading and
    trailing edge are found by bisection on "does the circle meet the mesh".
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise GeometryError("mesh_to_sections: expected a non-empty trimesh.Trimesh")
    if n_sections < 2 or n_stations < 4:
        raise GeometryError(
            f"mesh_to_sections: need at least 2 sections of 4 stations, got {n_sections} x {n_stations}")
    if not np.all(np.isfinite(mesh.vertices)):
        raise GeometryError("mesh_to_sections: mesh vertices contain NaN or infinite values")
    if not mesh.is_watertight:
        raise GeometryError(
            f"mesh_to_sections: blade mesh is not closed ({_count_open_edges(mesh)} open edges)")

    theta0 = _mean_angle(mesh)
    slicer = _Slicer(mesh, theta0)
    v = np.asarray(mesh.vertices)
    t_rel = np.arctan2(slicer.tri[..., 2], slicer.tri[..., 1])
    if np.max(np.abs(t_rel)) > 0.5 * np.pi:
        raise GeometryError(
            "mesh_to_sections: the mesh spans more than +-90 deg about its mean angle; "
            "expected one blade, not a whole blisk")
    diagonal = float(np.linalg.norm(np.ptp(v, axis=0)))
    merge_tol = _MERGE_REL * 10 * diagonal

    # --- meridional footprint ---------------------------------------------
    xmin, xmax = float(v[:, 0].min()), float(v[:, 0].max())
    if not xmax > xmin:
        raise GeometryError("mesh_to_sections: the mesh has no axial extent")
    xf = xmin + (xmax - xmin) * (np.arange(n_footprint) + 0.5) / n_footprint
    r_lo, r_hi, dip = slicer.radial_range(xf)
    good = np.isfinite(r_lo) & np.isfinite(r_hi)
    if np.count_nonzero(good) < 4:
        raise GeometryError("mesh_to_sections: no usable cross-sections of the mesh")
    xf, r_lo, r_hi, dip = xf[good], r_lo[good], r_hi[good], dip[good]
    rmin, rmax = float(r_lo.min()), float(r_hi.max())
    xn = (xf - xmin) / (xmax - xmin)
    rln = (r_lo - rmin) / (rmax - rmin)
    rhn = (r_hi - rmin) / (rmax - rmin)
    i_a = int(np.argmin(xn + rln))  # leading edge, hub
    i_b = int(np.argmax(xn - rln))  # trailing edge, hub
    i_d = int(np.argmin(xn - rhn))  # leading edge, tip
    i_c = int(np.argmax(xn + rhn))  # trailing edge, tip
    if i_b <= i_a or i_c <= i_d:
        raise GeometryError("mesh_to_sections: cannot identify the blade's hub and tip bounds in its footprint")
    span = float(np.median(r_hi - r_lo))
    inset = 1.5 * float(dip.max()) + span_margin * span
    hub_x, hub_r = xf[i_a:i_b + 1], r_lo[i_a:i_b + 1] + inset
    tip_x, tip_r = xf[i_d:i_c + 1], r_hi[i_d:i_c + 1] - inset
    if np.any(np.interp(np.linspace(0, 1, 33), (tip_x - tip_x[0]) / (tip_x[-1] - tip_x[0]), tip_r)
              <= np.interp(np.linspace(0, 1, 33), (hub_x - hub_x[0]) / (hub_x[-1] - hub_x[0]), hub_r)):
        raise GeometryError("mesh_to_sections: the blade's footprint is too thin in span")

    f = np.linspace(0.0, 1.0, n_sections)

    def section_points(u):
        """(x, r) of the section lines at chord parameters u, (S, U) each."""
        u = np.asarray(u, dtype=np.float64)
        if u.ndim == 1:
            u = np.broadcast_to(u, (n_sections, len(u)))
        uc = np.clip(u, 0.0, 1.0)

        def curve(cx, cr, uu):
            xx = cx[0] + uu * (cx[-1] - cx[0])
            return xx, np.interp(xx, cx, cr)

        hx, hr = curve(hub_x, hub_r, uc)
        tx, tr = curve(tip_x, tip_r, uc)
        x = (1 - f[:, None]) * hx + f[:, None] * tx
        r = (1 - f[:, None]) * hr + f[:, None] * tr
        # linear continuation beyond the ends with the end slopes
        du = 1.0 / (n_footprint - 1)
        for end, sign in ((0.0, 1.0), (1.0, -1.0)):
            outside = (u < 0) if end == 0.0 else (u > 1)
            if not np.any(outside):
                continue
            e = np.full((n_sections, 1), end)
            hx0, hr0 = curve(hub_x, hub_r, e)
            tx0, tr0 = curve(tip_x, tip_r, e)
            hx1, hr1 = curve(hub_x, hub_r, e + sign * du)
            tx1, tr1 = curve(tip_x, tip_r, e + sign * du)
            x0 = (1 - f[:, None]) * hx0 + f[:, None] * tx0
            r0 = (1 - f[:, None]) * hr0 + f[:, None] * tr0
            dx = ((1 - f[:, None]) * hx1 + f[:, None] * tx1 - x0) / (sign * du)
            dr = ((1 - f[:, None]) * hr1 + f[:, None] * tr1 - r0) / (sign * du)
            x = np.where(outside, x0 + (u - end) * dx, x)
            r = np.where(outside, r0 + (u - end) * dr, r)
        return x, r

    # --- leading and trailing edge of every section ------------------------
    reach = 0.25
    for _ in range(5):
        us = np.linspace(-reach, 1 + reach, n_scan)
        sx, sr = section_points(us)
        hit = slicer.hits(sx.ravel(), sr.ravel()).reshape(sx.shape)
        if not np.all(hit.any(axis=1)):
            s = int(np.argmin(hit.any(axis=1)))
            raise GeometryError(f"mesh_to_sections: section {s} does not meet the blade")
        if not np.any(hit[:, 0] | hit[:, -1]):
            break
        reach *= 2
    else:
        raise GeometryError("mesh_to_sections: cannot bracket the blade's leading and trailing edges")
    k_first = np.argmax(hit, axis=1)
    k_last = n_scan - 1 - np.argmax(hit[:, ::-1], axis=1)
    # brackets (miss, hit) for the leading edge and (hit, miss) for the trailing edge
    lo = np.concatenate([us[k_first - 1], us[k_last + 1]])
    hi = np.concatenate([us[k_first], us[k_last]])
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        mx, mr = section_points(np.stack([mid[:n_sections], mid[n_sections:]], axis=1))
        h = slicer.hits(mx.T.ravel(), mr.T.ravel())
        lo = np.where(h, lo, mid)
        hi = np.where(h, mid, hi)
        if np.max(np.abs(hi - lo)) < 1e-13:
            break
    u_le, u_te = hi[:n_sections], hi[n_sections:]
    if np.any(u_te <= u_le):
        raise GeometryError("mesh_to_sections: a section has no chord inside the blade")

    # --- stations and their circles -----------------------------------------
    k = np.arange(n_stations)
    w = edge_margin + (1 - 2 * edge_margin) * 0.5 * (1 - np.cos(np.pi * k / (n_stations - 1)))
    u = u_le[:, None] + (u_te - u_le)[:, None] * w[None, :]
    x, r = section_points(u)
    count, t_min, t_max = slicer.circle_angles(x.ravel(), r.ravel(), merge_tol)
    count = count.reshape(x.shape)
    bad = count != 2
    if np.any(bad):
        s, c = (int(i) for i in np.argwhere(bad)[np.argmax(count[bad])])
        n = int(count[s, c])
        if n > 2:
            raise GeometryError(
                f"mesh_to_sections: the circle x={x[s, c]:.4f} mm, r={r[s, c]:.4f} mm (section {s}, "
                f"station {c}) meets the mesh {n} times, i.e. in separate intervals: not a single blade")
        raise GeometryError(
            f"mesh_to_sections: the circle x={x[s, c]:.4f} mm, r={r[s, c]:.4f} mm (section {s}, "
            f"station {c}) meets the mesh {n} time(s) instead of twice")
    theta_minus = theta0 + t_min.reshape(x.shape)
    theta_plus = theta0 + t_max.reshape(x.shape)
    _log.debug("mesh_to_sections: %d x %d stations, x %.4g..%.4g mm, r %.4g..%.4g mm",
               n_sections, n_stations, x.min(), x.max(), r.min(), r.max())
    return BladeSections(x=x, r=r, theta_minus=theta_minus, theta_plus=theta_plus)
