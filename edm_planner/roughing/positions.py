"""Initial tool positions of plunge roughing (Chen & Dong section 2, eq. 10-13).

Everything here works on the target surface: the shroud's inner surface
offset by the allowance towards the blisk axis (a surface of revolution about
X), in channel 0 (other channels are the same rotated by k * pitch about X).
A point of it is addressed by its meridional arc length m (along the profile,
from the machining area's inlet end) and its angle theta; the
"developed" lateral coordinate is the arc r * theta. Units: mm, rad.

* eq. 10 -- the minimum blade gap L_min from the blade root data: in the
  shroud-enabled method the blades are milled on the shroud, so their root
  is where they meet the shroud; R_k is the shroud radius and m_k the blade's
  circumferential thickness r (theta_plus - theta_minus) at n stations along
  the blade there, the first and last excluded (1 < k < n).
* eq. 11 -- the largest tool radius r_max = (L_min - 2 delta) / (2 mu).
* machining area -- between the curves C''_ss and C''_ps: the suction wall
  (blade k) and the pressure wall (blade k + 1) on the target surface, each
  offset into the channel by the tool radius plus the allowance (normal
  offset in the surface's own metric); corresponding points share m.
* eq. 12 -- grooving: the midpoints O_i of corresponding points of the two
  curves, spaced along the mid curve by the step
  Delta l = 2 sqrt((1/k_i)^2 - (1/k_i - eps)^2) from its curvature k_i (the
  curve's curvature in space, on the surface), capped at ``max_step``.
* eq. 13 -- N_V1 = S / (2 sqrt(2 r h)) expansion lines, rounded up, S the
  meridional arc length of the machining area on the shroud and h the
  permissible residual height: the lines are spaced S / N_V1 <= 2 sqrt(2 r h)
  apart, at the centres of equal bands.
* the triangular travel: every expansion line crosses the channel at
  constant m, from A_i on the suction-side curve through B_j on the groove to
  C_i on the pressure-side curve, with plunges every <= ``lateral_step`` and
  B_j exactly at the middle. The grooving positions are machined first (inlet
  to outlet), then the lines from the outlet back to the inlet, each
  A_i -> B_j -> C_i, so every line starts at the suction side (a saw-tooth of
  triangles C_i -> A_{i+1} -> C_{i+1}).

The paper's figures 2 and 3 (the only description of the line layout) are
not in its text; the layout above is our reading of section 2.3-2.4 and is
stated so it can be checked.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import EdmError, ErrorCode


# -- the formulas --------------------------------------------------------------
def minimum_gap(radii, thickness, blade_count):
    """Eq. 10: L_min = min over 1 < k < n of (2 pi R_k - N m_k) / (2 N).

    Parameters
    ----------
    radii : (n,) float
        R_k, radius at the blade root data points [mm].
    thickness : (n,) float
        m_k, blade thickness there [mm].
    blade_count : int
        N.

    Returns
    -------
    float
        [mm]
    """
    radii = np.asarray(radii, dtype=np.float64)
    thickness = np.asarray(thickness, dtype=np.float64)
    if radii.shape != thickness.shape or radii.ndim != 1 or len(radii) < 3:
        raise ValueError("minimum_gap: radii and thickness must be 1-D of the same length >= 3")
    k = slice(1, len(radii) - 1)                 # 1 < k < n (1-based): the ends are left out
    return float(np.min((2 * np.pi * radii[k] - blade_count * thickness[k]) / (2 * blade_count)))


def max_tool_radius(l_min, allowance, mu):
    """Eq. 11: r_max = (L_min - 2 delta) / (2 mu) [mm]."""
    return (float(l_min) - 2.0 * float(allowance)) / (2.0 * float(mu))


def groove_step(curvature, tolerance, max_step):
    """Eq. 12: Delta l = 2 sqrt((1/k)^2 - (1/k - eps)^2), at most ``max_step``.

    Parameters
    ----------
    curvature : array_like
        k_i [1/mm], >= 0; 0 (straight) gives ``max_step``.
    tolerance : float
        eps, the permissible machining error [mm].
    max_step : float
        [mm]

    Returns
    -------
    ndarray
        [mm]; where the radius of curvature is below eps the chord is the diameter 2/k.
    """
    k = np.asarray(curvature, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        rad = 1.0 / k
        step = np.where(rad > tolerance, 2.0 * np.sqrt(np.maximum(rad ** 2 - (rad - tolerance) ** 2, 0.0)), 2.0 * rad)
    step = np.where(k > 0, step, np.inf)
    return np.minimum(step, max_step)


def line_spacing(tool_radius, residual_height):
    """The line spacing of eq. 13, 2 sqrt(2 r h) [mm]."""
    return 2.0 * np.sqrt(2.0 * tool_radius * residual_height)


def line_count(arc_length, tool_radius, residual_height):
    """Eq. 13: N_V1 = S / (2 sqrt(2 r h)), rounded up (at least 1).

    Returns
    -------
    count : int
    value : float
        The unrounded S / (2 sqrt(2 r h)).
    """
    value = float(arc_length) / line_spacing(tool_radius, residual_height)
    return max(1, int(np.ceil(value - 1e-9))), value


def triangular_order(groove_count, line_sizes):
    """Travel order and labels of grooving positions and expansion lines.

    Positions are stored grooving first (O_1 .. O_n, inlet to outlet), then
    line 1 (at the inlet) .. line N_V1 (at the outlet), each from its suction
    end A_i over B_i (middle) to its pressure end C_i. They are machined
    grooving first, then the lines from the outlet back to the inlet, each
    A_i -> B_i -> C_i.

    Parameters
    ----------
    groove_count : int
    line_sizes : sequence of int
        Number of positions of each line, inlet to outlet; odd (B in the middle), or 1 (only B).

    Returns
    -------
    order : (n,) int
        Indices into the stored positions, in machining order.
    labels : list of str
        Per stored position: ``O<i>``, ``A<i>``, ``B<i>``, ``C<i>``, or ``L<i>.<j>`` for the
        j-th plunge (1-based, from A) between them.
    """
    labels = [f"O{i + 1}" for i in range(groove_count)]
    starts = []
    for i, size in enumerate(line_sizes, start=1):
        if size < 1 or size % 2 == 0:
            raise ValueError(f"triangular_order: line {i} has {size} positions; need an odd count")
        starts.append(len(labels))
        if size == 1:
            labels.append(f"B{i}")
            continue
        mid = size // 2
        for j in range(size):
            labels.append(f"A{i}" if j == 0 else f"C{i}" if j == size - 1 else f"B{i}" if j == mid else f"L{i}.{j}")
    order = list(range(groove_count))
    for i in reversed(range(len(line_sizes))):
        order.extend(range(starts[i], starts[i] + line_sizes[i]))
    return np.array(order, dtype=int), labels


# -- the blisk's data ------------------------------------------------------------
def _wall_range(blisk, radius_of, n=1201):
    """x range where both walls of channel 0 exist on the surface r = radius_of(x)."""
    x0, x1 = blisk.axial_range
    xs = np.linspace(x0, x1, n)
    _, _, inside = blisk.wall_angles(xs, radius_of(xs), 0)
    if not inside.any():
        raise EdmError(ErrorCode.INFEASIBLE, "the blade walls do not reach the shroud surface")
    idx = np.flatnonzero(inside)
    return float(xs[idx[0]]), float(xs[idx[-1]])


def blade_root_data(blisk, n=101):
    """R_k and m_k of eq. 10: shroud radius and blade thickness at n stations of the blade root.

    Returns
    -------
    x : (n,) float
        Axial positions of the stations [mm].
    radii : (n,) float
        R_k [mm].
    thickness : (n,) float
        m_k = R_k (theta_plus - theta_minus), circumferential [mm].
    """
    lo, hi = _wall_range(blisk, blisk.shroud.radius_at)
    x = np.linspace(lo, hi, n)
    r = blisk.shroud.radius_at(x)
    th_s, th_p, inside = blisk.wall_angles(x, r, 0)
    keep = inside
    # blade 0's faces: theta_plus = channel 0's suction wall, theta_minus = the pressure wall - pitch
    thickness = r * (th_s - (th_p - blisk.pitch))
    return x[keep], r[keep], thickness[keep]


@dataclass
class MachiningArea:
    """The machining area on the target surface, sampled along m.

    Attributes
    ----------
    m : (k,) float
        Meridional arc length from the area's inlet end [mm].
    x : (k,) float
        Axial position [mm].
    radius : (k,) float
        Target surface radius [mm].
    theta_suction, theta_pressure : (k,) float
        Angles of C''_ss and C''_ps [rad] (channel 0).
    """

    m: np.ndarray
    x: np.ndarray
    radius: np.ndarray
    theta_suction: np.ndarray
    theta_pressure: np.ndarray

    @property
    def length(self):
        """S: meridional arc length of the area [mm]."""
        return float(self.m[-1] - self.m[0])

    @property
    def width(self):
        """Lateral arc width r (theta_ps - theta_ss) [mm]."""
        return self.radius * (self.theta_pressure - self.theta_suction)

    def at(self, m):
        """x, radius, theta_suction, theta_pressure at meridional positions m (linear interpolation)."""
        return tuple(np.interp(m, self.m, a) for a in (self.x, self.radius, self.theta_suction, self.theta_pressure))


def machining_area(blisk, target, offset, n=801):
    """The area between the walls offset by ``offset`` (tool radius + allowance) on the target surface.

    Parameters
    ----------
    blisk : Blisk
    target : RevolutionProfile
        The target surface's profile (shroud offset by the allowance).
    offset : float
        Distance of the tool centres from each wall, measured on the surface [mm].
    n : int
        Samples along the blade.

    Raises
    ------
    EdmError
        INFEASIBLE when the walls are closer than twice the offset everywhere, or an offset wall folds
        (offset beyond its radius of curvature).
    """
    lo, hi = _wall_range(blisk, target.radius_at)
    x = np.linspace(lo, hi, n)
    r = target.radius_at(x)
    th_s, th_p, _ = blisk.wall_angles(x, r, 0)
    slope = target.slope_at(x)
    dm = np.sqrt(1.0 + slope ** 2)
    m = np.concatenate([[0.0], np.cumsum(0.5 * (dm[1:] + dm[:-1]) * np.diff(x))])
    curves = []
    for th, side in ((th_s, 1.0), (th_p, -1.0)):
        # unit tangent (dm, r dtheta) and its normal towards the channel (+theta for the suction wall)
        ty = r * np.gradient(th, m)
        norm = np.hypot(1.0, ty)
        nm, ny = -ty / norm * side, 1.0 / norm * side
        m_off = m + offset * nm
        th_off = th + offset * ny / r
        if np.any(np.diff(m_off) <= 0):
            raise EdmError(ErrorCode.INFEASIBLE,
                           f"the blade wall offset by the tool radius plus allowance ({offset:.3f} mm) folds: the "
                           "wall's radius of curvature on the shroud is smaller; choose a smaller tool radius")
        curves.append((m_off, th_off))
    m_lo = max(curves[0][0][0], curves[1][0][0], 0.0)
    m_hi = min(curves[0][0][-1], curves[1][0][-1], m[-1])
    if m_hi <= m_lo:
        raise EdmError(ErrorCode.INFEASIBLE, "the offset blade walls do not overlap along the channel")
    mm = np.linspace(m_lo, m_hi, n)
    ts = np.interp(mm, *curves[0])
    tp = np.interp(mm, *curves[1])
    xm = np.interp(mm, m, x)
    rm = target.radius_at(xm)
    open_ = tp - ts >= 0
    if not open_.any():
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"the channel on the shroud is nowhere wider than twice the tool radius plus allowance "
                       f"({2 * offset:.3f} mm); choose a smaller tool radius")
    # the longest run of open samples
    idx = np.flatnonzero(open_)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=len)
    sel = slice(run[0], run[-1] + 1)
    m0 = mm[sel][0]
    return MachiningArea(m=mm[sel] - m0, x=xm[sel], radius=rm[sel], theta_suction=ts[sel], theta_pressure=tp[sel])


def groove_positions(area, tolerance, max_step):
    """Grooving positions O_i: midpoints of the two curves, spaced by eq. 12 along the mid curve.

    Returns
    -------
    m : (n,) float
        Meridional positions of O_i [mm].
    theta : (n,) float
        [rad]
    steps : (n - 1,) float
        Eq. 12 steps taken (the last one may be shorter: it ends on the curve's end) [mm].
    """
    theta_mid = 0.5 * (area.theta_suction + area.theta_pressure)
    pts = np.column_stack([area.x, area.radius * np.cos(theta_mid), area.radius * np.sin(theta_mid)])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-12])
    pts, m_k = pts[keep], area.m[keep]
    sigma = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    spline = CubicSpline(sigma, pts)
    d1, d2 = spline(sigma, 1), spline(sigma, 2)
    kappa = np.linalg.norm(np.cross(d1, d2), axis=1) / np.maximum(np.linalg.norm(d1, axis=1), 1e-300) ** 3
    length = sigma[-1]
    s = [0.0]
    while True:
        k = float(np.interp(s[-1], sigma, kappa))
        step = float(groove_step(k, tolerance, max_step))
        if s[-1] + step >= length - 1e-9:
            break
        s.append(s[-1] + step)
    if length - s[-1] > 1e-9 or len(s) == 1:
        s.append(length)
    s = np.array(s)
    m = np.interp(s, sigma, m_k)
    theta = np.interp(m, area.m, theta_mid)
    return m, theta, np.diff(s)


def expansion_lines(area, count, lateral_step):
    """The N_V1 expansion lines: meridional stations and lateral fractions of their plunges.

    Returns
    -------
    list of (m, fractions)
        Per line (inlet to outlet): its meridional position [mm] and the lateral fractions
        (0 = suction-side curve, 1 = pressure-side curve, odd count, 0.5 in the middle).
    """
    length = area.length
    lines = []
    for i in range(count):
        m = (i + 0.5) * length / count
        _, r, ts, tp = area.at(m)
        width = float(r * (tp - ts))
        half = int(np.ceil(width / (2.0 * lateral_step) - 1e-9))
        if width <= 1e-9 or half == 0:
            fr = np.array([0.5])
        else:
            fr = np.linspace(0.0, 1.0, 2 * half + 1)
        lines.append((m, fr))
    return lines


@dataclass
class ToolPositions:
    """Initial tool positions of one channel, stored grooving first (see :func:`triangular_order`).

    Attributes
    ----------
    points : (n, 3) float
        Bottom centres on the target surface in W, channel 0 [mm].
    x, theta : (n,) float
        Axial position [mm] and angle [rad] (channel 0).
    labels : list of str
    order : (n,) int
        Machining order (indices into the positions).
    groove_count : int
    line_count : int
        N_V1 (eq. 13).
    line_count_value : float
        Its unrounded value.
    line_spacing : float
        2 sqrt(2 r h) [mm].
    groove_steps : (groove_count - 1,) float
        Eq. 12 steps [mm].
    area : MachiningArea
    """

    points: np.ndarray
    x: np.ndarray
    theta: np.ndarray
    labels: list
    order: np.ndarray
    groove_count: int
    line_count: int
    line_count_value: float
    line_spacing: float
    groove_steps: np.ndarray
    area: MachiningArea = field(repr=False)


def plan_positions(blisk, target, tool_radius, allowance, residual_height, step_tolerance, max_step=None,
                   lateral_step=None, samples=801):
    """Grooving positions and expansion lines of channel 0 on the target surface.

    Parameters
    ----------
    blisk : Blisk
    target : RevolutionProfile
        Shroud offset by the allowance.
    tool_radius, allowance : float
        [mm]
    residual_height : float
        h of eq. 13 [mm].
    step_tolerance : float
        eps of eq. 12 [mm].
    max_step : float, optional
        Cap of the grooving step [mm] (default: the tool radius).
    lateral_step : float, optional
        Largest spacing of the plunges along a line [mm] (default: the line spacing of eq. 13).

    Returns
    -------
    ToolPositions
    """
    area = machining_area(blisk, target, tool_radius + allowance, n=samples)
    max_step = tool_radius if max_step is None else max_step
    gm, gth, steps = groove_positions(area, step_tolerance, max_step)
    count, value = line_count(area.length, tool_radius, residual_height)
    spacing = line_spacing(tool_radius, residual_height)
    lines = expansion_lines(area, count, spacing if lateral_step is None else lateral_step)
    ms, ths = [gm], [gth]
    for m, fr in lines:
        _, _, ts, tp = area.at(m)
        ms.append(np.full(len(fr), m))
        ths.append(ts + fr * (tp - ts))
    m = np.concatenate(ms)
    theta = np.concatenate(ths)
    x = area.at(m)[0]
    r = target.radius_at(x)
    points = np.column_stack([x, r * np.cos(theta), r * np.sin(theta)])
    order, labels = triangular_order(len(gm), [len(fr) for _, fr in lines])
    return ToolPositions(points=points, x=x, theta=theta, labels=labels, order=order, groove_count=len(gm),
                         line_count=count, line_count_value=value, line_spacing=spacing, groove_steps=steps,
                         area=area)
