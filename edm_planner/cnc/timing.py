"""Time-optimal parameterisation of a certified axis path (toppra), with measured deviation.

toppra (reachability analysis, Pham & Pham 2018) finds the fastest path
velocity along a cubic spline through the certified samples (parameter: the
normalised weighted chord length, rotary axes weighted by ``rotary_lever``
mm/rad) under per-axis velocity and acceleration limits, starting and ending at
rest, with one grid point per sample. Its path-velocity profile is smoothed
(never raised: :func:`smooth_profile`) and the trajectory is, as toppra's
``ParametrizeSpline`` builds it, the clamped C2 cubic spline q(t) through the
samples at the resulting times. Being piecewise cubic with knots at the points, it is exactly
what a controller interpolating quintics through each point's position,
velocity and acceleration executes (joint_trajectory_controller), so the
checks below hold for the executed motion, not just at the points.

Nothing is assumed: the exact velocity, acceleration and jerk peaks of the
piecewise cubic are computed and any excess (toppra's grid discretisation,
the spline fit, or a configured jerk limit, which toppra does not model) is
removed by a uniform time stretch, which keeps the path; the deviation from
the certified samples is measured at the samples' times, and between samples
the distance from the chord the certification checked (axis-linear motion).
"""

import logging
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import minimum_filter1d, uniform_filter1d

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
    smoothing_window : int
        Grid points of the filter that smooths toppra's path-velocity profile before the spline
        (1: none). toppra switches the path acceleration between its bounds from one grid point to
        the next; those switches are jerk, which toppra does not bound. A moving minimum then a
        moving mean (never faster than toppra at any point) cut the jerk so that, on the channel-3
        plan, the stretch the jerk limits need falls from 2.06 to 1.31 (15.4 s -> 10.6 s).
    consistency : float
        How well neighbouring points' p, v and a must agree by the trapezoid rule, as a fraction of the leg's
        peak velocity and acceleration per axis: ``|dp/dt - (v0 + v1)/2| <= consistency * v_peak`` and
        ``|dv/dt - (a0 + a1)/2| <= consistency * a_peak`` on every segment. The timing adds points on its
        profile until this holds (:func:`edm_planner.cnc.trajectory.resample`); ``inf``: points only
        where the profile has knots. The profile and the controller's quintics do not change either way.
    max_subdivision : int
        Most pieces one segment of the profile is cut into (bounds the point count whatever the profile).
    """

    rotary_lever: float = 100.0
    limit_fraction: float = 0.999
    limit_tolerance: float = 1e-9
    smoothing_window: int = 9
    consistency: float = 0.01
    max_subdivision: int = 64

    def __post_init__(self):
        if not (np.isfinite(self.rotary_lever) and self.rotary_lever > 0):
            raise ValueError(f"rotary_lever must be positive, got {self.rotary_lever!r}")
        if not (0 < self.limit_fraction <= 1):
            raise ValueError(f"limit_fraction must be in (0, 1], got {self.limit_fraction!r}")
        if int(self.smoothing_window) != self.smoothing_window or self.smoothing_window < 1:
            raise ValueError(f"smoothing_window must be a positive integer, got {self.smoothing_window!r}")
        if not self.consistency > 0:
            raise ValueError(f"consistency must be positive (inf: no points added), got {self.consistency!r}")
        if int(self.max_subdivision) != self.max_subdivision or self.max_subdivision < 1:
            raise ValueError(f"max_subdivision must be a positive integer, got {self.max_subdivision!r}")


def smooth_profile(x, window):
    """Smooth a squared path-velocity profile without exceeding it anywhere.

    Moving minimum then moving mean over ``window`` points: every mean is over minima of windows
    that contain the point, so the result is <= ``x`` pointwise. The rest states at both ends are
    kept out of the minimum (they would spread zero speed, i.e. infinite time) and restored after.

    Parameters
    ----------
    x : (n,) float
        sd^2 at the grid points, zero at both ends.
    window : int

    Returns
    -------
    (n,) float
    """
    if window <= 1 or len(x) < 3:
        return x.copy()
    inner = x.copy()
    inner[0], inner[-1] = inner[1], inner[-2]
    out = uniform_filter1d(minimum_filter1d(inner, window, mode="nearest"), window, mode="nearest")
    out = np.minimum(out, inner)            # round-off of the mean
    out[0], out[-1] = x[0], x[-1]
    return out


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
    peak_velocity, peak_acceleration, peak_jerk : (k,) float
        Exact largest magnitudes of the piecewise-cubic trajectory [mm/s, rad/s ...; ^2, ^3].
    deviation_at_samples : (k,) float
        max |q(t_i) - sample_i| per axis, the timed trajectory evaluated at the samples' times [mm, rad].
    deviation_between_samples : (k,) float
        Largest off-chord distance per axis of the trajectory between samples, from the axis-linear
        motion that was certified (8 points a segment) [mm, rad].
    time_scale : float
        Uniform time stretch applied after verification (1.0: toppra's timing met every limit);
        also how jerk limits are met, which toppra does not model.
    """

    axis_names: tuple
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    sample_index: np.ndarray
    peak_velocity: np.ndarray
    peak_acceleration: np.ndarray
    peak_jerk: np.ndarray
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


def load_solver():
    """toppra and the parts of it the timing uses, imported on first call: ``(toppra, algorithm, constraint)``.

    Heavy (0.8 to 1.5 s: its Cython extension, its solvers and matplotlib, which toppra imports), so not at
    this module's import: only the timing needs it. A process that times every request (the axis bridge)
    calls it at its start instead of at its first request.
    """
    import toppra
    import toppra.algorithm as algorithm
    import toppra.constraint as constraint
    return toppra, algorithm, constraint


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
    toppra, algo, constraint = load_solver()

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
    # toppra's path velocities at the grid points (reachability analysis, Seidel LP)
    inst = algo.TOPPRA(cons, path, gridpoints=ss)
    _, sd, _ = inst.compute_parameterization(0.0, 0.0)
    if sd is None:
        raise EdmError(ErrorCode.INFEASIBLE,
                       f"toppra found no parameterisation: {inst.problem_data.return_code.value}")
    x = smooth_profile(np.maximum(np.asarray(sd, dtype=np.float64), 0.0) ** 2, options.smoothing_window)
    sd = np.sqrt(x)
    times = np.concatenate([[0.0], np.cumsum(2.0 * np.diff(ss) / (sd[:-1] + sd[1:]))])
    # as toppra's ParametrizeSpline: the clamped C2 cubic spline q(t) through the samples at these
    # times. Piecewise cubic with knots at the points, so a controller's quintic through each point's
    # (position, velocity, acceleration) reproduces it exactly: what is verified here is what runs.
    traj = CubicSpline(times, q, bc_type=((1, np.zeros(q.shape[1])), (1, np.zeros(q.shape[1]))))
    coef = traj.c                                    # (4, n-1, k): c0 tau^3 + c1 tau^2 + c2 tau + c3
    pos, vel, acc = traj(times), traj(times, 1), traj(times, 2)
    if np.max(np.abs(vel[[0, -1]])) > 1e-9 * vmax.max():
        raise EdmError(ErrorCode.INTERNAL, f"trajectory not at rest at its ends: {vel[[0, -1]]}")
    vel[0] = vel[-1] = 0.0
    # exact peaks of the piecewise cubic: acceleration is linear per segment (extremes at knots),
    # velocity quadratic (extremes at knots or where the acceleration crosses zero), jerk constant
    dt = np.diff(times)[:, None]
    tau = np.clip(-coef[1] / np.where(coef[0] == 0, np.inf, 3 * coef[0]), 0.0, dt)
    v_vertex = 3 * coef[0] * tau ** 2 + 2 * coef[1] * tau + coef[2]
    peak_v = np.maximum(np.abs(vel).max(axis=0), np.abs(v_vertex).max(axis=0))
    peak_a = np.abs(acc).max(axis=0)
    peak_j = np.abs(6 * coef[0]).max(axis=0)
    jmax = np.array([lim.jerk_max for lim in limits])
    excess = max(float(np.max(peak_v / vmax)), float(np.sqrt(np.max(peak_a / amax))),
                 float(np.cbrt(np.max(peak_j / jmax))))
    scale = 1.0
    if excess > 1.0 + options.limit_tolerance:
        # uniform stretch q(t / scale): the same path and the same spline (clamped cubic spline
        # interpolation commutes with scaling time); velocity / scale, acceleration / scale^2, jerk / scale^3
        scale = excess * (1.0 + 1e-12)
        logger.info("timing exceeds a limit (toppra grid, spline fit or jerk); stretching time by %.6f", scale)
    times_out = times * scale
    vel, acc = vel / scale, acc / scale ** 2
    peak_v, peak_a, peak_j = peak_v / scale, peak_a / scale ** 2, peak_j / scale ** 3

    deviation = np.max(np.abs(pos - q), axis=0)
    # between samples: the spline's distance from the certified chord, per axis, at 8 points a segment
    # (the off-chord part: the point is compared with its projection on the chord, weighted as s)
    w = np.array([1.0 if a in ("X", "Y", "Z") else options.rotary_lever for a in axis_names]) ** 2
    frac = np.linspace(0.0, 1.0, 10)[1:-1]
    inner = np.concatenate([traj(times[:-1] + x * np.diff(times))[None] for x in frac])   # (8, n-1, k)
    chord = q[1:] - q[:-1]
    d = inner - q[:-1]
    sigma = np.clip((d * chord * w).sum(-1) / np.maximum((chord * chord * w).sum(-1), 1e-300), 0.0, 1.0)
    between = np.max(np.abs(d - sigma[..., None] * chord), axis=(0, 1))
    if not np.all(np.diff(times_out) > 0):
        raise EdmError(ErrorCode.INTERNAL, "time law is not strictly increasing")

    t_inner = np.concatenate([(times[:-1] + x * np.diff(times)) * scale for x in frac])
    check_travel(axis_names, limits, np.vstack([pos, inner.reshape(-1, len(axis_names))]),
                 np.concatenate([times_out, t_inner]))
    return TimedTrajectory(axis_names=axis_names, times=times_out, positions=pos, velocities=vel,
                           accelerations=acc, sample_index=index, peak_velocity=peak_v, peak_acceleration=peak_a,
                           peak_jerk=peak_j, deviation_at_samples=deviation, deviation_between_samples=between,
                           time_scale=scale)


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
