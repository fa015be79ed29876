"""ISO NC program and CSV of a timed plan, and the parser that reads the NC program back.

NC: ``G21`` millimetres, ``G90`` absolute, ``G93`` inverse-time feed (the
standard for simultaneous multi-axis moves: ``F`` = 1 / block duration in
minutes, so every block takes exactly the time the toppra law gives it).
Linear axes in mm, rotary axes in degrees (what ISO controllers take), in
machine joint coordinates (direction and offset of ``config/machine.yaml``), one word
per machine axis in the machine file's order: ``X Y Z C`` (4 axes, the channel
indexed before the program), ``X Y Z A C`` or ``X Y Z A C B``.
The first block positions the machine at the plan's start pose outside the
blisk (``G00``); every further block is one certified sample (``G01``).
"""

import math
import re

import numpy as np

from ..errors import EdmError, ErrorCode
from .config import LINEAR

#: decimals written: 0.1 um for linear axes, 1e-5 deg (0.17 urad) for rotary axes
LINEAR_DECIMALS = 4
ROTARY_DECIMALS = 5
_WORD = re.compile(r"([A-Z])([-+]?\d+(?:\.\d*)?)")


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
    names = arrays.axis_names
    lines = ["%", _comment(f"EDM_PLANNER PLAN {plan_id}"), _comment(f"GEOMETRY {geometry_id}")]
    if channel is not None:
        lines.append(_comment(f"CHANNEL {int(channel)} ELECTRODE {electrode_id or '-'}"))
    lines += [_comment("UNITS " + " ".join(f"{n}={'MM' if n in LINEAR else 'DEG'}" for n in names)
                       + " F=INVERSE TIME 1/MIN"),
              _comment("JOINTS " + " ".join(f"{n}={j}" for n, j in zip(names, arrays.joint_names))),
              _comment(f"POINTS {len(arrays.times)} DURATION {arrays.duration:.6f} S"),
              "G21 G90 G93",
              f"N10 G00 {_axis_values(names, arrays.positions[0])}"]
    dt = np.diff(arrays.times)
    for i in range(1, len(arrays.times)):
        feed = 60.0 / dt[i - 1]                        # blocks per minute
        lines.append(f"N{10 * (i + 1)} G01 {_axis_values(names, arrays.positions[i])} F{feed:.7g}")
    lines += ["G94", "M30", "%"]
    return "\n".join(lines) + "\n"


def parse_nc(text):
    """Read back an NC program of :func:`nc_program`.

    Returns
    -------
    dict
        ``plan_id``, ``geometry_id``, ``axis_names`` (tuple), ``positions`` (n, k) joint values
        [mm, rad], ``times`` (n,) [s] from the inverse-time feeds.

    Raises
    ------
    EdmError
        FILE_ERROR on anything this writer does not produce (unknown G code, missing feed, axis change).
    """
    header, names, rows, times = {}, None, [], []
    inverse_time = False
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line == "%":
            continue
        if line.startswith("("):
            body = line.strip("()")
            for key in ("EDM_PLANNER PLAN ", "GEOMETRY "):
                if body.startswith(key):
                    header[key.split()[-1].lower()] = body[len(key):]
            continue
        words = _WORD.findall(line.upper())
        codes = {("G", float(v)) for k, v in words if k == "G"} | {("M", float(v)) for k, v in words if k == "M"}
        if ("G", 93.0) in codes:
            inverse_time = True
        motion = [c for c in codes if c in {("G", 0.0), ("G", 1.0)}]
        unknown = codes - {("G", 0.0), ("G", 1.0), ("G", 21.0), ("G", 90.0), ("G", 93.0), ("G", 94.0), ("M", 30.0)}
        if unknown:
            raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: unsupported codes {sorted(unknown)}: {raw!r}")
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
            if rows[:-1]:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: G00 only positions at the start")
            times.append(0.0)
        else:
            if not (inverse_time and feed and feed[0] > 0):
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: G01 needs G93 and a positive F")
            times.append(times[-1] + 60.0 / feed[0])
    if names is None:
        raise EdmError(ErrorCode.FILE_ERROR, "NC program has no motion blocks")
    return dict(plan_id=header.get("plan", ""), geometry_id=header.get("geometry", ""), axis_names=names,
                positions=np.array(rows), times=np.array(times))


def trajectory_csv(arrays):
    """CSV text of the timed samples: time [s], then per axis position, velocity, acceleration (units in the header)."""
    cols = ["t_s"]
    for name in arrays.axis_names:
        u = "mm" if name in LINEAR else "rad"
        cols += [f"{name}_{u}", f"{name}_vel_{u}_s", f"{name}_acc_{u}_s2"]
    k = len(arrays.axis_names)
    table = np.empty((len(arrays.times), 1 + 3 * k))
    table[:, 0] = arrays.times
    table[:, 1::3], table[:, 2::3], table[:, 3::3] = arrays.positions, arrays.velocities, arrays.accelerations
    body = "\n".join(",".join(repr(float(v)) for v in row) for row in table)
    return ",".join(cols) + "\n" + body + "\n"
