"""ISO NC program and CSV of a timed plan, and the parser that reads the NC program back.

NC: ``G21`` millimetres, ``G90`` absolute, ``G93`` inverse-time feed (the
standard for simultaneous multi-axis moves: ``F`` = 1 / block duration in
minutes, so every block takes exactly the time the toppra law gives it).
Linear axes in mm, rotary axes in degrees (what ISO controllers take), in
machine joint coordinates (direction and offset of ``config/machine.yaml``), one word
per machine axis in the machine file's order: ``X Y Z C`` (4 axes, the channel
indexed before the program), ``X Y Z A C`` or ``X Y Z A C B``.
The first block positions the machine at the plan's start pose outside the
blisk (``G00``); every further block is one point of the timed trajectory
(``G01``): a certified sample, or a point of the timed profile between two
samples where the timing adds one (at a leg's rest quintics, on short legs).

A machining cycle marks each leg's start with a comment line
``(PHASE <phase> CHANNEL <k> : <what the leg does>)`` before its first motion
block (phases approach, feed, process, return, retract, index). A program of
several electrodes (:func:`nc_sequence_program`) calls each electrode with a
tool-change block ``T<n> M06`` after a comment ``(TOOL CHANGE T<n> ELECTRODE
<id> PLAN <plan id>)``, then positions with ``G00`` at the electrode's home
point (outside the blisk) and runs its trajectory; each electrode's
inverse-time feeds restart with its own trajectory.
"""

import csv
import io
import math
import re

import numpy as np

from ..errors import EdmError, ErrorCode
from .config import LINEAR

#: decimals written: 0.1 um for linear axes, 1e-5 deg (0.17 urad) for rotary axes
LINEAR_DECIMALS = 4
ROTARY_DECIMALS = 5
_WORD = re.compile(r"([A-Z])([-+]?\d+(?:\.\d*)?)")
_PHASE = re.compile(r"PHASE (\S+) CHANNEL (\d+)")


def _comment(text):
    # NC comments end at the first ')': keep ids and names printable and bracket-free
    return "(" + re.sub(r"[()\n\r]", "_", str(text)) + ")"


def _axis_values(axis_names, positions):
    """Joint positions -> NC words (rotary in degrees)."""
    words = []
    for name, value in zip(axis_names, positions):
        if name in LINEAR:
            words.append(f"{name}{value:.{LINEAR_DECIMALS}f}")
        else:
            words.append(f"{name}{math.degrees(value):.{ROTARY_DECIMALS}f}")
    return " ".join(words)


def _label(text):
    return str(text).replace("(", "[").replace(")", "]")


def _motion_blocks(arrays, number):
    """G00 to the first point, G01 to every further one, phase comments at leg starts; (lines, next number)."""
    names = arrays.axis_names
    marks = {}
    for mark in getattr(arrays, "phases", None) or []:
        marks.setdefault(mark.index, []).append(mark)
    lines = [f"N{number} G00 {_axis_values(names, arrays.positions[0])}"]
    number += 10

    def comment(i):
        for mark in marks.get(i, ()):
            lines.append(_comment(f"PHASE {mark.phase} CHANNEL {int(mark.channel)} : {_label(mark.label)}"))

    comment(0)
    dt = np.diff(arrays.times)
    for i in range(1, len(arrays.times)):
        feed = 60.0 / dt[i - 1]                        # blocks per minute
        lines.append(f"N{number} G01 {_axis_values(names, arrays.positions[i])} F{feed:.7g}")
        number += 10
        comment(i)
    return lines, number


def _units_lines(arrays):
    names = arrays.axis_names
    return [_comment("UNITS " + " ".join(f"{n}={'MM' if n in LINEAR else 'DEG'}" for n in names)
                     + " F=INVERSE TIME 1/MIN"),
            _comment("JOINTS " + " ".join(f"{n}={j}" for n, j in zip(names, arrays.joint_names)))]


def nc_sequence_program(trajectories, sequence_id, geometry_id, kind="blisk_program"):
    """One NC program of several electrodes' trajectories, a tool change before each.

    Parameters
    ----------
    trajectories : list of (JointTrajectoryArrays, electrode_id, plan_id)
        In machining order, each with its phase marks (:func:`~edm_planner.machine.trajectory.time_run`).
    sequence_id, geometry_id, kind : str

    Returns
    -------
    str
    """
    if not trajectories:
        raise EdmError(ErrorCode.INVALID_REQUEST, "a program needs at least one trajectory")
    first = trajectories[0][0]
    total = sum(a.duration for a, _, _ in trajectories)
    points = sum(len(a.times) for a, _, _ in trajectories)
    lines = ["%", _comment(f"EDM_PLANNER PLAN {sequence_id}"), _comment(f"GEOMETRY {geometry_id}"),
             _comment(f"SEQUENCE {kind} ELECTRODES {len(trajectories)}")]
    lines += _units_lines(first)
    lines += [_comment(f"POINTS {points} DURATION {total:.6f} S WITHOUT TOOL CHANGES"), "G21 G90 G93"]
    number = 10
    for order, (arrays, electrode_id, plan_id) in enumerate(trajectories, 1):
        if tuple(arrays.axis_names) != tuple(first.axis_names):
            raise EdmError(ErrorCode.INVALID_REQUEST, f"electrode {electrode_id}: axes {arrays.axis_names} differ "
                                                      f"from {first.axis_names}")
        channels = sorted({m.channel for m in arrays.phases}) if arrays.phases else []
        lines += [_comment(f"ELECTRODE {order} OF {len(trajectories)}: {len(arrays.times)} POINTS "
                           f"{arrays.duration:.6f} S CHANNELS {_channel_text(channels)}"),
                  _comment(f"TOOL CHANGE T{order} ELECTRODE {electrode_id or '-'} PLAN {plan_id}"),
                  f"N{number} T{order} M06"]
        number += 10
        body, number = _motion_blocks(arrays, number)
        lines += body
    lines += ["G94", "M30", "%"]
    return "\n".join(lines) + "\n"


def _channel_text(channels):
    if not channels:
        return "-"
    if channels == list(range(channels[0], channels[-1] + 1)) and len(channels) > 2:
        return f"{channels[0]}..{channels[-1]}"
    return ",".join(str(c) for c in channels)


def nc_program(arrays, plan_id, geometry_id, channel=None, electrode_id=""):
    """The NC program text of a timed plan.

    Parameters
    ----------
    arrays : JointTrajectoryArrays
        From :func:`edm_planner.machine.trajectory.plan_trajectory`.
    plan_id, geometry_id : str
    channel : int, optional
    electrode_id : str

    Returns
    -------
    str
    """
    lines = ["%", _comment(f"EDM_PLANNER PLAN {plan_id}"), _comment(f"GEOMETRY {geometry_id}")]
    if channel is not None:
        lines.append(_comment(f"CHANNEL {int(channel)} ELECTRODE {electrode_id or '-'}"))
    lines += _units_lines(arrays)
    lines += [_comment(f"POINTS {len(arrays.times)} DURATION {arrays.duration:.6f} S"), "G21 G90 G93"]
    body, _ = _motion_blocks(arrays, 10)
    lines += body
    lines += ["G94", "M30", "%"]
    return "\n".join(lines) + "\n"


def parse_nc(text):
    """Read back an NC program of :func:`nc_program`.

    Returns
    -------
    dict
        ``plan_id``, ``geometry_id``, ``axis_names`` (tuple), ``positions`` (n, k) joint values
        [mm, rad], ``times`` (n,) [s] from the inverse-time feeds (restarting at 0 with each electrode's
        trajectory), ``phases`` [(phase, channel, point index the leg starts from)], ``tool_changes``
        [(tool number, point index of the electrode's first point, comment)], ``trajectories``
        [(first, last) point index per trajectory].

    Raises
    ------
    EdmError
        FILE_ERROR on anything this writer does not produce (unknown G code, missing feed, axis change).
    """
    header, names, rows, times = {}, None, [], []
    phases, tool_changes, starts = [], [], []
    inverse_time = False
    changed = False                   # a tool change since the last motion: the next block is a G00
    last_comment = ""
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line == "%":
            continue
        if line.startswith("("):
            body = line.strip("()")
            for key in ("EDM_PLANNER PLAN ", "GEOMETRY "):
                if body.startswith(key):
                    header[key.split()[-1].lower()] = body[len(key):]
            phase = _PHASE.match(body)
            if phase:
                phases.append((phase.group(1), int(phase.group(2)), max(len(rows) - 1, 0)))
            last_comment = body
            continue
        words = _WORD.findall(line.upper())
        codes = {("G", float(v)) for k, v in words if k == "G"} | {("M", float(v)) for k, v in words if k == "M"}
        if ("G", 93.0) in codes:
            inverse_time = True
        motion = [c for c in codes if c in {("G", 0.0), ("G", 1.0)}]
        unknown = codes - {("G", 0.0), ("G", 1.0), ("G", 21.0), ("G", 90.0), ("G", 93.0), ("G", 94.0), ("M", 30.0),
                           ("M", 6.0)}
        if unknown:
            raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: unsupported codes {sorted(unknown)}: {raw!r}")
        if ("M", 6.0) in codes:
            tool = [int(float(v)) for k, v in words if k == "T"]
            if not tool or motion:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: M06 needs a T word and no motion: {raw!r}")
            tool_changes.append((tool[0], len(rows), last_comment))
            changed = True
            continue
        if not motion:
            continue
        axes = [(k, float(v)) for k, v in words if k in "XYZABC"]
        these = tuple(k for k, _ in axes)
        if names is None:
            names = these
        elif these != names:
            raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: axes {these} differ from {names}")
        rows.append([v if k in LINEAR else math.radians(v) for k, v in axes])
        feed = [float(v) for k, v in words if k == "F"]
        if motion[0] == ("G", 0.0):
            if rows[:-1] and not changed:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: G00 only positions at the start and after "
                                                     f"a tool change")
            times.append(0.0)
            starts.append(len(rows) - 1)
            changed = False
        else:
            if not (inverse_time and feed and feed[0] > 0):
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: G01 needs G93 and a positive F")
            if changed:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: after a tool change the program positions "
                                                     f"with G00 first")
            times.append(times[-1] + 60.0 / feed[0])
    if names is None:
        raise EdmError(ErrorCode.FILE_ERROR, "NC program has no motion blocks")
    bounds = starts + [len(rows)]
    return dict(plan_id=header.get("plan", ""), geometry_id=header.get("geometry", ""), axis_names=names,
                positions=np.array(rows), times=np.array(times), phases=phases, tool_changes=tool_changes,
                trajectories=[(a, b - 1) for a, b in zip(bounds[:-1], bounds[1:])])


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
