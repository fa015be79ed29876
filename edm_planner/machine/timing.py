"""Time-optimal parameterisation of a certified axis path (toppra), with measured deviation.

The geometric path is fixed: a C2 cubic spline in axis space through the
certified samples, parameterised by the normalised weighted chord length
``s`` in [0, 1] (rotary axes weighted by ``rotary_lever`` mm/rad). toppra (reachability
analysis, Pham & Pham 2018) finds the fastest ``s(t)`` under per-axis velocity
and acceleration limits that starts and ends at rest, with one grid point per
sample, and the trajectory is ``q(s(t))`` with ``s`` piecewise at constant
path acceleration (toppra's ``ParametrizeConstAccel``).

Nothing is assumed about the result: the limits are re-checked on the timed
trajectory at every sample and at every segment midpoint (and time is
stretched uniformly if toppra's grid discretisation left an excess), the
deviation from the certified samples is measured by evaluating the timed
trajectory at the samples' times, and the deviation between samples from the
chord the certification checked (axis-linear motion) is measured at the
segment midpoints.
"""

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import EdmError, ErrorCode

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TimingOptions:
    """Settings of the time law.

    Attributes
    ----------
    rotary_lever : float
        Weight of rotary axes in the path parameter [mm/rad] (a point 100 mm from the A axis).
    limit_fraction : float
        Fraction of each velocity/acceleration limit handed to toppra; the rest absorbs its
        grid discretisation (the limits themselves are then verified, not trusted).
    limit_tolerance : float
        Relative excess over a limit accepted as round-off in the verification.
    """

    rotary_lever: float = 100.0
    limit_fraction: float = 0.999
    limit_tolerance: float = 1e-9

    def __post_init__(self):
        if not (np.isfinite(self.rotary_lever) and self.rotary_lever > 0):
            raise ValueError(f"rotary_lever must be positive, got {self.rotary_lever!r}")
        if not (0 < self.limit_fraction <= 1):
            raise ValueError(f"limit_fraction must be in (0, 1], got {self.limit_fraction!r}")


@dataclass
class TimedTrajectory:
    """A timed axis trajectory through the certified samples (planner axis values).

    Attributes
    ----------
    axis_names : tuple of str
    times : (n,) float
        Strictly increasing, from 0 [s].
    positions, velocities, accelerations : (n, k) float
        [mm, rad], [mm/s, rad/s], [mm/s^2, rad/s^2]; velocities zero at both ends.
    sample_index : (n,) int
        The plan sample each point is (consecutive duplicate samples are dropped).
    peak_velocity, peak_acceleration : (k,) float
        Largest magnitudes over the points and the segment midpoints.
    deviation_at_samples : (k,) float
        max |q(t_i) - sample_i| per axis, the timed trajectory evaluated at the samples' times [mm, rad].
    deviation_between_samples : (k,) float
        max distance per axis of the trajectory, at the time it reaches the middle of each segment's
        path parameter, from the chord midpoint (the axis-linear motion that was certified) [mm, rad].
    time_scale : float
        Uniform time stretch applied after verification (1.0: toppra's timing met every limit).
    """

    axis_names: tuple
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    sample_index: np.ndarray
    peak_velocity: np.ndarray
    peak_acceleration: np.ndarray
    deviation_at_samples: np.ndarray
    deviation_between_samples: np.ndarray
    time_scale: float = 1.0

    @property
    def duration(self):
        return float(self.times[-1])


def path_parameter(samples, axis_names, rotary_lever):
    """Weighted cumulative chord length of axis samples [mm]: linear axes in mm, rotary axes x lever."""
    w = np.array([1.0 if a in ("X", "Y", "Z") else rotary_lever for a in axis_names])
    steps = np.linalg.norm(np.diff(samples, axis=0) * w, axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def time_parameterize(samples, axis_names, limits, options=TimingOptions()):
    """Time-optimal trajectory along the spline through ``samples``, at rest at both ends.

    Parameters
    ----------
    samples : (N, k) float
        Certified axis values in feed order [mm, rad].
    axis_names : sequence of str
    limits : sequence of AxisLimits
        In the order of ``axis_names`` (``MachineConfig.limits_for``).
    options : TimingOptions

    Returns
    -------
    TimedTrajectory

    Raises
    ------
    EdmError
        INVALID_REQUEST for a malformed path, INFEASIBLE when toppra finds no
        parameterisation or a position leaves the travel (axis, value and time named).
    """
    import toppra
    import toppra.algorithm as algo
    import toppra.constraint as constraint

    q = np.asanyarray(samples, dtype=np.float64)
    axis_names = tuple(axis_names)
    if q.ndim != 2 or q.shape[1] != len(axis_names) or len(limits) != len(axis_names):
        raise EdmError(ErrorCode.INVALID_REQUEST,
                       f"samples {q.shape} do not match axes {list(axis_names)} / {len(limits)} limits")
    if not np.all(np.isfinite(q)):
        raise EdmError(ErrorCode.INVALID_REQUEST, "samples contain NaN or infinite values")
    s_all = path_parameter(q, axis_names, options.rotary_lever)
    keep = np.concatenate([[True], np.diff(s_all) > 1e-9])   # drop repeated samples (zero-length steps)
    index = np.flatnonzero(keep)
    q, ss = q[keep], s_all[keep]
    if len(q) < 2:
        raise EdmError(ErrorCode.INVALID_REQUEST, "the path has fewer than two distinct samples")
    # toppra's Seidel LP works with absolute tolerances: with s in mm (sd^2 ~ 1e3) one grid point
    # of a real plan came out NaN ("not controllable"); on s in [0, 1] it is well conditioned
    ss = ss / ss[-1]
    vmax = np.array([lim.velocity_max for lim in limits])
    amax = np.array([lim.acceleration_max for lim in limits])

    path = toppra.SplineInterpolator(ss, q)
    f = options.limit_fraction
    cons = [constraint.JointVelocityConstraint(np.stack([-vmax * f, vmax * f], axis=1)),
            constraint.JointAccelerationConstraint(np.stack([-amax * f, amax * f], axis=1))]
    inst = algo.TOPPRA(cons, path, gridpoints=ss, parametrizer="ParametrizeConstAccel")
    traj = inst.compute_trajectory(0.0, 0.0)
    data = inst.problem_data
    if traj is None:
        raise EdmError(ErrorCode.INFEASIBLE, f"toppra found no parameterisation: {data.return_code.value}")
    sd = np.maximum(np.asarray(data.sd_vec, dtype=np.float64), 0.0)
    sdd = np.asarray(data.sdd_vec, dtype=np.float64)[: len(ss) - 1]
    ds = np.diff(ss)
    # constant path acceleration per segment: the time of a segment from its end speeds
    dt = 2.0 * ds / (sd[:-1] + sd[1:])
    times = np.concatenate([[0.0], np.cumsum(dt)])
    qs, qss = path(ss, 1), path(ss, 2)
    # at a grid point the path acceleration jumps; the mean of both sides is the value a
    # central difference sees and stays within the (convex) limits
    u = np.empty(len(ss))
    u[0], u[-1] = sdd[0], sdd[-1]
    u[1:-1] = 0.5 * (sdd[:-1] + sdd[1:])
    pos = path(ss)
    vel = qs * sd[:, None]
    acc = qss * sd[:, None] ** 2 + qs * u[:, None]
    vel[0] = vel[-1] = 0.0

    # verify on toppra's own trajectory: at the points (one-sided) and the segment midpoints
    t_mid = 0.5 * (times[:-1] + times[1:])
    v_mid, a_mid = traj(t_mid, 1), traj(t_mid, 2)
    peak_v = np.max(np.abs(np.vstack([vel, v_mid])), axis=0)
    peak_a = np.max(np.abs(np.vstack([acc, a_mid, traj(times[:-1], 2)])), axis=0)
    excess = max(float(np.max(peak_v / vmax)), float(np.sqrt(np.max(peak_a / amax))))
    scale = 1.0
    if excess > 1.0 + options.limit_tolerance:
        # uniform stretch: velocities / scale, accelerations / scale^2, same path
        scale = excess * (1.0 + 1e-12)
        logger.info("toppra's timing exceeds a limit by %.3g %%; stretching time by %.6f", (excess - 1) * 100, scale)
    times_out = times * scale
    vel, acc = vel / scale, acc / scale ** 2
    peak_v, peak_a = peak_v / scale, peak_a / scale ** 2

    deviation = np.max(np.abs(traj(times) - q), axis=0)
    # time at which s reaches the segment's middle (sd^2 is linear in s at constant path acceleration)
    sd_mid = np.sqrt(0.5 * (sd[:-1] ** 2 + sd[1:] ** 2))
    t_half = times[:-1] + ds / (sd[:-1] + sd_mid)
    between = np.max(np.abs(traj(t_half) - 0.5 * (q[:-1] + q[1:])), axis=0)
    if not np.all(np.diff(times_out) > 0):
        raise EdmError(ErrorCode.INTERNAL, "time law is not strictly increasing")

    check_travel(axis_names, limits, np.vstack([pos, traj(t_mid)]),
                 np.concatenate([times_out, t_mid * scale]))
    return TimedTrajectory(axis_names=axis_names, times=times_out, positions=pos, velocities=vel,
                           accelerations=acc, sample_index=index, peak_velocity=peak_v, peak_acceleration=peak_a,
                           deviation_at_samples=deviation, deviation_between_samples=between, time_scale=scale)


def check_travel(axis_names, limits, positions, times):
    """INFEASIBLE naming axis, joint, value and time at the first position outside the travel.

    Parameters
    ----------
    positions : (n, k) float
        Planner axis values [mm, rad].
    times : (n,) float
        [s].
    """
    positions = np.atleast_2d(positions)
    order = np.argsort(times, kind="stable")
    for j, (name, lim) in enumerate(zip(axis_names, limits)):
        joint = lim.to_joint(positions[order, j])
        bad = np.flatnonzero((joint < lim.position_min) | (joint > lim.position_max))
        if len(bad):
            i = bad[0]
            raise EdmError(ErrorCode.INFEASIBLE,
                           f"axis {name} (joint {lim.joint}) at {joint[i]:.6g} {lim.unit} leaves its travel "
                           f"[{lim.position_min:g}, {lim.position_max:g}] {lim.unit} at t = {times[order][i]:.3f} s")


def check_limits(trajectory, limits, tolerance=1e-6):
    """INFEASIBLE naming axis and time if a point's velocity or acceleration exceeds its limit.

    The bridge's last gate before publishing (never publish a limit violation).
    """
    for j, (name, lim) in enumerate(zip(trajectory.axis_names, limits)):
        for kind, values, bound, unit in (("velocity", trajectory.velocities[:, j], lim.velocity_max, "/s"),
                                          ("acceleration", trajectory.accelerations[:, j], lim.acceleration_max,
                                           "/s^2")):
            bad = np.flatnonzero(np.abs(values) > bound * (1 + tolerance))
            if len(bad):
                i = bad[0]
                raise EdmError(ErrorCode.INFEASIBLE,
                               f"axis {name} (joint {lim.joint}) {kind} {values[i]:.6g} {lim.unit}{unit} exceeds "
                               f"{bound:g} {lim.unit}{unit} at t = {trajectory.times[i]:.3f} s")
