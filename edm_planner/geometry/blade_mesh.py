"""Blade triangle meshes: build, load, validate and slice into sections.

* :func:`closed_blade_mesh` closes the two faces of a blade (sampled on one
  (S, C) grid) into a watertight, outward-wound solid with per-face labels.
* :func:`face_grid_mesh` triangulates one (S, C) grid as an open surface.
* :func:`load_blade_mesh` reads a CAD mesh (STL/OBJ/PLY, millimetres) and
  rejects anything that is not one closed, consistently wound body.
* :func:`mesh_to_sections` converts a closed blade mesh into the internal
  :class:`~edm_planner.geometry.sections.BladeSections` form by exact slicing:
  every station (x0, r0) is the circle ``{(x0, r0 cos t, r0 sin t)}``, cut with
  the mesh's cross-section in the plane ``x = x0``. Given the hub and shroud,
  it slices only the span the channel needs (their wall overlap included), so
  a CAD blade may run past the walls, closed by caps of any shape there.

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

#: deepest end zone of a cross-section taken for an end cap dipping into the blade and
#: left out of the slicing, as a fraction of the blade's span (mesh_to_sections)
_MAX_CAP_DEPTH = 0.05

#: a face whose unit normal has a radial component of at least this is part of an end cap
#: (mesh_to_sections)
_CAP_NORMAL = 0.9

#: a circle crossing into the blade through a face whose unit normal has a +theta
#: component above this (or out of it through one below minus this) crosses faces
#: the wrong way: the mesh intersects itself (mesh_to_sections)
_CROSSED_FACES = 0.1


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


def _stl_problem(path):
    """Why the file cannot be an STL ('' when it may be one): checked on its bytes, before a parser sees it.

    A binary STL is 84 bytes (80 of header, the triangle count) and 50 per triangle; anything else must be
    ASCII STL: text (UTF-8, of which ASCII is part) starting with ``solid``.
    """
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        head = fh.read(84)
        count = int(np.frombuffer(head[80:84], dtype="<u4")[0]) if len(head) == 84 else None
        if count is not None and size == 84 + 50 * count:
            return ""                                  # binary (its header may start with "solid", too)
        if head[:5].lower() == b"solid":
            fh.seek(0)
            try:
                fh.read().decode("utf-8")
            except UnicodeDecodeError as exc:
                return (f"not an STL: it starts like ASCII STL ('solid') but is not text (byte {exc.start} is "
                        f"not UTF-8), nor a binary STL of consistent size")
            return ""
    binary = (f"a binary STL of consistent size (84 bytes + 50 per triangle: the {count} triangles its header "
              f"announces would make {84 + 50 * count} bytes, the file has {size})" if count is not None else
              f"a binary STL (at least 84 bytes, the file has {size})")
    return f"not an STL: neither {binary} nor ASCII STL text starting with 'solid'"


def _looks_like_stl(path):
    """True if the file is an ASCII STL or a binary STL of consistent size."""
    return not _stl_problem(path)


def load_blade_mesh(path, max_bytes=None):
    """Read and validate a closed blade mesh in millimetres.

    Parameters
    ----------
    path : str or os.PathLike
        STL, OBJ or PLY file of one blade.
    max_bytes : int, optional
        Size limit of the file, checked before anything reads it (None: none; the geometry loader passes
        its ``max_mesh_bytes``).

    Returns
    -------
    mesh : trimesh.Trimesh
        One closed, consistently outward-wound body (vertices merged) [mm].
        Inverted normals are fixed with ``trimesh.repair.fix_normals`` (a
        warning is logged).

    Raises
    ------
    GeometryFileError
        Missing file, larger than ``max_bytes``, unsupported format, unreadable file (an STL that is
        neither binary of consistent size nor ASCII text: said so) or not a mesh.
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
    if max_bytes is not None:
        from .loader import check_file_size

        check_file_size(name, max_bytes, f"blade mesh '{name}'", "mesh")
    if suffix == ".stl":
        try:
            problem = _stl_problem(name)
        except OSError as exc:
            raise GeometryFileError(f"blade mesh '{name}': cannot be read ({exc.strerror or exc})") from None
        if problem:
            raise GeometryFileError(f"blade mesh '{name}': {problem}")
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
        # unit face normals in the rotated frame (zero for degenerate triangles)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1)
        self.normal = n / np.where(length > 0, length, 1.0)[:, None]

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
        face : (N,) int
            The mesh face each segment cuts.
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
        return plane, a, b, face

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
        plane, closest, near, far = self._radial_intervals(x0)
        r_lo = np.full(len(x0), np.inf)
        r_hi = np.full(len(x0), -np.inf)
        dip = np.zeros(len(x0))
        np.minimum.at(r_lo, plane, closest)
        np.maximum.at(r_hi, plane, far)
        np.maximum.at(dip, plane, near - closest)
        return r_lo, r_hi, dip

    def _radial_intervals(self, x0, with_normal=False):
        """Per segment of the cross-sections: plane, closest, nearer-end and farther-end radius [mm].

        With ``with_normal`` also the radial component of the unit normal of
        the face each segment cuts (at the segment's middle).
        """
        plane, a, b, face = self.slice(x0)
        ab = b - a
        length2 = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(-np.einsum("ij,ij->i", a, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        closest = np.linalg.norm(a + t[:, None] * ab, axis=1)
        ra, rb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        out = (plane, closest, np.minimum(ra, rb), np.maximum(ra, rb))
        if with_normal:
            mid = 0.5 * (a + b)
            e_r = mid / np.maximum(np.linalg.norm(mid, axis=1), 1e-300)[:, None]
            out += (np.einsum("ij,ij->i", self.normal[face, 1:], e_r),)
        return out

    def end_caps(self, x0, cos_min):
        """Radial range of the end caps of each plane's cross-section.

        A cap segment cuts a face whose unit normal points along +r (tip
        end, in the outer half of the cross-section's radial extent) or -r
        (hub end, inner half) with a component of at least ``cos_min``.

        Returns
        -------
        hub_cap_hi : (P,) float
            Largest radius of the hub-end cap segments [mm] (-inf if none).
        tip_cap_lo : (P,) float
            Smallest radius (closest approach) of the tip-end cap segments [mm]
            (inf if none).
        """
        x0 = np.asarray(x0, dtype=np.float64)
        P = len(x0)
        plane, closest, _, far, n_r = self._radial_intervals(x0, with_normal=True)
        r_lo = np.full(P, np.inf)
        r_hi = np.full(P, -np.inf)
        np.minimum.at(r_lo, plane, closest)
        np.maximum.at(r_hi, plane, far)
        r_mid = 0.5 * (r_lo + r_hi)[plane]
        hub_cap_hi = np.full(P, -np.inf)
        tip_cap_lo = np.full(P, np.inf)
        hub = (n_r <= -cos_min) & (far <= r_mid)
        tip = (n_r >= cos_min) & (closest >= r_mid)
        np.maximum.at(hub_cap_hi, plane[hub], far[hub])
        np.minimum.at(tip_cap_lo, plane[tip], closest[tip])
        return hub_cap_hi, tip_cap_lo

    def single_interval_range(self, x0, tol):
        """Radial range about mid-span in which every circle meets the cross-section exactly twice.

        A circle of radius r crosses a segment once if r lies between the
        radii of its end points, and twice if r lies between the segment's
        closest approach to the axis and its nearer end point; summed over
        the segments this gives the exact number of crossings n(r) of every
        circle of the plane, piecewise constant in r.

        Parameters
        ----------
        x0 : (P,) float
        tol : float
            Intervals of r shorter than this [mm] do not interrupt the range
            (shared end points of segments).

        Returns
        -------
        r_in_lo, r_in_hi : (P,) float
            The range of r about the middle of the cross-section's radial
            extent with n(r) == 2 [mm]; beyond it, towards either end, some
            circles meet the cross-section more than twice (an end cap
            dipping into the blade) or not at all. NaN where n != 2 at the
            middle.
        """
        x0 = np.asarray(x0, dtype=np.float64)
        P = len(x0)
        r_in_lo = np.full(P, np.nan)
        r_in_hi = np.full(P, np.nan)
        plane, closest, near, far = self._radial_intervals(x0)
        if len(plane) == 0:
            return r_in_lo, r_in_hi
        # events (plane, r, change of n): +1 at the nearer end, -1 at the farther end
        # (one crossing in between), +2 at the closest approach, -2 at the nearer end
        ev_plane = np.concatenate([plane, plane, plane, plane])
        ev_r = np.concatenate([near, far, closest, near])
        ev_dn = np.concatenate([np.ones_like(near), -np.ones_like(far),
                                np.full_like(near, 2.0), np.full_like(near, -2.0)])
        o = np.lexsort((ev_r, ev_plane))
        ev_plane, ev_r = ev_plane[o], ev_r[o]
        n = np.rint(np.cumsum(ev_dn[o]))       # n(r) just above each event; 0 after a plane's last one
        # interval k = (r_k, r_k+1) of a plane; runs of consecutive good intervals
        lo, hi = ev_r[:-1], ev_r[1:]
        same = ev_plane[1:] == ev_plane[:-1]
        good = same & ((n[:-1] == 2) | (hi - lo <= tol))
        run = np.cumsum(~good)
        r_mid = np.full(P, np.nan)
        first = np.ones(len(ev_r), dtype=bool)
        first[1:] = ~same
        last = np.ones(len(ev_r), dtype=bool)
        last[:-1] = ~same
        r_mid[ev_plane[first]] = 0.5 * (ev_r[first] + ev_r[last])
        k_mid = np.nonzero(same & (lo <= r_mid[ev_plane[:-1]]) & (r_mid[ev_plane[:-1]] < hi))[0]
        k_mid = k_mid[good[k_mid]]
        if len(k_mid) == 0:
            return r_in_lo, r_in_hi
        run_lo = np.full(run[-1] + 1, np.inf)
        run_hi = np.full(run[-1] + 1, -np.inf)
        np.minimum.at(run_lo, run[good], lo[good])
        np.maximum.at(run_hi, run[good], hi[good])
        pl = ev_plane[k_mid]
        r_in_lo[pl] = run_lo[run[k_mid]]
        r_in_hi[pl] = run_hi[run[k_mid]]
        return r_in_lo, r_in_hi

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
        n_min, n_max : (P,) float
            Component along +theta of the unit normal of the face crossed at
            ``t_min`` and ``t_max`` (0 where there is no crossing). For an
            outward-wound solid the circle enters at its first crossing
            (``n_min < 0``) and leaves at its last (``n_max > 0``).
        """
        x0 = np.asarray(x0, dtype=np.float64)
        r0 = np.asarray(r0, dtype=np.float64)
        P = len(x0)
        plane, a, b, face = self.slice(x0)
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
        # a circle through a segment's end point is found on both segments that
        # share it (then merged), whatever the rounding of the end point's radius
        valid = ok[:, None] & (t >= -1e-9) & (t <= 1.0 + 1e-9)
        seg_idx, root = np.nonzero(valid)
        pts = a[seg_idx] + t[seg_idx, root, None] * ab[seg_idx]
        pl = plane[seg_idx]
        ang = np.arctan2(pts[:, 1], pts[:, 0])
        nrm = self.normal[face[seg_idx]]
        n_theta = np.cos(ang) * nrm[:, 2] - np.sin(ang) * nrm[:, 1]
        count = np.zeros(P, dtype=np.int64)
        t_min = np.full(P, np.nan)
        t_max = np.full(P, np.nan)
        n_min = np.zeros(P)
        n_max = np.zeros(P)
        if len(ang) == 0:
            return count, t_min, t_max, n_min, n_max
        o = np.lexsort((ang, pl))
        pl, ang, n_theta = pl[o], ang[o], n_theta[o]
        new = np.ones(len(ang), dtype=bool)
        new[1:] = (pl[1:] != pl[:-1]) | (np.diff(ang) * r0[pl[1:]] > merge_tol)
        np.add.at(count, pl[new], 1)
        first = np.ones(len(ang), dtype=bool)
        first[1:] = pl[1:] != pl[:-1]
        last = np.ones(len(ang), dtype=bool)
        last[:-1] = pl[1:] != pl[:-1]
        t_min[pl[first]] = ang[first]
        t_max[pl[last]] = ang[last]
        n_min[pl[first]] = n_theta[first]
        n_max[pl[last]] = n_theta[last]
        return count, t_min, t_max, n_min, n_max


def _mean_angle(mesh):
    """Circular mean of the vertex angles about X [rad]."""
    v = np.asarray(mesh.vertices)
    theta = np.arctan2(v[:, 2], v[:, 1])
    return float(np.arctan2(np.sin(theta).sum(), np.cos(theta).sum()))


def _station_count(flags):
    """'all', 'none' or 'k of n' stations where ``flags`` holds."""
    k, n = int(np.count_nonzero(flags)), len(flags)
    return "all" if k == n else "none" if k == 0 else f"{k} of {n} stations"


def mesh_to_sections(mesh, n_sections=25, n_stations=81, *, hub=None, shroud=None, overlap=None,
                     span_margin=1e-3, edge_margin=1e-4, n_footprint=256, n_scan=81, with_report=False):
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
    hub, shroud : RevolutionProfile, optional
        The walls the blade stands between (both or neither). With them the
        blade is sliced only over the span the channel needs: the hub-side
        bound is never below ``hub(x) - overlap`` and the tip-side bound
        never above ``shroud(x) + overlap``, so a mesh that runs past the
        walls (CAD blades often do, closed by caps of any shape) is sliced
        inside them. A mesh that stops short is sliced to its own ends, as
        without profiles (:class:`~.blisk.Blisk` then extends it).
    overlap : float, optional
        How far beyond the walls to slice [mm]; default
        :func:`~.blisk.mesh_slice_overlap` (3 % of the smallest channel
        height, more than the :func:`~.blisk.wall_overlap` :class:`~.blisk.Blisk`
        extends its blade by).
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
    with_report : bool
        Also return what was sliced.

    Returns
    -------
    sections : BladeSections
        (S, C) stations; ``theta_minus``/``theta_plus`` are the smallest and
        largest angle at which the station's circle meets the mesh, unwrapped
        around the blade's mean angle.
    report : dict, only with ``with_report``
        Plain data, lengths in mm: ``axial_extent_mm`` and
        ``radial_extent_mm`` (the mesh's own extent, [min, max]),
        ``sliced_axial_extent_mm``, ``sliced_hub_side_radius_mm`` and
        ``sliced_tip_side_radius_mm`` ([min, max] of the stations, of section
        0 and S-1), and with profiles ``wall_overlap_mm``,
        ``beyond_hub_mm`` / ``beyond_shroud_mm`` ([min, max] over
        the hub-/tip-side stations of how far the mesh's own end reaches
        beyond the wall; negative where it stops short) and
        ``clipped_to_hub`` / ``clipped_to_shroud`` ('all', 'none' or
        'k of n stations' sliced at the wall's bound instead of the mesh's
        own end).

    Raises
    ------
    GeometryError
        Not a closed mesh, not a single blade (a circle meets the mesh in two
        separate intervals, or leaves it where it should enter it: faces
        crossing), or no usable footprint; every such circle is named by its
        x and r.

    Notes
    -----
    The footprint (the blade's projection on the (x, r) half-plane) is found
    from the exact radial extent ``[r_lo(x), r_hi(x)]`` of cross-sections at
    ``n_footprint`` planes. Its four corners (leading/trailing edge at
    hub/tip) split the lower bound into the hub-side curve and the upper
    bound into the tip-side curve. Both are moved into the blade by 1.5 times
    the depth of chords across the caps plus ``span_margin``, and past each
    end zone -- the radial range of the end caps (faces whose normal is within
    about 25 deg of -r at the hub end, +r at the tip end) and the range where
    circles meet the cross-section other than twice (a flat cap dipping into
    the blade between two points of its section), counted exactly from the
    segments -- by ``span_margin``, if that zone is at most 5 % of the span
    deep (a deeper one is no cap: the circles report it where they meet it).
    With profiles the curves are then clipped to ``hub - overlap`` and
    ``shroud + overlap``. Section j is the curve ``(1 - f_j) H(u) + f_j T(u)``
    between them (u the chord fraction along each curve, H and T continued
    linearly beyond u in [0, 1]); its leading and trailing edge are found by
    bisection on "does the circle meet the mesh". Every station's circle must
    meet the mesh exactly twice, entering it at the first crossing and leaving
    it at the last.
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
    if (hub is None) != (shroud is None):
        raise GeometryError("mesh_to_sections: give both the hub and the shroud profile, or neither")
    walls = hub is not None
    if walls:
        if overlap is None:
            from .blisk import mesh_slice_overlap  # blisk imports this module
            overlap = mesh_slice_overlap(hub, shroud)
        overlap = float(overlap)
        if not (np.isfinite(overlap) and overlap >= 0):
            raise GeometryError(f"mesh_to_sections: overlap must be a finite length >= 0 mm, got {overlap!r}")

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
    in_lo, in_hi = slicer.single_interval_range(xf, merge_tol)
    cap_lo, cap_hi = slicer.end_caps(xf, _CAP_NORMAL)
    good = np.isfinite(r_lo) & np.isfinite(r_hi)
    if np.count_nonzero(good) < 4:
        raise GeometryError("mesh_to_sections: no usable cross-sections of the mesh")
    xf, r_lo, r_hi, dip, in_lo, in_hi, cap_lo, cap_hi = (
        a[good] for a in (xf, r_lo, r_hi, dip, in_lo, in_hi, cap_lo, cap_hi))
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
    # end zones -- the radial range of faces looking along -r / +r (the caps) and where
    # circles meet the cross-section other than twice (a cap dipping into the blade) --
    # are left out if shallow; a deeper one is no cap (the circles report it if sliced)
    zone_lo = np.fmax(cap_lo, in_lo)        # NaN in_lo (no single interval at mid-span): the cap alone
    zone_hi = np.fmin(cap_hi, in_hi)
    deep = _MAX_CAP_DEPTH * span
    lo_own = np.maximum(r_lo + inset, np.where(zone_lo - r_lo <= deep, zone_lo + span_margin * span, -np.inf))
    hi_own = np.minimum(r_hi - inset, np.where(r_hi - zone_hi <= deep, zone_hi - span_margin * span, np.inf))
    hub_x, hub_r = xf[i_a:i_b + 1], lo_own[i_a:i_b + 1]
    tip_x, tip_r = xf[i_d:i_c + 1], hi_own[i_d:i_c + 1]

    du = 1.0 / (n_footprint - 1)

    def curve(side, uu):
        """(x, r) of the hub-side (0) or tip-side (1) bound at chord parameters uu.

        Linear in x along uu; r interpolated in [0, 1] and continued beyond with
        the end slopes, then clipped to the walls.
        """
        cx, cr = (hub_x, hub_r) if side == 0 else (tip_x, tip_r)
        uu = np.asarray(uu, dtype=np.float64)

        def x_at(w):
            return cx[0] + w * (cx[-1] - cx[0])

        xx = x_at(uu)
        rr = np.interp(x_at(np.clip(uu, 0.0, 1.0)), cx, cr)
        for end, sign in ((0.0, 1.0), (1.0, -1.0)):
            outside = (uu < 0) if end == 0.0 else (uu > 1)
            if np.any(outside):
                r0 = np.interp(x_at(end), cx, cr)
                slope = (np.interp(x_at(end + sign * du), cx, cr) - r0) / (sign * du)
                rr = np.where(outside, r0 + (uu - end) * slope, rr)
        if walls:
            rr = (np.maximum(rr, hub.radius_at(xx) - overlap) if side == 0
                  else np.minimum(rr, shroud.radius_at(xx) + overlap))
        return xx, rr

    u_check = np.linspace(0, 1, 33)
    if np.any(curve(1, u_check)[1] <= curve(0, u_check)[1]):
        where = " between the hub and shroud profiles" if walls else ""
        raise GeometryError(f"mesh_to_sections: the blade's footprint{where} is too thin in span")

    f = np.linspace(0.0, 1.0, n_sections)[:, None]

    def section_points(u):
        """(x, r) of the section lines at chord parameters u, (S, U) each."""
        u = np.asarray(u, dtype=np.float64)
        if u.ndim == 1:
            u = np.broadcast_to(u, (n_sections, len(u)))
        hx, hr = curve(0, u)
        tx, tr = curve(1, u)
        return (1 - f) * hx + f * tx, (1 - f) * hr + f * tr

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
    count, t_min, t_max, n_min, n_max = slicer.circle_angles(x.ravel(), r.ravel(), merge_tol)
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
    # an outward-wound solid is entered at the first crossing and left at the last
    sign = 1.0 if mesh.volume >= 0 else -1.0
    crossed = ((sign * n_min > _CROSSED_FACES) | (sign * n_max < -_CROSSED_FACES)).reshape(x.shape)
    if np.any(crossed):
        s, c = (int(i) for i in np.argwhere(crossed)[0])
        raise GeometryError(
            f"mesh_to_sections: the circle x={x[s, c]:.4f} mm, r={r[s, c]:.4f} mm (section {s}, "
            f"station {c}) leaves the mesh where it should enter it: its faces cross (a self-intersecting "
            "mesh), not a single blade")
    theta_minus = theta0 + t_min.reshape(x.shape)
    theta_plus = theta0 + t_max.reshape(x.shape)
    _log.debug("mesh_to_sections: %d x %d stations, x %.4g..%.4g mm, r %.4g..%.4g mm",
               n_sections, n_stations, x.min(), x.max(), r.min(), r.max())
    sections = BladeSections(x=x, r=r, theta_minus=theta_minus, theta_plus=theta_plus)
    if not with_report:
        return sections

    def extent(a):
        return [float(np.min(a)), float(np.max(a))]

    report = {
        "axial_extent_mm": [xmin, xmax],
        "radial_extent_mm": [rmin, rmax],
        "sliced_axial_extent_mm": extent(x),
        "sliced_hub_side_radius_mm": extent(r[0]),
        "sliced_tip_side_radius_mm": extent(r[-1]),
    }
    if walls:
        # the mesh's own ends (no inset) at the hub-side and tip-side stations
        own_hub = np.interp(x[0], hub_x, r_lo[i_a:i_b + 1])
        own_tip = np.interp(x[-1], tip_x, r_hi[i_d:i_c + 1])
        hub_r0, shroud_r1 = hub.radius_at(x[0]), shroud.radius_at(x[-1])
        report.update({
            "wall_overlap_mm": overlap,
            "beyond_hub_mm": extent(hub_r0 - own_hub),
            "beyond_shroud_mm": extent(own_tip - shroud_r1),
            "clipped_to_hub": _station_count(r[0] <= hub_r0 - overlap + 1e-9 * span),
            "clipped_to_shroud": _station_count(r[-1] >= shroud_r1 + overlap - 1e-9 * span),
        })
    return sections, report
