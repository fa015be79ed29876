"""Write config/mesh_blisk/blade.stl: the default blisk's blade as a CAD-style closed mesh.

The mesh-based example blisk (config/mesh_blisk.yaml) exercises the third
blade source of the loader, "a closed triangle mesh of one blade as a CAD
system exports it". Its blade is blade 0 of config/default_blisk.yaml:

* the default blisk is loaded and its ``blisk.blade_mesh`` (closed, watertight,
  sampled from the reconstructed spline faces) is taken if its binary STL
  stays below ``MAX_BYTES``;
* otherwise (the default's mesh is ~0.93 MB) the two blade faces are
  re-sampled coarser -- cosine-clustered along the chord, uniform along the
  span -- and closed with
  :func:`edm_planner.geometry.blade_mesh.closed_blade_mesh`; of a few
  candidate grids the one with the smallest faceting error whose STL fits is
  used.

The faceting error is measured, not estimated: points on every face triangle
(centroid, edge midpoints and three interior points) are projected exactly
onto the spline face they approximate (``BladeFace.closest_points``); the
largest distance must stay below ``MAX_FACETING`` mm. The script prints the
figures and refuses to write a mesh that misses either limit.

Units: millimetres, radians; frame W (X the blisk axis, theta = atan2(z, y)).

Usage::

    .venv/bin/python tools/make_example_mesh.py [--output config/mesh_blisk/blade.stl]
"""

import argparse
import pathlib
import sys

import numpy as np

REPO = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from edm_planner.geometry.mesh_build import FACE_LABELS, MeshFaceLabel as BladeFace, closed_blade_mesh  # noqa: E402
from edm_planner.geometry.mesh_read import load_blade_mesh  # noqa: E402
from edm_planner.geometry.loader import load_geometry  # noqa: E402

#: largest binary STL written [bytes]
MAX_BYTES = 600_000
#: largest faceting error accepted [mm]
MAX_FACETING = 0.01
#: candidate (chord stations, span sections) grids, tried in order
GRIDS = ((191, 15), (181, 15), (201, 13), (171, 16), (141, 21), (121, 25))
#: barycentric sample points per triangle for the faceting error
_BARY = np.array([[1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5],
                  [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])


def stl_bytes(mesh):
    """Size of the binary STL of ``mesh`` [bytes]."""
    return 84 + 50 * len(mesh.faces)


def faceting_error(blisk, mesh):
    """Largest distance [mm] of points on the mesh's face triangles from the exact spline faces.

    Returns
    -------
    dict
        ``{'minus': e_pressure, 'plus': e_suction}``.
    """
    labels = mesh.face_attributes.get(FACE_LABELS) if hasattr(mesh, "face_attributes") else None
    if labels is None:
        # an unlabelled mesh: measure every triangle against the nearer face
        pts = np.einsum("kj,tjd->tkd", _BARY, mesh.triangles).reshape(-1, 3)
        d = np.minimum(blisk.pressure_face.closest_points(pts)[1], blisk.suction_face.closest_points(pts)[1])
        return {"minus": float(d.max()), "plus": float(d.max())}
    out = {}
    for name, face, label in (("minus", blisk.pressure_face, BladeFace.MINUS),
                              ("plus", blisk.suction_face, BladeFace.PLUS)):
        tri = mesh.triangles[labels == label]
        pts = np.einsum("kj,tjd->tkd", _BARY, tri).reshape(-1, 3)
        out[name] = float(face.closest_points(pts)[1].max())
    return out


def resampled_mesh(blisk, n_chord, n_span):
    """Closed blade mesh of the blisk's spline faces on an (n_span, n_chord) grid."""
    u = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n_chord))
    v = np.linspace(0.0, 1.0, n_span)
    uu, vv = np.meshgrid(u, v)
    return closed_blade_mesh(blisk.pressure_face.surface.evaluate(uu, vv),
                             blisk.suction_face.surface.evaluate(uu, vv))


def build(blisk, max_bytes=MAX_BYTES, max_faceting=MAX_FACETING):
    """(mesh, faceting error [mm], description) of the blade mesh to write."""
    mesh = blisk.blade_mesh
    if stl_bytes(mesh) <= max_bytes:
        err = max(faceting_error(blisk, mesh).values())
        if err <= max_faceting:
            return mesh, err, "blisk.blade_mesh"
    best = None
    for n_chord, n_span in GRIDS:
        mesh = resampled_mesh(blisk, n_chord, n_span)
        if stl_bytes(mesh) > max_bytes:
            continue
        err = max(faceting_error(blisk, mesh).values())
        if err <= max_faceting and (best is None or err < best[1]):
            best = (mesh, err, f"re-sampled {n_chord} chord x {n_span} span")
    if best is None:
        raise SystemExit(f"make_example_mesh: no grid gives an STL below {max_bytes} bytes "
                         f"with a faceting error below {max_faceting} mm")
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--source", default=str(REPO / "config" / "default_blisk.yaml"))
    parser.add_argument("--output", default=str(REPO / "config" / "mesh_blisk" / "blade.stl"))
    args = parser.parse_args(argv)

    blisk = load_geometry(args.source).blisk
    mesh, err, how = build(blisk)
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise SystemExit("make_example_mesh: the blade mesh is not a closed, outward-wound solid")
    out = pathlib.Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(mesh.export(file_type="stl"))
    # what a reader gets back (float32 STL): still one closed blade
    back = load_blade_mesh(out)
    print(f"make_example_mesh: {how}: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles, "
          f"volume {mesh.volume:.3f} mm^3 (read back {back.volume:.3f} mm^3)")
    print(f"make_example_mesh: faceting error {err:.5f} mm (limit {MAX_FACETING} mm), "
          f"{out.stat().st_size} bytes (limit {MAX_BYTES}) -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
