"""The blisk: hub and shroud of revolution, N copies of one blade, its channels.

:class:`Blisk` is the geometry every other part of the product reads. It is
built from a :class:`~.sections.BladeSections` (whatever the blade's source)
and two :class:`~.profiles.RevolutionProfile`, validated on construction, and
answers the questions the planner asks: the faces of the channel k, their
meshes, the walls' angles at a meridional position.

Channel k lies between the *suction* face of blade k (its +theta face) and the
*pressure* face of blade k+1 (its -theta face), above the hub and below the
shroud. Blade k is blade 0 rotated by ``k * pitch`` about X. A blisk as measured
has blades that differ: its channel k is then a Blisk of its own
(:mod:`.as_measured`) whose ``blade`` is blade k and whose ``pressure_blade``
is blade k+1, both turned back into blade 0's position, so that its channel k
is the part's channel k and every periodic tool (fields, checks, plans turned
by k pitches) applies to it unchanged.
"""

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..constants import SIZE, TOL
from ..errors import GeometryError
from .frames import cylindrical_to_cartesian, rotation_about_x
from .mesh_build import closed_blade_mesh, face_grid_mesh
from .parametric_yaml import SPAN_EXTENSION
from .profiles import RevolutionProfile
from .sections import BladeSections
from .surfaces import BladeFace

#: labels of the channel surfaces, in the order used by every interface
CHANNEL_SURFACES = ("suction", "pressure", "hub", "shroud")
MODEL_FORMAT = "edm_planner.geometry/1"
#: how far the blade reaches into the hub and the shroud (:func:`extend_to_walls`), as a
#: fraction of the smallest channel height; see :func:`wall_overlap`
WALL_OVERLAP_FRACTION = 0.02


def channel_height_range(hub, shroud):
    """(min, max) of shroud minus hub radius over the profiles' common x range [mm]."""
    lo = max(hub.x_range[0], shroud.x_range[0])
    hi = min(hub.x_range[1], shroud.x_range[1])
    xs = np.linspace(lo, hi, 400)
    h = shroud.radius_at(xs) - hub.radius_at(xs)
    return float(h.min()), float(h.max())


def wall_overlap(hub, shroud):
    """How far blade sections reach into the hub and the shroud [mm].

    ``WALL_OVERLAP_FRACTION`` of the smallest channel height: :class:`Blisk`
    extends its blade at least this far into both walls (a blade mesh is
    sliced farther, :func:`mesh_slice_overlap`).
    """
    return WALL_OVERLAP_FRACTION * channel_height_range(hub, shroud)[0]


#: how far a blade mesh is sliced beyond hub and shroud (:func:`mesh_slice_overlap`), as a fraction of
#: the smallest channel height: the parametric blade's default ``span_extension``
MESH_SLICE_FRACTION = SPAN_EXTENSION


def mesh_slice_overlap(hub, shroud):
    """How far :func:`~.mesh_sections.mesh_to_sections` slices a blade mesh beyond hub and shroud [mm].

    ``MESH_SLICE_FRACTION`` (3 %) of the smallest channel height, more than the
    :func:`wall_overlap` (2 %) every blade is extended to: the blade's sections
    inside the walls count where a figure is taken over all sections (the
    widest angular blade thickness behind the set designer's largest
    circumferential reduction, :attr:`Blisk.full_span_axial_range`), so a mesh
    of a parametric blade (continued 3 % into the walls by default) is sliced
    as far as that blade runs and reproduces those figures, not only its walls
    inside the channel. Still well inside end caps a CAD blade has past the walls.
    """
    return MESH_SLICE_FRACTION * channel_height_range(hub, shroud)[0]


def extend_to_walls(sections, hub, shroud, overlap):
    """Extend a blade whose end sections stop at (or short of) the hub or shroud.

    Measured blades end exactly on the hub and shroud lines (Rotor 37's
    sections 1 and 13 are the intersections), so interpolation noise could
    open a sliver between blade and wall. The blade gets one more section at
    each short end, continued linearly along the last section step by the
    same fraction at every station (so no station repeats a point), the
    fraction grown until every station reaches ``overlap`` mm into the wall
    at its own, shifted x. A blade that already reaches is returned as is,
    so extending twice changes nothing.

    Returns
    -------
    BladeSections
    """
    stacked = np.stack([sections.x, sections.r, sections.theta_minus, sections.theta_plus])  # (4, S, C)

    def reach(end, inner, wall_r, sign):
        """One extra section beyond ``end`` (None if none is needed); sign -1: hub, +1: shroud."""
        dr = np.maximum(np.abs(end[1] - inner[1]), 1e-9)
        t = 0.0
        for _ in range(20):
            cand = end + t * (end - inner)
            short = sign * (wall_r(cand[0]) + sign * overlap - cand[1])
            if np.all(short <= 1e-12):
                break
            t += 1.05 * float(np.max(short / dr)) + 1e-6
        if t == 0.0:
            return None
        cand[3] = np.maximum(cand[3], cand[2])    # a zero-thickness edge must not cross
        return cand

    out = stacked
    extra = reach(out[:, 0], out[:, 1], hub.radius_at, -1.0)
    if extra is not None:
        out = np.concatenate([extra[:, None], out], axis=1)
    extra = reach(out[:, -1], out[:, -2], shroud.radius_at, +1.0)
    if extra is not None:
        out = np.concatenate([out, extra[:, None]], axis=1)
    if out is stacked:
        return sections
    return BladeSections(*out)


def validate_profiles(hub, shroud):
    """Plausibility of the hub and shroud profiles: units, and hub below shroud."""
    hub_r = hub.points[:, 1]
    if hub_r.min() < SIZE.min_radius:
        raise GeometryError(
            f"hub_profile: radius {hub_r.min():g} mm is implausibly small for a blisk; "
            "are the values in metres? All lengths are millimetres")
    if shroud.points[:, 1].max() > SIZE.max_radius:
        raise GeometryError(
            f"shroud_profile: radius {shroud.points[:, 1].max():g} mm is implausibly large; "
            "are the values in micrometres or another unit? All lengths are millimetres")
    lo = max(hub.x_range[0], shroud.x_range[0])
    hi = min(hub.x_range[1], shroud.x_range[1])
    if hi <= lo:
        raise GeometryError("hub_profile and shroud_profile do not overlap in x")
    xs = np.linspace(lo, hi, 400)
    height = shroud.radius_at(xs) - hub.radius_at(xs)
    if height.min() < SIZE.min_channel_height:
        i = int(np.argmin(height))
        raise GeometryError(
            f"hub_profile is not below shroud_profile: at x = {xs[i]:.3f} mm the hub radius "
            f"{hub.radius_at(xs[i]):.3f} mm is not at least {SIZE.min_channel_height} mm below "
            f"the shroud radius {shroud.radius_at(xs[i]):.3f} mm")


@dataclass(frozen=True, eq=False)
class Blisk:
    """An integral shrouded blisk.

    Parameters
    ----------
    blade_count : int
        N >= 2 blades, pitch 2*pi/N.
    hub, shroud : RevolutionProfile
        Meridional profiles [mm].
    blade : BladeSections
        Blade 0 [mm, rad]; extended into hub and shroud if it stops at them.
    name : str
    source : str
        'parametric', 'sections' or 'mesh' (for the summary).
    knot_rule : str
        'chord' (default, accurate) or 'paper' (Liu 2024 eq. 15) for the face reconstruction.
    part_axial_range : (float, float), optional
        Where the part's material lies along X [mm]; it must hold the blades. None: the profiles' and the
        blades' whole x range. Profiles that run on through a rig's ducts (NASA Rotor 37's hub and casing
        lines reach 229 mm upstream) would otherwise put the cycle's clear position beyond a machine's travel.
    pressure_blade : BladeSections, optional
        The blade on the pressure side of channel 0 (blade 1) turned back by one pitch into blade 0's
        position [mm, rad], where it differs from ``blade`` (one channel of a blisk as measured,
        :mod:`.as_measured`). None: every blade is ``blade``.
    """

    blade_count: int
    hub: RevolutionProfile
    shroud: RevolutionProfile
    blade: BladeSections
    name: str = ""
    source: str = "parametric"
    knot_rule: str = "chord"
    part_axial_range: tuple = None
    pressure_blade: BladeSections = None
    _cache: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self):
        n = self.blade_count
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            raise GeometryError(f"blade_count: must be an integer >= 2, got {n!r}")
        object.__setattr__(self, "blade_count", int(n))
        validate_profiles(self.hub, self.shroud)
        overlap = wall_overlap(self.hub, self.shroud)
        object.__setattr__(self, "blade", extend_to_walls(self.blade, self.hub, self.shroud, overlap))
        if self.pressure_blade is not None:
            object.__setattr__(self, "pressure_blade",
                               extend_to_walls(self.pressure_blade, self.hub, self.shroud, overlap))
        self._validate_blade()
        if self.part_axial_range is not None:
            object.__setattr__(self, "part_axial_range", self._checked_part_range(self.part_axial_range))

    # -- validation -----------------------------------------------------------
    def _validate_blade(self):
        b = self.blade
        lo = max(self.hub.x_range[0], self.shroud.x_range[0])
        hi = min(self.hub.x_range[1], self.shroud.x_range[1])
        for which, blade in (("blade", b), ("pressure_blade", self.pressure_blade)):
            if blade is not None and (blade.x.min() < lo - 1e-6 or blade.x.max() > hi + 1e-6):
                raise GeometryError(
                    f"{which}: axial extent [{blade.x.min():.3f}, {blade.x.max():.3f}] mm reaches beyond the "
                    f"hub/shroud profiles' common range [{lo:.3f}, {hi:.3f}] mm; extend the profiles")
        # each blade occupies [theta_minus, theta_plus] at (x, r); its neighbour the same + pitch
        gap = (b.theta_minus + self.pitch - b.theta_plus) * b.r
        if self.pressure_blade is not None:
            # the neighbour differs: its pressure face at blade 0's stations
            nb = self.pressure_blade
            th_p, inside = self.pressure_face.theta_at(b.x.ravel(), b.r.ravel())
            gap = np.where(inside.reshape(b.shape), (th_p.reshape(b.shape) + self.pitch - b.theta_plus) * b.r,
                           np.inf)
            th_s, inside_s = self.suction_face.theta_at(nb.x.ravel(), nb.r.ravel())
            back = np.where(inside_s.reshape(nb.shape),
                            (nb.theta_minus + self.pitch - th_s.reshape(nb.shape)) * nb.r, np.inf)
            if back.min() < gap.min():
                b, gap = nb, back
        if gap.min() < TOL.min_feature:
            s, c = np.unravel_index(np.argmin(gap), gap.shape)
            raise GeometryError(
                f"blade: intersects its neighbour blade at x = {b.x[s, c]:.3f} mm, r = {b.r[s, c]:.3f} mm "
                f"(blade angular thickness {b.theta_plus[s, c] - b.theta_minus[s, c]:.4f} rad exceeds the "
                f"pitch 2*pi/{self.blade_count} = {self.pitch:.4f} rad); check blade_count and the blade's units")
        height = self.channel_height_range[1]
        if np.ptp(b.x) > 20 * max(height, 1e-9) or np.ptp(b.x) < 1e-3 * height:
            raise GeometryError(
                f"blade: axial extent {np.ptp(b.x):g} mm is absurd against the channel height "
                f"{height:g} mm; check the units of the blade data (mm expected)")

    # -- basic figures ---------------------------------------------------------
    @property
    def pitch(self):
        """Angle between neighbouring blades [rad]."""
        return 2.0 * np.pi / self.blade_count

    @property
    def axial_range(self):
        """(x_min, x_max) of the blade [mm]."""
        return float(self.blade.x.min()), float(self.blade.x.max())

    @property
    def part_envelope(self):
        """(x_min, x_max) [mm] within which the part's material lies: ``part_axial_range``, or by default the
        hub's, shroud's and blades' whole x range."""
        if self.part_axial_range is not None:
            return tuple(self.part_axial_range)
        blade = self.axial_range
        return (float(min(self.hub.x_range[0], self.shroud.x_range[0], blade[0])),
                float(max(self.hub.x_range[1], self.shroud.x_range[1], blade[1])))

    def _checked_part_range(self, value):
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise GeometryError(f"part_axial_range: expected two numbers [x_min, x_max] in mm, got {value!r}") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise GeometryError(f"part_axial_range: expected finite x_min < x_max in mm, got [{lo!r}, {hi!r}]")
        b0, b1 = self.axial_range
        if lo > b0 + 1e-9 or hi < b1 - 1e-9:
            raise GeometryError(f"part_axial_range: [{lo:g}, {hi:g}] mm does not hold the blades, which span "
                                f"[{b0:.3f}, {b1:.3f}] mm")
        return (lo, hi)

    @property
    def channel_height_range(self):
        """(min, max) of shroud minus hub radius over the profiles' common range [mm]."""
        return channel_height_range(self.hub, self.shroud)

    @property
    def full_span_axial_range(self):
        """(x_start, x_end) [mm] where both blade faces exist over the whole span."""
        return float(self.blade.x[:, 0].max()), float(self.blade.x[:, -1].min())

    # -- faces -----------------------------------------------------------------
    @cached_property
    def suction_face(self):
        """The +theta face of blade 0 (the suction side of channel 0)."""
        return BladeFace(self.blade.face_points("plus"), name="blade suction face", knot_rule=self.knot_rule)

    @cached_property
    def pressure_face(self):
        """The -theta face of blade 0 (of ``pressure_blade`` where given); channel 0's pressure wall is this
        face turned by one pitch."""
        blade = self.blade if self.pressure_blade is None else self.pressure_blade
        return BladeFace(blade.face_points("minus"), name="blade pressure face", knot_rule=self.knot_rule)

    def wall_angles(self, x, r, channel=0, with_gradient=False):
        """Angles of channel k's two blade walls at meridional positions (x, r).

        Returns
        -------
        theta_suction, theta_pressure : (n,) float
            [rad]; the channel is ``theta_suction < theta < theta_pressure``.
        inside : (n,) bool
            Both walls exist at (x, r).
        gradients : ((n, 2), (n, 2)), only with ``with_gradient``
        """
        base = channel * self.pitch
        res_s = self.suction_face.theta_at(x, r, with_gradient)
        res_p = self.pressure_face.theta_at(x, r, with_gradient)
        th_s, th_p = res_s[0] + base, res_p[0] + base + self.pitch
        inside = res_s[1] & res_p[1]
        if with_gradient:
            return th_s, th_p, inside, (res_s[2], res_p[2])
        return th_s, th_p, inside

    def channel_transform(self, channel):
        """4x4 transform taking channel 0 onto channel k (rotation k*pitch about X)."""
        return rotation_about_x(channel * self.pitch)

    # -- meshes ----------------------------------------------------------------
    @cached_property
    def blade_mesh(self):
        """Closed, watertight mesh of blade 0 sampled from its spline faces [mm]."""
        minus, plus = self._face_grids()
        return closed_blade_mesh(minus, plus)

    def _face_parameters(self, resolution=0.5):
        """(u, v) of the blade face grids at ``resolution``: (nu,), (nv,); grid row j is v[j]."""
        chord = np.ptp(self.blade.x) + 1e-9
        span = np.ptp(self.blade.r) + 1e-9
        nu = int(np.clip(np.ceil(2 * chord / resolution), 40, 400))
        nv = int(np.clip(np.ceil(span / resolution), 20, 200))
        # cluster stations at the edges (cosine spacing), where curvature is highest
        u = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, nu))
        v = np.linspace(0, 1, nv)
        return u, v

    def _face_grids(self, resolution=0.5):
        uu, vv = np.meshgrid(*self._face_parameters(resolution))
        return (self.pressure_face.surface.evaluate(uu, vv), self.suction_face.surface.evaluate(uu, vv))

    def _wall_parameters(self, profile, resolution):
        """(x (nx,) [mm], theta (nth,) [rad]) of channel 0's hub or shroud patch; grid row i is theta[i]."""
        x0, x1 = self.axial_range
        margin = 0.25 * (x1 - x0)       # the patches reach a margin beyond the blade
        lo = max(self.hub.x_range[0], self.shroud.x_range[0], x0 - margin)
        hi = min(self.hub.x_range[1], self.shroud.x_range[1], x1 + margin)
        th_lo = float(self.blade.theta_minus.min())
        th_hi = float(self.blade.theta_plus.max()) + self.pitch
        prof = profile.sample(lo, hi, step=resolution)
        r_mean = prof[:, 1].mean()
        nth = int(np.clip(np.ceil((th_hi - th_lo) * r_mean / resolution), 8, 400))
        return prof[:, 0], np.linspace(th_lo, th_hi, nth)

    def channel_mesh_parameters(self, resolution=0.5):
        """The true-surface parameters of every vertex of channel 0's :meth:`channel_meshes`.

        Parameters
        ----------
        resolution : float
            As for :meth:`channel_meshes` [mm].

        Returns
        -------
        dict
            ``label -> (S, C, 2) float``: vertex ``s * C + c`` of that mesh is the
            true surface at ``params[s, c]``. Suction and pressure: the face
            spline's (u, v) (the pressure wall is blade 0's pressure face turned
            by one pitch); hub and shroud: (x [mm], theta [rad]) on the surface
            of revolution. Channel k's meshes are these turned by ``k * pitch``.
        """
        u, v = self._face_parameters(resolution)
        uu, vv = np.meshgrid(u, v)
        out = {"suction": np.stack([uu, vv], axis=-1), "pressure": np.stack([uu, vv], axis=-1)}
        for label, profile in (("hub", self.hub), ("shroud", self.shroud)):
            x, th = self._wall_parameters(profile, resolution)
            xx, tt = np.meshgrid(x, th)
            out[label] = np.stack([xx, tt], axis=-1)
        return out

    def channel_meshes(self, channel=0, resolution=0.5):
        """Labelled surface meshes bounding channel k, normals pointing into the channel.

        Parameters
        ----------
        channel : int
        resolution : float
            Target edge length along the walls [mm].

        Returns
        -------
        dict
            ``{'suction', 'pressure', 'hub', 'shroud'} -> trimesh.Trimesh`` in W.
        """
        key = ("channel_meshes", resolution)
        if key not in self._cache:
            self._cache[key] = self._channel0_meshes(resolution)
        rot = self.channel_transform(channel)
        out = {}
        for label, mesh in self._cache[key].items():
            m = mesh.copy()
            if channel:
                m.apply_transform(rot)
            out[label] = m
        return out

    def _channel0_meshes(self, resolution):
        minus, plus = self._face_grids(resolution)
        pressure = cylindrical_to_cartesian(*_cyl(minus, self.pitch))
        meshes = {"suction": face_grid_mesh(plus), "pressure": face_grid_mesh(pressure)}
        # hub and shroud patches over the channel sector, a margin beyond the blade
        for label, profile in (("hub", self.hub), ("shroud", self.shroud)):
            x, th = self._wall_parameters(profile, resolution)
            grid = cylindrical_to_cartesian(x[None, :], profile.radius_at(x)[None, :], th[:, None])
            meshes[label] = face_grid_mesh(grid)
        # orient every normal into the channel
        for label, mesh in meshes.items():
            c = mesh.triangles_center
            _, r, th = _xr_theta(c)
            if label == "suction":
                into = np.column_stack([np.zeros_like(r), -np.sin(th), np.cos(th)])
            elif label == "pressure":
                into = -np.column_stack([np.zeros_like(r), -np.sin(th), np.cos(th)])
            else:
                radial = np.column_stack([np.zeros_like(r), np.cos(th), np.sin(th)])
                into = radial if label == "hub" else -radial
            if np.einsum("ij,ij->i", mesh.face_normals, into).mean() < 0:
                mesh.invert()
        return meshes

    # -- serialisation ---------------------------------------------------------
    def to_dict(self):
        """Lossless plain-data form (the ``model_json`` of the geometry topic)."""
        b = self.blade
        return {
            "format": MODEL_FORMAT,
            "name": self.name,
            "source": self.source,
            "knot_rule": self.knot_rule,
            "blade_count": self.blade_count,
            "hub_profile": self.hub.points.tolist(),
            "shroud_profile": self.shroud.points.tolist(),
            "blade_sections": {
                "x": b.x.tolist(), "r": b.r.tolist(),
                "theta_minus": b.theta_minus.tolist(), "theta_plus": b.theta_plus.tolist(),
            },
            "part_axial_range": None if self.part_axial_range is None else list(self.part_axial_range),
            "pressure_blade_sections": None if self.pressure_blade is None else {
                "x": self.pressure_blade.x.tolist(), "r": self.pressure_blade.r.tolist(),
                "theta_minus": self.pressure_blade.theta_minus.tolist(),
                "theta_plus": self.pressure_blade.theta_plus.tolist()},
        }

    @classmethod
    def from_dict(cls, data):
        """Rebuild a Blisk from :meth:`to_dict` output."""
        if data.get("format") != MODEL_FORMAT:
            raise GeometryError(f"geometry model: unknown format {data.get('format')!r}, expected {MODEL_FORMAT}")
        s = data["blade_sections"]
        p = data.get("pressure_blade_sections")
        return cls(
            blade_count=data["blade_count"],
            hub=RevolutionProfile(data["hub_profile"], "hub_profile"),
            shroud=RevolutionProfile(data["shroud_profile"], "shroud_profile"),
            blade=BladeSections(s["x"], s["r"], s["theta_minus"], s["theta_plus"]),
            name=data.get("name", ""), source=data.get("source", "sections"),
            knot_rule=data.get("knot_rule", "chord"), part_axial_range=data.get("part_axial_range"),
            pressure_blade=None if p is None else BladeSections(p["x"], p["r"], p["theta_minus"], p["theta_plus"]))


def _xr_theta(points):
    return points[..., 0], np.hypot(points[..., 1], points[..., 2]), np.arctan2(points[..., 2], points[..., 1])


def _cyl(points, dtheta):
    x, r, th = _xr_theta(points)
    return x, r, th + dtheta
