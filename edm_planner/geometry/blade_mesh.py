"""Blade triangle meshes: the former home of building, reading, validating and slicing them.

Kept so that old imports work; the code lives in one module per concern:

* :mod:`.mesh_build`: :func:`~.mesh_build.closed_blade_mesh`,
  :func:`~.mesh_build.face_grid_mesh`, :class:`~.mesh_build.MeshFaceLabel`
  (the labels of a closed blade mesh's triangles), ``FACE_LABELS``;
* :mod:`.mesh_read`: :func:`~.mesh_read.load_blade_mesh`, ``MESH_SUFFIXES``;
* :mod:`.mesh_validate`: the checks that a mesh is one closed blade;
* :mod:`.mesh_slicer`: :class:`~.mesh_slicer.MeshSlicer`, exact cross-sections
  by many planes at once;
* :mod:`.mesh_sections`: :func:`~.mesh_sections.mesh_to_sections` and
  :func:`~.mesh_sections.mesh_to_sections_with_report`.

``BladeFace`` (this module's name of :class:`~.mesh_build.MeshFaceLabel`,
easily confused with the spline surface :class:`~.surfaces.BladeFace`) still
imports from here, with a DeprecationWarning.
"""

import warnings

from .mesh_build import FACE_LABELS, MeshFaceLabel, closed_blade_mesh, face_grid_mesh
from .mesh_read import MESH_SUFFIXES, load_blade_mesh
from .mesh_sections import mesh_to_sections, mesh_to_sections_with_report

__all__ = ["FACE_LABELS", "MESH_SUFFIXES", "MeshFaceLabel", "closed_blade_mesh", "face_grid_mesh",
           "load_blade_mesh", "mesh_to_sections", "mesh_to_sections_with_report"]

#: old names of this module -> (new object, its new name), each warning when used
_RENAMED = {"BladeFace": (MeshFaceLabel, "edm_planner.geometry.mesh_build.MeshFaceLabel")}


def __getattr__(name):
    """PEP 562: the renamed ``BladeFace``, with a DeprecationWarning."""
    if name in _RENAMED:
        value, new = _RENAMED[name]
        warnings.warn(f"edm_planner.geometry.blade_mesh.{name} is deprecated, use {new} (not to be confused with "
                      "the spline surface edm_planner.geometry.surfaces.BladeFace)", DeprecationWarning, stacklevel=2)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
