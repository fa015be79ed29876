"""The CSV of a timed plan, cycle or program (the NC program itself: :mod:`.post`, dialects :mod:`.dialect`)."""

import csv
import io

import numpy as np

from .config import LINEAR


def _csv_columns(arrays):
    cols = ["t_s"]
    for name in arrays.axis_names:
        u = "mm" if name in LINEAR else "rad"
        cols += [f"{name}_{u}", f"{name}_vel_{u}_s", f"{name}_acc_{u}_s2"]
    return cols


def _csv_table(arrays):
    k = len(arrays.axis_names)
    table = np.empty((len(arrays.times), 1 + 3 * k))
    table[:, 0] = arrays.times
    table[:, 1::3], table[:, 2::3], table[:, 3::3] = arrays.positions, arrays.velocities, arrays.accelerations
    return table


#: the columns a cycle's or a program's CSV has after the numbers
PHASE_COLUMNS = ["phase", "channel", "trajectory", "electrode", "plan_id", "leg"]


def trajectory_csv(arrays):
    """CSV text of the timed samples: time [s], then per axis position, velocity, acceleration (units in the header).

    A cycle (``arrays.phases``) gets the columns of :data:`PHASE_COLUMNS` after the numbers: each point's
    phase, channel, trajectory (0), electrode, plan id and leg (a leg's first point, at rest, belongs to the
    leg before it).
    """
    if getattr(arrays, "phases", None):
        return program_csv([arrays])
    cols = _csv_columns(arrays)
    body = "\n".join(",".join(repr(float(v)) for v in row) for row in _csv_table(arrays))
    return ",".join(cols) + "\n" + body + "\n"


def program_csv(trajectories):
    """CSV text of one or more phased trajectories (one per electrode, in order); ``t_s`` restarts with each.

    Parameters
    ----------
    trajectories : list of JointTrajectoryArrays
        With phase marks.
    """
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_csv_columns(trajectories[0]) + PHASE_COLUMNS)
    for order, arrays in enumerate(trajectories):
        marks = arrays.point_phases()
        for row, mark in zip(_csv_table(arrays), marks):
            w.writerow([repr(float(v)) for v in row] + [mark.phase, int(mark.channel), order, mark.electrode_id,
                                                        mark.plan_id, mark.label])
    return buf.getvalue()
