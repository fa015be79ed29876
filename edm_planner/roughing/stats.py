"""Error statistics of tool positions against the target surface (Chen & Dong eq. 14-15).

The error of one discretised point of the tool bottom is its signed distance
to the target surface (the shroud's inner surface offset by the allowance),
``z_i - z_target`` in the paper's notation: positive where the tool stops
short of the target (material left beyond the allowance), negative where it
cuts into the allowance. Units: mm.
"""

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class ErrorStats:
    """Eq. 14-15 and the error range over a set of tool-bottom points.

    Attributes
    ----------
    count : int
        N, the number of points.
    mean_abs : float
        mu = (1/N) sum |e_i| (eq. 14) [mm].
    std_abs : float
        sigma = sqrt((1/N) sum (|e_i| - mu)^2) (eq. 15, population form) [mm].
    min, max : float
        Smallest and largest signed error [mm] (the paper's "error range -5.28 mm to 6.87 mm").
    max_abs : float
        Largest |e_i| [mm].
    """

    count: int
    mean_abs: float
    std_abs: float
    min: float
    max: float
    max_abs: float

    @property
    def range(self):
        """max - min [mm]."""
        return self.max - self.min

    def to_dict(self):
        d = asdict(self)
        d["range"] = self.range
        return d


def error_stats(errors):
    """ErrorStats of signed errors.

    Parameters
    ----------
    errors : array_like
        Signed errors [mm], any shape (flattened); at least one value.

    Returns
    -------
    ErrorStats
    """
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("error_stats: no errors given")
    a = np.abs(e)
    mu = float(a.mean())
    return ErrorStats(count=int(e.size), mean_abs=mu, std_abs=float(np.sqrt(np.mean((a - mu) ** 2))),
                      min=float(e.min()), max=float(e.max()), max_abs=float(a.max()))


def reduction_percent(before, after):
    """Relative reduction 100 (before - after) / before [%] (the paper's 57.79 % for the mean absolute error)."""
    before, after = float(before), float(after)
    if before == 0.0:
        return 0.0
    return 100.0 * (before - after) / before
