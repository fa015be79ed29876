"""A timed plan as controller joint arrays (trajectory_msgs-independent; the node converts).

Joint values are machine joint coordinates (``direction * planner + offset``
per axis, from ``config/machine.yaml``); velocities and accelerations carry
the direction sign. The first point is the plan's start pose, the last its
machining pose, both at rest.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import EdmError, ErrorCode
from .timing import TimingOptions, check_limits, time_parameterize


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
        The planner-axis trajectory it was made from (peaks, deviation).
    """

    joint_names: list
    axis_names: tuple
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    timed: object

    @property
    def duration(self):
        return float(self.times[-1])


def plan_trajectory(samples, axis_names, machine, options=TimingOptions()):
    """Time a certified axis path on a machine and express it in joint coordinates.

    Parameters
    ----------
    samples : (N, k) float
        Plan samples (planner axis values, feed order) [mm, rad].
    axis_names : sequence of str
    machine : MachineConfig
    options : TimingOptions

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
    timed = time_parameterize(samples, axis_names, limits, options)
    check_limits(timed, limits)
    sign = np.array([lim.direction for lim in limits])
    offset = np.array([lim.offset for lim in limits])
    out = JointTrajectoryArrays(joint_names=[lim.joint for lim in limits], axis_names=axis_names,
                                times=timed.times.copy(), positions=timed.positions * sign + offset,
                                velocities=timed.velocities * sign, accelerations=timed.accelerations * sign,
                                timed=timed)
    if not np.all(np.diff(out.times) > 0):
        raise EdmError(ErrorCode.INTERNAL, "time_from_start is not strictly increasing")
    return out
