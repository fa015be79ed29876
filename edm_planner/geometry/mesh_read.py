"""Reading a blade mesh file (STL, OBJ, PLY in millimetres) and checking it is one blade.

:func:`load_blade_mesh` refuses a file that is missing, too large, of an
unsupported format or not what its suffix says (an STL is checked on its bytes
before a parser sees it), cleans the mesh (merged vertices, no degenerate or
duplicate triangles) and rejects anything that is not one closed, consistently
wound body (:func:`~.mesh_validate.check_blade_solid`).

Units: millimetres.
"""

import os

import numpy as np
import trimesh

from ..errors import GeometryError, GeometryFileError
from .file_size import check_file_size
from .mesh_validate import check_blade_solid

#: mesh file formats :func:`load_blade_mesh` accepts
MESH_SUFFIXES = (".stl", ".obj", ".ply")


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


def load_blade_mesh(path, max_bytes=None, what="blade mesh"):
    """Read and validate a closed blade mesh in millimetres.

    Parameters
    ----------
    path : str or os.PathLike
        STL, OBJ or PLY file of one blade.
    max_bytes : int, optional
        Size limit of the file, checked before anything reads it (None: none; the geometry loader passes
        its ``max_mesh_bytes``).
    what : str
        What the mesh is, for the messages (``"blade mesh"``, ``"blisk scan"``).

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
        raise GeometryFileError(f"{what} '{name}': file not found")
    suffix = os.path.splitext(name)[1].lower()
    if suffix not in MESH_SUFFIXES:
        raise GeometryFileError(
            f"{what} '{name}': unsupported format '{suffix}' (expected one of {', '.join(MESH_SUFFIXES)})")
    if max_bytes is not None:
        check_file_size(name, max_bytes, f"{what} '{name}'", "mesh")
    if suffix == ".stl":
        try:
            problem = _stl_problem(name)
        except OSError as exc:
            raise GeometryFileError(f"{what} '{name}': cannot be read ({exc.strerror or exc})") from None
        if problem:
            raise GeometryFileError(f"{what} '{name}': {problem}")
    try:
        mesh = trimesh.load(name, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for bad files
        raise GeometryFileError(f"{what} '{name}': cannot be read as {suffix[1:].upper()} ({exc})") from exc
    if not isinstance(mesh, trimesh.Trimesh):
        raise GeometryFileError(f"{what} '{name}': not a triangle mesh ({type(mesh).__name__})")
    if len(mesh.faces) == 0:
        valid_empty = _looks_like_stl(name) if suffix == ".stl" else len(mesh.vertices) > 0
        if not valid_empty:
            raise GeometryFileError(f"{what} '{name}': no geometry could be read, not a {suffix[1:].upper()} mesh")
        raise GeometryError(f"{what} '{name}': the mesh is empty (no triangles)")
    vertices = np.asarray(mesh.vertices)
    if not np.all(np.isfinite(vertices)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(vertices), axis=1)))
        raise GeometryError(f"{what} '{name}': {bad} vertices are NaN or infinite")

    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise GeometryError(f"{what} '{name}': the mesh is empty (all triangles are degenerate)")
    return check_blade_solid(mesh, f"{what} '{name}'")
