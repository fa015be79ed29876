"""Blisk geometry: surfaces of revolution, blades, channels, electrodes.

Workpiece frame W: X is the blisk's rotation axis, a point at radius r and
angle theta is ``(x, r*cos(theta), r*sin(theta))``, i.e. ``theta = atan2(z, y)``.
Millimetres and radians everywhere.

One module per concern:

* the model: ``blisk`` (the blisk and its channels), ``profiles`` (hub and
  shroud), ``sections`` (a blade as stacked sections), ``surfaces``, ``nurbs``
  and ``spline_kernels`` (the spline faces), ``frames``, ``centerline``,
  ``electrode``;
* loading: ``loader`` (the geometry YAML), ``file_size``, ``readers``
  (section and meridional tables);
* blade meshes: ``mesh_build``, ``mesh_read``, ``mesh_validate``,
  ``mesh_slicer``, ``mesh_sections`` (mesh to sections), ``mesh_deviation``;
* parametric blades: ``parametric_quintic``, ``parametric_outline``,
  ``parametric_stacking``, ``parametric_yaml``.

``blade_mesh`` and ``parametric`` are the former homes of the mesh and
parametric code, kept for their old imports.
"""
