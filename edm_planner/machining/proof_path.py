"""Which samples of a machining cycle the removal proof visits: every leg that retraces none before it.

Axis values determine the pose, so a leg that runs over motion already made (the return runs the feed
backwards, the retract the approach, every "back" move of copy processing its straight move out) puts the
electrode where it has been and erodes nothing new: the removal proof (:mod:`.electrode_set`,
:mod:`.rough_finish`) and the removed volume (:mod:`edm_planner.process.report`) leave it out, and with it
the clear leg, which moves from the home point away from the blisk. About half the poses.
Plain numpy; no rclpy. Units: mm, rad.
"""

import numpy as np


def _off_line(points, p, q):
    """Largest distance of ``points`` from the straight line through p and q in axis space (mm and rad mixed:
    only ever compared with a rounding tolerance)."""
    d = q - p
    length2 = float(d @ d)
    if length2 == 0.0:
        return float(np.abs(points - p).max())
    t = (points - p) @ d / length2
    return float(np.abs(points - (p + t[:, None] * d)).max())


def retraces(a, earlier, tol=1e-9):
    """Axis samples ``a`` run over motion already made: an earlier move reversed (the return), or a straight
    move whose segment earlier straight moves on the same line cover (a move back out of copy processing)."""
    if any(len(a) == len(b) and np.array_equal(a[::-1], b) for b in earlier):
        return True
    p, q = a[0], a[-1]
    if _off_line(a, p, q) > tol:
        return False
    d = q - p
    length2 = float(d @ d)
    if length2 == 0.0:
        return any(np.abs(b - p).max(axis=1).min() <= tol for b in earlier)
    spans = []
    for b in earlier:
        if _off_line(b, p, q) <= tol:                 # a straight move on the same line
            t = (b[[0, -1]] - p) @ d / length2
            spans.append((float(t.min()), float(t.max())))
    reach = 0.0
    for lo, hi in sorted(spans):
        if lo > reach + tol:
            break
        reach = max(reach, hi)
    return reach >= 1.0 - tol


def proof_legs(cycle):
    """The cycle's legs the removal proof visits: a leg that retraces earlier ones (:func:`retraces`) is left
    out, since axis values determine the pose: its electrode positions, and what they erode, are the same; so is
    the clear leg, which moves from the home point away from the blisk (it erodes nothing)."""
    kept = []
    for leg in cycle.legs:
        if leg.phase != "clear" and not retraces(np.asarray(leg.samples, dtype=np.float64), [k.samples for k in kept]):
            kept.append(leg)
    return kept


def proof_samples(cycle):
    """(axis samples of the legs the proof visits, in order; indices i where sample i + 1 starts a leg that
    does not continue from sample i)."""
    parts, breaks, n = [], [], 0
    for leg in proof_legs(cycle):
        s = np.asarray(leg.samples, dtype=np.float64)
        if parts and np.array_equal(parts[-1][-1], s[0]):
            s = s[1:]                                 # the rest shared with the leg before
        elif parts:
            breaks.append(n - 1)
        parts.append(s)
        n += len(s)
    return np.vstack(parts), np.asarray(breaks, dtype=np.int64)
