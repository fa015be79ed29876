"""Load a blisk from its YAML description: validation, file sandbox, content hash.

YAML schema (mm, rad; file paths relative to the YAML's directory)::

    name: "free text"                     # optional
    blade_count: 60                       # N >= 2
    hub_profile: [[x, r], ...]            # or {file: F, format: nasa_meridional, length_unit: cm}
    shroud_profile: [[x, r], ...]         # same forms
    blade:                                # exactly one of parametric / sections / mesh
      parametric: {...}                   # see edm_planner.geometry.parametric_yaml
      sections: {file: F, format: nasa_table | csv, length_unit: mm}
      mesh: F                             # or {file: F, length_unit: mm, section_count: 25, station_count: 81}
      knot_rule: chord                    # optional: chord (default) | paper (Liu 2024 eq. 15)
    part_axial_range: [x_min, x_max]      # optional [mm]: where the part's material lies along X (it holds
                                          # the blades; default: the profiles' and blades' x range); the
                                          # cycle's clear position and index moves keep out of it
    electrode: {...}                      # optional, see ElectrodeDesign

or, for a blisk from CAD, instead of blade_count, hub_profile, shroud_profile and blade::

    step: {file: F.step, length_unit: mm, section_count: 25, station_count: 81}   # or step: F.step

(a whole-blisk solid or one sector; see edm_planner.geometry.step_import; length_unit overrides the unit
the file declares). ``load_geometry`` also takes a ``.step``/``.stp`` file directly.
    as_measured:                          # optional: blades as inspected (edm_planner.geometry.as_measured)
      tolerance: 0.005                    # [mm] channels whose walls agree within this share a plan
      scan: {file: S.stl, length_unit: mm, section_count: 25, station_count: 81,   # or scan: S.stl: the whole
             root_fillet_depth: 0.0, tip_fillet_depth: 0.0}   # blisk as one closed mesh (every blade read from
                                          # it, edm_planner.geometry.blisk_scan; fillet depths in mm)
      blades:                             # each in its own place on the part (blade k near k * pitch)
        - {blade: 3, sections: {file: F, format: csv}}   # or mesh: F, as for blade; others stay nominal
                                          # (or as scanned; a blade given here takes the scan's place)

A document holding only the blisk keys loads with the default electrode design.
A blade mesh is sliced only over the span the channel needs (hub to shroud
plus 3 % of the smallest channel height, see ``blisk.mesh_slice_overlap``),
so it may run past the walls and be closed there by caps of any shape outside
that span; what was sliced is in :meth:`LoadedGeometry.info` (``edm-plan
geometry info``).
"""

import collections
import hashlib
import json
import logging
import os
import pathlib
from dataclasses import dataclass, field, replace

import numpy as np
import yaml

from ..environment import CACHE_ROOT
from ..errors import ErrorCode, GeometryError, GeometryFileError
from .as_measured import MeasuredBlades, channel_blisk, channel_field_key, channel_groups, to_blade_zero
from .blisk import Blisk, mesh_slice_overlap, validate_profiles
from .centerline import channel_centerline
from .disk_cache import arrays_digest, content_key, get_or_make_json
from .electrode import ElectrodeDesign
from .electrode_cache import cached_design
from .file_size import check_file_size, too_large_message
from .mesh_read import load_blade_mesh
from .mesh_sections import mesh_to_sections_with_report
from .parametric_yaml import parse_parametric
from .profiles import RevolutionProfile
from .readers import read_nasa_meridional, read_nasa_table, read_sections_csv, unit_scale

_log = logging.getLogger(__name__)

TOP_KEYS = {"name", "blade_count", "hub_profile", "shroud_profile", "blade", "electrode", "part_axial_range",
            "as_measured"}
TOP_KEYS = TOP_KEYS | {"step"}
#: the keys a ``step:`` source replaces
STEP_REPLACES = ("blade_count", "hub_profile", "shroud_profile", "blade")
#: file name endings read as STEP by :func:`load_geometry`
STEP_SUFFIXES = (".step", ".stp")
BLADE_SOURCES = ("parametric", "sections", "mesh")
#: largest YAML document accepted (inline or file) [bytes]
MAX_YAML_BYTES = 4 * 1024 * 1024
#: largest blade mesh file accepted [bytes] (a fine CAD export of one blade is tens of MB)
MAX_MESH_BYTES = 200 * 1024 * 1024
#: largest table file (blade sections, meridional lines) accepted [bytes]
MAX_TABLE_BYTES = 16 * 1024 * 1024
#: largest STEP file accepted [bytes] (a whole blisk of 60 blades as B-spline faces is tens of MB)
MAX_STEP_BYTES = 256 * 1024 * 1024
#: deepest nesting of a YAML document (a geometry needs 6 levels, scalars counted)
MAX_YAML_DEPTH = 32
#: most aliases (``*name``) in a YAML document
MAX_YAML_ALIASES = 100
#: most nodes of a YAML document with every alias expanded (what a traversal of it visits)
MAX_YAML_NODES = 2_000_000


@dataclass(frozen=True)
class FileLimits:
    """Size limits of the files a geometry is read from, checked before a byte is parsed [bytes].

    Attributes
    ----------
    yaml_bytes : int
        The geometry YAML (a file or inline text).
    mesh_bytes : int
        A blade mesh (STL, OBJ, PLY).
    table_bytes : int
        A blade section table or a meridional (hub, shroud) table.
    step_bytes : int
        A STEP file of the whole blisk or a sector.
    """

    yaml_bytes: int = MAX_YAML_BYTES
    mesh_bytes: int = MAX_MESH_BYTES
    table_bytes: int = MAX_TABLE_BYTES
    step_bytes: int = MAX_STEP_BYTES

    def __post_init__(self):
        for name in ("yaml_bytes", "mesh_bytes", "table_bytes", "step_bytes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer number of bytes, got {value!r}")

    def of(self, kind):
        """The limit of a kind of file: 'yaml', 'mesh', 'table', 'step' or 'any' (the largest)."""
        if kind == "any":
            return max(self.yaml_bytes, self.mesh_bytes, self.table_bytes, self.step_bytes)
        return getattr(self, f"{kind}_bytes")


class FileAccess:
    """Resolves file names against a base directory, inside allowed directories only.

    Parameters
    ----------
    base_dir : path
        Where relative names resolve (the YAML's directory).
    allowed_dirs : list of path or None
        Files must resolve (symlinks followed) inside one of these; None allows any.
    limits : FileLimits, optional
        Size limits by kind of file (default :class:`FileLimits`).
    """

    def __init__(self, base_dir, allowed_dirs=None, limits=None, cache_dir=None):
        self.base_dir = pathlib.Path(base_dir)
        self.cache_dir = CACHE_ROOT if cache_dir is None else os.fspath(cache_dir)     # what is slow to read, kept
        self.allowed = None if allowed_dirs is None else [os.path.realpath(d) for d in allowed_dirs]
        self.limits = limits or FileLimits()
        self.hashes = []        # (name, sha256) of every file read, for the geometry id
        self.kinds = {}         # name -> kind of file ('yaml', 'mesh', 'table'), for re-reading it

    def resolve(self, name, where, kind="any"):
        """The real path of ``name``, inside the allowed directories and within the size limit of ``kind``.

        The file is read (at most the limit and one byte) for the geometry id; one larger than the limit is
        refused before anything parses it.
        """
        if not isinstance(name, str) or not name:
            raise GeometryError(f"{where}: expected a file name, got {name!r}")
        path = pathlib.Path(name)
        if not path.is_absolute():
            path = self.base_dir / path
        real = os.path.realpath(path)
        if self.allowed is not None and not any(
                os.path.commonpath([real, a]) == a for a in self.allowed):
            raise GeometryFileError(
                f"{where}: {name} resolves to {real}, outside the allowed directories {self.allowed}")
        if not os.path.isfile(real):
            raise GeometryFileError(f"{where}: file not found: {path}")
        limit = self.limits.of(kind)
        check_file_size(real, limit, where, kind)
        try:
            with open(real, "rb") as f:
                data = f.read(limit + 1)      # a file growing after the check is cut off here, and refused
        except OSError as exc:
            raise GeometryFileError(f"{where}: cannot read {path} ({exc.strerror or exc})") from None
        if len(data) > limit:
            raise GeometryFileError(too_large_message(where, real, f"more than {limit}", limit, kind))
        self.hashes.append((str(name), hashlib.sha256(data).hexdigest()))
        self.kinds[str(name)] = kind
        return pathlib.Path(real)


@dataclass(eq=False)
class LoadedGeometry:
    """A validated blisk with its designed electrodes and its content hash.

    ``designed``: the electrodes of ``design``, or None until ``electrodes`` is first read (a file without
    an ``electrode:`` section: its default design is only a fallback, so callers that design their own,
    as ``edm-plan plan`` with design options or the set designer, do not wait for it).
    """

    geometry_id: str
    blisk: Blisk
    design: ElectrodeDesign
    designed: list
    source: str = ""
    _summary: dict = field(default=None, repr=False)
    #: the file has an ``electrode:`` section; without one the planner designs the electrode set itself
    design_given: bool = True
    #: what was sliced of a blade mesh (the report of ``mesh_to_sections``), None for other sources
    blade_slicing: dict = None
    #: what was found in a STEP file (:func:`~.step_import.import_step`'s report), None for other sources
    step_import: dict = None
    #: blades as measured (:class:`~.as_measured.MeasuredBlades`), None for a nominal (periodic) blisk
    measured: MeasuredBlades = None
    #: the part's channel whose own walls this geometry has (:meth:`for_channel`), None otherwise
    channel: int = None
    #: the key of this geometry's fast field in the field cache: ``geometry_id``, or per channel as measured
    field_key: str = None
    #: where electrodes designed on first use are kept and found (:func:`~.electrode_cache.cached_design`;
    #: None: designed every time)
    cache_dir: str = None

    def __post_init__(self):
        if self.field_key is None:
            self.field_key = self.geometry_id
        self._channels = {}             # channel -> its geometry (for_channel), a blisk as measured only
        self._nominal = None             # the one geometry of all its channels with nominal walls

    def for_channel(self, channel):
        """The geometry channel ``channel`` is designed, planned and proven on.

        For a nominal blisk (or a channel's own geometry): this geometry. For a blisk as measured: a geometry
        of that channel alone (``channel`` set, ``measured`` None, the same ``geometry_id``: the part's),
        whose blisk has the channel's own two blades (:func:`~.as_measured.channel_blisk`: its channel
        ``channel`` is the part's) and whose ``field_key`` is its own; where both blades are nominal, the
        nominal blisk, one geometry shared by all such channels, whose field is the nominal file's (the field
        key ``measured.nominal_field_key``: the id of the same file without its ``as_measured`` section).
        """
        if self.measured is None:
            return self
        n = self.blisk.blade_count
        if not (isinstance(channel, (int, np.integer)) and 0 <= channel < n):
            raise GeometryError(f"channel must be an integer in 0 .. {n - 1}, got {channel!r}",
                                ErrorCode.INVALID_REQUEST)
        channel = int(channel)
        if channel not in self._channels:
            blisk = channel_blisk(self.blisk, self.measured, channel)
            if blisk is self.blisk:
                if self._nominal is None:
                    self._nominal = LoadedGeometry(self.geometry_id, blisk, self.design, None, self.source,
                                                   design_given=self.design_given, cache_dir=self.cache_dir,
                                                   field_key=self.measured.nominal_field_key)
                self._channels[channel] = self._nominal
            else:
                self._channels[channel] = LoadedGeometry(
                    self.geometry_id, blisk, self.design, None, self.source, design_given=self.design_given,
                    channel=channel, field_key=channel_field_key(self.geometry_id, channel), cache_dir=self.cache_dir)
        return self._channels[channel]

    def channel_groups(self):
        """Channels that share a plan (:func:`~.as_measured.channel_groups` within ``measured.tolerance``):
        a list of (representative, members, wall deviations [mm]); one group of all channels when nominal."""
        n = self.blisk.blade_count
        if self.measured is None:
            return [(0, list(range(n)), [0.0] * n)]
        return channel_groups([self.for_channel(k).blisk for k in range(n)], self.measured.tolerance)

    @property
    def electrodes(self):
        """The electrodes of ``design`` (list of Electrode), designed on first use where the load left them."""
        if self.designed is None:
            self.designed = cached_design(self.blisk, self.design, cache_dir=self.cache_dir)
        return self.designed

    def electrode(self, electrode_id=""):
        """The electrode with this id ('' for the first)."""
        if not electrode_id:
            return self.electrodes[0]
        for e in self.electrodes:
            if e.electrode_id == electrode_id:
                return e
        raise KeyError(electrode_id)

    def summary(self):
        """Figures of the geometry (the fields of GeometrySummary.msg).

        Computed once per object; with a ``cache_dir`` read from ``<cache_dir>/summary/`` where the same
        blisk, electrodes and code made them before (:func:`summary_key`): the channel's centreline alone
        takes 0.8 s, and the geometry loader summarises every geometry it loads, the default one at each start.
        """
        if self._summary is None:
            if self.cache_dir:
                path = pathlib.Path(self.cache_dir) / "summary" / f"{summary_key(self)[:32]}.json"
                self._summary = get_or_make_json(path, self._figures, fmt=SUMMARY_FORMAT, keep=SUMMARY_KEEP,
                                                 what="geometry summary", decode=_summary_value)
            else:
                self._summary = self._figures()
        return dict(self._summary)

    def _figures(self):
        """What :meth:`summary` returns, computed."""
        b = self.blisk
        x0, x1 = b.axial_range
        xs = np.linspace(x0, x1, 200)
        cl = channel_centerline(b)
        thick = (b.blade.theta_plus - b.blade.theta_minus) * b.blade.r
        meshes = b.channel_meshes()
        return {
            "geometry_id": self.geometry_id, "name": b.name, "blade_source": b.source,
            "blade_count": b.blade_count, "channel_count": b.blade_count,
            "blade_pitch": b.pitch, "axial_min": x0, "axial_max": x1,
            "hub_radius_min": float(b.hub.radius_at(xs).min()),
            "hub_radius_max": float(b.hub.radius_at(xs).max()),
            "shroud_radius_min": float(b.shroud.radius_at(xs).min()),
            "shroud_radius_max": float(b.shroud.radius_at(xs).max()),
            "min_channel_width": cl.min_width, "max_blade_thickness": float(thick.max()),
            "centerline_length": cl.length, "centerline_sweep": cl.sweep,
            "electrode_count": len(self.electrodes),
            "electrode_extent": [float(v) for e in self.electrodes for v in e.mesh.extents],
            "electrode_volume": [float(e.mesh.volume) for e in self.electrodes],
            "blade_mesh_vertices": len(b.blade_mesh.vertices),
            "blade_mesh_triangles": len(b.blade_mesh.faces),
            "channel_mesh_triangles": int(sum(len(m.faces) for m in meshes.values())),
            "electrode_mesh_triangles": int(sum(len(e.mesh.faces) for e in self.electrodes)),
        }

    def info(self):
        """:meth:`summary` and, for a blade given as a mesh, what was sliced of it; for a blisk as measured,
        the measured blades, how many channels have walls of their own and how many plan groups they form
        (``largest_wall_deviation``: the largest deviation [mm] of a channel from its group's representative).

        The extra ``input_mesh_*`` keys (lengths in mm; not fields of
        GeometrySummary.msg, and not to be confused with ``blade_mesh_*``,
        the blisk's own blade mesh re-sampled from its faces) are the report
        of :func:`~.mesh_sections.mesh_to_sections_with_report`: the input mesh's axial and
        radial extent, how far it reaches beyond hub and shroud, the wall
        overlap, the span actually sliced and whether it was clipped to the
        walls. For a STEP source the ``step_*`` keys say what was found: the
        axis and the transform taking it onto X, whole blisk or sector, the
        blade count, the hub and shroud ranges, the section radii and counts,
        any fillet zones kept clear of, and the fit deviation (the largest
        distance between the STEP's blade and the reconstructed faces at
        cylinders half way between the section radii, mm).
        """
        out = self.summary()
        for key, value in (self.blade_slicing or {}).items():
            out[f"input_mesh_{key}"] = value
        for key, value in (self.step_import or {}).items():
            out[f"step_{key}"] = value
        if self.measured is not None:
            groups = self.channel_groups()
            n = self.blisk.blade_count
            for key, value in (self.measured.scan or {}).items():
                out[f"scan_{key}"] = value
            out.update(measured_blades=sorted(self.measured.blades), as_measured_tolerance=self.measured.tolerance,
                       channels_own_geometry=sum(self.for_channel(k).blisk is not self.blisk for k in range(n)),
                       channel_groups=len(groups),
                       largest_wall_deviation=max((max(g[2]) for g in groups), default=0.0))
        return out


def _profile(spec, name, files):
    if isinstance(spec, dict):
        _known(spec, {"file", "format", "length_unit"}, name)
        fmt = spec.get("format", "nasa_meridional")
        if fmt != "nasa_meridional":
            raise GeometryError(f"{name}.format: only 'nasa_meridional' files are read, got {fmt!r}")
        path = files.resolve(spec.get("file"), f"{name}.file", "table")
        pts = read_nasa_meridional(path, name.split("_")[0], spec.get("length_unit", "cm"),
                                   max_bytes=files.limits.table_bytes)
        return RevolutionProfile(pts, name)
    if not isinstance(spec, list):
        raise GeometryError(f"{name}: expected a list of [x, r] pairs in mm or a {{file: ...}} mapping")
    try:
        pts = np.asarray(spec, dtype=np.float64)
    except (TypeError, ValueError):
        raise GeometryError(f"{name}: expected a list of [x, r] pairs of numbers in mm") from None
    return RevolutionProfile(pts, name)


def _known(spec, allowed, where):
    unknown = sorted(set(spec) - set(allowed))
    if unknown:
        raise GeometryError(f"{where}: unknown key(s) {unknown}; known: {sorted(allowed)}")


def _slice_counts(spec, where):
    """``section_count`` (default 25, at least 4) and ``station_count`` (81, at least 8) of a sliced source."""
    counts = {}
    for key, default, lo in (("section_count", 25, 4), ("station_count", 81, 8)):
        v = spec.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo or v > 1000:
            raise GeometryError(f"{where}.{key}: must be an integer in {lo} .. 1000, got {v!r}")
        counts[key] = v
    return counts


def _blade(spec, hub, shroud, files):
    if not isinstance(spec, dict):
        raise GeometryError("blade: expected a mapping with exactly one of parametric, sections, mesh")
    _known(spec, set(BLADE_SOURCES) | {"knot_rule"}, "blade")
    given = [k for k in BLADE_SOURCES if k in spec]
    if len(given) != 1:
        raise GeometryError(f"blade: give exactly one of {list(BLADE_SOURCES)}, got {given or 'none'}")
    source = given[0]
    sub = spec[source]
    if source == "parametric":
        return parse_parametric(sub, hub, shroud), source, None
    if source == "mesh" and isinstance(sub, str):
        sub = {"file": sub}                 # mesh: FILE, the short form
    if not isinstance(sub, dict):
        form = "a file name or " if source == "mesh" else ""
        raise GeometryError(f"blade.{source}: expected {form}a mapping with a 'file' key")
    if source == "sections":
        _known(sub, {"file", "format", "length_unit"}, "blade.sections")
        path = files.resolve(sub.get("file"), "blade.sections.file", "table")
        fmt = sub.get("format", "csv")
        limit = files.limits.table_bytes
        if fmt == "nasa_table":
            return read_nasa_table(path, sub.get("length_unit", "cm"), max_bytes=limit), source, None
        if fmt == "csv":
            return read_sections_csv(path, sub.get("length_unit", "mm"), max_bytes=limit), source, None
        raise GeometryError(f"blade.sections.format: must be 'nasa_table' or 'csv', got {fmt!r}")
    _known(sub, {"file", "length_unit", "section_count", "station_count"}, "blade.mesh")
    path = files.resolve(sub.get("file"), "blade.mesh.file", "mesh")
    mesh = load_blade_mesh(path, max_bytes=files.limits.mesh_bytes)
    scale = unit_scale(sub.get("length_unit", "mm"), "blade.mesh")
    if scale != 1.0:
        mesh.apply_scale(scale)
    counts = _slice_counts(sub, "blade.mesh")
    sections, report = mesh_to_sections_with_report(mesh, counts["section_count"], counts["station_count"],
                                                    hub=hub, shroud=shroud, overlap=mesh_slice_overlap(hub, shroud))
    return sections, source, report


class YamlLimitError(yaml.YAMLError):
    """A YAML document beyond a limit of :class:`LimitedSafeLoader` (depth, aliases, expanded nodes)."""


class LimitedSafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` (plain data only) that refuses documents too deep or too large once aliases expand.

    Checked while composing, before anything is constructed: nesting deeper than :data:`MAX_YAML_DEPTH`,
    more than :data:`MAX_YAML_ALIASES` aliases, an alias inside the node it names (a recursive document), and
    more than :data:`MAX_YAML_NODES` nodes with every alias expanded (the "billion laughs": a few aliases of
    aliases stand for billions of nodes, which the geometry id's hash of the document would visit).
    """

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0

    def _limit(self, what):
        mark = self.peek_event().start_mark
        raise YamlLimitError(f"{what} (line {mark.line + 1}, column {mark.column + 1})")

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_YAML_ALIASES:
                self._limit(f"more than {MAX_YAML_ALIASES} aliases (limit MAX_YAML_ALIASES)")
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            self._limit(f"nested deeper than {MAX_YAML_DEPTH} levels (limit MAX_YAML_DEPTH)")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def compose_document(self):
        node = super().compose_document()
        count = expanded_node_count(node)
        if count > MAX_YAML_NODES:
            raise YamlLimitError(f"{count} nodes with its aliases expanded, more than {MAX_YAML_NODES} (limit "
                                 f"MAX_YAML_NODES; a YAML bomb?)")
        return node


def expanded_node_count(root):
    """Nodes of a composed YAML document with every alias expanded (shared nodes counted at every use).

    Linear in the distinct nodes (memoised); YamlLimitError for a node that contains itself.
    """
    sizes, active, stack = {}, set(), [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [x for pair in node.value for x in pair]
        if done:
            active.discard(key)
            sizes[key] = 1 + sum(sizes[id(c)] for c in children)
            continue
        if key in sizes:
            continue
        if key in active:
            raise YamlLimitError("an alias refers to a node that contains it (a recursive document)")
        active.add(key)
        stack.append((node, True))
        for child in children:
            if id(child) in active:
                raise YamlLimitError("an alias refers to a node that contains it (a recursive document)")
            if id(child) not in sizes:
                stack.append((child, False))
    return sizes[id(root)]


def parse_document(text, where="geometry", max_bytes=MAX_YAML_BYTES):
    """YAML text -> mapping, with errors that name the line or the limit.

    Read by :class:`LimitedSafeLoader`: plain data only (no Python objects), at most ``max_bytes`` bytes,
    :data:`MAX_YAML_DEPTH` levels, :data:`MAX_YAML_ALIASES` aliases and :data:`MAX_YAML_NODES` nodes with
    the aliases expanded.
    """
    size = len(text.encode("utf-8", "replace"))
    if size > max_bytes:
        raise GeometryFileError(f"{where}: YAML of {size} bytes, larger than the limit of {max_bytes} bytes "
                                f"(geometry_loader parameter max_yaml_bytes): not parsed")
    try:
        doc = yaml.load(text, Loader=LimitedSafeLoader)
    except YamlLimitError as exc:
        raise GeometryFileError(f"{where}: YAML refused: {exc}") from None
    except RecursionError:
        raise GeometryFileError(f"{where}: YAML refused: nested too deeply to read") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise GeometryFileError(f"{where}: malformed YAML{at}: {getattr(exc, 'problem', exc)}") from None
    if not isinstance(doc, dict):
        raise GeometryError(f"{where}: the YAML document must be a mapping of geometry keys")
    return doc


def _step(spec, files):
    """The :class:`~.step_import.StepBlisk` of a ``step:`` entry, its file resolved in the sandbox."""
    from .step_import import import_step

    if isinstance(spec, str):
        spec = {"file": spec}
    if not isinstance(spec, dict):
        raise GeometryError("step: expected a file name or a mapping with a 'file' key")
    _known(spec, {"file", "length_unit", "section_count", "station_count"}, "step")
    path = files.resolve(spec.get("file"), "step.file", "step")
    counts = _slice_counts(spec, "step")
    return import_step(path, counts["section_count"], counts["station_count"], spec.get("length_unit"))


def _build_step(doc, files, source):
    """:class:`LoadedGeometry` of a document with a ``step:`` source."""
    from .solid_sections import fit_deviation

    both = [k for k in STEP_REPLACES if k in doc]
    if both:
        raise GeometryError(f"step: replaces {list(STEP_REPLACES)}; give either step or those keys, not both "
                            f"(also given: {both})")
    name = doc.get("name", "")
    if not isinstance(name, str):
        raise GeometryError("name: must be a string")
    found = _step(doc["step"], files)
    blisk = Blisk(found.blade_count, found.hub, found.shroud, found.sections, name=name, source="step",
                  part_axial_range=doc.get("part_axial_range"))
    deviation, points = fit_deviation(blisk, found)
    report = dict(found.report, fit_deviation_mm=deviation, fit_points=points)
    return _loaded(doc, files, source, blisk, step_import=report)


def build_geometry(doc, files, source=""):
    """Validated :class:`LoadedGeometry` from a parsed document."""
    _known(doc, TOP_KEYS, "geometry")
    if "step" in doc:
        return _build_step(doc, files, source)
    for key in ("blade_count", "hub_profile", "shroud_profile", "blade"):
        if key not in doc:
            raise GeometryError(f"geometry: missing required key '{key}'")
    hub = _profile(doc["hub_profile"], "hub_profile", files)
    shroud = _profile(doc["shroud_profile"], "shroud_profile", files)
    validate_profiles(hub, shroud)      # units first: a blade in metres fails confusingly otherwise
    blade, blade_source, slicing = _blade(doc["blade"], hub, shroud, files)
    knot_rule = doc["blade"].get("knot_rule", "chord")
    if knot_rule not in ("chord", "paper"):
        raise GeometryError(f"blade.knot_rule: must be 'chord' or 'paper', got {knot_rule!r}")
    name = doc.get("name", "")
    if not isinstance(name, str):
        raise GeometryError("name: must be a string")
    blisk = Blisk(doc["blade_count"], hub, shroud, blade, name=name, source=blade_source, knot_rule=knot_rule,
                  part_axial_range=doc.get("part_axial_range"))
    return _loaded(doc, files, source, blisk, blade_slicing=slicing)


def _loaded(doc, files, source, blisk, **found):
    """The LoadedGeometry of a built blisk (any source): blades as measured, the electrode design, the id."""
    nominal_files = list(files.hashes)          # what the nominal blisk was read from
    measured, checks = _as_measured(doc.get("as_measured"), blisk, files) if "as_measured" in doc else (None, {})
    if measured is not None:
        # the channels with nominal walls share the field of the same file without its as_measured section
        measured = replace(measured, nominal_field_key=_geometry_digest(
            {k: v for k, v in doc.items() if k != "as_measured"}, nominal_files))
    design = ElectrodeDesign.from_dict(doc.get("electrode"))
    design_given = doc.get("electrode") is not None
    # a design the file gives is checked now (its errors belong to the load); the default one on first use
    electrodes = cached_design(blisk, design, cache_dir=files.cache_dir) if design_given else None
    geometry = LoadedGeometry(_geometry_digest(doc, files.hashes), blisk, design, electrodes, source, design_given=design_given,
                              measured=measured, cache_dir=files.cache_dir, **found)
    if measured is not None:
        _channels_as_measured(geometry, checks)
    return geometry


def _geometry_digest(doc, hashes):
    """The geometry id: SHA-256 of the parsed document and of every file read for it."""
    digest = hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode())
    for fname, h in hashes:
        digest.update(f"\0{fname}\0{h}".encode())
    return digest.hexdigest()


def _as_measured(spec, blisk, files):
    """The ``as_measured`` section: blades as inspected (a whole-blisk scan and/or blade by blade), each turned
    back into blade 0's position."""
    if not isinstance(spec, dict):
        raise GeometryError("as_measured: expected a mapping with 'blades' and/or 'scan' (and optionally "
                            "'tolerance' in mm)")
    _known(spec, {"blades", "scan", "tolerance"}, "as_measured")
    tol = spec.get("tolerance", 0.005)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (0 <= tol <= 0.1):
        raise GeometryError(f"as_measured.tolerance: must be a number of mm in 0 .. 0.1, got {tol!r}")
    entries = spec.get("blades", [] if "scan" in spec else None)
    if not isinstance(entries, list) or not (entries or "scan" in spec):
        raise GeometryError("as_measured.blades: expected a non-empty list of {blade: k, sections|mesh: ...} "
                            "(or give the whole blisk as 'scan')")
    blades, sources = {}, {}
    n = blisk.blade_count
    scan, checks = None, {}
    if "scan" in spec:
        scanned, checks, scan = _scan(spec["scan"], blisk, files)
        for k, sections in scanned.items():
            blades[k] = to_blade_zero(sections, k, n)
            sources[k] = "scan"
    given = set()
    for i, entry in enumerate(entries):
        where = f"as_measured.blades[{i}]"
        if not isinstance(entry, dict) or "blade" not in entry:
            raise GeometryError(f"{where}: expected a mapping with 'blade' (its index) and one of "
                                f"{list(BLADE_SOURCES)}")
        k = entry["blade"]
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < n:
            raise GeometryError(f"{where}.blade: must be a blade index in 0 .. {n - 1}, got {k!r}")
        if k in given:
            raise GeometryError(f"{where}.blade: blade {k} is given twice")
        given.add(k)
        rest = {key: v for key, v in entry.items() if key != "blade"}
        try:
            sections, source, _ = _blade(rest, blisk.hub, blisk.shroud, files)
        except (GeometryError, GeometryFileError) as exc:
            raise type(exc)(f"{where} (blade {k}): {exc.message}") from None
        blades[k] = to_blade_zero(sections, k, n)
        sources[k] = source
    checks = {k: c for k, c in checks.items() if sources.get(k) == "scan"}
    return MeasuredBlades(blades, float(tol), sources, scan), checks


def _channels_as_measured(geometry, checks):
    """Every channel a measured blade bounds made (so checked: no intersecting neighbours) and kept; for a scan,
    the fit of the channels' faces to the scan's check sections."""
    from .blisk_scan import face_fit

    n = geometry.blisk.blade_count
    fit, points = 0.0, 0
    for k in sorted({c for b in geometry.measured.blades for c in (b, (b - 1) % n)}):
        view = geometry.for_channel(k).blisk
        if checks:
            dev, count = face_fit(view, checks.get(k), checks.get((k + 1) % n), k)
            fit, points = max(fit, dev), points + count
    if checks:
        geometry.measured.scan.update(fit_deviation_mm=fit, fit_points=points)


def _scan(spec, blisk, files):
    """The blades of an ``as_measured.scan`` (a closed mesh of the whole blisk), in place, and the scan's report."""
    from .blisk_scan import READER_VERSION, load_scan, read_blisk_scan, save_scan

    if isinstance(spec, str):
        spec = {"file": spec}
    if not isinstance(spec, dict):
        raise GeometryError("as_measured.scan: expected a file name or a mapping with a 'file' key")
    _known(spec, {"file", "length_unit", "section_count", "station_count", "root_fillet_depth",
                  "tip_fillet_depth"}, "as_measured.scan")
    depths = {}
    for key in ("root_fillet_depth", "tip_fillet_depth"):
        v = spec.get(key, 0.0)
        height = blisk.channel_height_range[0]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v < 0.4 * height:
            raise GeometryError(f"as_measured.scan.{key}: must be a number of mm in 0 .. {0.4 * height:.3f} "
                                f"(0.4 of the smallest channel height), got {v!r}")
        depths[key] = float(v)
    path = files.resolve(spec.get("file"), "as_measured.scan.file", "mesh")
    scale = unit_scale(spec.get("length_unit", "mm"), "as_measured.scan")
    counts = _slice_counts(spec, "as_measured.scan")
    # what was read from these very bytes against this nominal blisk is read once (tens of seconds a scan)
    key = hashlib.sha256(json.dumps({"reader": READER_VERSION, "mesh_sha256": files.hashes[-1][1],
                                     "scale": scale, "counts": counts, "depths": depths,
                                     "nominal": blisk.to_dict()}, sort_keys=True).encode()).hexdigest()
    kept = os.path.join(files.cache_dir, "scan", f"{key}.npz")
    found = load_scan(kept)
    if found is None:
        mesh = load_blade_mesh(path, max_bytes=files.limits.mesh_bytes, what="blisk scan")
        if scale != 1.0:
            mesh.apply_scale(scale)
        found = read_blisk_scan(mesh, blisk, counts["section_count"], counts["station_count"], **depths)
        try:
            save_scan(found, kept)
        except OSError as exc:                 # a read-only cache costs time, not the geometry
            _log.warning("scan cache %s not written (%s)", kept, exc)
        from_cache = False
    else:
        from_cache = True
    return found.blades, found.checks, dict(found.report, file=str(spec.get("file")), read_from_cache=from_cache,
                                            cache_file=kept)


#: the summary cache's file format; a new one computes every summary again
SUMMARY_FORMAT = "edm_planner.summary/2"
#: summaries kept in the cache directory (the least recently used go first); one is about 1 kB
SUMMARY_KEEP = 256


def summary_key(geometry):
    """The cache key of ``geometry.summary()`` (hex sha256): its id, its blisk as the nodes exchange it
    (a channel's own as measured differs from the part's), its electrodes' meshes and the package's code."""
    return content_key({"format": SUMMARY_FORMAT, "geometry_id": geometry.geometry_id,
                        "blisk": geometry.blisk.to_dict(),
                        "electrodes": [arrays_digest(e.mesh.vertices, e.mesh.faces) for e in geometry.electrodes]})


def _summary_value(value):
    """A cached summary's value, checked: the summary's dict."""
    if not isinstance(value, dict):
        raise TypeError(f"a summary is a mapping, not {type(value).__name__}")
    return value


class GeometryMemo:
    """Geometries loaded before, answered again while their content is unchanged.

    Keyed by the parsed document and the directory its file names resolve in;
    a hit re-reads and re-hashes every file the geometry was built from
    (through the same sandbox), so an edited profile or mesh file, or one now
    outside the allowed directories, is never answered from memory. Holds the
    ``size`` geometries used last.
    """

    def __init__(self, size=8):
        self.size = int(size)
        self._entries = collections.OrderedDict()     # key -> (geometry, [(name, sha256)], {name: kind})

    @staticmethod
    def _key(doc, files):
        return hashlib.sha256(json.dumps([doc, str(files.base_dir)], sort_keys=True, default=str).encode()).hexdigest()

    def lookup(self, doc, files, where):
        """The remembered geometry of ``doc`` if every file it read is unchanged, else None."""
        key = self._key(doc, files)
        entry = self._entries.get(key)
        if entry is None:
            return None
        geometry, hashes, kinds = entry
        files.hashes.clear()
        for name, _ in hashes:
            files.resolve(name, "geometry file", kinds.get(name, "any"))    # sandbox and limits as on a first load
        if files.hashes != hashes:
            return None
        self._entries.move_to_end(key)
        return geometry if geometry.source == where else replace(geometry, source=where)

    def remember(self, doc, files, geometry):
        self._entries[self._key(doc, files)] = (geometry, list(files.hashes), dict(files.kinds))
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)


def load_geometry(path=None, text=None, allowed_dirs=None, base_dir=None, memo=None, limits=None, cache_dir=None):
    """Load a blisk geometry from a YAML file or inline YAML text.

    Parameters
    ----------
    path : path, optional
        The YAML file, or a STEP file (``.step``/``.stp``: a whole blisk or one sector as one solid, read by
        :func:`~.step_import.import_step` with the default section and station counts).
    text : str, optional
        Inline YAML (exactly one of path and text).
    allowed_dirs : list of path, optional
        Directories files may be read from (the YAML and every file it names);
        None allows any.
    base_dir : path, optional
        Where relative names in inline YAML resolve (default: the first allowed
        directory, else the working directory).
    memo : GeometryMemo, optional
        Answers a document whose content (and every file's) is unchanged
        without building it again.
    limits : FileLimits, optional
        Size limits of the YAML, mesh and table files (default :class:`FileLimits`); a
        larger file is refused before it is parsed.
    cache_dir : path, optional
        Where what is slow to read is kept, keyed by the bytes read (a whole-blisk scan's blades, under
        ``scan/``); default ``~/.cache/edm_planner``.

    Returns
    -------
    LoadedGeometry

    Raises
    ------
    GeometryFileError, GeometryError
    """
    if (path is None) == (text is None):
        raise GeometryError("load_geometry: give exactly one of a path and inline YAML text")
    if path is not None and str(path).lower().endswith(STEP_SUFFIXES):
        # a STEP file on its own: the document {name, step: {file}} next to it
        files = FileAccess(pathlib.Path.cwd(), allowed_dirs, limits, cache_dir)
        real = files.resolve(str(path), "geometry file", "step")
        files.hashes.clear()
        files.base_dir = real.parent
        doc = {"name": real.stem, "step": {"file": real.name}}
        geometry = memo.lookup(doc, files, str(path)) if memo is not None else None
        if geometry is None:
            files.hashes.clear()
            geometry = build_geometry(doc, files, source=str(path))
            if memo is not None:
                memo.remember(doc, files, geometry)
        return geometry
    if path is not None:
        files = FileAccess(pathlib.Path.cwd(), allowed_dirs, limits, cache_dir)
        real = files.resolve(str(path), "geometry file", "yaml")
        files.hashes.clear()      # the YAML's own bytes enter the id through the parsed document
        try:
            text = real.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise GeometryFileError(f"{path}: cannot read ({exc})") from None
        files.base_dir = real.parent
        where = str(path)
    else:
        base = base_dir or (allowed_dirs[0] if allowed_dirs else pathlib.Path.cwd())
        files = FileAccess(base, allowed_dirs, limits, cache_dir)
        where = "inline YAML"
    doc = parse_document(text, where, files.limits.yaml_bytes)
    if memo is not None:
        geometry = memo.lookup(doc, files, where)
        if geometry is not None:
            _log.info("loaded %s: unchanged content, id %s (from memory)", where, geometry.geometry_id[:12])
            return geometry
        files.hashes.clear()
    geometry = build_geometry(doc, files, source=where)
    if memo is not None:
        memo.remember(doc, files, geometry)
    _log.info("loaded %s: %d blades, %s blade, id %s", where, geometry.blisk.blade_count,
              geometry.blisk.source, geometry.geometry_id[:12])
    return geometry
