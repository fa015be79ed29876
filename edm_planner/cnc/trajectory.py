"""A timed plan as controller joint arrays (trajectory_msgs-independent; the node converts).

Plans come in the planner's axis convention (A0 = 0, C pivot at the
electrode origin). The machine's A0 and C pivot (``config/machine.yaml``) are
applied first, by the exact transform that keeps every electrode pose (Huang
eq. 2, :class:`FiveAxisKinematics`; the residual is measured), then the path
is timed on the machine's axes, then expressed in joint coordinates
(``direction * axis + offset``; velocities and accelerations carry the sign).
The first point is the plan's start pose, the last its machining pose, both at rest.

A machining cycle (or a program of cycles) is a chain of rest-to-rest legs
whose direction reverses at the joints (feed in, process, return): one
curve through a reversal would round it off. Each leg is timed on its own
(:func:`time_leg`), its end points are made full rest (velocity AND
acceleration zero, so the rest sample shared by two legs is the same point
for both and appears once), and the legs are concatenated
(:func:`concatenate_legs`) with :class:`PhaseMark` s at every leg start.

Every leg leaves :func:`time_leg` through :func:`resample`: where its knots are too
far apart for their positions, velocities and accelerations to agree by the
trapezoid rule (the rest quintics at a leg's ends, the short legs of the
process), points of the same profile are added between them, each with the
profile's velocity and acceleration at its instant, so that what a controller
or a check integrates between points is the motion that was timed.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import EdmError, ErrorCode
from .kinematics import _rot_x, _rot_y, _rot_z, axis_poses
from .timing import TimingOptions, check_limits, time_parameterize


def machine_poses(final_pose, axis_names, q, a_zero=0.0, c_pivot=(0.0, 0.0, 0.0)):
    """The machine's forward kinematics: electrode poses in W from machine axis values.

    ``R_x(A - A0) . T(X, Y, Z) . T_final . T(c) . R_z(C) . T(-c) [. R_y(B)]`` (Huang eq. 2 with the
    six-axis B of :func:`edm_planner.cnc.kinematics.state_poses`; no A: the blisk indexed to the
    channel outside the path, poses in channel 0). B only with ``c = 0``.
    """
    q = np.atleast_2d(np.asanyarray(q, dtype=np.float64))
    col = {n: i for i, n in enumerate(axis_names)}
    c = np.asarray(c_pivot, dtype=np.float64)
    n = len(q)
    a = q[:, col["A"]] - a_zero if "A" in col else np.zeros(n)
    pivot, unpivot = np.eye(4), np.eye(4)
    pivot[:3, 3], unpivot[:3, 3] = c, -c
    inner = np.asarray(final_pose, dtype=np.float64) @ pivot @ _rot_z(q[:, col["C"]]) @ unpivot
    if "B" in col:
        if c.any():
            raise EdmError(ErrorCode.INVALID_REQUEST, "a C pivot with a B axis is not modelled")
        inner = inner @ _rot_y(q[:, col["B"]])
    inner[:, :3, 3] += q[:, [col["X"], col["Y"], col["Z"]]]
    return _rot_x(a) @ inner


def machine_axis_values(samples, axis_names, final_pose, machine):
    """Planner axis values -> the machine's axis values (its A0 and C pivot), same electrode poses.

    With the pivot ``c`` (electrode frame) the machine reaches the planner's pose
    with ``XYZ' = XYZ - R_final (c - R_z(C) c)`` and ``A' = A + A0``. A four-axis plan
    has no A (A0 unused: the channel is indexed outside the path); a six-axis plan's B
    is taken as it is (B with a C pivot is rejected).

    Parameters
    ----------
    samples : (N, k) float
        [mm, rad], planner convention.
    axis_names : sequence of str
    final_pose : (4, 4) float or None
        Electrode frame -> W at the machining pose in channel 0 (needed only with a pivot or A0).
    machine : MachineConfig

    Returns
    -------
    q : (N, k) float
        Machine axis values [mm, rad].
    residual : float
        Largest difference of the machine's forward kinematics from the planner's poses
        (rotation entries and mm), 0.0 when nothing was converted.
    """
    q = np.array(samples, dtype=np.float64)
    names = tuple(axis_names)
    pivot = np.asarray(machine.c_pivot, dtype=np.float64)
    a_zero = machine.a_zero if "A" in names else 0.0
    if "B" in names and pivot.any():
        raise EdmError(ErrorCode.INVALID_REQUEST, "a C pivot with a B axis is not modelled; plan with 5 axes")
    if not pivot.any() and a_zero == 0.0:
        return q, 0.0
    if final_pose is None:
        raise EdmError(ErrorCode.INVALID_REQUEST, "the machine has an A0 or a C pivot: the plan's final pose is needed")
    col = {n: i for i, n in enumerate(names)}
    if "A" in col:
        q[:, col["A"]] += a_zero
    xyz = [col["X"], col["Y"], col["Z"]]
    if pivot.any():
        rz = _rot_z(q[:, col["C"]])[:, :3, :3]
        q[:, xyz] -= (pivot - rz @ pivot) @ np.asarray(final_pose)[:3, :3].T
    # measured, not assumed: the machine's kinematics at q against the planner's poses
    residual = float(np.max(np.abs(machine_poses(final_pose, names, q, a_zero, pivot)
                                   - axis_poses(final_pose, names, samples))))
    if residual > 1e-9:
        raise EdmError(ErrorCode.INTERNAL, f"machine axis conversion misses the planned poses by {residual:.3g}")
    return q, residual


def check_samples_travel(samples, axis_names, machine, final_pose=None, what="plan"):
    """INFEASIBLE unless every sample lies inside the machine's travel: the bridge's check before any timing.

    The samples are converted to the machine's axis values (its A0 and C pivot, :func:`machine_axis_values`)
    and then to joint values (``direction * axis + offset``), and every one of them is compared with the
    travel; a value that is not finite counts as outside.

    Parameters
    ----------
    samples : (N, k) float
        Planner axis values [mm, rad].
    axis_names : sequence of str
        Must be the machine's axes (INVALID_REQUEST otherwise).
    machine : MachineConfig
    final_pose : (4, 4) float, optional
        As for :func:`machine_axis_values`.
    what : str
        What the samples are, for the message (e.g. "plan 0123... leg 3 (process: ...)").

    Raises
    ------
    EdmError
        INFEASIBLE naming what, the sample, the axis, its joint, the value and the travel.
    """
    limits = machine.limits_for(axis_names)
    samples = np.asarray(samples, dtype=np.float64).reshape(-1, len(limits))
    finite = np.isfinite(samples).all(axis=1)
    q = np.full_like(samples, np.nan)
    if finite.any():
        q[finite] = machine_axis_values(samples[finite], axis_names, final_pose, machine)[0]
    for j, lim in enumerate(limits):
        joint = lim.to_joint(q[:, j])
        bad = np.flatnonzero(~((joint >= lim.position_min) & (joint <= lim.position_max)))
        if len(bad):
            i = int(bad[0])
            raise EdmError(ErrorCode.INFEASIBLE,
                           f"{what}: sample {i} of {len(samples)}: axis {lim.name} (joint {lim.joint}) at "
                           f"{joint[i]:.6g} {lim.unit} is outside its travel [{lim.position_min:g}, "
                           f"{lim.position_max:g}] {lim.unit} on machine {machine.name!r} ({len(bad)} sample(s) "
                           f"outside); checked before timing, nothing sent")


@dataclass
class JointTrajectoryArrays:
    """What a ``trajectory_msgs/JointTrajectory`` holds, as arrays.

    Attributes
    ----------
    joint_names : list of str
        In the machine config's order.
    axis_names : tuple of str
        Planner axis of each joint (the machine's order, which may differ from the plan's).
    times : (n,) float
        time_from_start [s], strictly increasing, 0 at the first point.
    positions, velocities, accelerations : (n, k) float
        Joint coordinates [mm, rad], [mm/s, rad/s], [mm/s^2, rad/s^2].
    timed : TimedTrajectory
        The machine-axis trajectory it was made from (peaks, deviation).
    kinematic_residual : float
        Measured pose difference of the A0 / C-pivot conversion (0.0 when there is none).
    """

    joint_names: list
    axis_names: tuple
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    timed: object
    kinematic_residual: float = 0.0
    phases: list = field(default_factory=list)

    @property
    def duration(self):
        return float(self.times[-1])

    def point_phases(self):
        """Per point the PhaseMark of the leg it ends or lies in (a joint belongs to the leg it ends); None
        without phases."""
        if not self.phases:
            return None
        out = [self.phases[0]] * len(self.times)
        for mark, nxt in zip(self.phases, self.phases[1:] + [None]):
            stop = nxt.index if nxt is not None else len(self.times) - 1
            for i in range(mark.index + 1, stop + 1):
                out[i] = mark
        return out


@dataclass
class PhaseMark:
    """Where a leg starts in a timed cycle or program.

    Attributes
    ----------
    phase : str
        approach, feed, process, return, retract, index, tool_change.
    label : str
    index : int
        The point (at rest) the leg starts from; the leg's motion begins after it.
    time : float
        time_from_start of that point [s].
    channel : int
    plan_id, electrode_id : str
    regime : str
        The discharge regime of a cutting leg (the generator is on, in this regime, from this point to the
        next mark); '' where the generator is off (rapid and non-cutting moves).
    condition_code : str
        The control's code of that regime ('' with the generator off).
    removed_volume : float
        Blisk material the leg removes [mm^3] (a model estimate, :mod:`edm_planner.process.volume`); NaN
        where not computed.
    """

    phase: str
    label: str
    index: int
    time: float
    channel: int = 0
    plan_id: str = ""
    electrode_id: str = ""
    regime: str = ""
    condition_code: str = ""
    removed_volume: float = float("nan")

    @property
    def generator_on(self):
        return bool(self.regime)


def plan_trajectory(samples, axis_names, machine, options=TimingOptions(), final_pose=None):
    """Time a certified axis path on a machine and express it in joint coordinates.

    One point per sample: the pieces between them are toppra's cubics, whose velocities and accelerations
    agree exactly by the trapezoid rule and whose positions and velocities to ``jerk * dt^2 / 12`` (a leg of a
    cycle, which comes to rest in acceleration too, gets points between its samples: :func:`time_leg`).

    Parameters
    ----------
    samples : (N, k) float
        Plan samples (planner axis values, feed order) [mm, rad].
    axis_names : sequence of str
        The plan's axes (``plan.axis_names``); matched to the machine's by name, the result is in
        the machine's configured joint order.
    machine : MachineConfig
    options : TimingOptions
    final_pose : (4, 4) float, optional
        Electrode frame -> W at the machining pose in channel 0; needed when the machine
        has an A0 or a C pivot.

    Returns
    -------
    JointTrajectoryArrays

    Raises
    ------
    EdmError
        INVALID_REQUEST (plan axes not the machine's, malformed samples), INFEASIBLE (travel or
        limit violation, with axis and time).
    """
    return _plan_arrays(samples, axis_names, machine, options, final_pose)


def _plan_arrays(samples, axis_names, machine, options, final_pose):
    """:func:`plan_trajectory` with a point at every sample and nowhere else (the knots of its profile)."""
    order = machine.joint_order(axis_names)       # INVALID_REQUEST unless the plan's axes are the machine's
    q, residual = machine_axis_values(samples, axis_names, final_pose, machine)
    axis_names = tuple(axis_names[i] for i in order)
    limits = machine.limits_for(axis_names)
    timed = time_parameterize(q[:, order], axis_names, limits, options)
    check_limits(timed, limits)
    sign = np.array([lim.direction for lim in limits])
    offset = np.array([lim.offset for lim in limits])
    out = JointTrajectoryArrays(joint_names=[lim.joint for lim in limits], axis_names=axis_names,
                                times=timed.times.copy(), positions=timed.positions * sign + offset,
                                velocities=timed.velocities * sign, accelerations=timed.accelerations * sign,
                                timed=timed, kinematic_residual=residual)
    if not np.all(np.diff(out.times) > 0):
        raise EdmError(ErrorCode.INTERNAL, "time_from_start is not strictly increasing")
    return out


# -- cycles: legs timed rest to rest ------------------------------------------------------------

def _quintics(t0, t1, p0, v0, a0, p1, v1, a1):
    """Coefficients (c3, c4, c5) and duration of the quintics a controller puts through two points."""
    T = t1 - t0
    h = p1 - p0
    c3 = (20 * h - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T ** 2) / (2 * T ** 3)
    c4 = (-30 * h + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T ** 2) / (2 * T ** 4)
    c5 = (12 * h - 6 * (v1 + v0) * T + (a1 - a0) * T ** 2) / (2 * T ** 5)
    return c3, c4, c5, T


def quintic_segment_extremes(t0, t1, p0, v0, a0, p1, v1, a1):
    """Exact extremes per axis of the quintic through (p, v, a) at two points (joint_trajectory_controller).

    Returns
    -------
    dict
        ``position_min``, ``position_max``, ``velocity``, ``acceleration``, ``jerk`` (largest magnitudes),
        each (k,); velocity from the roots of the acceleration (a cubic), acceleration from the roots of the
        jerk (a quadratic), the jerk from its vertex, positions from the roots of the velocity (a quartic).
    """
    c3, c4, c5, T = _quintics(t0, t1, p0, v0, a0, p1, v1, a1)
    k = len(p0)
    out = {n: np.zeros(k) for n in ("position_min", "position_max", "velocity", "acceleration", "jerk")}
    for j in range(k):
        pos = np.polynomial.Polynomial([p0[j], v0[j], a0[j] / 2, c3[j], c4[j], c5[j]])
        vel, acc = pos.deriv(1), pos.deriv(2)
        jerk = pos.deriv(3)

        def inside(poly):
            r = poly.roots() if poly.degree() > 0 and np.any(poly.coef[1:]) else np.array([])
            r = np.real(r[np.abs(np.imag(r)) <= 1e-12 * max(1.0, T)])
            return np.concatenate([[0.0, T], r[(r > 0) & (r < T)]])

        xs = inside(vel)
        out["position_min"][j], out["position_max"][j] = pos(xs).min(), pos(xs).max()
        out["velocity"][j] = np.abs(vel(inside(acc))).max()
        out["acceleration"][j] = np.abs(acc(inside(jerk))).max()
        out["jerk"][j] = np.abs(jerk(inside(jerk.deriv()))).max()
    return out


def _rest_at_ends(arrays, limits, options):
    """A timed leg brought to full rest at both ends (velocity and acceleration zero), limits re-verified.

    The cubic spline of :func:`time_parameterize` is at rest in velocity but not in acceleration at its ends;
    a point shared by two legs can carry one acceleration only. With zero there, the end segments are the
    quintics the controller puts through the points: their exact velocity, acceleration and jerk peaks,
    positions and off-chord deviation are computed; a uniform stretch of the leg meets the limits (the
    quintics scale with it).
    """
    times = arrays.times
    pos, vel, acc = arrays.positions, arrays.velocities, arrays.accelerations.copy()
    acc[0] = acc[-1] = 0.0
    vel = vel.copy()
    vel[0] = vel[-1] = 0.0
    timed = arrays.timed
    n = len(times)
    ends = sorted({0, n - 2})
    vmax = np.array([lim.velocity_max for lim in limits])
    amax = np.array([lim.acceleration_max for lim in limits])
    jmax = np.array([lim.jerk_max for lim in limits])
    peak_v, peak_a, peak_j = timed.peak_velocity.copy(), timed.peak_acceleration.copy(), timed.peak_jerk.copy()
    extremes = []
    for i in ends:
        e = quintic_segment_extremes(times[i], times[i + 1], pos[i], vel[i], acc[i], pos[i + 1], vel[i + 1],
                                     acc[i + 1])
        extremes.append((i, e))
        peak_v, peak_a, peak_j = (np.maximum(peak_v, e["velocity"]), np.maximum(peak_a, e["acceleration"]),
                                  np.maximum(peak_j, e["jerk"]))
    excess = max(float(np.max(peak_v / vmax)), float(np.sqrt(np.max(peak_a / amax))),
                 float(np.cbrt(np.max(peak_j / jmax))))
    scale = 1.0
    if excess > 1.0 + options.limit_tolerance:
        scale = excess * (1.0 + 1e-12)
    times = times * scale
    vel, acc = vel / scale, acc / scale ** 2
    peak_v, peak_a, peak_j = peak_v / scale, peak_a / scale ** 2, peak_j / scale ** 3
    # travel: the end quintics' exact position extremes (the interior is the verified spline)
    for i, e in extremes:
        for j, lim in enumerate(limits):
            for value in (e["position_min"][j], e["position_max"][j]):
                if not lim.position_min - 1e-9 <= value <= lim.position_max + 1e-9:
                    raise EdmError(ErrorCode.INFEASIBLE,
                                   f"axis {lim.name} (joint {lim.joint}) at {value:.6g} {lim.unit} leaves its travel "
                                   f"[{lim.position_min:g}, {lim.position_max:g}] {lim.unit} at t = "
                                   f"{times[i]:.3f} s (coming to rest at a leg's end)")
    # off-chord deviation of the end quintics (joint coordinates: distances are the axes')
    w = np.array([1.0 if a in ("X", "Y", "Z") else options.rotary_lever for a in arrays.axis_names]) ** 2
    frac = np.linspace(0.0, 1.0, 10)[1:-1]
    between = timed.deviation_between_samples.copy()
    for i, _ in extremes:
        c3, c4, c5, T = _quintics(times[i], times[i + 1], pos[i], vel[i], acc[i], pos[i + 1], vel[i + 1],
                                  acc[i + 1])
        x = frac[:, None] * T
        inner = pos[i] + vel[i] * x + acc[i] / 2 * x ** 2 + c3 * x ** 3 + c4 * x ** 4 + c5 * x ** 5
        chord = pos[i + 1] - pos[i]
        d = inner - pos[i]
        sigma = np.clip((d * chord * w).sum(-1) / max(float((chord * chord * w).sum()), 1e-300), 0.0, 1.0)
        between = np.maximum(between, np.abs(d - sigma[:, None] * chord).max(axis=0))
    sign = np.array([lim.direction for lim in limits])
    timed = replace(timed, times=times.copy(), velocities=vel * sign, accelerations=acc * sign,
                    peak_velocity=peak_v, peak_acceleration=peak_a, peak_jerk=peak_j,
                    deviation_between_samples=between, time_scale=timed.time_scale * scale)
    return replace(arrays, times=times, velocities=vel, accelerations=acc, timed=timed)


def _hermite(p0, v0, a0, c3, c4, c5, x):
    """Position, velocity and acceleration of the quintic ``p0 + v0 x + a0/2 x^2 + c3 x^3 + c4 x^4 + c5 x^5``."""
    pos = p0 + x * (v0 + x * (a0 / 2 + x * (c3 + x * (c4 + x * c5))))
    vel = v0 + x * (a0 + x * (3 * c3 + x * (4 * c4 + x * 5 * c5)))
    acc = a0 + x * (6 * c3 + x * (12 * c4 + x * 20 * c5))
    return pos, vel, acc


def _end_on_whole_nanosecond(arrays):
    """The leg stretched uniformly (by less than 1 ns over its duration) so that its end is a whole nanosecond.

    The end is a rest whose state goes out bit for bit; at a rounded time it would bend the controller's
    last quintic (on a piece of a few ms, by a few 1e-7 of the jerk). A uniform stretch keeps the profile's
    shape and only lowers its velocities, accelerations and jerks.
    """
    end = float(arrays.times[-1])
    if not end > 0 or round(end * 1e9) / 1e9 == end:
        return arrays
    return stretch_leg(arrays, end)


def stretch_leg(arrays, duration):
    """A timed leg stretched uniformly, q(t / k), to end at ``duration`` [s] rounded up to a whole nanosecond.

    The same path and the same profile shape: velocities fall by k, accelerations by k^2, jerks by k^3, so
    every verified limit still holds (k >= 1). An erosion-timed cutting leg is its motion-limited timing
    stretched to the time the regime's removal rate needs (:func:`time_run`).
    """
    end = float(arrays.times[-1])
    whole = round(duration * 1e9)
    if whole < duration * 1e9:
        whole += 1
    k = (whole / 1e9) / end
    if k < 1.0:
        raise EdmError(ErrorCode.INTERNAL, f"a leg of {end:.9f} s cannot be shortened to {duration:.9f} s")
    times = arrays.times * k
    times[-1] = whole / 1e9
    timed = arrays.timed
    timed = replace(timed, times=times.copy(), velocities=timed.velocities / k, accelerations=timed.accelerations / k ** 2,
                    peak_velocity=timed.peak_velocity / k, peak_acceleration=timed.peak_acceleration / k ** 2,
                    peak_jerk=timed.peak_jerk / k ** 3, time_scale=timed.time_scale * k)
    return replace(arrays, times=times, velocities=arrays.velocities / k, accelerations=arrays.accelerations / k ** 2,
                   timed=timed)


def resample(arrays, limits, options=TimingOptions()):
    """Points of the timed profile added between the knots until neighbouring points' p, v and a agree.

    The timed profile of a plan or a leg is piecewise polynomial with its knots at the points: toppra's C2
    cubic spline inside, and at a leg's ends the quintics that bring the acceleration to rest
    (:func:`_rest_at_ends`). Each piece is exactly the quintic a controller puts through its two points'
    (p, v, a) (joint_trajectory_controller's quintic Hermite; a cubic is one), so a point added at time t
    carries the profile's p, v and a at t, and the controller's spline through all the points is the same
    spline: the motion, its peaks and the limits verified on it do not change. The profile is C2 everywhere:
    only the jerk switches, at the knots, which stay points, so no point needs one-sided values.

    What the points add is agreement by the trapezoid rule, for a controller or a check that integrates
    between points: on a piece of length h cut into equal parts,
    ``|dp/h - (v0 + v1)/2| <= h^2/12 max|jerk|`` and ``|dv/h - (a0 + a1)/2| <= h^2/12 max|snap|``; each
    segment is cut into the fewest parts (at most ``options.max_subdivision``) that bring both below
    ``options.consistency`` times the leg's peak velocity and acceleration of each axis (its profile's, at
    least 1e-6 of the axis' limit, so an axis at rest asks for nothing).

    Parameters
    ----------
    arrays : JointTrajectoryArrays
        One plan or one leg, its points at the knots of its profile.
    limits : sequence of AxisLimits
        In the order of ``arrays.axis_names``.
    options : TimingOptions

    Returns
    -------
    JointTrajectoryArrays
        Points added between the knots; ``timed`` likewise (``sample_index`` -1 at the added points). First
        the leg is stretched uniformly so that its end (a rest) lies on a whole nanosecond (by less than 1 ns;
        :func:`_end_on_whole_nanosecond`). When points are added, every time is a whole nanosecond (what the
        message carries) and every point the profile's state at that time: a knot lies on the profile within
        its speed x 0.5 ns of its sample, the first and the last point (the rests) are the knots bit for bit.
        Nothing to add: the stretched ``arrays``.
    """
    if len(arrays.times) < 2:
        return arrays
    arrays = _end_on_whole_nanosecond(arrays)
    eps = float(options.consistency)
    t = arrays.times
    if not np.isfinite(eps):
        return arrays
    vmax = np.array([lim.velocity_max for lim in limits])
    amax = np.array([lim.acceleration_max for lim in limits])
    v_ref = np.maximum(arrays.timed.peak_velocity, 1e-6 * vmax)
    a_ref = np.maximum(arrays.timed.peak_acceleration, 1e-6 * amax)
    p, v, a = arrays.positions, arrays.velocities, arrays.accelerations
    c3, c4, c5, T = _quintics(t[:-1, None], t[1:, None], p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:])
    # largest |jerk| (a quadratic: ends and vertex) and |snap| (linear: ends) of each piece
    vertex = np.clip(-c4 / np.where(c5 == 0, np.inf, 5 * c5), 0.0, T)
    jerk = np.max(np.abs([6 * c3 + 24 * c4 * x + 60 * c5 * x ** 2 for x in (0.0, T, vertex)]), axis=0)
    snap = np.maximum(np.abs(24 * c4), np.abs(24 * c4 + 120 * c5 * T))
    need = np.maximum(T * np.sqrt(jerk / (12 * eps * v_ref)), T * np.sqrt(snap / (12 * eps * a_ref)))
    parts = np.clip(np.ceil(need.max(axis=1) * (1 + 1e-9)), 1, options.max_subdivision).astype(int)
    if np.all(parts == 1):
        return arrays
    seg = np.repeat(np.arange(len(T)), parts - 1)                 # the piece each added point lies on
    k = np.arange(len(seg)) - np.repeat(np.cumsum(parts - 1) - (parts - 1), parts - 1) + 1
    knot = np.arange(len(t)) + np.concatenate([[0], np.cumsum(parts - 1)])
    times = np.empty(len(t) + len(seg))
    times[knot] = t
    times[np.setdiff1d(np.arange(len(times)), knot)] = t[seg] + k / parts[seg] * T[seg, 0]
    # time_from_start goes out in whole nanoseconds (builtin_interfaces/Duration). On pieces of a few
    # milliseconds a stamp rounded by half a nanosecond would bend the controller's quintic by a few 1e-6 of
    # the acceleration limit, so every point is put on a whole nanosecond and carries the profile's state
    # at that instant (a knot moves along the profile by at most its speed x 0.5 ns); the rest at the end
    # stays as it is (the profile is flat there: jerk x (0.5 ns)^3 / 6).
    times = np.round(times * 1e9) / 1e9
    if not np.all(np.diff(times) > 0):
        raise EdmError(ErrorCode.INTERNAL, "resampled time_from_start is not strictly increasing")
    piece = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(T) - 1)
    x = (times - t[piece])[:, None]

    def fill(pos, vel, acc):
        q3, q4, q5, _ = _quintics(t[:-1, None], t[1:, None], pos[:-1], vel[:-1], acc[:-1], pos[1:], vel[1:], acc[1:])
        out = _hermite(pos[piece], vel[piece], acc[piece], q3[piece], q4[piece], q5[piece], x)
        for y, z in zip(out, (pos, vel, acc)):
            y[0], y[-1] = z[0], z[-1]
        return out

    pos, vel, acc = fill(p, v, a)
    timed = arrays.timed
    tpos, tvel, tacc = fill(timed.positions, timed.velocities, timed.accelerations)
    index = np.full(len(times), -1)
    index[knot] = timed.sample_index
    timed = replace(timed, times=times.copy(), positions=tpos, velocities=tvel, accelerations=tacc, sample_index=index)
    return replace(arrays, times=times, positions=pos, velocities=vel, accelerations=acc, timed=timed)


def time_leg(samples, axis_names, machine, options=TimingOptions(), final_pose=None):
    """One rest-to-rest leg timed as :func:`plan_trajectory` does, then brought to full rest at both ends.

    Returns
    -------
    JointTrajectoryArrays
        Velocity and acceleration zero at the first and the last point; every limit verified, also on the
        quintics the controller runs through the end points. A two-sample leg (a short straight move) gets
        its chord's middle as a third point (``timed.sample_index`` -1 there). Then points of the profile
        between the knots wherever the trapezoid rule needs them (:func:`resample`, ``sample_index`` -1): the
        end segments, whose quintics bring the acceleration to rest, and every segment of a short leg.
    """
    samples = np.asarray(samples, dtype=np.float64)
    inserted = len(samples) == 2 and not np.array_equal(samples[0], samples[1])
    if inserted:
        # toppra needs a grid point between two rests (else the speed is zero everywhere): the chord's middle,
        # a point of the certified straight move; it is no plan sample (sample_index -1)
        samples = np.vstack([samples[0], 0.5 * (samples[0] + samples[1]), samples[1]])
    arrays = _plan_arrays(samples, axis_names, machine, options, final_pose)
    if inserted:
        arrays = replace(arrays, timed=replace(arrays.timed, sample_index=np.array([0, -1, 1])))
    limits = machine.limits_for(arrays.axis_names)
    return resample(_rest_at_ends(arrays, limits, options), limits, options)


def shift_joint(arrays, axis, delta, machine):
    """A timed leg with planner axis ``axis`` moved by ``delta`` (an A index: timing unchanged), travel checked.

    The whole motion moves by the same constant, so velocities, accelerations and the verified limits stay;
    the travel is checked on the positions and on the quintics between them (8 points a segment).
    """
    if not delta:
        return arrays
    j = list(arrays.axis_names).index(axis)
    lim = machine.axes[axis]
    pos = arrays.positions.copy()
    pos[:, j] += lim.direction * delta
    tpos = arrays.timed.positions.copy()
    tpos[:, j] += delta
    t = arrays.times
    c3, c4, c5, T = _quintics(t[:-1], t[1:], pos[:-1, j], arrays.velocities[:-1, j], arrays.accelerations[:-1, j],
                              pos[1:, j], arrays.velocities[1:, j], arrays.accelerations[1:, j])
    x = np.linspace(0.0, 1.0, 10)[:, None] * T
    inner = (pos[:-1, j] + arrays.velocities[:-1, j] * x + arrays.accelerations[:-1, j] / 2 * x ** 2
             + c3 * x ** 3 + c4 * x ** 4 + c5 * x ** 5)
    bad = np.flatnonzero(((inner < lim.position_min - 1e-9) | (inner > lim.position_max + 1e-9)).any(axis=0))
    if len(bad):
        i = bad[0]
        value = inner[:, i][np.argmax(np.maximum(lim.position_min - inner[:, i], inner[:, i] - lim.position_max))]
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"axis {axis} (joint {lim.joint}) at {value:.6g} {lim.unit} leaves its travel "
                       f"[{lim.position_min:g}, {lim.position_max:g}] {lim.unit} at t = {t[i]:.3f} s of the leg")
    return replace(arrays, positions=pos, timed=replace(arrays.timed, positions=tpos))


def concatenate_legs(parts, marks):
    """Legs at full rest -> one trajectory: times run on, the rest point shared by two legs appears once.

    Parameters
    ----------
    parts : list of JointTrajectoryArrays
        From :func:`time_leg`, same joints, each starting where the previous one ends.
    marks : list of dict
        Per part: ``phase``, ``label``, ``channel``, ``plan_id``, ``electrode_id`` (its PhaseMark).

    Returns
    -------
    JointTrajectoryArrays
        With ``phases`` (a PhaseMark per leg) and a ``timed`` summary: peaks and deviations the largest of the
        legs', ``time_scale`` the largest stretch, ``sample_index`` into the legs' samples chained (a shared
        rest sample once, as ``MachiningCycle.samples``; -1 for a point inserted in a two-sample leg).
    """
    if not parts:
        raise EdmError(ErrorCode.INVALID_REQUEST, "nothing to concatenate: no legs")
    times, pos, vel, acc, tpos, tvel, tacc, index, phases = [], [], [], [], [], [], [], [], []
    offset, sample_offset, count = 0.0, 0, 0
    for i, (part, mark) in enumerate(zip(parts, marks)):
        if list(part.joint_names) != list(parts[0].joint_names):
            raise EdmError(ErrorCode.INTERNAL, "legs of one trajectory on different joints")
        if np.any(part.velocities[[0, -1]]) or np.any(part.accelerations[[0, -1]]):
            raise EdmError(ErrorCode.INTERNAL, f"leg {i} ({mark['phase']}) is not at rest at its ends")
        first = 0
        if i:
            gap = np.abs(part.positions[0] - pos[-1][-1]).max()
            if gap > 1e-9:
                raise EdmError(ErrorCode.INTERNAL, f"leg {i} ({mark['phase']}: {mark['label']}) starts {gap:.3g} "
                                                   f"away from where leg {i - 1} ends")
            first = 1
        phases.append(PhaseMark(mark["phase"], mark["label"], max(count - 1, 0), offset, int(mark.get("channel", 0)),
                                mark.get("plan_id", ""), mark.get("electrode_id", ""), mark.get("regime", ""),
                                mark.get("condition_code", ""), float(mark.get("removed_volume", float("nan")))))
        sl = slice(first, None)
        times.append(part.times[sl] + offset)
        pos.append(part.positions[sl])
        vel.append(part.velocities[sl])
        acc.append(part.accelerations[sl])
        tpos.append(part.timed.positions[sl])
        tvel.append(part.timed.velocities[sl])
        tacc.append(part.timed.accelerations[sl])
        si = part.timed.sample_index[sl]
        index.append(np.where(si >= 0, si + sample_offset, -1))
        sample_offset += int(part.timed.sample_index[-1])
        count += len(part.times) - first
        offset = float(times[-1][-1])
    t0 = parts[0].timed
    timed = replace(t0, times=np.concatenate(times), positions=np.vstack(tpos), velocities=np.vstack(tvel),
                    accelerations=np.vstack(tacc), sample_index=np.concatenate(index),
                    peak_velocity=np.max([p.timed.peak_velocity for p in parts], axis=0),
                    peak_acceleration=np.max([p.timed.peak_acceleration for p in parts], axis=0),
                    peak_jerk=np.max([p.timed.peak_jerk for p in parts], axis=0),
                    deviation_at_samples=np.max([p.timed.deviation_at_samples for p in parts], axis=0),
                    deviation_between_samples=np.max([p.timed.deviation_between_samples for p in parts], axis=0),
                    time_scale=max(p.timed.time_scale for p in parts))
    out = JointTrajectoryArrays(joint_names=list(parts[0].joint_names), axis_names=parts[0].axis_names,
                                times=np.concatenate(times), positions=np.vstack(pos), velocities=np.vstack(vel),
                                accelerations=np.vstack(acc), timed=timed,
                                kinematic_residual=max(p.kinematic_residual for p in parts), phases=phases)
    if not np.all(np.diff(out.times) > 0):
        raise EdmError(ErrorCode.INTERNAL, "time_from_start of the concatenated legs is not strictly increasing")
    return out


def time_run(legs, machine, options=TimingOptions(), cache=None):
    """One electrode's legs (:class:`~edm_planner.machining.program.ProgramLeg`) as one trajectory.

    Each leg is timed rest to rest (:func:`time_leg`); a leg equal to one timed before up to a constant A
    (the same cycle leg in another channel, the same index turn) reuses that timing, moved
    (:func:`shift_joint`, travel checked). ``cache`` (a dict) may be shared between runs.

    Cutting legs are erosion-timed: a leg with a discharge regime of the machine's process model
    (``machine.process``) and a removed volume V takes at least V / (the regime's removal rate) -- the gap
    servo advances only as fast as the discharges erode -- so its motion-limited timing is stretched
    uniformly to that time (:func:`stretch_leg`; the average servo feed is the path over that time). Its
    PhaseMark carries the regime and condition code (the generator is on); every other leg (approach,
    return, retract, index, a move over material already removed) runs at the machine's limits with the
    generator off.
    """
    cache = {} if cache is None else cache
    process = machine.process
    parts, marks = [], []
    for leg in legs:
        names = tuple(leg.plan.axis_names)
        samples = np.asarray(leg.samples, dtype=np.float64)
        base = samples.copy()
        a0 = 0.0
        if "A" in names:
            ia = names.index("A")
            a0 = float(samples[0, ia])
            base[:, ia] -= a0
        key = (leg.plan.plan_id, names, np.asarray(leg.plan.final_pose).tobytes(), base.tobytes())
        hit = cache.get(key)
        if hit is None:
            hit = cache[key] = (time_leg(samples, names, machine, options, final_pose=leg.plan.final_pose), a0)
            part = hit[0]
        else:
            part = shift_joint(hit[0], "A", a0 - hit[1], machine)
        mark = {"phase": leg.phase, "label": leg.label, "channel": leg.channel, "plan_id": leg.plan.plan_id,
                "electrode_id": leg.plan.electrode_id}
        regime_name, volume = leg.regime, float(leg.removed_volume)
        if regime_name:
            regime = process.regimes.get(regime_name)
            if regime is None:
                raise EdmError(ErrorCode.INVALID_REQUEST,
                               f"leg {leg.label!r} of plan {leg.plan.plan_id} is to run in regime {regime_name!r}, "
                               f"which machine {machine.name!r} does not configure (process.regimes: "
                               f"{sorted(process.regimes)})")
            if volume > 0:                      # a move over cleared space erodes nothing: generator off
                mark.update(regime=regime.name, condition_code=regime.condition_code, removed_volume=volume)
                erosion = regime.erosion_seconds(volume)
                if erosion > part.duration:
                    part = stretch_leg(part, erosion)
            else:
                mark.update(removed_volume=volume)
        parts.append(part)
        marks.append(mark)
    return concatenate_legs(parts, marks)
