"""Huang & Liu's per-node objective (eq. 4-6).

Objfun = a3 * Objfun1 + b3 * Objfun2, with

* Objfun1 (eq. 4), smoothness: sum over the free axes of
  w_axis * |(increment now - increment before) / (dt * range_axis)|, i.e. the
  change of each axis' step from one node to the next, normalised by the
  axis' feasible range (dt = 1: nodes are equally spaced along the reference);
* Objfun2 (eq. 5), margin: a2 (D_L - D_R)^2 + b2 S_L + c2 S_R, with D_L / D_R
  the smallest distance of the electrode's left / right surface points to the
  suction / pressure wall and S_L / S_R the standard deviations of those
  distances.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Weights:
    """Weights of Objfun (eq. 4-6); each group is normalised to sum 1 as in the paper."""

    smoothness: tuple = (1 / 3, 1 / 3, 1 / 3)     # a1, b1, c1 (z, y, C); extra axes share c1
    margin: tuple = (0.5, 0.25, 0.25)              # a2, b2, c2
    total: tuple = (0.5, 0.5)                      # a3, b3

    def __post_init__(self):
        for name, count in (("smoothness", 3), ("margin", 3), ("total", 2)):
            w = np.asarray(getattr(self, name), dtype=np.float64)
            if w.shape != (count,) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
                raise ValueError(f"weights.{name}: {count} non-negative finite numbers with a positive sum, "
                                 f"got {w}")
            object.__setattr__(self, name, tuple(float(v) for v in w / w.sum()))


def smoothness(step, previous_step, ranges, weights):
    """Objfun1 for candidate steps.

    Parameters
    ----------
    step : (n, d) float
        Candidate increments of the free axes at this node.
    previous_step : (d,) float
        Increments at the previous node.
    ranges : (d,) float
        Feasible range of each free axis (eq. 7), the normalisation.
    weights : (d,) float

    Returns
    -------
    (n,) float
    """
    step = np.atleast_2d(step)
    return (np.abs(step - previous_step) / ranges * weights).sum(axis=1)


def margin(left_distances, right_distances, weights):
    """Objfun2 from per-point wall distances.

    Parameters
    ----------
    left_distances, right_distances : (n, m) float
        Distances of the left points to the suction wall and of the right
        points to the pressure wall, per candidate.
    weights : (3,) float
        a2, b2, c2.

    Returns
    -------
    (n,) float
    """
    dl, dr = np.min(left_distances, axis=1), np.min(right_distances, axis=1)
    a2, b2, c2 = weights
    return a2 * (dl - dr) ** 2 + b2 * np.std(left_distances, axis=1) + c2 * np.std(right_distances, axis=1)
