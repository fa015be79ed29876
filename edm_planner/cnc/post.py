"""The post-processor: timed trajectories -> the NC program of one control dialect (:mod:`.dialect`).

Input: one timed trajectory per electrode (:func:`~edm_planner.cnc.trajectory.time_run`), each
starting and ending at the electrode's clear position (:class:`~edm_planner.machining.cycle.ClearZone`),
with its phase marks. Output: a program that

* numbers its blocks and programs, frames and comments them as the dialect says, writes every
  coordinate with a decimal point at the dialect's decimals (joint coordinates of the machine YAML,
  rotary axes in degrees);
* writes a block per timed point, in the dialect's linear feed mode (G94, F in mm/min) where no rotary
  axis moves and its rotary mode (G93) where one does, F giving the block the time the time law gave
  it; a point is left out only where it lies within ``merge_tolerance_mm`` of the line of the block that
  passes over it (straight legs become one block, and blocks too short for the control's F range are
  merged with their neighbours); a block that still needs an F beyond the range is slowed to it (never
  sped up: the motion only takes longer), and the header says how many were and what it cost;
* switches the EDM generator and flushing with the phase marks (a cutting leg's regime and condition
  code), as far as the dialect has words for them;
* changes tools at the clear position: G94 first, the change, tool length and work offset of the
  electrode, then the positioning move from the changer to the electrode's clear position, X alone
  first, then the other axes at that X (where the clear zone certifies any A, C, Y, Z);
* in ``subprograms`` structure, writes each distinct channel pass once as a subprogram in the
  coordinates of the first channel that runs it, and calls it in every channel after a local
  coordinate shift of A (G52): the program's size grows with the electrodes and their wear
  compensation steps, not with the channels. Two passes are the same when they have the same phase
  marks, their local positions agree within :data:`SAME_PASS_SHARE` of the dialect's resolution and
  their durations within :data:`SAME_PASS_TIME` (relative): each channel's pass is timed on its own A
  values, which differ by the pitch, and its durations came out up to 3e-7 apart (positions 6e-9 rad),
  enough to flip the last digit of a feed, so comparing the texts alone made a subprogram per channel
  on some CPUs. ``flat`` (DNC) writes every block in the main program.

:func:`check_program` reads the text back (:func:`read_program`, subprograms expanded) and refuses a
program that breaks its dialect's limits or does not reproduce the trajectories within the stated
resolution; :func:`write_program` runs it on everything it writes.
"""

import bisect
import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import EdmError, ErrorCode
from .config import LINEAR
from .dialect import load_dialect

_WORD = re.compile(r"([A-Z])([-+]?\d+(?:\.\d*)?)")
_PHASE = re.compile(r"PHASE (\S+)(?: CH (\d+))?")
_PASS = re.compile(r"CHANNEL (\d+) PASS")
_RADIANS = re.compile(r"([-+]?\d*\.?\d+) rad(/mm)?\b")


def _degrees_text(label):
    """A label's radians in degrees, as the program's A and C words are (comments carry no '+')."""
    return _RADIANS.sub(lambda m: f"{math.degrees(float(m.group(1))):.4f} DEG{m.group(2) or ''}", str(label))


@dataclass
class ProgramRun:
    """One electrode's part of a program: its timed trajectory and who it is."""

    arrays: object               # JointTrajectoryArrays with phases
    label: str
    plan_id: str
    pitch: float = 0.0           # 2 pi / N [rad]: channel k's A offset from the plan's channel is (k - k0) pitch


@dataclass
class PostStats:
    """What the post-processor did (for the header, the CLI and the tests)."""

    blocks: int = 0
    points: int = 0
    merged_points: int = 0
    slowed_blocks: int = 0
    added_seconds: float = 0.0
    subprograms: int = 0
    calls: int = 0
    max_merge_deviation: float = 0.0
    lines: int = 0
    notes: list = field(default_factory=list)
    dialect: str = ""
    tolerance: float = 0.0             # merge tolerance [mm]


def _fmt(value, decimals):
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = f"{0.0:.{decimals}f}"                 # no "-0.0000"
    return text


class _Writer:
    """Block numbering and line collection of one program or subprogram."""

    def __init__(self, dialect):
        self.d = dialect
        self.lines = []
        self.number = dialect.block_start

    def block(self, text):
        if self.d.block_numbers:
            text = f"N{self.number} {text}"
            self.number += self.d.block_increment
            if self.number > self.d.block_max:      # numbers may repeat on these controls: start again
                self.number = self.d.block_increment
        self.lines.append(text)

    def comment(self, text):
        self.lines.append(self.d.comment(text))


def _axis_words(dialect, names, q):
    out = []
    for name, value in zip(names, q):
        v = value if name in LINEAR else math.degrees(value)
        out.append(f"{name}{_fmt(v, dialect.decimals(name))}")
    return " ".join(out)


def _rounded(dialect, names, q, which):
    """The values the program writes for the axes ``which`` (a mask), as text."""
    return np.array([_fmt(v if n in LINEAR else math.degrees(v), dialect.decimals(n))
                     for n, v, keep in zip(names, q, which) if keep])


def _weights(dialect, names):
    return np.array([1.0 if n in LINEAR else dialect.rotary_lever for n in names])


def _segments(dialect, names, q, breaks):
    """Blocks of one stretch of points: [(first, last)] point indices, merged where the dialect allows.

    A block runs from point ``first`` to point ``last``; interior points are left out when each lies within
    the merge tolerance of the block's line and no break (a phase mark, a change of feed mode) lies inside.
    Greedy from the start; blocks shorter than the rotary/linear F range needs are always merged when the
    tolerance allows, others too (a straight leg is one block).
    """
    w = _weights(dialect, names)
    rot = np.array([n not in LINEAR for n in names])
    qw = q * w
    out, i, n = [], 0, len(q) - 1
    tol = dialect.merge_tolerance

    def fits(a, b):
        if b - a < 2:
            return True, 0.0
        k = bisect.bisect_right(breaks, a)
        if k < len(breaks) and breaks[k] < b:
            return False, 0.0
        p0, p1 = qw[a], qw[b]
        d = p1 - p0
        inner = qw[a + 1:b]
        den = float(d @ d)
        s = np.clip(((inner - p0) @ d) / den, 0.0, 1.0) if den > 0 else np.zeros(len(inner))
        dev = float(np.linalg.norm(inner - p0 - s[:, None] * d, axis=1).max())
        return dev <= tol, dev

    while i < n:
        best, best_dev, step, hi = i + 1, 0.0, 1, None
        while True:                                  # grow by doubling, then bisect back
            cand = min(best + step, n)
            if cand == best:
                break
            ok, dev = fits(i, cand)
            if not ok:
                hi = cand
                break
            best, best_dev, step = cand, dev, step * 2
        while hi is not None and hi - best > 1:
            mid = (best + hi) // 2
            ok, dev = fits(i, mid)
            if ok:
                best, best_dev = mid, dev
            else:
                hi = mid
        out.append((i, best, best_dev, bool(np.any(_rounded(dialect, names, q[i], rot)
                                                   != _rounded(dialect, names, q[best], rot)))))
        i = best
    return out


def _motion(dialect, names, q, t, marks, writer, stats, edm_state, channels=True):
    """Write the blocks of points 0..n (point 0 is where the machine is); marks at their point indices."""
    by_index = {}
    for m in marks:
        by_index.setdefault(m.index, []).append(m)
    lin = np.array([n in LINEAR for n in names])
    breaks = sorted(by_index)
    mode = None
    for a, b, dev, rotary in _segments(dialect, names, q, breaks):
        for m in by_index.get(a, ()):
            _phase_events(dialect, writer, m, edm_state, channels)
        seconds = float(t[b] - t[a])
        length = float(np.linalg.norm(q[b, lin] - q[a, lin]))
        feed = dialect.rotary_feed if rotary else dialect.linear_feed
        if not rotary and not feed.min <= feed.value(seconds, length):
            feed = dialect.rotary_feed                # too short a move for a feed rate: inverse time takes any
        f = feed.value(seconds, length)
        scale = 10.0 ** dialect.feed_decimals
        if f > feed.max:                              # slower, never faster: the block takes longer
            f_new = math.floor(feed.max * scale) / scale
            stats.slowed_blocks += 1
            stats.added_seconds += feed.seconds(f_new, length) - seconds
            f = f_new
        pieces = 1
        if feed.unit == "inverse_min" and f < feed.min:       # longer than the control's longest block: split
            pieces = int(math.ceil(feed.min / f * (1 + 1e-9)))
        elif feed.unit == "block_seconds" and f < feed.min:   # shorter than the shortest: slower
            stats.slowed_blocks += 1
            stats.added_seconds += feed.min - f
            f = feed.min
        elif feed.unit == "block_seconds" and f > feed.max:
            pieces = int(math.ceil(f / feed.max * (1 + 1e-9)))
        f_text = _fmt(f * pieces if feed.unit == "inverse_min" else
                      (f / pieces if feed.unit == "block_seconds" else f), dialect.feed_decimals)
        code = feed.code if feed.code != mode else ""
        mode = feed.code
        for k in range(1, pieces + 1):
            point = q[a] + (q[b] - q[a]) * (k / pieces)
            writer.block(" ".join(x for x in (code, "G01", _axis_words(dialect, names, point), f"F{f_text}") if x))
            code = ""
            stats.blocks += 1
        stats.merged_points += b - a - 1
        stats.max_merge_deviation = max(stats.max_merge_deviation, dev)
    for m in by_index.get(len(q) - 1, ()):
        _phase_events(dialect, writer, m, edm_state, channels)
    stats.points += len(q) - 1


def _phase_events(dialect, writer, mark, state, channels=True):
    """Comment the leg; switch condition, flushing and generator as the mark's regime asks.

    In a subprogram (``channels`` False) the comment names no channel: the call's comment does.
    """
    where = f" CH {int(mark.channel)}" if channels else ""
    writer.comment(f"PHASE {mark.phase}{where} {_degrees_text(mark.label)}")
    regime = mark.regime if mark.generator_on else ""
    if regime and regime != state.get("regime"):
        code = mark.condition_code
        if dialect.condition_select:
            writer.block(dialect.condition_select.format(code=code, digits=re.sub(r"\D", "", code)))
        else:
            writer.comment(f"REGIME {regime} CONDITION {code} SET ON THE GENERATOR")
    if regime and not state.get("on"):
        for word in (dialect.flushing_on, dialect.generator_on):
            if word:
                writer.block(word)
        state["on"] = True
    if not regime and state.get("on"):
        _generator_off(dialect, writer, state)
    state["regime"] = regime or state.get("regime")


def _generator_off(dialect, writer, state):
    if state.get("on"):
        for word in (dialect.generator_off, dialect.flushing_off):
            if word:
                writer.block(word)
        state["on"] = False


#: share of the dialect's resolution (its last decimal, per axis) within which the local positions of two
#: channel passes sharing a subprogram agree: one pass's text then says the other's points as well as its own
SAME_PASS_SHARE = 0.01
#: relative: channel passes whose point-to-point durations differ by no more share a subprogram (a feed's
#: difference of 1e-5 is 36 ms in an hour)
SAME_PASS_TIME = 1e-5


def _resolution(dialect, names):
    """(k,) the dialect's last decimal per axis, in mm or rad (its rotary axes are written in degrees)."""
    return np.array([10.0 ** -dialect.decimals(n) * (1.0 if n in LINEAR else math.pi / 180) for n in names])


def _same_pass(one, other, tolerance):
    """Whether two channel passes ((local positions, durations, marks key) each) are the same motion.

    ``tolerance`` (k,): per axis [mm or rad], for the positions.
    """
    (q1, dt1, key1), (q2, dt2, key2) = one, other
    return (key1 == key2 and q1.shape == q2.shape
            and bool(np.all(np.abs(q1 - q2) <= tolerance))
            and bool(np.all(np.abs(dt1 - dt2) <= SAME_PASS_TIME * np.maximum(np.abs(dt1), np.abs(dt2)))))


def _channel_passes(arrays):
    """Split a trajectory at its index legs: [(kind, first point, last point, channel, marks)]."""
    marks = list(arrays.phases or [])
    n = len(arrays.times) - 1
    out = []
    start, channel, current = 0, marks[0].channel if marks else 0, []
    for k, m in enumerate(marks):
        if m.phase == "index":
            end = marks[k + 1].index if k + 1 < len(marks) else n
            if m.index > start:
                out.append(("pass", start, m.index, channel, current))
            out.append(("index", m.index, end, m.channel, [m]))
            start, channel, current = end, m.channel, []
        elif m.index >= start:
            current.append(m)
    if start < n:
        out.append(("pass", start, n, channel, current))
    return out


def _shifted_marks(marks, first):
    return [replace(m, index=m.index - first) for m in marks]


def write_program(runs, name, geometry_id="", kind="plan", machine=None, dialect=None, structure=None):
    """The NC program of one or more electrodes' timed trajectories.

    Parameters
    ----------
    runs : list of ProgramRun
        In machining order; each trajectory starts and ends at rest (its clear position in a cycle).
    name : str
        Program name (a plan, set or program id).
    geometry_id, kind : str
    machine : MachineConfig, optional
        Its ``nc`` section picks dialect and structure when they are not given.
    dialect : Dialect or str, optional
    structure : str, optional
        ``subprograms`` (default where the dialect has them) or ``flat`` (DNC).

    Returns
    -------
    (str, PostStats)

    Raises
    ------
    EdmError
        INVALID_REQUEST (more electrodes than work offsets, axes differing), INTERNAL when the final check
        (:func:`check_program`) finds the program breaking its dialect's limits.
    """
    nc = getattr(machine, "nc", None) or {}
    d = dialect if dialect is not None and not isinstance(dialect, str) else load_dialect(
        dialect or nc.get("dialect") or "iso_fanuc")
    structure = structure or nc.get("structure") or "subprograms"
    if structure not in ("subprograms", "flat"):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"NC structure must be subprograms or flat, got {structure!r}")
    use_subs = structure == "subprograms" and d.subprograms
    if not runs:
        raise EdmError(ErrorCode.INVALID_REQUEST, "a program needs at least one trajectory")
    names = tuple(runs[0].arrays.axis_names)
    if len(runs) > len(d.work_offsets):
        raise EdmError(ErrorCode.INVALID_REQUEST, f"{len(runs)} electrodes, dialect {d.name} has {len(d.work_offsets)} "
                                                  f"work offsets ({', '.join(d.work_offsets)})")
    stats = PostStats(dialect=d.name, tolerance=d.merge_tolerance)
    main = _Writer(d)
    main.number += d.block_increment          # the safety line is the first block
    subs, sub_text = [], {}                   # [(number, title, writer)], canonical text -> number
    sub_passes = []                           # [(number, (local positions, durations, marks key))]
    same = SAME_PASS_SHARE * _resolution(d, names)
    total = sum(r.arrays.duration for r in runs)
    ia = names.index("A") if "A" in names else None
    for order, run in enumerate(runs):
        arrays = run.arrays
        if tuple(arrays.axis_names) != names:
            raise EdmError(ErrorCode.INVALID_REQUEST, f"electrode {run.label}: axes {arrays.axis_names} differ from "
                                                      f"{names}")
        q, t = np.asarray(arrays.positions, dtype=np.float64), np.asarray(arrays.times, dtype=np.float64)
        tool, offset = order + 1, d.work_offsets[order]
        channels = sorted({int(m.channel) for m in arrays.phases or ()})
        main.comment(f"ELECTRODE {order + 1} OF {len(runs)} {run.label}")
        main.comment(f"PLAN {run.plan_id} CHANNELS {_channel_text(channels)}")
        main.comment(f"{len(t)} POINTS {arrays.duration:.1f} S")
        for word in d.tool_change_before:
            main.block(word.format(tool=tool, work_offset=offset))
        main.block(d.tool_change.format(tool=tool, work_offset=offset))
        for word in d.tool_change_after:
            main.block(word.format(tool=tool, work_offset=offset))
        ix = names.index("X")
        main.comment("TO THE CLEAR POSITION X FIRST")
        main.block(f"{d.positioning} X{_fmt(q[0, ix], d.linear_decimals)}")
        main.block(f"{d.positioning} " + _axis_words(d, [n for n in names if n != "X"],
                                                    [v for n, v in zip(names, q[0]) if n != "X"]))
        edm_state = {}
        if not use_subs or ia is None or not any(m.phase == "index" for m in arrays.phases or ()):
            _motion(d, names, q, t, arrays.phases or [], main, stats, edm_state)
            _generator_off(d, main, edm_state)
            continue
        base_a, shift_vec = None, np.zeros(len(names))
        for what, a, b, channel, marks in _channel_passes(arrays):
            if what == "index":
                _motion(d, names, q[a:b + 1] - shift_vec, t[a:b + 1], _shifted_marks(marks, a), main, stats,
                        edm_state)
                continue
            if base_a is None:
                base_a = float(q[a, ia])
            shift = float(q[a, ia]) - base_a
            shift = round(math.degrees(shift), d.rotary_decimals)       # a shift the control takes exactly
            shift_vec = np.zeros(len(names))
            shift_vec[ia] = math.radians(shift)
            local = q[a:b + 1] - shift_vec
            local_marks = _shifted_marks(marks, a)
            motion = (local, np.diff(t[a:b + 1]), [(m.index, m.phase, m.label, m.regime, m.condition_code)
                                                   for m in local_marks])
            number = next((n for n, other in sub_passes if _same_pass(motion, other, same)), None)
            if number is None:                # a motion not seen before: its blocks are written (and merged)
                sub, sub_stats, sub_state = _Writer(d), PostStats(), {}
                _motion(d, names, local, t[a:b + 1], local_marks, sub, sub_stats, sub_state, channels=False)
                _generator_off(d, sub, sub_state)
                key = "\n".join(line.split(" ", 1)[1] if d.block_numbers and line.startswith("N") else line
                                for line in sub.lines if not line.startswith(d.comment_open))
                number = sub_text.get(key)
                if number is None:
                    number = d.subprogram_first + len(subs)
                    if number > d.program_number_max:
                        raise EdmError(ErrorCode.INVALID_REQUEST, f"more subprograms than dialect {d.name}'s "
                                                                  f"program numbers (up to {d.program_number_max})")
                    sub_text[key] = number
                    sub_passes.append((number, motion))
                    subs.append((number, f"CHANNEL PASS {run.label}", sub))
                    for name_ in ("blocks", "merged_points", "slowed_blocks", "added_seconds"):
                        setattr(stats, name_, getattr(stats, name_) + getattr(sub_stats, name_))
                    stats.max_merge_deviation = max(stats.max_merge_deviation, sub_stats.max_merge_deviation)
            stats.points += len(local) - 1
            main.block(d.channel_shift.format(a=_fmt(shift, d.rotary_decimals)))
            main.comment(f"CHANNEL {channel} PASS")
            main.block(d.subprogram_call.format(number=number))
            stats.calls += 1
        main.block(d.channel_shift_cancel)
    stats.subprograms = len(subs)
    head = ["%"] if d.percent_lines else []
    top = _Writer(d)
    for line in (d.program_start.format(number=d.program_number, name=_clean(d, name)),
                 d.comment(f"EDM_PLANNER PLAN {name}"), d.comment(f"GEOMETRY {geometry_id}"),
                 d.comment(f"{kind} {len(runs)} ELECTRODES"), d.comment(f"DIALECT {d.name}"),
                 *[d.comment(f"{n} JOINT {j} {'MM' if n in LINEAR else 'DEG'}")
                   for n, j in zip(names, runs[0].arrays.joint_names)],
                 d.comment(f"DURATION {total:.1f} S WITHOUT TOOL CHANGES"),
                 d.comment(f"POINT TOLERANCE {d.merge_tolerance:g} MM")):
        top.lines.append(line)
    top.block(d.safety_line)
    main_lines = top.lines + main.lines
    end = _Writer(d)
    end.number = main.number
    end.block(d.program_end)
    main_lines += end.lines
    sub_lines = []
    for number, title, w in subs:
        w.block(d.subprogram_return)
        sub_lines += [d.subprogram_start.format(number=number, name=_clean(d, title))] + w.lines
    lines = head + (main_lines + sub_lines if d.subprogram_placement == "after_main" else sub_lines + main_lines)
    if stats.slowed_blocks:
        note = (f"{stats.slowed_blocks} BLOCKS SLOWED TO THE F RANGE +{stats.added_seconds:.3f} S")
        lines.insert(len(head) + 7, d.comment(note))
        stats.notes.append(note.lower())
    if d.percent_lines:
        lines.append("%")
    text = "\n".join(lines) + "\n"
    stats.lines = len(lines)
    check_program(text, d, [r.arrays for r in runs])
    return text, stats


def _clean(dialect, text):
    return dialect.comment(text)[len(dialect.comment_open):-len(dialect.comment_close) or None]


def _channel_text(channels):
    if not channels:
        return "-"
    if channels == list(range(channels[0], channels[-1] + 1)) and len(channels) > 2:
        return f"{channels[0]}..{channels[-1]}"
    return ",".join(str(c) for c in channels)


# -- reading back and the final check ----------------------------------------------------------------

def _template_regex(template):
    """A regex of a one-line template with {number}/{name}/{a} fields."""
    parts = re.split(r"(\{\w+\})", template)
    out = ""
    for p in parts:
        if p == "{number}":
            out += r"(?P<number>\d+)"
        elif p == "{name}":
            out += r"(?P<name>.*)"
        elif p == "{a}":
            out += r"(?P<a>[-+]?\d+(?:\.\d*)?)"
        else:
            out += re.escape(p)
    return re.compile("^" + out + "$")


def read_program(text, dialect):
    """Read a program of :func:`write_program` back, subprograms expanded, local shifts applied.

    Returns
    -------
    dict
        ``axis_names``; ``trajectories``: per electrode (in tool order) a dict with ``tool``, ``positions``
        (n, k) joint values [mm, rad] from the clear position on, ``times`` (n,) [s] from the feeds,
        ``phases`` [(phase, channel, point index)], ``feeds`` [(code, F)] per motion block;
        ``blocks`` (every numbered block's number), ``comments``, ``lines``.

    Raises
    ------
    EdmError
        FILE_ERROR on anything the writer does not produce.
    """
    d = dialect if not isinstance(dialect, str) else load_dialect(dialect)
    raw = [line for line in text.splitlines() if line.strip() and line.strip() != "%"]
    start_re = _template_regex(d.program_start)
    sub_re = _template_regex(d.subprogram_start) if d.subprogram_start else None
    call_re = _template_regex(d.subprogram_call) if d.subprogram_call else None
    shift_re = _template_regex(d.channel_shift) if d.channel_shift else None
    programs, current = {}, None
    for number, line in enumerate(raw, 1):
        body = line.strip()
        m = start_re.match(body)
        if m and ("number" not in m.groupdict() or int(m.group("number")) == d.program_number):
            current = "main"
            programs[current] = []
            continue
        m = sub_re.match(body) if sub_re else None
        if m:
            current = int(m.group("number"))
            programs[current] = []
            continue
        if current is None:
            raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: {body!r} before the program start")
        programs[current].append((number, body))
    if "main" not in programs:
        raise EdmError(ErrorCode.FILE_ERROR, "no main program found")
    names, trajectories, comments, blocks = None, [], [], []
    state = {"mode": None, "shift": 0.0, "pos": None}

    def run(program, depth):
        nonlocal names
        if depth > 4:
            raise EdmError(ErrorCode.FILE_ERROR, "subprograms nested deeper than 4")
        for number, body in programs[program]:
            if body.startswith(d.comment_open):
                comments.append(body)
                ph, ps = _PHASE.search(body), _PASS.search(body)
                if body.startswith(d.comment_open + "ELECTRODE "):
                    state["electrode"] = body
                if ps:
                    state["channel"] = int(ps.group(1))
                if ph and trajectories:
                    tr = trajectories[-1]
                    channel = int(ph.group(2)) if ph.group(2) is not None else state.get("channel", 0)
                    tr["phases"].append((ph.group(1).lower(), channel, max(len(tr["positions"]) - 1, 0)))
                continue
            words = body
            if d.block_numbers:
                m = re.match(r"^N(\d+) (.*)$", body)
                if not m:
                    raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: block without N number: {body!r}")
                blocks.append(int(m.group(1)))
                words = m.group(2)
            if words == d.subprogram_return and program != "main":
                return
            if call_re and call_re.match(words):
                sub = int(call_re.match(words).group("number"))
                if sub not in programs:
                    raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: calls {sub}, which the file lacks")
                run(sub, depth + 1)
                continue
            if shift_re and shift_re.match(words):
                state["shift"] = math.radians(float(shift_re.match(words).group("a")))
                continue
            if words == d.channel_shift_cancel:
                state["shift"] = 0.0
                continue
            if words == d.tool_change.format(tool=len(trajectories) + 1, work_offset=""):
                if state["mode"] not in (None, d.linear_feed.code):
                    raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: tool change in {state['mode']}")
                trajectories.append({"tool": len(trajectories) + 1, "positions": [], "times": [], "phases": [],
                                     "feeds": [], "comment": state.get("electrode", "")})
                state["pos"] = None
                continue
            tokens = words.split()
            codes = [w for w in tokens if re.fullmatch(r"[GM]\d+(\.\d+)?", w)]
            for c in codes:
                if c in (d.linear_feed.code, d.rotary_feed.code):
                    state["mode"] = c
            axes = [(k, float(v)) for k, v in _WORD.findall(words) if k in "XYZABC"]
            if not axes:
                continue
            if "G01" not in tokens and d.positioning not in tokens:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: axis words without motion: {body!r}")
            if not trajectories:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: motion before the first tool change")
            tr = trajectories[-1]
            values = {k: (v if k in LINEAR else math.radians(v) + (state["shift"] if k == "A" else 0.0))
                      for k, v in axes}
            if d.positioning in tokens:
                pos = dict(state["pos"] or {})
                pos.update(values)
                state["pos"] = pos
                if tr["positions"]:
                    raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: positioning after the motion began")
                continue
            if tr["positions"] == [] and state["pos"] is not None:
                if names is None:
                    names = tuple(k for k, _ in axes)
                if set(state["pos"]) != set(names):
                    raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: axes {tuple(k for k, _ in axes)} differ "
                                                         f"from the positioning's {tuple(state['pos'])}")
                tr["positions"].append([state["pos"][k] for k in names])
                tr["times"].append(0.0)
            these = tuple(k for k, _ in axes)
            if these != names:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: axes {these} differ from {names}")
            f = [float(v) for k, v in _WORD.findall(words) if k == "F"]
            if not f or f[0] <= 0:
                raise EdmError(ErrorCode.FILE_ERROR, f"NC line {number}: G01 without a positive F")
            mode = d.rotary_feed if state["mode"] == d.rotary_feed.code else d.linear_feed
            point = [values[k] for k in names]
            length = math.dist([point[i] for i, k in enumerate(names) if k in LINEAR],
                               [tr["positions"][-1][i] for i, k in enumerate(names) if k in LINEAR])
            tr["positions"].append(point)
            tr["times"].append(tr["times"][-1] + mode.seconds(f[0], length))
            tr["feeds"].append((mode.code, f[0]))

    run("main", 0)
    for tr in trajectories:
        tr["positions"] = np.array(tr["positions"])
        tr["times"] = np.array(tr["times"])
    return dict(axis_names=names, trajectories=trajectories, comments=comments, blocks=blocks, lines=raw)


def check_program(text, dialect, reference=None):
    """The exporter's final check: the program against its dialect's limits and the timed trajectories.

    Checks every line's length, every comment's characters and length, the block numbers' range, every F
    against its mode's range, the feed mode at every tool change (read_program), and -- given the
    trajectories -- that the program's points are the trajectory's points, in order, within the rounding
    of the dialect's decimals, and that every point left out lies within the merge tolerance of its block's
    line. Raises EdmError INTERNAL naming the first violation (nothing is written then).
    """
    d = dialect if not isinstance(dialect, str) else load_dialect(dialect)

    def fail(msg):
        raise EdmError(ErrorCode.INTERNAL, f"NC program breaks dialect {d.name}: {msg}")

    comment_ok = re.compile(f"^{re.escape(d.comment_open)}[{d.comment_allowed}]*{re.escape(d.comment_close)}$")
    for i, line in enumerate(text.splitlines(), 1):
        if len(line) > d.line_max:
            fail(f"line {i} has {len(line)} characters, more than {d.line_max}")
        if line.startswith(d.comment_open):
            if not comment_ok.match(line) or len(line) - len(d.comment_open) - len(d.comment_close) > d.comment_max:
                fail(f"line {i}: comment {line!r} breaks the comment rules")
    try:
        back = read_program(text, d)
    except EdmError as exc:
        fail(exc.message)
    if d.block_numbers and back["blocks"] and not (0 < min(back["blocks"]) and max(back["blocks"]) <= d.block_max):
        fail(f"block numbers {min(back['blocks'])}..{max(back['blocks'])} outside 1..{d.block_max}")
    for tr in back["trajectories"]:
        for code, f in tr["feeds"]:
            mode = d.rotary_feed if code == d.rotary_feed.code else d.linear_feed
            if not mode.min <= f <= mode.max:
                fail(f"F{f:g} in {code} outside [{mode.min:g}, {mode.max:g}]")
    if reference is None:
        return back
    if len(reference) != len(back["trajectories"]):
        fail(f"{len(back['trajectories'])} electrodes read back, {len(reference)} written")
    names = back["axis_names"]
    res, w = 0.5 * _resolution(d, names) + 1e-9, _weights(d, names)
    for k, (arrays, tr) in enumerate(zip(reference, back["trajectories"])):
        q = np.asarray(arrays.positions, dtype=np.float64)
        got = tr["positions"]
        j = prev = 0
        for p_i, p in enumerate(got):
            while j < len(q) and np.any(np.abs(q[j] - p) > res * 2.0001):
                j += 1
            if j == len(q):
                fail(f"electrode {k + 1}: program point {p_i} {np.round(p, 5)} is no point of the trajectory "
                     f"(in order)")
            if p_i:
                a = prev
                seg = q[a:j + 1] * w
                p0, p1 = seg[0], seg[-1]
                dd = p1 - p0
                den = float(dd @ dd)
                if len(seg) > 2 and den > 0:
                    s = np.clip(((seg[1:-1] - p0) @ dd) / den, 0, 1)
                    dev = np.linalg.norm(seg[1:-1] - p0 - s[:, None] * dd, axis=1).max()
                    if dev > d.merge_tolerance + 2 * float(np.max(res * w)):
                        fail(f"electrode {k + 1}: trajectory points {a}..{j} lie {dev:.4g} mm from the block's line")
            prev = j
        if j != len(q) - 1:
            fail(f"electrode {k + 1}: the program ends at trajectory point {j} of {len(q) - 1}")
    return back


def parse_nc(text, dialect="iso_fanuc"):
    """A program of :func:`write_program` read back as one table (the form the tests and tools compare).

    Returns
    -------
    dict
        ``plan_id``, ``geometry_id`` (from the header comments, lower case), ``axis_names``, ``positions``
        (n, k) joint values [mm, rad] of every electrode in order, ``times`` (n,) [s] restarting at 0 with
        each electrode, ``phases`` [(phase, channel, index into positions)], ``tool_changes`` [(tool, index of
        its first point, the electrode's comment)], ``trajectories`` [(first, last)] per electrode.
    """
    back = read_program(text, dialect)
    header = {}
    for c in back["comments"]:
        for key in ("EDM_PLANNER PLAN ", "GEOMETRY "):
            body = c.strip("()")
            if body.startswith(key) and key.split()[-1].lower() not in header:
                header[key.split()[-1].lower()] = body[len(key):].lower()
    positions, times, phases, tools, spans = [], [], [], [], []
    offset = 0
    for tr in back["trajectories"]:
        n = len(tr["positions"])
        positions.append(tr["positions"])
        times.append(tr["times"])
        phases += [(p, c, i + offset) for p, c, i in tr["phases"]]
        tools.append((tr["tool"], offset, tr.get("comment", "")))
        spans.append((offset, offset + n - 1))
        offset += n
    return dict(plan_id=header.get("plan", ""), geometry_id=header.get("geometry", ""),
                axis_names=back["axis_names"], positions=np.vstack(positions) if positions else np.zeros((0, 0)),
                times=np.concatenate(times) if times else np.zeros(0), phases=phases, tool_changes=tools,
                trajectories=spans)
