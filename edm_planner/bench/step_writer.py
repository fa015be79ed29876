"""STEP files written FROM a parametric blisk with OpenCascade (``cadquery-ocp``): the writer the STEP bench
suite (:mod:`.step`) and the STEP import tests (``test/step_fixtures.py``) share.

Only the bench and the tests use it; no product module imports it. OCP is imported inside the functions.

A blade is lofted (``BRepOffsetAPI_ThruSections``) through every ``section_stride``-th of the blade's sections
(the blade as the Blisk extends it into the walls) and every ``station_stride``-th station, each section a
closed wire of two interpolated B-spline curves (pressure face LE -> TE, suction face TE -> LE, meeting at the
knife edges), with a planar cap section half a millimetre inside each wall; hub and shroud are their profiles
revolved about X (a bore at r = :data:`R_BORE`, an outer skin at r = :data:`R_OUTER`); everything is fused
(``BRepAlgoAPI_Fuse``) into one solid. Units mm, rad; X is the blisk axis.
"""

import numpy as np

#: the bore radius and the outer skin radius of the written hub and shroud rings [mm]
R_BORE = 90.0
R_OUTER = 126.0
#: the axial extent of the written rings [mm] (the default blisk's part)
X_RANGE = (-4.0, 29.0)


def bspline(points, periodic=False):
    """An interpolated B-spline curve (Geom_BSplineCurve) through 3-D points; ``periodic``: closed, the first
    point not repeated at the end."""
    from OCP.GeomAPI import GeomAPI_Interpolate
    from OCP.collections import HArray1_gp_Pnt
    from OCP.gp import gp_Pnt

    arr = HArray1_gp_Pnt(1, len(points))
    for i, p in enumerate(points):
        arr.SetValue(i + 1, gp_Pnt(*(float(v) for v in p)))
    it = GeomAPI_Interpolate(arr, bool(periodic), 1e-9)
    it.Perform()
    return it.Curve()


def cart(x, r, t):
    """(x, r, theta) -> (x, y, z) stacked on the last axis."""
    return np.stack([x, r * np.cos(t), r * np.sin(t)], -1)


def loft_rows(blisk, section_stride, station_stride):
    """The sections a blade is lofted through: every ``section_stride``-th section of blade 0 at every
    ``station_stride``-th station (the last ones kept), between two planar caps (the end sections moved
    radially onto a plane 0.5 mm beyond them): [(x, r_minus, r_plus, theta_minus, theta_plus)] per section."""
    b = blisk.blade
    si = np.unique(np.r_[np.arange(0, b.shape[0], section_stride), b.shape[0] - 1])
    ci = np.unique(np.r_[np.arange(0, b.shape[1], station_stride), b.shape[1] - 1])
    x, r, tm, tp = (a[np.ix_(si, ci)] for a in (b.x, b.r, b.theta_minus, b.theta_plus))
    mean = 0.5 * (tm.mean() + tp.mean())
    d = r[0].min() - 0.5
    rows = [(x[0], d / np.cos(tm[0] - mean), d / np.cos(tp[0] - mean), tm[0], tp[0])]
    rows += [(x[s], r[s], r[s], tm[s], tp[s]) for s in range(len(si))]
    d = r[-1].max() + 0.5
    rows.append((x[-1], d / np.cos(tm[-1] - mean), d / np.cos(tp[-1] - mean), tm[-1], tp[-1]))
    return rows


def blade_solid(blisk, section_stride=3, station_stride=2):
    """Blade 0 of ``blisk`` as a lofted OCP solid."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire
    from OCP.BRepOffsetAPI import BRepOffsetAPI_ThruSections

    rows = loft_rows(blisk, section_stride, station_stride)
    loft = BRepOffsetAPI_ThruSections(True, False, 1e-6)
    for xs, rm, rp, thm, thp in rows:
        pm, pp = cart(xs, rm, thm), cart(xs, rp, thp)
        pp[0], pp[-1] = pm[0], pm[-1]
        wire = BRepBuilderAPI_MakeWire(BRepBuilderAPI_MakeEdge(bspline(pm)).Edge(),
                                       BRepBuilderAPI_MakeEdge(bspline(pp[::-1])).Edge()).Wire()
        loft.AddWire(wire)
    loft.CheckCompatibility(False)
    loft.Build()
    return loft.Shape()


def loft(rows, solid=True):
    """A lofted solid through closed section wires; rows: (pressure points LE->TE, suction points LE->TE)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire
    from OCP.BRepOffsetAPI import BRepOffsetAPI_ThruSections

    maker = BRepOffsetAPI_ThruSections(solid, False, 1e-6)
    for pm, pp in rows:
        pp = pp.copy()
        pp[0], pp[-1] = pm[0], pm[-1]
        maker.AddWire(BRepBuilderAPI_MakeWire(BRepBuilderAPI_MakeEdge(bspline(pm)).Edge(),
                                              BRepBuilderAPI_MakeEdge(bspline(pp[::-1])).Edge()).Wire())
    maker.CheckCompatibility(False)
    maker.Build()
    return maker.Shape()


def ring(profile, r_other, angle=2 * np.pi, start=0.0):
    """The solid between a profile and r = r_other, revolved about X by ``angle`` from ``start``."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeWire
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeRevol
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    x0, x1 = X_RANGE
    pts = profile.sample(x0, x1, step=1.0)
    line = BRepBuilderAPI_MakeEdge(bspline(np.column_stack([pts, np.zeros(len(pts))]))).Edge()
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
    """The boolean union of the shapes (the first the argument, the others the tools)."""
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
    """Write ``shape`` to the STEP file ``path`` (AP214, mm); raises RuntimeError when the writer fails."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    writer = STEPControl_Writer()
    writer.Transfer(shape, STEPControl_AsIs)
    status = writer.Write(str(path))
    if status != IFSelect_RetDone:
        raise RuntimeError(f"{path}: the STEP writer answered {status}")
    return path


def subshapes(shape, kind):
    from OCP.TopExp import TopExp_Explorer

    e, out = TopExp_Explorer(shape, kind), []
    while e.More():
        out.append(e.Current())
        e.Next()
    return out


def count(shape, kind):
    return len(subshapes(shape, kind))


def is_valid(shape):
    """BRepCheck_Analyzer's verdict on the shape."""
    from OCP.BRepCheck import BRepCheck_Analyzer

    return bool(BRepCheck_Analyzer(shape).IsValid())


def wall_deviation(original, imported, turn=0.0, shift=0.0, core=False, top=1.0, bottom=0.0):
    """The round trip: the largest r * |dtheta| [mm] of channel 0's two walls between the original and the
    imported blisk, at meridional points over the blade (60 axial stations over the original's full-span axial
    range, 21 span fractions from hub to shroud; ``core``: 19 from 5 % to 95 %; none above the fraction ``top`` or
    below ``bottom``),
    where both have both walls; the imported point is the original one shifted by ``shift`` along X, its angles
    turned back by ``turn``. Returns (deviation, points compared, points with both walls in the original)."""
    x0, x1 = original.full_span_axial_range
    xs = np.linspace(x0, x1, 60)
    f = np.linspace(0.05, 0.95, 19) if core else np.linspace(0.0, 1.0, 21)
    f = f[(f <= top) & (f >= bottom)]
    xx, ff = np.meshgrid(xs, f)
    hub, shroud = original.hub.radius_at(xx), original.shroud.radius_at(xx)
    rr = hub + ff * (shroud - hub)
    x, r = xx.ravel(), rr.ravel()
    s0, p0, in0 = original.wall_angles(x, r)
    s1, p1, in1 = imported.wall_angles(x + shift, r)
    ok = in0 & in1
    pitch = original.pitch
    d_s = (s1 - turn - s0 + pitch / 2) % pitch - pitch / 2
    d_p = (p1 - turn - p0 + pitch / 2) % pitch - pitch / 2
    dev = np.maximum(np.abs(d_s), np.abs(d_p)) * r
    if not ok.any():
        return float("inf"), 0, int(in0.sum())
    return float(dev[ok].max()), int(ok.sum()), int(in0.sum())
