"""Continuous check of a motion segment between two electrode poses.

Discrete checks at waypoints alone can let a path pass through an obstacle
between them. Here a segment is certified by a conservative bound: if every
electrode point moves at most ``L * |s - s'|`` between motion parameters s
and s' (L, the Lipschitz constant of the motion, from the largest lever arm
of the electrode), then between two samples a and b the clearance is at
least ``max(c_a - L (s - a), c_b - L (b - s))``, whose minimum over the
interval is ``(c_a + c_b - L (b - a)) / 2``. Where that is not above the
threshold the interval is halved and its midpoint checked, depth first from
the start, so the first contact is the first one found.

Written by hand: no library certifies rigid motions against a clearance
oracle. The oracle must return a *lower bound* of the clearance (the exact
method, or the fast method minus its error bound).
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


@dataclass(frozen=True)
class SegmentResult:
    """Outcome of a segment check (SegmentCheck.msg).

    Attributes
    ----------
    certified : bool
        The whole segment is clear above the threshold.
    first_contact : float
        Motion parameter in [0, 1] of the first sample found below the
        threshold, or of the interval that could not be certified; NaN if certified.
    penetration_bound : float
        [mm] How far below the threshold the clearance may go there
        (measured at a sample, or the bound of an uncertified interval); 0 if certified.
    evaluations : int
        Clearance evaluations made (subdivisions + 2).
    clearance_lower_bound : float
        Certified lower bound of the clearance over the segment (the smallest of its intervals') [mm].
    """

    certified: bool
    first_contact: float
    penetration_bound: float
    evaluations: int
    clearance_lower_bound: float


def screw_motion(pose0, pose1, points):
    """Rigid motion from pose0 to pose1 (linear translation, geodesic rotation) and its Lipschitz bound.

    Parameters
    ----------
    pose0, pose1 : (4, 4) float
        Electrode frame -> W.
    points : (M, 3) float
        Electrode points in its frame [mm] (for the lever arm).

    Returns
    -------
    pose_at : callable
        ``s -> (4, 4)`` pose for s in [0, 1].
    lipschitz : float
        [mm per unit s] bound on any electrode point's speed.
    """
    rots = Rotation.from_matrix(np.stack([pose0[:3, :3], pose1[:3, :3]]))
    slerp = Slerp([0.0, 1.0], rots)
    angle = (rots[1] * rots[0].inv()).magnitude()
    t0, t1 = pose0[:3, 3], pose1[:3, 3]
    lever = float(np.linalg.norm(np.asanyarray(points), axis=1).max())

    def pose_at(s):
        m = np.eye(4)
        m[:3, :3] = slerp([s]).as_matrix()[0]
        m[:3, 3] = t0 + s * (t1 - t0)
        return m

    # p(s) = R(s) q + t(s): |dp/ds| <= |omega| |q| + |t1 - t0|
    return pose_at, float(np.linalg.norm(t1 - t0) + angle * lever)


def certify_segment(clearance, pose_at, lipschitz, threshold=0.0, min_interval=1e-6, max_evaluations=4096,
                    c0=None, c1=None):
    """Certify the motion ``pose_at(s)``, s in [0, 1], against a clearance oracle.

    Parameters
    ----------
    clearance : callable
        ``(k, 4, 4) poses -> (k,)`` lower bounds of the electrode's clearance [mm].
    pose_at : callable
        ``s -> (4, 4)``.
    lipschitz : float
        Bound on electrode point speed [mm per unit s].
    threshold : float
        Clearance required [mm].
    min_interval : float
        Smallest interval subdivided; below it an interval that cannot be
        certified is reported with its bound.
    max_evaluations : int
        Budget of clearance evaluations.
    c0, c1 : float, optional
        Clearances at the ends if already known.

    Returns
    -------
    SegmentResult
    """
    evals = 0
    if c0 is None or c1 is None:
        c0, c1 = clearance(np.stack([pose_at(0.0), pose_at(1.0)]))
        evals = 2
    c0, c1 = float(c0), float(c1)
    lowest = min(c0, c1)
    if c0 < threshold:
        return SegmentResult(False, 0.0, threshold - c0, evals, c0)
    contact = (1.0, c1) if c1 < threshold else None      # earliest sample below the threshold so far
    stack = [(0.0, 1.0, c0, c1)]                         # depth first, the earliest interval on top
    while stack:
        a, b, ca, cb = stack.pop()
        if contact is not None and a >= contact[0]:
            continue                                     # after a known contact: irrelevant
        bound = 0.5 * (ca + cb - lipschitz * (b - a))
        if bound > threshold:
            lowest = min(lowest, bound)
            continue
        if b - a < min_interval or evals >= max_evaluations:
            if contact is not None and b >= contact[0] and cb < threshold:
                continue                                 # this interval ends in the known contact
            # the earliest interval that cannot be certified
            return SegmentResult(False, 0.5 * (a + b), threshold - bound, evals, min(lowest, bound))
        m = 0.5 * (a + b)
        cm = float(clearance(pose_at(m)[None])[0])
        evals += 1
        lowest = min(lowest, cm)
        if cm < threshold:
            contact = (m, cm)
            stack.append((a, m, ca, cm))                 # an earlier contact may hide in [a, m]
        else:
            stack.append((m, b, cm, cb))
            stack.append((a, m, ca, cm))
    if contact is None:
        return SegmentResult(True, float("nan"), 0.0, evals, lowest)
    return SegmentResult(False, contact[0], threshold - contact[1], evals, lowest)
