"""Stacking a parametric blade: designer's sections interpolated along the span and placed between hub and shroud.

All parameters of the definition sections (:class:`~.parametric_outline.SectionDefinition`)
are interpolated along the span fraction ``s`` (:func:`interpolate_definitions`);
each section's outline is placed at ``r = r_hub(x) + s * (r_shroud(x) - r_hub(x))``,
``theta = y / r + lean`` (:func:`stack_sections`).
"""

import logging
from dataclasses import replace

import numpy as np
from scipy.interpolate import CubicSpline, make_interp_spline

from ..constants import SIZE
from ..errors import GeometryError
from .parametric_outline import SectionDefinition, definition_outline
from .sections import BladeSections

__all__ = ["interpolate_definitions", "stack_sections"]

_log = logging.getLogger(__name__)


_SCALARS = ("x_le", "x_te", "le_radius", "te_radius", "inlet_angle", "outlet_angle",
            "le_wedge", "te_wedge", "stagger", "lean")


def _as_vector(d):
    return np.array([getattr(d, k) for k in _SCALARS] + list(d.minus_curvature) + list(d.plus_curvature)
                    + [d.stacking_x], dtype=np.float64)


def _from_vector(span, v):
    n = len(_SCALARS)
    kw = dict(zip(_SCALARS, (float(a) for a in v[:n])))
    return SectionDefinition(span=float(span), minus_curvature=(float(v[n]), float(v[n + 1])),
                             plus_curvature=(float(v[n + 2]), float(v[n + 3])), stack_x=float(v[n + 4]), **kw)


def interpolate_definitions(definitions, spans, method="cubic"):
    """Designer's parameters at the given span fractions.

    Parameters
    ----------
    definitions : sequence of SectionDefinition
        Spans strictly increasing; one definition gives a constant blade.
    spans : (S,) float
        Span fractions wanted; values outside the definitions' range are
        extrapolated (linear, or the end polynomial of the cubic spline).
    method : {'linear', 'cubic'}
        Linear, or natural cubic spline (linear with two definitions).

    Returns
    -------
    list of SectionDefinition
        One per span, with ``stack_x`` filled in.
    """
    defs = list(definitions)
    spans = np.atleast_1d(np.asanyarray(spans, dtype=np.float64))
    if not defs:
        raise GeometryError("parametric blade: no definition sections")
    if method not in ("linear", "cubic"):
        raise GeometryError(f"parametric blade: interpolation must be 'linear' or 'cubic', got {method!r}")
    if len(defs) == 1:
        return [replace(defs[0], span=float(s), stack_x=defs[0].stacking_x) for s in spans]
    s_def = np.array([d.span for d in defs])
    if np.any(np.diff(s_def) <= 0):
        raise GeometryError("parametric blade: definition spans must be strictly increasing")
    values = np.stack([_as_vector(d) for d in defs])
    if method == "cubic":
        fn = CubicSpline(s_def, values, axis=0, bc_type="natural", extrapolate=True)
    else:
        fn = make_interp_spline(s_def, values, k=1, axis=0)
    out = fn(spans)
    return [_from_vector(s, v) for s, v in zip(spans, out)]


def stack_sections(definitions, hub, shroud, station_count=101, where="blade.parametric"):
    """Stack designer's sections between hub and shroud into :class:`BladeSections`.

    Each section's outline (in the unrolled plane, stacking point at y = 0)
    is placed at ``r = r_hub(x) + s * (r_shroud(x) - r_hub(x))`` for its
    span fraction s and at ``theta = y / r + lean``.

    Parameters
    ----------
    definitions : sequence of SectionDefinition
        One per stacked section, in span order (e.g. from
        :func:`interpolate_definitions`); S >= 2.
    hub, shroud : RevolutionProfile
        Meridional profiles; shroud above hub over the blade.
    station_count : int
        Stations C per section.
    where : str
        Key path used in error messages.

    Returns
    -------
    BladeSections
        (S, C) arrays; ``theta_minus``/``theta_plus`` are the minus/plus
        sides.
    """
    defs = list(definitions)
    if len(defs) < 2:
        raise GeometryError(f"{where}: need at least two stacked sections, got {len(defs)}")
    xs, rs, tm, tp = [], [], [], []
    for d in defs:
        name = f"{where}: section at span {d.span:.4g}"
        out = definition_outline(d, station_count=station_count, name=name)
        rh, rt = hub.radius_at(out.x), shroud.radius_at(out.x)
        height = rt - rh
        if np.any(height < SIZE.min_channel_height):
            k = int(np.argmin(height))
            raise GeometryError(
                f"{where}: shroud_profile must lie at least {SIZE.min_channel_height:g} mm above hub_profile "
                f"over the blade, channel height at x = {out.x[k]:.4g} mm is {height[k]:.4g} mm")
        r = rh + d.span * height
        if np.any(r <= 0):
            raise GeometryError(f"{name}: non-positive radius")
        xs.append(out.x)
        rs.append(r)
        tm.append(out.y_minus / r + d.lean)
        tp.append(out.y_plus / r + d.lean)
    for prof in (hub, shroud):
        lo, hi = prof.x_range
        x_all = np.concatenate(xs)
        if x_all.min() < lo or x_all.max() > hi:
            _log.warning("%s: blade spans x = [%.3f, %.3f] mm beyond %s x = [%.3f, %.3f] mm; "
                         "the profile is continued as a cylinder", where, x_all.min(), x_all.max(),
                         prof.name, lo, hi)
    return BladeSections(np.array(xs), np.array(rs), np.array(tm), np.array(tp))
