"""STEP files written FROM the parametric default blisk with OpenCascade, for test/test_step_import.py.

The writer itself (the lofted blade, the hub and shroud rings, the fuse, the STEP writer) is
edm_planner/bench/step_writer.py, shared with the STEP bench suite; here: the default blisk and the test files
of their own (the filleted sectors).
"""

import numpy as np

from edm_planner.bench.step_writer import (R_BORE, R_OUTER, X_RANGE, blade_solid, bspline, cart, count, fuse,
                                           is_valid, loft, loft_rows, matrix_trsf, ring, rotated, sector_solid,
                                           subshapes, transformed, wall_deviation, whole_solid, write_step)
from edm_planner.geometry.loader import load_geometry

#: the writer's names the tests use through this module
__all__ = ["R_BORE", "R_OUTER", "X_RANGE", "blade_solid", "bspline", "cart", "count", "fuse", "is_valid", "loft",
           "matrix_trsf", "ring", "rotated", "sector_solid", "subshapes", "transformed", "wall_deviation",
           "whole_solid", "write_step", "default_blisk", "filleted_sector_solid", "smooth_blade_solid",
           "junction_edges", "cad_filleted_sector", "face_wall_depth"]


def default_blisk():
    return load_geometry("config/default_blisk.yaml").blisk


def filleted_sector_solid(blisk, radius, blade_count, n_u=41):
    """A sector whose blade meets the shroud with a fillet of ``radius`` [mm], the fillet faces of their own.

    A fillet of exactly known depth (a CAD fillet's depth follows from the angle the blade meets the shroud at:
    :func:`cad_filleted_sector` is the real one). OCP's BRepFilletAPI_MakeFillet fails on the junction of
    :func:`blade_solid`'s blade with the shroud (its two-curve sections make corners at the leading and
    trailing edge), so the fillet is built into the blade: a loft through rows of
    the blade's faces sampled at the same (u, v), in which each face is moved outward along the circle by the
    quarter circle ``radius - sqrt(radius^2 - (radius - d)^2)`` at the distance ``d`` below the shroud
    (``radius`` at the shroud and beyond, none below ``radius``). The sector is then split (BRepAlgoAPI_Splitter)
    by the surface of revolution ``radius`` below the shroud and fused again, so the blade's faces above it,
    the fillet, are faces of their own, as a CAD fillet's are.
    """
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Splitter
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeRevol
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.collections import List_TopoDS_Shape
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    u = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n_u))

    def flared(points, sign):
        x, r = points[:, 0], np.hypot(points[:, 1], points[:, 2])
        th = np.arctan2(points[:, 2], points[:, 1])
        d = np.clip(blisk.shroud.radius_at(x) - r, 0.0, radius)
        delta = radius - np.sqrt(np.maximum(radius ** 2 - (radius - d) ** 2, 0.0))
        return cart(x, r, th + sign * delta / r)

    rows = []
    for v in np.r_[np.linspace(0.0, 0.8, 6), np.linspace(0.85, 1.0, 6)]:    # denser in the fillet
        vv = np.full_like(u, v)
        rows.append((flared(blisk.pressure_face.surface.evaluate(u, vv), -1.0),
                     flared(blisk.suction_face.surface.evaluate(u, vv), +1.0)))
    ends = []
    for pm, pp in (rows[0], rows[-1]):
        r_all = np.hypot(np.r_[pm[:, 1], pp[:, 1]], np.r_[pm[:, 2], pp[:, 2]])
        d = r_all.min() - 0.5 if not ends else r_all.max() + 0.5          # one plane for both faces
        mean = 0.5 * (np.arctan2(pm[:, 2], pm[:, 1]).mean() + np.arctan2(pp[:, 2], pp[:, 1]).mean())
        ends.append(tuple(cart(q[:, 0], d / np.cos(np.arctan2(q[:, 2], q[:, 1]) - mean), np.arctan2(q[:, 2], q[:, 1]))
                          for q in (pm, pp)))
    blade = loft([ends[0]] + rows + [ends[1]])
    solid = sector_solid(blisk, blade, blade_count)
    # the splitting surface: the shroud profile moved down by the radius, revolved over the whole turn
    x0, x1 = X_RANGE
    pts = blisk.shroud.sample(x0 - 1, x1 + 1, step=1.0)
    moved = np.column_stack([pts[:, 0], pts[:, 1] - radius, np.zeros(len(pts))])
    line = BRepBuilderAPI_MakeEdge(bspline(moved)).Edge()
    tool = BRepPrimAPI_MakeRevol(line, gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)), 2 * np.pi).Shape()
    split = BRepAlgoAPI_Splitter()
    args, tools = List_TopoDS_Shape(), List_TopoDS_Shape()
    args.Append(solid)
    tools.Append(tool)
    split.SetArguments(args)
    split.SetTools(tools)
    split.Build()
    pieces = subshapes(split.Shape(), TopAbs_SOLID)
    return fuse(pieces)


def smooth_blade_solid(blisk, section_stride=1, station_stride=2):
    """Blade 0 of ``blisk`` lofted through closed smooth sections: as :func:`blade_solid`, but each section one
    periodic B-spline through the pressure face's points LE -> TE and the suction face's TE -> LE, so the
    blade's side is one face, smooth round its leading and trailing edge, with its seam at the leading edge.

    The default blade's faces meet at the edges with a round nose (the thickness grows as the square root of
    the distance from the edge), which the two-curve section of :func:`blade_solid` turns into a corner; over
    the one smooth curve OpenCascade's fillet tool can roll round the edges."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire
    from OCP.BRepOffsetAPI import BRepOffsetAPI_ThruSections

    rows = loft_rows(blisk, section_stride, station_stride)
    maker = BRepOffsetAPI_ThruSections(True, False, 1e-6)
    for xs, rm, rp, thm, thp in rows:
        pm, pp = cart(xs, rm, thm), cart(xs, rp, thp)
        ring_points = np.r_[pm, pp[-2:0:-1]]             # LE -> TE on the pressure face, back on the suction face
        closed = BRepBuilderAPI_MakeEdge(bspline(ring_points, periodic=True)).Edge()
        maker.AddWire(BRepBuilderAPI_MakeWire(closed).Wire())
    maker.CheckCompatibility(False)
    maker.Build()
    return maker.Shape()


def junction_edges(shape, wall, tol=0.01):
    """The edges where a B-spline face (the blade's) meets the wall whose profile is ``wall``: edges with a
    B-spline face among their faces whose middle lies on the wall's surface of revolution (within ``tol`` mm)."""
    from OCP.BRepAdaptor import BRepAdaptor_Curve, BRepAdaptor_Surface
    from OCP.GeomAbs import GeomAbs_BSplineSurface
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
    from OCP.TopExp import TopExp
    from OCP.TopoDS import TopoDS
    from OCP.collections import IndexedDataMap_TopoDS_Shape_List_TopoDS_Shape_TopTools_ShapeMapHasher as Map

    ancestors = Map()
    TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, ancestors)
    out = []
    for i in range(1, ancestors.Size() + 1):
        faces = [TopoDS.Face(f) for f in ancestors.FindFromIndex(i)]
        if not any(BRepAdaptor_Surface(f).GetType() == GeomAbs_BSplineSurface for f in faces):
            continue
        edge = TopoDS.Edge(ancestors.FindKey(i))
        c = BRepAdaptor_Curve(edge)
        p = c.Value(0.5 * (c.FirstParameter() + c.LastParameter()))
        if abs(np.hypot(p.Y(), p.Z()) - float(wall.radius_at(p.X()))) < tol:
            out.append(edge)
    return out


def cad_filleted_sector(blisk, radius, blade_count, walls=("shroud",), section_stride=1, station_stride=2):
    """A sector of ``blade_count`` blades (the blade of :func:`smooth_blade_solid` with the strides given) whose
    edges where the blade meets the ``walls`` ("shroud": the tip, "hub": the root) are filleted with ``radius``
    [mm] by OpenCascade's fillet tool (BRepFilletAPI_MakeFillet, all in one) after the fuse.

    Returns (solid, {wall: its fillet faces}). Raises RuntimeError with the tool's status per contour where it
    fails, and where BRepCheck_Analyzer finds the result invalid.

    The tool is fragile on these lofted blades (cadquery-ocp 8.0.1.1): with a 1 mm radius it rounds the
    tip of the blade lofted through every section and every second station and fails on its root (contour
    status ChFiDS_TwistedSurface; ChFiDS_WalkingFailure through sections moved by a station), and rounds both
    root and tip of the blade through every second section and every fourth station only; on the two-curve
    blade of :func:`blade_solid` it fails at the tip (ChFiDS_WalkingFailure, 0.05 to 1 mm).
    """
    from OCP.BRepFilletAPI import BRepFilletAPI_MakeFillet
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopoDS import TopoDS

    solid = sector_solid(blisk, smooth_blade_solid(blisk, section_stride, station_stride), blade_count)
    maker = BRepFilletAPI_MakeFillet(solid)
    for wall in walls:
        edges = junction_edges(solid, getattr(blisk, wall))
        if not edges:
            raise RuntimeError(f"no edge where the blade meets the {wall}")
        for e in edges:
            maker.Add(float(radius), e)
    maker.Build()
    what = f"BRepFilletAPI_MakeFillet, {radius} mm where the blade meets the {' and the '.join(walls)}"
    if not maker.IsDone():
        status = [maker.StripeStatus(c).name for c in range(1, maker.NbContours() + 1)]
        raise RuntimeError(f"{what}: not done; contour status {status}")
    shape = maker.Shape()
    if not is_valid(shape):
        raise RuntimeError(f"{what}: an invalid solid (BRepCheck_Analyzer)")
    made = [f for i in range(1, maker.NbSurfaces() + 1) for f in _list(maker.NewFaces(i))]
    faces = [TopoDS.Face(f) for f in subshapes(shape, TopAbs_FACE) if any(f.IsSame(m) for m in made)]
    by_wall = {w: [] for w in walls}
    for f in faces:                                     # each fillet face to the wall it lies along
        by_wall[min(walls, key=lambda w: face_wall_depth(f, getattr(blisk, w), 11))].append(f)
    return shape, by_wall


def _list(shapes):
    return list(shapes)


def face_wall_depth(face, wall, n=41):
    """The largest distance [mm] of the face from the wall, radially (|wall radius at x - r|), on an n x n grid
    over the face's parameter bounds."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepTools import BRepTools

    u0, u1, v0, v1 = BRepTools.UVBounds_s(face)
    surf = BRepAdaptor_Surface(face)
    pts = np.array([surf.Value(u, v).Coord() for u in np.linspace(u0, u1, n) for v in np.linspace(v0, v1, n)])
    return float(np.max(np.abs(wall.radius_at(pts[:, 0]) - np.hypot(pts[:, 1], pts[:, 2]))))
