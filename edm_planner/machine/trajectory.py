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
from .kinematics import _rot_x, _rot_y, _rot_z, axis_poses
from .timing import TimingOptions, check_limits, time_parameterize


def machine_poses(final_pose, axis_names, q, a_zero=0.0, c_pivot=(0.0, 0.0, 0.0)):
    """The machine's forward kinematics: electrode poses in W from machine axis values.

    ``R_x(A - A0) . T(X, Y, Z) . T_final . T(c) . R_z(C) . T(-c) [. R_y(B)]`` (Huang eq. 2 with the
    six-axis B of :func:`edm_planner.machine.kinematics.state_poses`; no A: the blisk indexed to the
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
