"""A timed plan as controller joint arrays (trajectory_msgs-independent; the node converts).

Plans come in the planner's axis convention (A0 = 0, C pivot at the
electrode origin). The machine's A0 and C pivot (``config/machine.yaml``) are
applied first, by the exact transform that keeps every electrode pose (Huang
eq. 2, :class:`FiveAxisKinematics`; the residual is measured), then the path
is timed on the machine's axes, then expressed in joint coordinates
(``direction * axis + offset``; velocities and accelerations carry the sign).
The first point is the plan's start pose, the last its machining pose, both at rest.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import EdmError, ErrorCode
from .kinematics import AXES_5, FiveAxisKinematics, _rot_z, axis_poses
from .timing import TimingOptions, check_limits, time_parameterize


def machine_axis_values(samples, axis_names, final_pose, machine):
    """Planner axis values -> the machine's axis values (its A0 and C pivot), same electrode poses.

    With the pivot ``c`` (electrode frame) the machine reaches the planner's pose
    with ``XYZ' = XYZ - R_final (c - R_z(C) c)`` and ``A' = A + A0``.

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
    if not pivot.any() and machine.a_zero == 0.0:
        return q, 0.0
    if final_pose is None:
        raise EdmError(ErrorCode.INVALID_REQUEST, "the machine has an A0 or a C pivot: the plan's final pose is needed")
    if "B" in names and pivot.any():
        raise EdmError(ErrorCode.INVALID_REQUEST, "a C pivot with a B axis is not modelled; plan with 5 axes")
    col = {n: i for i, n in enumerate(names)}
    if "A" in col:
        q[:, col["A"]] += machine.a_zero
    xyz = [col["X"], col["Y"], col["Z"]]
    if pivot.any():
        rz = _rot_z(q[:, col["C"]])[:, :3, :3]
        q[:, xyz] -= (pivot - rz @ pivot) @ np.asarray(final_pose)[:3, :3].T
    # measured, not assumed: the machine's kinematics at q against the planner's poses
    full = np.zeros((len(q), 5))
    full[:, 3] = machine.a_zero
    for i, n in enumerate(AXES_5):
        if n in col:
            full[:, i] = q[:, col[n]]
    kin = FiveAxisKinematics(np.asarray(final_pose, dtype=np.float64), 0.0, c_pivot=tuple(pivot),
                             a_zero=machine.a_zero)
    residual = float(np.max(np.abs(kin.forward(full) - axis_poses(final_pose, names, samples))))
    if residual > 1e-9:
        raise EdmError(ErrorCode.INTERNAL, f"machine axis conversion misses the planned poses by {residual:.3g}")
    return q, residual


@dataclass
class JointTrajectoryArrays:
    """What a ``trajectory_msgs/JointTrajectory`` holds, as arrays.

    Attributes
    ----------
    joint_names : list of str
    axis_names : tuple of str
        Planner axis of each joint.
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

    @property
    def duration(self):
        return float(self.times[-1])


def plan_trajectory(samples, axis_names, machine, options=TimingOptions(), final_pose=None):
    """Time a certified axis path on a machine and express it in joint coordinates.

    Parameters
    ----------
    samples : (N, k) float
        Plan samples (planner axis values, feed order) [mm, rad].
    axis_names : sequence of str
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
        INVALID_REQUEST (axes not configured, malformed samples), INFEASIBLE (travel or
        limit violation, with axis and time).
    """
    axis_names = tuple(axis_names)
    limits = machine.limits_for(axis_names)
    q, residual = machine_axis_values(samples, axis_names, final_pose, machine)
    timed = time_parameterize(q, axis_names, limits, options)
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
