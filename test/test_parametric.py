"""Tests of the parametric quintic blade (edm_planner.geometry.parametric_*)."""

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from edm_planner.errors import GeometryError
from edm_planner.geometry.frames import cylindrical_to_cartesian
from edm_planner.geometry import parametric
from edm_planner.geometry.parametric_outline import (SectionDefinition, definition_outline, section_outline,
                                                     tangent_point)
from edm_planner.geometry.parametric_quintic import quintic_coefficients
from edm_planner.geometry.parametric_stacking import interpolate_definitions, stack_sections
from edm_planner.geometry.parametric_yaml import SPAN_EXTENSION, parse_parametric
from edm_planner.geometry.profiles import RevolutionProfile
from edm_planner.geometry.sections import BladeSections

DEFAULT_BLISK = Path(__file__).resolve().parents[1] / "config" / "default_blisk.yaml"

HUB = RevolutionProfile([[-5.0, 100.5], [10.0, 100.0], [30.0, 99.0]], name="hub_profile")
SHROUD = RevolutionProfile([[-5.0, 119.0], [10.0, 120.0], [30.0, 121.5]], name="shroud_profile")

SECTION = dict(x_le=0.5, x_te=24.6, le_radius=0.5, te_radius=0.3, inlet_angle=0.85,
               outlet_angle=-0.97, le_wedge=0.08, te_wedge=0.03)


def _spec(**overrides):
    spec = {
        "interpolation": "cubic",
        "span_count": 5,
        "station_count": 41,
        "sections": [
            dict(SECTION, span=0.0, stagger=0.08),
            dict(SECTION, span=0.5),
            dict(SECTION, span=1.0, stagger=-0.08, lean=0.01),
        ],
    }
    spec.update(overrides)
    return spec


def _poly_end_values(coef, x):
    return (np.polyval(coef, x), np.polyval(np.polyder(coef), x), np.polyval(np.polyder(coef, 2), x))


# ---------------------------------------------------------------- quintic


def test_quintic_reproduces_end_conditions_for_random_inputs():
    rng = np.random.default_rng(1234)
    for _ in range(200):
        x0 = rng.uniform(-30.0, 30.0)
        x1 = x0 + rng.uniform(0.5, 40.0)
        y0, y1 = rng.uniform(-10.0, 10.0, 2)
        dy0, dy1 = rng.uniform(-3.0, 3.0, 2)
        ddy0, ddy1 = rng.uniform(-0.5, 0.5, 2)
        coef = quintic_coefficients(x0, y0, dy0, ddy0, x1, y1, dy1, ddy1)
        assert coef.shape == (6,)
        got0 = _poly_end_values(coef, x0)
        got1 = _poly_end_values(coef, x1)
        np.testing.assert_allclose(got0, (y0, dy0, ddy0), rtol=0, atol=1e-6)
        np.testing.assert_allclose(got1, (y1, dy1, ddy1), rtol=0, atol=1e-6)


def test_quintic_matches_the_eq4_system_with_corrected_row():
    x0, x1 = -7.0, 12.0
    rhs = np.array([1.0, 0.5, 0.01, -2.0, -1.2, 0.02])
    m = np.array([[x ** 5, x ** 4, x ** 3, x ** 2, x, 1] for x in (x0,)]
                 + [[5 * x0 ** 4, 4 * x0 ** 3, 3 * x0 ** 2, 2 * x0, 1, 0],
                    [20 * x0 ** 3, 12 * x0 ** 2, 6 * x0, 2, 0, 0],
                    [x1 ** 5, x1 ** 4, x1 ** 3, x1 ** 2, x1, 1],
                    [5 * x1 ** 4, 4 * x1 ** 3, 3 * x1 ** 2, 2 * x1, 1, 0],
                    [20 * x1 ** 3, 12 * x1 ** 2, 6 * x1, 2, 0, 0]], dtype=float)
    coef = quintic_coefficients(x0, rhs[0], rhs[1], rhs[2], x1, rhs[3], rhs[4], rhs[5])
    np.testing.assert_allclose(m @ coef, rhs, atol=1e-8)


def test_quintic_rejects_reversed_interval():
    with pytest.raises(GeometryError):
        quintic_coefficients(1.0, 0, 0, 0, 1.0, 0, 0, 0)


# ---------------------------------------------------------------- tangent points


@pytest.mark.parametrize("side", ["minus", "plus"])
def test_tangent_points_lie_on_circle_with_circle_slope(side):
    rng = np.random.default_rng(7)
    for _ in range(50):
        centre = rng.uniform(-5, 5, 2)
        radius = rng.uniform(0.1, 2.0)
        beta = rng.uniform(-1.4, 1.4)
        p = tangent_point(centre, radius, beta, side)
        d = p - centre
        assert math.isclose(np.hypot(*d), radius, rel_tol=1e-12)
        # minus side touches the lower half, plus side the upper half
        assert (d[1] < 0) if side == "minus" else (d[1] > 0)
        # slope of the circle y(x) there: -dx/dy of the radius vector
        assert math.isclose(-d[0] / d[1], math.tan(beta), rel_tol=1e-9, abs_tol=1e-12)


# ---------------------------------------------------------------- outline


def _outline(stagger=0.0, **kw):
    args = dict(le_centre=(0.0, 0.0), le_radius=0.5, te_centre=(24.0, -3.0), te_radius=0.3,
                minus_angles=(0.75, -0.9), plus_angles=(0.95, -1.0), stagger=stagger,
                pivot=(12.0, 2.0), station_count=61, name="test section")
    args.update(kw)
    return section_outline(**args)


@pytest.mark.parametrize("stagger", [0.0, 0.15, -0.2])
def test_outline_thickness_zero_at_ends_positive_inside(stagger):
    o = _outline(stagger)
    assert o.x.shape == o.y_minus.shape == o.y_plus.shape == (61,)
    assert np.all(np.diff(o.x) > 0)
    assert o.thickness[0] == 0.0 and o.thickness[-1] == 0.0
    assert np.all(o.thickness[1:-1] > 0)
    # ends are the circles' extreme points
    assert math.isclose(o.x[0], o.le_centre[0] - 0.5, abs_tol=1e-12)
    assert math.isclose(o.x[-1], o.te_centre[0] + 0.3, abs_tol=1e-12)
    # cosine clustering: finer at the edges than in the middle
    dx = np.diff(o.x)
    assert dx[0] < 0.1 * dx[len(dx) // 2]


def test_outline_follows_edge_circles_and_quintics():
    o = _outline()
    # stations on the LE circle arcs satisfy the circle equation
    for y, side, beta in ((o.y_minus, "minus", 0.75), (o.y_plus, "plus", 0.95)):
        near = o.x <= tangent_point((0.0, 0.0), 0.5, beta, side)[0]
        assert np.count_nonzero(near) >= 3
        d = np.hypot(o.x[near] - 0.0, y[near] - 0.0)
        np.testing.assert_allclose(d, 0.5, atol=1e-9)
    # between the tangent points the minus side is the eq. 3 quintic
    p0 = tangent_point((0.0, 0.0), 0.5, 0.75, "minus")
    p1 = tangent_point((24.0, -3.0), 0.3, -0.9, "minus")
    coef = quintic_coefficients(p0[0], p0[1], math.tan(0.75), 0.0, p1[0], p1[1], math.tan(-0.9), 0.0)
    mid = (o.x > p0[0]) & (o.x < p1[0])
    np.testing.assert_allclose(o.y_minus[mid], np.polyval(coef, o.x[mid]), atol=1e-9)


def test_stagger_rotates_the_outline_about_the_pivot():
    pivot = np.array([12.0, 2.0])
    a = _outline(0.0)
    b = _outline(0.2, station_count=801)
    rot = np.array([[math.cos(0.2), -math.sin(0.2)], [math.sin(0.2), math.cos(0.2)]])
    pts = np.concatenate([np.column_stack([a.x, a.y_minus]), np.column_stack([a.x, a.y_plus])])
    moved = pivot + (pts - pivot) @ rot.T
    # every rotated point lies on the staggered outline (between its sides, on one of them)
    ym = np.interp(moved[:, 0], b.x, b.y_minus)
    yp = np.interp(moved[:, 0], b.x, b.y_plus)
    err = np.minimum(abs(moved[:, 1] - ym), abs(moved[:, 1] - yp))
    inside = (moved[:, 0] > b.x[0] + 1.0) & (moved[:, 0] < b.x[-1] - 1.0)
    assert np.count_nonzero(inside) > 60
    assert np.max(err[inside]) < 1e-3  # linear interpolation between dense stations
    np.testing.assert_allclose(b.le_centre, pivot + rot @ (np.array([0.0, 0.0]) - pivot))


def test_crossing_sides_raise():
    with pytest.raises(GeometryError, match="test section.*cross"):
        _outline(minus_angles=(0.95, -0.9), plus_angles=(0.75, -1.0))


def test_stagger_beyond_axial_normal_raises():
    with pytest.raises(GeometryError, match="single-valued"):
        _outline(stagger=0.7)


def test_chord_too_short_raises():
    with pytest.raises(GeometryError, match="chord is too short"):
        _outline(te_centre=(0.6, 0.0), le_radius=0.5, te_radius=0.5)


# ---------------------------------------------------------------- stacking


def test_stacking_lies_on_requested_spans_and_twists():
    defs = [SectionDefinition(span=0.0, stagger=0.1, **SECTION),
            SectionDefinition(span=1.0, stagger=-0.1, lean=0.02, **SECTION)]
    spans = np.array([-0.05, 0.0, 0.3, 0.5, 1.0, 1.05])
    stacked = interpolate_definitions(defs, spans, method="linear")
    blade = stack_sections(stacked, HUB, SHROUD, station_count=31)
    assert isinstance(blade, BladeSections)
    assert blade.shape == (6, 31)
    for j, s in enumerate(spans):
        rh, rt = HUB.radius_at(blade.x[j]), SHROUD.radius_at(blade.x[j])
        np.testing.assert_allclose((blade.r[j] - rh) / (rt - rh), s, atol=1e-12)
    # twist: the section turns along the span, so the inclination of the
    # stations' theta (at fixed relative chord position) changes with span
    assert np.all(blade.theta_plus >= blade.theta_minus)
    mean = 0.5 * (blade.theta_minus + blade.theta_plus)
    turn = [np.polyfit(blade.x[j], blade.r[j] * mean[j], 1)[0] for j in range(len(spans))]
    assert np.all(np.diff(turn) < 0)
    assert turn[0] - turn[-1] > 0.15
    # parameters are interpolated (and extrapolated into the extension) linearly
    np.testing.assert_allclose([d.lean for d in stacked], 0.02 * spans, atol=1e-12)
    np.testing.assert_allclose([d.stagger for d in stacked], 0.1 - 0.2 * spans, atol=1e-12)


def test_lean_shifts_the_stacking_point():
    base = SectionDefinition(span=0.5, **SECTION)
    leaned = SectionDefinition(span=0.5, lean=0.03, **SECTION)
    a = stack_sections([base, base], HUB, SHROUD, station_count=31)
    b = stack_sections([leaned, leaned], HUB, SHROUD, station_count=31)
    np.testing.assert_allclose(b.theta_minus - a.theta_minus, 0.03, atol=1e-12)
    # the stacking point (stack_x, y = 0) lies on the camber line: between the faces there
    o = definition_outline(base, station_count=201)
    k = np.searchsorted(o.x, base.stacking_x)
    assert o.y_minus[k] < 0 < o.y_plus[k]


def test_parse_parametric_shapes_and_extension():
    blade = parse_parametric(_spec(), HUB, SHROUD)
    assert blade.shape == (7, 41)
    rh, rt = HUB.radius_at(blade.x), SHROUD.radius_at(blade.x)
    s = (blade.r - rh) / (rt - rh)
    np.testing.assert_allclose(s[:, 0], [-0.03, 0, 0.25, 0.5, 0.75, 1.0, 1.03], atol=1e-12)


def test_single_section_gives_constant_blade():
    spec = _spec(sections=[dict(SECTION, span=0.3)], span_extension=0.0)
    blade = parse_parametric(spec, HUB, SHROUD)
    assert blade.shape == (5, 41)
    d = blade.r * (blade.theta_plus - blade.theta_minus)
    np.testing.assert_allclose(d, d[:1].repeat(5, axis=0), atol=1e-9)


# ---------------------------------------------------------------- default blisk


def _seg_distance(points, poly):
    a, b = poly[:-1], poly[1:]
    ab = b - a
    ap = points[:, None, :] - a[None]
    t = np.clip(np.einsum("nmk,mk->nm", ap, ab) / np.einsum("mk,mk->m", ab, ab), 0.0, 1.0)
    d = ap - t[..., None] * ab[None]
    return np.sqrt((d * d).sum(-1)).min()


@pytest.fixture(scope="module")
def default_blisk():
    doc = yaml.safe_load(DEFAULT_BLISK.read_text())
    assert set(doc) == {"blade_count", "hub_profile", "shroud_profile", "blade"}
    hub = RevolutionProfile(doc["hub_profile"], name="hub_profile")
    shroud = RevolutionProfile(doc["shroud_profile"], name="shroud_profile")
    blade = parse_parametric(doc["blade"]["parametric"], hub, shroud)
    return doc, hub, shroud, blade


def test_default_blisk_is_plausible(default_blisk):
    doc, hub, shroud, blade = default_blisk
    assert doc["blade_count"] == 60
    assert 95 < hub.radius_at(12.5) < 105
    assert 18 < shroud.radius_at(12.5) - hub.radius_at(12.5) < 22
    # the profiles extend beyond the blade on both sides
    assert hub.x_range[0] < blade.x.min() - 2 and hub.x_range[1] > blade.x.max() + 2
    assert shroud.x_range[0] < blade.x.min() - 2 and shroud.x_range[1] > blade.x.max() + 2
    S = blade.shape[0]
    assert 22 < np.ptp(blade.x[S // 2]) < 28  # axial chord about 25 mm
    # the blade penetrates hub and shroud
    rh, rt = hub.radius_at(blade.x), shroud.radius_at(blade.x)
    assert np.all(blade.r[0] < rh[0]) and np.all(blade.r[-1] > rt[-1])


def test_default_blisk_neighbours_do_not_intersect(default_blisk):
    doc, _, _, blade = default_blisk
    pitch = 2 * math.pi / doc["blade_count"]
    thickness = blade.theta_plus - blade.theta_minus
    assert thickness.max() < 0.6 * pitch
    # plus face of blade 0 stays below the minus face of blade 1 with margin
    assert np.all(blade.theta_plus < blade.theta_minus + pitch - 0.02)


def _channel(blade, pitch, j):
    p = cylindrical_to_cartesian(blade.x[j], blade.r[j], blade.theta_plus[j])
    q = cylindrical_to_cartesian(blade.x[j], blade.r[j], blade.theta_minus[j] + pitch)
    width = min(_seg_distance(p, q), _seg_distance(q, p))
    mid = 0.5 * (blade.theta_plus[j] + blade.theta_minus[j] + pitch)
    sweep = float(blade.r[j].mean() * np.ptp(mid))
    return width, sweep


def test_default_blisk_channel_width_and_sweep(default_blisk):
    doc, hub, shroud, blade = default_blisk
    pitch = 2 * math.pi / doc["blade_count"]
    j = blade.shape[0] // 2
    rh, rt = hub.radius_at(blade.x[j]), shroud.radius_at(blade.x[j])
    np.testing.assert_allclose((blade.r[j] - rh) / (rt - rh), 0.5, atol=1e-12)
    width, sweep = _channel(blade, pitch, j)
    assert width >= 3.0
    # the mid-line sweeps circumferentially by more than the channel width:
    # an electrode filling the channel cannot leave it straight along X
    assert sweep > width
    assert sweep > 1.5 * width
    # figures stated in the YAML comment
    assert abs(width - 5.9) < 0.1 and abs(sweep - 11.9) < 0.1
    # every span keeps a real channel
    for k in range(blade.shape[0]):
        assert _channel(blade, pitch, k)[0] >= 3.0


def test_default_blisk_is_twisted(default_blisk):
    _, _, _, blade = default_blisk
    mean = 0.5 * (blade.theta_minus + blade.theta_plus)
    turn = [np.polyfit(blade.x[j], blade.r[j] * mean[j], 1)[0] for j in range(blade.shape[0])]
    assert turn[1] - turn[-2] > 0.1


# ---------------------------------------------------------------- bad inputs


def _with_section(i, **changes):
    spec = _spec()
    spec = copy.deepcopy(spec)
    for k, v in changes.items():
        if v is None:
            spec["sections"][i].pop(k)
        elif v == "__null__":
            spec["sections"][i][k] = None
        else:
            spec["sections"][i][k] = v
    return spec


@pytest.mark.parametrize("spec, message", [
    (_with_section(1, le_radius=-0.3), r"blade\.parametric\.sections\[1\]\.le_radius: must be > 0 mm, got -0\.3"),
    (_with_section(0, te_radius=float("nan")), r"blade\.parametric\.sections\[0\]\.te_radius: .*finite"),
    (_with_section(2, inlet_angle=float("inf")), r"blade\.parametric\.sections\[2\]\.inlet_angle: .*finite"),
    (_with_section(1, camber=0.1), r"blade\.parametric\.sections\[1\]\.camber: unknown key"),
    (_with_section(1, x_te=None), r"blade\.parametric\.sections\[1\]\.x_te: required key missing"),
    (_with_section(1, x_te=0.2), r"blade\.parametric\.sections\[1\]\.x_te: must be > x_le"),
    (_with_section(0, le_wedge="wide"), r"blade\.parametric\.sections\[0\]\.le_wedge: must be a number"),
    (_with_section(0, le_wedge=True), r"blade\.parametric\.sections\[0\]\.le_wedge: must be a number"),
    (_with_section(0, inlet_angle=1.6), r"blade\.parametric\.sections\[0\]\.inlet_angle: must lie"),
    (_with_section(0, le_wedge=0.8), r"blade\.parametric\.sections\[0\]\.le_wedge: inlet_angle"),
    (_with_section(1, span=0.0), r"blade\.parametric\.sections\[1\]\.span: must exceed"),
    (_with_section(0, span=0.1), r"blade\.parametric\.sections\[0\]\.span: the first section"),
    (_with_section(1, minus_curvature=[0.1]), r"blade\.parametric\.sections\[1\]\.minus_curvature: must be a list"),
    (_with_section(1, plus_curvature=[0.0, float("nan")]),
     r"blade\.parametric\.sections\[1\]\.plus_curvature\[1\]: .*finite"),
    (_with_section(1, le_radius="__null__"), r"blade\.parametric\.sections\[1\]\.le_radius: must be a number"),
    (_with_section(1, stack_x=40.0), r"blade\.parametric\.sections\[1\]\.stack_x: must lie within"),
    (_spec(colour="red"), r"blade\.parametric\.colour: unknown key"),
    (_spec(interpolation="quadratic"), r"blade\.parametric\.interpolation: must be"),
    (_spec(span_count=1), r"blade\.parametric\.span_count: must be >= 2"),
    (_spec(span_extension=float("nan")), r"blade\.parametric\.span_extension: .*finite"),
    (_spec(sections=[]), r"blade\.parametric\.sections: must be a non-empty list"),
])
def test_bad_inputs_raise_with_key_path(spec, message):
    with pytest.raises(GeometryError, match=message):
        parse_parametric(spec, HUB, SHROUD)


def test_crossing_sides_in_spec_raise_naming_the_section():
    # negative wedge is refused by key; crossing by strongly opposite end curvatures
    spec = _with_section(1, minus_curvature=[2.0, 2.0], plus_curvature=[-2.0, -2.0])
    with pytest.raises(GeometryError, match=r"blade\.parametric: section at span .* cross"):
        parse_parametric(spec, HUB, SHROUD)


def test_stagger_making_section_multivalued_raises():
    spec = _with_section(2, stagger=-0.7)
    with pytest.raises(GeometryError, match=r"blade\.parametric: section at span .*single-valued"):
        parse_parametric(spec, HUB, SHROUD)


def test_shroud_below_hub_raises():
    with pytest.raises(GeometryError, match="channel height"):
        parse_parametric(_spec(), SHROUD, HUB)


def test_custom_where_prefix():
    with pytest.raises(GeometryError, match=r"my\.blade\.sections\[1\]\.le_radius: must be > 0 mm"):
        parse_parametric(_with_section(1, le_radius=0.0), HUB, SHROUD, where="my.blade")


def test_the_old_module_still_exports_its_names():
    assert parametric.parse_parametric is parse_parametric and parametric.SPAN_EXTENSION == SPAN_EXTENSION
    for name in ("quintic_coefficients", "tangent_point", "SectionOutline", "section_outline", "SectionDefinition",
                 "definition_outline", "interpolate_definitions", "stack_sections"):
        assert getattr(parametric, name) is not None
