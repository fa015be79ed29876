"""STEP files written FROM the parametric default blisk with OpenCascade, for test/test_step_import.py.

Blade 0 is lofted (BRepOffsetAPI_ThruSections) through every third of the default blade's sections (the
blade as the Blisk extends it into the walls) and every second station, each section a closed wire of two
interpolated B-spline curves (pressure face LE -> TE, suction face TE -> LE, meeting at the knife edges), with
a planar cap section half a millimetre inside each wall; hub and shroud are their profiles revolved about X
(a bore at r = 90 mm, an outer skin at r = 126 mm); everything fused into one solid.
"""

import numpy as np

from edm_planner.geometry.loader import load_geometry

R_BORE = 90.0
R_OUTER = 126.0
X_RANGE = (-4.0, 29.0)


def default_blisk():
    return load_geometry("config/default_blisk.yaml").blisk


def _bspline(points):
    from OCP.GeomAPI import GeomAPI_Interpolate
    from OCP.collections import HArray1_gp_Pnt
    from OCP.gp import gp_Pnt

    arr = HArray1_gp_Pnt(1, len(points))
    for i, p in enumerate(points):
        arr.SetValue(i + 1, gp_Pnt(*(float(v) for v in p)))
    it = GeomAPI_Interpolate(arr, False, 1e-9)
    it.Perform()
    return it.Curve()


def _cart(x, r, t):
    return np.stack([x, r * np.cos(t), r * np.sin(t)], -1)


def blade_solid(blisk, section_stride=3, station_stride=2):
    """Blade 0 of ``blisk`` as a lofted OCP solid."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire
    from OCP.BRepOffsetAPI import BRepOffsetAPI_ThruSections

    b = blisk.blade
    si = np.unique(np.r_[np.arange(0, b.shape[0], section_stride), b.shape[0] - 1])
    ci = np.unique(np.r_[np.arange(0, b.shape[1], station_stride), b.shape[1] - 1])
    x, r, tm, tp = (a[np.ix_(si, ci)] for a in (b.x, b.r, b.theta_minus, b.theta_plus))
    mean = 0.5 * (tm.mean() + tp.mean())
    rows = []
    d = r[0].min() - 0.5                     # planar cap sections: the end sections moved radially onto a plane
    rows.append((x[0], d / np.cos(tm[0] - mean), d / np.cos(tp[0] - mean), tm[0], tp[0]))
    rows += [(x[s], r[s], r[s], tm[s], tp[s]) for s in range(len(si))]
    d = r[-1].max() + 0.5
    rows.append((x[-1], d / np.cos(tm[-1] - mean), d / np.cos(tp[-1] - mean), tm[-1], tp[-1]))
    loft = BRepOffsetAPI_ThruSections(True, False, 1e-6)
    for xs, rm, rp, thm, thp in rows:
        pm, pp = _cart(xs, rm, thm), _cart(xs, rp, thp)
        pp[0], pp[-1] = pm[0], pm[-1]
        wire = BRepBuilderAPI_MakeWire(BRepBuilderAPI_MakeEdge(_bspline(pm)).Edge(),
                                       BRepBuilderAPI_MakeEdge(_bspline(pp[::-1])).Edge()).Wire()
        loft.AddWire(wire)
    loft.CheckCompatibility(False)
    loft.Build()
    return loft.Shape()


def ring(profile, r_other, angle=2 * np.pi, start=0.0):
    """The solid between a profile and r = r_other, revolved about X by ``angle`` from ``start``."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeWire
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeRevol
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    x0, x1 = X_RANGE
    pts = profile.sample(x0, x1, step=1.0)
    line = BRepBuilderAPI_MakeEdge(_bspline(np.column_stack([pts, np.zeros(len(pts))]))).Edge()
    a, b = gp_Pnt(x1, float(pts[-1, 1]), 0), gp_Pnt(x1, r_other, 0)
    c, d = gp_Pnt(x0, r_other, 0), gp_Pnt(x0, float(pts[0, 1]), 0)
    wire = BRepBuilderAPI_MakeWire(line, BRepBuilderAPI_MakeEdge(a, b).Edge(), BRepBuilderAPI_MakeEdge(b, c).Edge(),
                                   BRepBuilderAPI_MakeEdge(c, d).Edge()).Wire()
    face = BRepBuilderAPI_MakeFace(wire, True).Face()
    solid = BRepPrimAPI_MakeRevol(face, gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)), angle).Shape()
    return rotated(solid, start) if start else solid


def rotated(shape, angle, axis=(1.0, 0.0, 0.0), point=(0.0, 0.0, 0.0)):
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt, gp_Trsf

    t = gp_Trsf()
    t.SetRotation(gp_Ax1(gp_Pnt(*point), gp_Dir(*axis)), float(angle))
    return transformed(shape, t)


def transformed(shape, trsf):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform

    return BRepBuilderAPI_Transform(shape, trsf, True).Shape()


def matrix_trsf(matrix):
    from OCP.gp import gp_Trsf

    t = gp_Trsf()
    t.SetValues(*[float(v) for v in np.asarray(matrix)[:3, :].ravel()])
    return t


def fuse(shapes):
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Fuse
    from OCP.collections import List_TopoDS_Shape

    args, tools = List_TopoDS_Shape(), List_TopoDS_Shape()
    args.Append(shapes[0])
    for s in shapes[1:]:
        tools.Append(s)
    op = BRepAlgoAPI_Fuse()
    op.SetArguments(args)
    op.SetTools(tools)
    op.Build()
    return op.Shape()


def sector_solid(blisk, blade, blade_count):
    """One sector of ``blade_count`` blades: blade 0 with its hub and shroud sector (meridional sides), centred
    on the blade's mean angle."""
    b = blisk.blade
    mean = 0.5 * (b.theta_minus.mean() + b.theta_plus.mean())
    p = 2 * np.pi / blade_count
    hub = ring(blisk.hub, R_BORE, p, mean - p / 2)
    shroud = ring(blisk.shroud, R_OUTER, p, mean - p / 2)
    return fuse([fuse([hub, blade]), shroud])


def whole_solid(blisk, blade, blade_count):
    """A whole blisk of ``blade_count`` copies of the blade."""
    hub = ring(blisk.hub, R_BORE)
    shroud = ring(blisk.shroud, R_OUTER)
    blades = [rotated(blade, k * 2 * np.pi / blade_count) if k else blade for k in range(blade_count)]
    return fuse([hub, shroud] + blades)


def write_step(shape, path):
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    Interface_Static.SetIVal_s("write.step.verbose", 0) if hasattr(Interface_Static, "SetIVal_s") else None
    writer = STEPControl_Writer()
    writer.Transfer(shape, STEPControl_AsIs)
    assert writer.Write(str(path)) == IFSelect_RetDone
    return path


def count(shape, kind):
    from OCP.TopExp import TopExp_Explorer

    e, n = TopExp_Explorer(shape, kind), 0
    while e.More():
        n += 1
        e.Next()
    return n


def subshapes(shape, kind):
    from OCP.TopExp import TopExp_Explorer

    e, out = TopExp_Explorer(shape, kind), []
    while e.More():
        out.append(e.Current())
        e.Next()
    return out


def _loft(rows, solid=True):
    """A lofted solid through closed section wires; rows: (pressure points LE->TE, suction points LE->TE)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire
    from OCP.BRepOffsetAPI import BRepOffsetAPI_ThruSections

    loft = BRepOffsetAPI_ThruSections(solid, False, 1e-6)
    for pm, pp in rows:
        pp = pp.copy()
        pp[0], pp[-1] = pm[0], pm[-1]
        loft.AddWire(BRepBuilderAPI_MakeWire(BRepBuilderAPI_MakeEdge(_bspline(pm)).Edge(),
                                             BRepBuilderAPI_MakeEdge(_bspline(pp[::-1])).Edge()).Wire())
    loft.CheckCompatibility(False)
    loft.Build()
    return loft.Shape()


def filleted_sector_solid(blisk, radius, blade_count, n_u=41):
    """A sector whose blade meets the shroud with a fillet of ``radius`` [mm], the fillet faces of their own.

    OCP's BRepFilletAPI_MakeFillet fails on the knife-edged blade's junction with the shroud (the leading and
    trailing edge are corners of zero angle), so the fillet is built into the blade: a loft through rows of
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
        return _cart(x, r, th + sign * delta / r)

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
        ends.append(tuple(_cart(q[:, 0], d / np.cos(np.arctan2(q[:, 2], q[:, 1]) - mean), np.arctan2(q[:, 2], q[:, 1]))
                          for q in (pm, pp)))
    blade = _loft([ends[0]] + rows + [ends[1]])
    solid = sector_solid(blisk, blade, blade_count)
    # the splitting surface: the shroud profile moved down by the radius, revolved over the whole turn
    x0, x1 = X_RANGE
    pts = blisk.shroud.sample(x0 - 1, x1 + 1, step=1.0)
    moved = np.column_stack([pts[:, 0], pts[:, 1] - radius, np.zeros(len(pts))])
    line = BRepBuilderAPI_MakeEdge(_bspline(moved)).Edge()
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
