"""The smoothing spline of the path fit: scipy's GCV estimator, computed in Demmler-Reinsch form."""

import numpy as np
import pytest
from scipy.interpolate import make_smoothing_spline

from edm_planner.planning.smoothing import SmoothingBasis


def _path(n, seed):
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.uniform(0.05, 0.15, n))             # uneven node spacing, as the search gives
    y = np.column_stack([np.sin(x / 3.0), 0.2 * x + 0.3 * np.cos(x), 1e-3 * x ** 2])
    return x, y + 0.01 * rng.standard_normal(y.shape)


@pytest.mark.parametrize("n,seed", [(5, 0), (40, 1), (211, 2), (600, 3)])
def test_weight_and_fit_equal_scipys(n, seed):
    x, y = _path(n, seed)
    basis = SmoothingBasis(x)
    for j in range(y.shape[1]):
        ref = make_smoothing_spline(x, y[:, j])                  # scipy's own GCV choice
        lam = basis.gcv_weight(y[:, j])
        # the same criterion minimised by the same bounded Brent search: weights agree to its tolerance
        assert np.abs(basis.fit(y[:, j], lam) - ref(x)).max() < 1e-5
        for level in (0.1, 0.01):                                # the planner's reduced levels
            ref_l = make_smoothing_spline(x, y[:, j], lam=lam * level)(x)
            assert np.abs(basis.fit(y[:, j], lam * level) - ref_l).max() < 1e-9


def test_zero_weight_interpolates_and_large_weight_gives_the_line():
    x, y = _path(50, 4)
    basis = SmoothingBasis(x)
    assert np.abs(basis.fit(y[:, 0], 0.0) - y[:, 0]).max() < 1e-9
    line = np.polyval(np.polyfit(x, y[:, 0], 1), x)              # the null space of the penalty
    assert np.abs(basis.fit(y[:, 0], 1e12) - line).max() < 1e-6


@pytest.mark.parametrize("x", [[0, 1, 2, 3], [0, 1, 1, 2, 3, 4], [0, 2, 1, 3, 4]])
def test_too_few_or_unordered_abscissae_are_refused(x):
    with pytest.raises(ValueError, match="at least 5 strictly increasing"):
        SmoothingBasis(np.asarray(x, dtype=float))
