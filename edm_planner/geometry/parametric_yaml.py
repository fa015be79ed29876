"""The ``blade: parametric:`` mapping of a geometry YAML: schema, validation with key paths, the blade.

:func:`parse_parametric` validates the mapping, interpolates its definition
sections along the span and stacks them between hub and shroud
(:mod:`.parametric_stacking`); the parameters are those of
:class:`~.parametric_outline.SectionDefinition`.

YAML schema of ``blade: parametric:`` (mm, rad)
-----------------------------------------------
::

    blade:
      parametric:
        interpolation: cubic    # 'linear' or 'cubic' (natural cubic spline
                                # through the definition sections; linear with
                                # two). Optional, default 'cubic'.
        span_extension: 0.03    # blade continued this fraction of the channel
                                # height inside hub and shroud (>= 0, <= 0.5),
                                # default 0.03; parameters are extrapolated.
        span_count: 21          # stacked sections from s = 0 to s = 1
                                # inclusive (>= 2), default 21; plus one at
                                # -span_extension and one at 1 + span_extension
                                # when span_extension > 0.
        station_count: 101      # chordwise stations per section, shared by both
                                # faces, cosine-clustered towards the edges
                                # (>= 8), default 101.
        sections:               # required, >= 1 definition sections; with 2 or
                                # more the first must be at span 0 and the last
                                # at span 1, spans strictly increasing.
          - span: 0.0           # required, span fraction in [0, 1]
            x_le: 0.5           # required, axial position of the LE circle centre [mm]
            x_te: 24.6          # required, axial position of the TE circle centre [mm], > x_le
            le_radius: 0.5      # required, LE circle radius [mm], > 0
            te_radius: 0.35     # required, TE circle radius [mm], > 0
            inlet_angle: 0.9    # required, camber-line angle at the LE [rad], |.| < pi/2
            outlet_angle: -1.0  # required, camber-line angle at the TE [rad], |.| < pi/2
            le_wedge: 0.3       # required, half wedge angle at the LE [rad], >= 0
            te_wedge: 0.1       # required, half wedge angle at the TE [rad], >= 0
            minus_curvature: [0.0, 0.0]  # optional, d2y/dx2 of the minus side at
                                         # its LE and TE tangent point [1/mm], default [0, 0]
            plus_curvature: [0.0, 0.0]   # optional, same for the plus side, default [0, 0]
            stagger: 0.0        # optional, rotation of the section about the
                                # stacking point [rad], |.| < pi/2, default 0
            lean: 0.0           # optional, angular shift of the stacking point
                                # about X [rad], |.| < pi, default 0
            stack_x: 12.55      # optional, axial position of the stacking point
                                # [mm], default (x_le + x_te) / 2

Every key is validated; unknown keys, NaN/inf, wrong types and impossible
shapes (crossing sides, sides turned beyond +-pi/2, chord too short for the
edge circles) raise :class:`~edm_planner.errors.GeometryError` naming the
key path, e.g. ``blade.parametric.sections[1].le_radius: must be > 0 mm,
got -0.3``.
"""

import logging
import math
from numbers import Real

import numpy as np

from ..errors import GeometryError
from .parametric_outline import SectionDefinition
from .parametric_stacking import interpolate_definitions, stack_sections
from .profiles import RevolutionProfile
from .sections import BladeSections

__all__ = ["SPAN_EXTENSION", "parse_parametric"]

_log = logging.getLogger(__name__)

_HALF_PI = 0.5 * math.pi

_SECTION_REQUIRED = ("span", "x_le", "x_te", "le_radius", "te_radius", "inlet_angle", "outlet_angle",
                     "le_wedge", "te_wedge")
_SECTION_OPTIONAL = ("minus_curvature", "plus_curvature", "stagger", "lean", "stack_x")
#: default ``span_extension``: the blade continued this fraction of the channel height past hub and shroud
SPAN_EXTENSION = 0.03

_TOP_KEYS = ("interpolation", "span_extension", "span_count", "station_count", "sections")


def _number(value, path, unit=""):
    if isinstance(value, bool) or not isinstance(value, Real):
        raise GeometryError(f"{path}: must be a number{' in ' + unit if unit else ''}, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise GeometryError(f"{path}: must be a finite number, got {v}")
    return v


def _integer(value, path, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise GeometryError(f"{path}: must be an integer, got {value!r}")
    if value < minimum:
        raise GeometryError(f"{path}: must be >= {minimum}, got {value}")
    return int(value)


def _mapping(value, path, allowed):
    if not isinstance(value, dict):
        raise GeometryError(f"{path}: must be a mapping, got {type(value).__name__}")
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise GeometryError(f"{path}.{unknown[0]}: unknown key (allowed: {', '.join(allowed)})")
    return value


def _parse_section(spec, path):
    _mapping(spec, path, _SECTION_REQUIRED + _SECTION_OPTIONAL)
    for k in _SECTION_REQUIRED:
        if k not in spec:
            raise GeometryError(f"{path}.{k}: required key missing")
    units = {"x_le": "mm", "x_te": "mm", "le_radius": "mm", "te_radius": "mm", "stack_x": "mm",
             "inlet_angle": "rad", "outlet_angle": "rad", "le_wedge": "rad", "te_wedge": "rad",
             "stagger": "rad", "lean": "rad", "span": ""}
    # stack_x: null means the default (mid-way between x_le and x_te)
    v = {k: _number(spec[k], f"{path}.{k}", units[k]) for k in units
         if k in spec and not (k == "stack_x" and spec[k] is None)}
    for k in ("minus_curvature", "plus_curvature"):
        if k in spec:
            c = spec[k]
            if not isinstance(c, (list, tuple)) or len(c) != 2:
                raise GeometryError(f"{path}.{k}: must be a list [start, end] of two numbers in 1/mm, got {c!r}")
            v[k] = tuple(_number(c[i], f"{path}.{k}[{i}]", "1/mm") for i in range(2))
    if not 0.0 <= v["span"] <= 1.0:
        raise GeometryError(f"{path}.span: must lie in [0, 1], got {v['span']:g}")
    if not v["x_te"] > v["x_le"]:
        raise GeometryError(f"{path}.x_te: must be > x_le ({v['x_le']:g} mm), got {v['x_te']:g}")
    for k in ("le_radius", "te_radius"):
        if not v[k] > 0:
            raise GeometryError(f"{path}.{k}: must be > 0 mm, got {v[k]:g}")
        if v[k] > 0.25 * (v["x_te"] - v["x_le"]):
            raise GeometryError(f"{path}.{k}: must be at most a quarter of x_te - x_le, got {v[k]:g} mm")
    for k in ("inlet_angle", "outlet_angle"):
        if not abs(v[k]) < _HALF_PI:
            raise GeometryError(f"{path}.{k}: must lie strictly between -pi/2 and pi/2 rad, got {v[k]:g}")
    for k, base in (("le_wedge", "inlet_angle"), ("te_wedge", "outlet_angle")):
        if not v[k] >= 0:
            raise GeometryError(f"{path}.{k}: must be >= 0 rad, got {v[k]:g}")
        if not abs(v[base]) + v[k] < _HALF_PI:
            raise GeometryError(
                f"{path}.{k}: {base} +- {k} must lie strictly between -pi/2 and pi/2 rad, "
                f"got {v[base]:g} +- {v[k]:g}")
    if "stack_x" in v and not v["x_le"] - v["le_radius"] < v["stack_x"] < v["x_te"] + v["te_radius"]:
        raise GeometryError(f"{path}.stack_x: must lie within the section's axial extent "
                            f"({v['x_le'] - v['le_radius']:g} ... {v['x_te'] + v['te_radius']:g} mm), "
                            f"got {v['stack_x']:g}")
    if "stagger" in v and not abs(v["stagger"]) < _HALF_PI:
        raise GeometryError(f"{path}.stagger: must lie strictly between -pi/2 and pi/2 rad, got {v['stagger']:g}")
    if "lean" in v and not abs(v["lean"]) < math.pi:
        raise GeometryError(f"{path}.lean: must lie strictly between -pi and pi rad, got {v['lean']:g}")
    return SectionDefinition(**v)


def parse_parametric(spec, hub: RevolutionProfile, shroud: RevolutionProfile,
                     where: str = "blade.parametric") -> BladeSections:
    """Build a blade from the ``blade: parametric:`` mapping (schema in the module docstring).

    Parameters
    ----------
    spec : dict
        The mapping as loaded from YAML.
    hub, shroud : RevolutionProfile
        Meridional profiles of the channel.
    where : str
        Key path of ``spec``, prefixed to every error message.

    Returns
    -------
    BladeSections
        ``span_count`` sections from s = 0 to s = 1 inclusive, plus one at
        each extended end; ``station_count`` stations each.

    Raises
    ------
    GeometryError
        With the key path, for missing, unknown, mistyped or out-of-range
        keys and for impossible sections.
    """
    _mapping(spec, where, _TOP_KEYS)
    method = spec.get("interpolation", "cubic")
    if method not in ("linear", "cubic"):
        raise GeometryError(f"{where}.interpolation: must be 'linear' or 'cubic', got {method!r}")
    ext = _number(spec.get("span_extension", SPAN_EXTENSION), f"{where}.span_extension")
    if not 0.0 <= ext <= 0.5:
        raise GeometryError(f"{where}.span_extension: must lie in [0, 0.5], got {ext:g}")
    span_count = _integer(spec.get("span_count", 21), f"{where}.span_count", 2)
    station_count = _integer(spec.get("station_count", 101), f"{where}.station_count", 8)
    if "sections" not in spec:
        raise GeometryError(f"{where}.sections: required key missing")
    sections = spec["sections"]
    if not isinstance(sections, list) or not sections:
        raise GeometryError(f"{where}.sections: must be a non-empty list of sections")
    defs = [_parse_section(s, f"{where}.sections[{i}]") for i, s in enumerate(sections)]
    for i in range(1, len(defs)):
        if not defs[i].span > defs[i - 1].span:
            raise GeometryError(
                f"{where}.sections[{i}].span: must exceed the previous section's span "
                f"{defs[i - 1].span:g}, got {defs[i].span:g}")
    if len(defs) > 1:
        if defs[0].span != 0.0:
            raise GeometryError(f"{where}.sections[0].span: the first section must be at span 0, "
                                f"got {defs[0].span:g}")
        if defs[-1].span != 1.0:
            raise GeometryError(f"{where}.sections[{len(defs) - 1}].span: the last section must be at span 1, "
                                f"got {defs[-1].span:g}")
    spans = np.linspace(0.0, 1.0, span_count)
    if ext > 0:
        spans = np.concatenate([[-ext], spans, [1.0 + ext]])
    stacked = interpolate_definitions(defs, spans, method)
    blade = stack_sections(stacked, hub, shroud, station_count=station_count, where=where)
    _log.debug("%s: %d x %d blade sections from %d definition sections", where, *blade.shape, len(defs))
    return blade
