"""A blisk from a STEP file: one closed solid of the whole blisk or of one sector, read with OpenCascade.

:func:`import_step` reads the solid (``cadquery-ocp``, imported only here and only when a STEP file is read, so
no other geometry path pays for it) and finds what the loader's other sources give by hand:

1. **The solid.** Exactly one closed solid: an unreadable file, an open shell (free edges), several bodies or
   none are refused with a :class:`~edm_planner.errors.GeometryError` that names the problem.
2. **The rotation axis**, from the faces of revolution (cylinders, cones, tori, surfaces of revolution; the
   coaxial family of the largest area), or, without any, from the inertia axes (two equal principal moments:
   the third axis). A part with neither is refused (no rotational symmetry). An axis that is not X is taken
   onto X by a rigid transform (the rotation of least angle taking its direction onto +X, the foot of the
   world origin on the axis onto the origin), reported and applied.
3. **The blade count.** Whole blisk: the blades are counted on the solid's section with the coaxial
   cylinder at mid span (sampled by circles, one per axial station: the stretches of material on the circle
   where the most blades are met); they must be equally spaced copies (else: no rotational symmetry). Sector:
   from the sector angle (the angular extent of the hub ring, by bisection on meridional rays), which must
   divide the full turn.
4. **Hub and shroud profiles** from the meridional section: rays in meridional half-planes at several angles
   between the blades; per axial station the hub is the top of the first stretch of material (lowest over
   the angles, so a ray through a blade or its root fillet does not count), the shroud the bottom of the last.
5. **The blade sections**, on ``section_count`` coaxial cylinders at radii from the hub to the shroud, clear of
   the walls and of any root or tip fillet (faces lying wholly near a wall): on each, blade 0 (the blade
   nearest theta = 0) is followed along the axis from station to station, its leading and trailing edge found
   by bisection, and at ``station_count`` stations between them the circle (x, r) enters it at theta_minus and
   leaves it at theta_plus. That is a :class:`~.sections.BladeSections` as the measured-sections path has it,
   which goes on through the same NURBS reconstruction (:class:`~.blisk.Blisk` extends it into the walls).
6. **Fit deviation** (:func:`fit_deviation`): sections on more cylinders, half way between the section radii,
   against the reconstructed faces (the largest distance along the circle, mm).

Written by hand, because OpenCascade has no function for them: the free-edge count of step 1, the choice of
the axis among the faces' axes and the inertia axes (step 2), counting the blades, their spacing and the
sector angle (step 3), the profiles from rays (step 4), the fillet zones, following blade 0 and its edges and
stations (step 5), and the fit (step 6). OCP gives the STEP reader, the topology explorer, each face's own
axis, the mass properties, the tessellation and the curve/shape intersector (the crossings of a line or an
arc with the faces, with the transition in or out) they are built on.

Units: millimetres and radians (the reader converts the file's declared unit to mm). Frame W: X is the blisk
axis, ``theta = atan2(z, y)``.
"""

import logging
from dataclasses import dataclass, field

import numpy as np

from ..errors import GeometryError, GeometryFileError
from .profiles import RevolutionProfile
from .readers import unit_scale
from .sections import BladeSections
from .solid_sections import (angular_extent, blade_sections, merge_wrap, mid_span_blades, stretches, walls,
                             whole_count, wrap_angle)

_log = logging.getLogger(__name__)

#: two axes of revolution are one when their directions differ by less than this [rad] ...
AXIS_ANGLE_TOL = 1e-6
#: ... and their lines pass within this fraction of the part's size of each other
AXIS_OFFSET_TOL = 1e-6
#: two principal moments of inertia are equal (an axis of symmetry) within this relative difference
INERTIA_TOL = 1e-4
#: a sector angle must be 2*pi/N within this fraction of it
SECTOR_TOL = 0.002
#: a blade face whose points all lie within this fraction of the channel height of a wall is a fillet there
FILLET_ZONE = 0.3
#: STEP unit names (as the file declares them) -> LENGTH_UNITS names
_STEP_UNITS = {"MM": "mm", "MILLIMETRE": "mm", "CM": "cm", "CENTIMETRE": "cm", "M": "m", "METRE": "m",
               "INCH": "in", "IN": "in"}


@dataclass
class StepBlisk:
    """What :func:`import_step` found.

    Attributes
    ----------
    sections : BladeSections
        Blade 0 (the blade nearest theta = 0 after the transform), S x C stations.
    hub, shroud : RevolutionProfile
    blade_count : int
    report : dict
        What was found, for :meth:`~.loader.LoadedGeometry.info` (keys without the ``step_`` prefix).
    check : dict
        Sections half way between the section radii (``x``, ``r``, ``theta_minus``, ``theta_plus``
        lists of arrays), for :func:`fit_deviation`.
    """

    sections: BladeSections
    hub: RevolutionProfile
    shroud: RevolutionProfile
    blade_count: int
    report: dict = field(default_factory=dict)
    check: dict = field(default_factory=dict, repr=False)


# -- reading -------------------------------------------------------------------------------------------
def read_step_solid(path, length_unit=None):
    """The one closed solid of a STEP file, in mm (OCP ``TopoDS_Solid``) and a dict of what was read.

    Parameters
    ----------
    path : path
    length_unit : str, optional
        The unit the file's numbers are in, overriding the unit it declares (one of
        :data:`~.readers.LENGTH_UNITS`); None: as declared.

    Raises
    ------
    GeometryFileError
        Not a readable STEP file.
    GeometryError
        No solid, an open shell, several bodies.
    """
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_SHELL, TopAbs_SOLID
    from OCP.collections import Sequence_TCollection_AsciiString

    reader = STEPControl_Reader()
    status = reader.ReadFile(str(path))
    if status != IFSelect_RetDone:
        raise GeometryFileError(f"{path}: not a readable STEP file (the reader answered {status.name})")
    reader.TransferRoots()
    shape = reader.OneShape()
    if shape is None or shape.IsNull():
        raise GeometryError(f"{path}: the STEP file holds no shape")
    names = [Sequence_TCollection_AsciiString() for _ in range(3)]
    reader.FileUnits(*names)
    declared = sorted({names[0].Value(i).ToCString().upper() for i in range(1, names[0].Length() + 1)})
    info = {"file": str(path), "declared_units": declared}
    solids = _subshapes(shape, TopAbs_SOLID)
    if not solids:
        shells = _subshapes(shape, TopAbs_SHELL)
        free = sum(_free_edge_count(s) for s in shells) if shells else 0
        if shells and free:
            raise GeometryError(f"{path}: an open shell, not a closed solid ({len(shells)} shell(s) with {free} "
                                f"free edges, edges of only one face): export the blisk as a closed solid")
        if shells:
            raise GeometryError(f"{path}: {len(shells)} closed shell(s) but no solid: export the blisk as a solid")
        raise GeometryError(f"{path}: holds no solid (only loose faces, edges or points): export the blisk as a "
                            f"closed solid")
    if len(solids) > 1:
        raise GeometryError(f"{path}: several bodies ({len(solids)} solids); give one solid: the whole blisk or "
                            f"one sector of it")
    solid = solids[0]
    free = _free_edge_count(solid)
    if free:
        raise GeometryError(f"{path}: an open shell, not a closed solid: the solid has {free} free edges (edges "
                            f"of only one face)")
    if len(_subshapes(solid, TopAbs_SHELL)) != 1:
        raise GeometryError(f"{path}: the solid has {len(_subshapes(solid, TopAbs_SHELL))} shells (voids or "
                            f"several bodies); give one closed solid without voids")
    scale = 1.0
    if length_unit is not None:
        given = unit_scale(length_unit, "step")
        known = [_STEP_UNITS.get(n) for n in declared]
        if len(set(known)) != 1 or known[0] is None:
            raise GeometryError(f"step.length_unit: the file declares the length units {declared}, which are not "
                                f"understood; cannot override them")
        scale = given / unit_scale(known[0], "step")
    if scale != 1.0:
        solid = _transformed(solid, _scaling(scale))
    info["scale"] = scale
    return solid, info


def _subshapes(shape, kind):
    from OCP.TopExp import TopExp_Explorer

    out, seen = [], set()
    explorer = TopExp_Explorer(shape, kind)
    while explorer.More():
        s = explorer.Current()
        key = s.__hash__()
        if key not in seen or not any(s.IsSame(o) for o in out):
            seen.add(key)
            out.append(s)
        explorer.Next()
    return out


def _free_edge_count(shape):
    """Edges bounding only one face (a seam, used twice by its face, and degenerate edges do not count).

    Written by hand: OCP's ShapeAnalysis_FreeBounds gives the free wires of shells, not a count on a solid.
    """
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
    from OCP.TopExp import TopExp
    from OCP.TopoDS import TopoDS
    from OCP.collections import IndexedDataMap_TopoDS_Shape_List_TopoDS_Shape_TopTools_ShapeMapHasher as Map

    ancestors = Map()
    TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, ancestors)
    free = 0
    for i in range(1, ancestors.Size() + 1):
        edge = TopoDS.Edge(ancestors.FindKey(i))
        faces = ancestors.FindFromIndex(i)
        if faces.Size() >= 2 or BRep_Tool.Degenerated_s(edge):
            continue
        if faces.Size() == 1 and BRep_Tool.IsClosed_s(edge, TopoDS.Face(faces.First())):
            continue
        free += 1
    return free


def _transformed(shape, trsf):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform

    return BRepBuilderAPI_Transform(shape, trsf, True).Shape()


def _scaling(scale):
    from OCP.gp import gp_Pnt, gp_Trsf

    t = gp_Trsf()
    t.SetScale(gp_Pnt(0, 0, 0), float(scale))
    return t


# -- the axis ------------------------------------------------------------------------------------------
def _size(shape):
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib

    box = Bnd_Box()
    BRepBndLib.Add_s(shape, box, True)
    lo = np.array(box.CornerMin().Coord())
    hi = np.array(box.CornerMax().Coord())
    return lo, hi


def _face_axes(shape):
    """(point, unit direction, area) of every face of revolution (cylinder, cone, torus, surface of revolution)."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepGProp import BRepGProp
    from OCP.GeomAbs import GeomAbs_Cone, GeomAbs_Cylinder, GeomAbs_SurfaceOfRevolution, GeomAbs_Torus
    from OCP.GProp import GProp_GProps
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopoDS import TopoDS

    out = []
    for f in _subshapes(shape, TopAbs_FACE):
        face = TopoDS.Face(f)
        surf = BRepAdaptor_Surface(face)
        kind = surf.GetType()
        if kind == GeomAbs_Cylinder:
            ax = surf.Cylinder().Axis()
        elif kind == GeomAbs_Cone:
            ax = surf.Cone().Axis()
        elif kind == GeomAbs_Torus:
            ax = surf.Torus().Axis()
        elif kind == GeomAbs_SurfaceOfRevolution:
            ax = surf.AxeOfRevolution()
        else:
            continue
        props = GProp_GProps()
        BRepGProp.SurfaceProperties_s(face, props)
        out.append((np.array(ax.Location().Coord()), np.array(ax.Direction().Coord()), props.Mass()))
    return out


def find_axis(shape):
    """The rotation axis of a solid: (point, unit direction, how it was found).

    Written by hand (OCP gives each face's own axis and the principal axes of inertia, not the part's axis):
    the faces of revolution are grouped into coaxial families (direction within :data:`AXIS_ANGLE_TOL`, lines
    within :data:`AXIS_OFFSET_TOL` of the part's size) and the family of the largest area is the axis.
    Without faces of revolution, the principal axes of inertia: two equal moments (within
    :data:`INERTIA_TOL`) make the third axis, through the centre of mass, an axis of symmetry.

    Raises
    ------
    GeometryError
        Neither: no rotational symmetry about any axis.
    """
    lo, hi = _size(shape)
    size = float(np.linalg.norm(hi - lo))
    families = []             # [point, direction, area]
    for p, d, area in _face_axes(shape):
        for fam in families:
            q, e = fam[0], fam[1]
            if np.linalg.norm(np.cross(d, e)) < AXIS_ANGLE_TOL:
                off = np.linalg.norm(np.cross(p - q, e))
                if off < AXIS_OFFSET_TOL * size + 1e-9:
                    fam[2] += area
                    break
        else:
            families.append([p, d, area])
    if families:
        p, d, _ = max(families, key=lambda f: f[2])
        plural = "y" if len(families) == 1 else "ies"
        return p, _canonical(d), f"faces of revolution ({len(families)} axis famil{plural}; the largest by area)"
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, props)
    principal = props.PrincipalProperties()
    moments = np.array(principal.Moments())
    axes = [principal.FirstAxisOfInertia(), principal.SecondAxisOfInertia(), principal.ThirdAxisOfInertia()]
    scale = float(np.max(np.abs(moments)))
    for i in range(3):
        j, k = [m for m in range(3) if m != i]
        if abs(moments[j] - moments[k]) <= INERTIA_TOL * scale and abs(moments[i] - moments[j]) > INERTIA_TOL * scale:
            centre = np.array(props.CentreOfMass().Coord())
            return centre, _canonical(np.array(axes[i].Coord())), "inertia axes (no faces of revolution)"
    raise GeometryError(
        "the part has no rotational symmetry about any axis: no faces of revolution, and no two equal principal "
        f"moments of inertia (moments {', '.join(f'{m:.6g}' for m in moments)} mm^5): not a blisk or a sector "
        f"of one")


def _canonical(d):
    """The axis direction with a positive X component (else its largest component positive)."""
    d = np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
    lead = 0 if abs(d[0]) > 1e-9 else int(np.argmax(np.abs(d)))
    return d if d[lead] > 0 else -d


def axis_transform(point, direction, tol=1e-9):
    """4x4 rigid transform taking the axis (point, direction) onto X: the rotation of least angle taking the
    direction onto +X, and the foot of the world origin on the axis to the origin. Identity for X itself."""
    d = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    p = np.asarray(point, dtype=np.float64)
    foot = p - (p @ d) * d                          # the axis point nearest the world origin
    x = np.array([1.0, 0.0, 0.0])
    axis = np.cross(d, x)
    s, c = np.linalg.norm(axis), float(d @ x)
    if s < tol:
        rot = np.eye(3) if c > 0 else np.diag([-1.0, 1.0, -1.0])
    else:
        k = axis / s
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + s * kx + (1 - c) * kx @ kx
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = -rot @ foot
    if np.linalg.norm(foot) < tol * max(1.0, np.linalg.norm(p)):
        out[:3, 3] = 0.0
    return out


def _gp_trsf(matrix):
    from OCP.gp import gp_Trsf

    t = gp_Trsf()
    m = np.asarray(matrix, dtype=np.float64)
    t.SetValues(*[float(v) for v in m[:3, :].ravel()])
    return t


def describe_transform(matrix):
    """Words for a rigid 4x4 transform: rotation angle about a unit axis, and the translation."""
    m = np.asarray(matrix, dtype=np.float64)
    rot, t = m[:3, :3], m[:3, 3]
    angle = float(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1.0, 1.0)))
    if angle < 1e-12:
        turn = "no rotation"
    else:
        k = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
        if np.linalg.norm(k) < 1e-9:          # a half turn
            w, v = np.linalg.eigh(rot + np.eye(3))
            k = v[:, np.argmax(w)]
        k = k / np.linalg.norm(k)
        turn = f"rotation by {np.degrees(angle):.6g} deg about ({k[0]:.6g}, {k[1]:.6g}, {k[2]:.6g})"
    return f"{turn}, then translation by ({t[0]:.6g}, {t[1]:.6g}, {t[2]:.6g}) mm"


# -- rays, sections ------------------------------------------------------------------------------------
class _Rays:
    """Meridional rays (the stretches of material along the half-line from the axis at (x, theta)) and
    coaxial circles (the stretches of material along the circle (x, r)).

    Written by hand on OCP's IntCurvesFace_ShapeIntersector (a curve's crossings of the faces), with the
    transition (in or out) at each. A circle at (x, r) is a line of the solid's
    section on the coaxial cylinder of radius r: the cylinder sections are sampled by circles, one per axial
    station (a boolean section of the whole cylinder, BRepAlgoAPI_Section, took about 5 s per cylinder on a
    sector, the circles a few milliseconds each).
    """

    def __init__(self, shape, r_max):
        from OCP.IntCurvesFace import IntCurvesFace_ShapeIntersector

        self.hits = IntCurvesFace_ShapeIntersector()
        self.hits.Load(shape, 1e-7)
        self.r_max = float(r_max)


    def intervals(self, x, theta):
        """[(r_in, r_out), ...] of material on the ray, or None where the crossings do not pair up."""
        from OCP.gp import gp_Dir, gp_Lin, gp_Pnt

        line = gp_Lin(gp_Pnt(float(x), 0.0, 0.0), gp_Dir(0.0, float(np.cos(theta)), float(np.sin(theta))))
        self.hits.Perform(line, 0.0, self.r_max)
        if not self.hits.IsDone():
            return None
        w = sorted(self.hits.WParameter(i) for i in range(1, self.hits.NbPnt() + 1))
        merged = []
        for v in w:                                   # a crossing on an edge is found once per face
            if not merged or v - merged[-1] > 1e-7:
                merged.append(v)
        if len(merged) % 2:
            return None
        return [(merged[i], merged[i + 1]) for i in range(0, len(merged), 2)]


    def circle(self, x, r, start, length=2 * np.pi):
        """[(theta_in, theta_out), ...] of material on the arc of the circle (x, r) about X from ``start`` over
        ``length`` (unwrapped: start <= theta <= start + length; a stretch running past the arc's end is cut
        there), or None where the crossings do not pair up."""
        from OCP.Geom import Geom_Circle
        from OCP.GeomAdaptor import GeomAdaptor_Curve
        from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt

        # parameter u of this circle is theta: (x, r cos u, r sin u). The intersector is given arcs of at most
        # an eighth of a turn: on a whole periodic circle it missed crossings and took 0.2 s, on arcs 1 ms each.
        circle = Geom_Circle(gp_Ax2(gp_Pnt(float(x), 0, 0), gp_Dir(1, 0, 0), gp_Dir(0, 1, 0)), float(r))
        pieces = max(1, int(np.ceil(length / (np.pi / 4))))
        bounds = np.linspace(start, start + length, pieces + 1)
        from OCP.IntCurveSurface import IntCurveSurface_In, IntCurveSurface_Out

        w = []
        for a, b in zip(bounds[:-1], bounds[1:]):
            self.hits.Perform(GeomAdaptor_Curve(circle, float(a), float(b)), float(a), float(b))
            if not self.hits.IsDone():
                return None
            for i in range(1, self.hits.NbPnt() + 1):
                t = self.hits.Transition(i)
                if t in (IntCurveSurface_In, IntCurveSurface_Out):
                    w.append((self.hits.WParameter(i), t == IntCurveSurface_In))
        found = stretches(w, start, start + length, 1e-9)
        return None if found is None else merge_wrap(found, start, length)


# -- the import ----------------------------------------------------------------------------------------
def import_step(path, section_count=25, station_count=81, length_unit=None, check_count=4):
    """Read a STEP blisk (whole or one sector) and find its axis, blade count, hub, shroud and blade sections.

    Parameters
    ----------
    path : path
        The STEP file (already checked for size and place by the caller, :class:`~.loader.FileAccess`).
    section_count, station_count : int
        S cylinders from hub to shroud, C stations per section.
    length_unit : str, optional
        Overrides the length unit the file declares.
    check_count : int
        Cylinders half way between section radii kept for :func:`fit_deviation`.

    Returns
    -------
    StepBlisk

    Raises
    ------
    GeometryFileError, GeometryError
    """
    solid, report = read_step_solid(path, length_unit)
    point, direction, how = find_axis(solid)
    matrix = axis_transform(point, direction)
    moved = not np.allclose(matrix, np.eye(4), atol=1e-12)
    if moved:
        solid = _transformed(solid, _gp_trsf(matrix))
    report.update({"axis_point": [float(v) for v in point], "axis_direction": [float(v) for v in direction],
                   "axis_found_from": how, "transform_applied": bool(moved),
                   "transform": matrix.tolist(),
                   "transform_text": describe_transform(matrix) if moved else "none: the axis is X"})
    lo, hi = _size(solid)
    r_max = 1.05 * float(np.max(np.abs(np.r_[lo[1:], hi[1:]]))) * np.sqrt(2.0)
    x_lo, x_hi = float(lo[0]), float(hi[0])
    rays = _Rays(solid, r_max)
    # the angular extent of the part at the axial middle: the hub ring's (whole turn or a sector)
    kind, sector, angles = angular_extent(rays, x_lo, x_hi)
    hub, shroud, found = walls(rays, x_lo, x_hi, angles)
    report.update(found)
    mid_x = 0.5 * (max(hub.x_range[0], shroud.x_range[0]) + min(hub.x_range[1], shroud.x_range[1]))
    r_mid = 0.5 * float(hub.radius_at(mid_x) + shroud.radius_at(mid_x))
    loops = mid_span_blades(rays, r_mid, x_lo, x_hi)
    if not loops:
        raise GeometryError(f"{path}: no blade meets the cylinder at mid span (r = {r_mid:.3f} mm): not a blisk")
    if kind == "whole":
        blade_count = whole_count(loops, path, r_mid)
    else:
        blade_count = int(round(2 * np.pi / sector))
        if blade_count < 2 or abs(blade_count * sector - 2 * np.pi) > SECTOR_TOL * 2 * np.pi:
            raise GeometryError(
                f"{path}: no rotational symmetry: the sector spans {np.degrees(sector):.5g} deg, not 360/N deg for "
                f"a whole number N of blades (nearest N = {blade_count}, off by "
                f"{abs(blade_count * sector - 2 * np.pi) / (2 * np.pi):.2%} of the turn)")
        if len(loops) != 1:
            raise GeometryError(f"{path}: a sector of {np.degrees(sector):.4g} deg holds {len(loops)} blade "
                                f"sections at mid span, not one")
    blade0 = min(loops, key=lambda lp: abs(wrap_angle(lp["theta"])))
    report.update({"kind": "whole blisk" if kind == "whole" else "sector", "blade_count": blade_count,
                   "sector_angle": float(sector), "mid_span_radius": r_mid, "mid_span_blades": len(loops)})
    zones = _fillet_zones(solid, hub, shroud)
    report.update(zones)
    sections, check, radii = blade_sections(rays, hub, shroud, blade0, 2 * np.pi / blade_count, zones, section_count,
                                       station_count, check_count, x_lo, x_hi, path)
    report.update({"section_count": int(section_count), "station_count": int(station_count),
                   "section_radii": [float(radii[0]), float(radii[-1])]})
    return StepBlisk(sections, hub, shroud, blade_count, report, check)



def _fillet_zones(solid, hub, shroud):
    """How far root and tip fillets (or other blend faces) reach from the walls [mm].

    Written by hand on OCP's tessellation: every face's mesh nodes are placed in the channel's span fraction
    f = (r - hub(x)) / (shroud(x) - hub(x)); a face with nodes inside the channel (0 < f < 1) whose nodes all
    lie in the hub-side (f < FILLET_ZONE) or tip-side (f > 1 - FILLET_ZONE) band is a fillet there.
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    BRepMesh_IncrementalMesh(solid, 0.05, False, 0.3, False)
    lo_x = max(hub.x_range[0], shroud.x_range[0])
    hi_x = min(hub.x_range[1], shroud.x_range[1])
    root, tip, blend = 0.0, 0.0, 0
    for f in _subshapes(solid, TopAbs_FACE):
        face = TopoDS.Face(f)
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(face, loc)
        if tri is None:
            continue
        trsf = loc.Transformation()
        pts = np.array([tri.Node(i).Transformed(trsf).Coord() for i in range(1, tri.NbNodes() + 1)])
        x, r = pts[:, 0], np.hypot(pts[:, 1], pts[:, 2])
        keep = (x > lo_x) & (x < hi_x)
        if not keep.any():
            continue
        x, r = x[keep], r[keep]
        h_r, s_r = hub.radius_at(x), shroud.radius_at(x)
        frac = (r - h_r) / (s_r - h_r)
        height = s_r - h_r
        tol = 1e-3
        inner = (frac > tol) & (frac < 1 - tol)
        if not inner.any():
            continue                       # a wall face (hub, shroud, bore, sides)
        if frac.max() < FILLET_ZONE:
            root = max(root, float(np.max((frac * height)[inner])))
            blend += 1
        elif frac.min() > 1 - FILLET_ZONE:
            tip = max(tip, float(np.max(((1 - frac) * height)[inner])))
            blend += 1
    return {"root_fillet_depth": root, "tip_fillet_depth": tip, "fillet_faces": blend}

