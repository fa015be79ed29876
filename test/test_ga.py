"""Tests of edm_planner.planning.ga: Huang & Liu's binary-coded adaptive GA (III.C).

* coding: bit counts of eq. 8 and decoding of eq. 9 against hand-computed
  cases (the paper's example string "01001001101" included), and encode /
  decode as inverse operations on the grid;
* the Srinivas & Patnaik adaptive rates and the penalised roulette fitness;
* the whole algorithm: a 2-D quadratic with a disc constraint (optimum on
  the boundary) and the multimodal Rastrigin function, determinism by seed,
  the feasible initial population (NoFeasibleStart), warm-start seeds,
  elitism and the evaluation count.

Callbacks take a batch X (n, d), as the planner's do.
"""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from edm_planner.errors import EdmError, ErrorCode
from edm_planner.planning.ga import (
    BinaryCoding, GAOptions, GAResult, NoFeasibleStart, adaptive_rate, bit_counts, fitness,
    minimize_ga)


def always(x):
    return np.ones(len(x), dtype=bool)


def rastrigin(x):
    return 10.0 * x.shape[1] + np.sum(x ** 2 - 10.0 * np.cos(2.0 * np.pi * x), axis=1)


# the constrained quadratic: min |x - c|^2 subject to |x| <= 1, optimum c / |c|
C = np.array([2.0, 1.0])
X_STAR = C / np.linalg.norm(C)
F_STAR = (np.linalg.norm(C) - 1.0) ** 2


def quadratic(x):
    return np.sum((x - C) ** 2, axis=1)


def in_disc(x):
    return np.sum(x ** 2, axis=1) <= 1.0


class Counting:
    """Wrap the callbacks, count the rows they see, check the objective sees only feasible rows."""

    def __init__(self, objective, feasible):
        self.objective_fn, self.feasible_fn = objective, feasible
        self.feasible_rows = 0
        self.objective_rows = 0
        self.objective_calls = 0

    def feasible(self, x):
        self.feasible_rows += len(x)
        return self.feasible_fn(x)

    def objective(self, x):
        assert np.all(self.feasible_fn(x)), "objective called on an infeasible individual"
        self.objective_rows += len(x)
        self.objective_calls += 1
        return self.objective_fn(x)


# ---------------------------------------------------------------- coding (eq. 8, 9)

def test_bit_count_hand_case():
    # D = (1 - (-1)) / 0.001 = 2000; 2^10 = 1024 < 2000 <= 2^11 = 2048
    assert bit_counts([-1.0], [1.0], 0.001).tolist() == [11]


@pytest.mark.parametrize("span, precision, expected", [
    (1.024, 0.001, 10),   # D = 1024 = 2^10 exactly (computed 1023.99... in floating point)
    (1.025, 0.001, 11),   # D = 1025
    (3.0, 1.0, 2),        # D = 3
    (4.0, 1.0, 2),        # D = 4
    (1.0, 1.0, 1),        # D = 1: at least one bit
    (0.5, 1.0, 1),        # D < 1
    (0.0, 1.0, 1),        # fixed variable, U = L
    (10.24, 0.01, 10),
])
def test_bit_count_cases(span, precision, expected):
    assert bit_counts([2.0], [2.0 + span], precision).tolist() == [expected]


def test_bit_counts_per_variable_and_chromosome_length():
    coding = BinaryCoding.from_precision([-1.0, 0.0, -0.5], [1.0, 10.0, 0.5], [1e-3, 1e-2, 1e-4])
    # D = 2000, 1000, 10000 -> 11, 10, 14 bits
    assert coding.n_bits.tolist() == [11, 10, 14]
    assert coding.length == 35
    # the resolution is within the precision (no D here is a power of two)
    assert np.all(coding.step <= np.array([1e-3, 1e-2, 1e-4]))


def test_decode_hand_cases():
    coding = BinaryCoding.from_precision([-1.0], [1.0], 0.001)
    zeros, ones = np.zeros(11, np.uint8), np.ones(11, np.uint8)
    assert coding.decode(zeros)[0] == -1.0
    assert coding.decode(ones)[0] == 1.0
    # the paper's example string, MSB first: Dec = 2^9 + 2^6 + 2^3 + 2^2 + 2^0 = 589
    paper = np.array([int(c) for c in "01001001101"], np.uint8)
    assert coding.integers(paper)[0] == 589
    assert coding.decode(paper)[0] == pytest.approx(-1.0 + 589 * 2.0 / 2047.0, abs=1e-15)
    # least significant bit alone: one step; most significant alone: 1024 steps
    lsb = zeros.copy()
    lsb[-1] = 1
    msb = zeros.copy()
    msb[0] = 1
    assert coding.decode(lsb)[0] == pytest.approx(-1.0 + 2.0 / 2047.0, abs=1e-15)
    assert coding.decode(msb)[0] == pytest.approx(-1.0 + 1024 * 2.0 / 2047.0, abs=1e-15)


def test_decode_concatenated_variables():
    coding = BinaryCoding.from_precision([0.0, -3.0], [7.0, 0.0], [1.0, 1.0])   # 3 and 2 bits
    assert coding.n_bits.tolist() == [3, 2]
    bits = np.array([[1, 0, 1, 0, 1],
                     [0, 0, 0, 1, 1]], np.uint8)
    # [5, 1] -> 0 + 5 * 7/7, -3 + 1 * 3/3; [0, 3] -> 0, 0
    np.testing.assert_allclose(coding.decode(bits), [[5.0, -2.0], [0.0, 0.0]], atol=1e-15)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3))
def test_encode_is_nearest_code(u):
    coding = BinaryCoding.from_precision([-1.0, 0.0, 5.0], [1.0, 0.3, 5.5], [1e-3, 1e-2, 7e-4])
    x = coding.lower + np.asarray(u) * (coding.upper - coding.lower)
    back = coding.decode(coding.encode(x))
    assert np.all(np.abs(back - x) <= coding.step / 2 * (1 + 1e-9))


def test_encode_inverts_decode_and_clips():
    coding = BinaryCoding.from_precision([-1.0, 0.0], [1.0, 2.0], [1e-3, 1e-2])
    bits = np.random.default_rng(1).integers(0, 2, size=(50, coding.length), dtype=np.uint8)
    np.testing.assert_array_equal(coding.encode(coding.decode(bits)), bits)
    np.testing.assert_allclose(coding.decode(coding.encode([-5.0, 9.0])), [-1.0, 2.0])


def test_coding_rejects_bad_boxes():
    with pytest.raises(ValueError):
        bit_counts([1.0], [0.0], 0.1)
    with pytest.raises(ValueError):
        bit_counts([0.0], [1.0], 0.0)
    with pytest.raises(ValueError):
        bit_counts([0.0], [1.0], 1e-20)    # more than 52 bits
    with pytest.raises(ValueError):
        bit_counts([0.0, 0.0], [1.0], 0.1)


# ---------------------------------------------------------------- rates and fitness

def test_adaptive_rate_hand_cases():
    # f_max = 1, f_avg = 0.5: linear from k_high at the average to 0 at the best
    assert adaptive_rate(0.75, 1.0, 0.5, 1.0, 0.9) == pytest.approx(0.5)
    assert adaptive_rate(0.5, 1.0, 0.5, 1.0, 0.9) == pytest.approx(1.0)
    assert adaptive_rate(1.0, 1.0, 0.5, 1.0, 0.9) == 0.0
    assert adaptive_rate(0.2, 1.0, 0.5, 1.0, 0.9) == pytest.approx(0.9)
    # converged population: the value at the average, k_high
    np.testing.assert_allclose(adaptive_rate(np.full(4, 0.3), 0.3, 0.3, 0.5, 0.5), 0.5)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 10.0), min_size=2, max_size=30),
       st.floats(0.0, 1.0), st.floats(0.0, 1.0))
@example([0.23857011978310366] * 3, 0.0, 1.0)          # their mean rounds above them: a converged population
def test_adaptive_rate_within_bounds(values, k_high, k_low):
    f = np.asarray(values)
    f_max, f_avg = f.max(), f.mean()
    rate = adaptive_rate(f, f_max, f_avg, k_high, k_low)
    assert rate.shape == f.shape
    assert np.all(rate >= 0.0) and np.all(rate <= max(k_high, k_low))
    if f_max <= f_avg:
        # converged: every fitness equal, whatever the rounding of the mean says (three equal values can
        # average a hair above themselves): all get k_high, the formula's value at the average
        np.testing.assert_array_equal(rate, k_high)
        return
    below = f < f_avg
    np.testing.assert_array_equal(rate[below], k_low)
    if f_max > f_avg:
        assert np.all(rate[f == f_max] == 0.0)
        # at or above the average: non-increasing in fitness
        order = np.argsort(f[~below])
        assert np.all(np.diff(rate[~below][order]) <= 1e-12)


def test_fitness_penalises_infeasible_and_reverses_the_objective():
    fun = np.array([3.0, 1.0, 2.0, np.nan, -7.0])
    ok = np.array([True, True, True, False, False])
    fit = fitness(fun, ok, epsilon=1e-3, infeasible=1e-6)
    # worst feasible (3) gets epsilon, best (1) gets 1 + epsilon, the infeasible ones 1e-6
    np.testing.assert_allclose(fit, [1e-3, 1.0 + 1e-3, 0.5 + 1e-3, 1e-6, 1e-6])
    assert fit[ok].min() > fit[~ok].max()
    # equal feasible values: equal chances
    np.testing.assert_allclose(fitness(np.full(3, 4.0), np.ones(3, bool)), 1e-3)
    # none feasible: uniform
    np.testing.assert_allclose(fitness(np.zeros(3), np.zeros(3, bool)), 1e-6)


@pytest.mark.parametrize("kwargs", [
    dict(population_size=1), dict(generations=-1), dict(crossover_k1=1.5), dict(mutation_k4=-0.1),
    dict(max_init_attempts=-1), dict(fitness_epsilon=0.0), dict(infeasible_fitness=0.1),
])
def test_options_validated(kwargs):
    with pytest.raises(ValueError):
        GAOptions(**kwargs)


# ---------------------------------------------------------------- the algorithm

def test_constrained_quadratic_reaches_boundary_optimum():
    precision = 0.01
    options = GAOptions(population_size=100, generations=200, seed=0)
    res = minimize_ga(quadratic, in_disc, [-2.0, -2.0], [2.0, 2.0], precision, options)
    assert isinstance(res, GAResult)
    assert res.feasible and in_disc(res.x[None])[0]
    assert res.n_bits.tolist() == [9, 9]          # D = 400
    assert np.linalg.norm(res.x - X_STAR) <= 5 * precision
    # objective within what a few grid steps inside the boundary cost (|grad f| = 2(|c| - 1))
    assert F_STAR <= res.fun <= F_STAR + 2 * (np.linalg.norm(C) - 1) * 3 * precision
    assert res.fun == pytest.approx(quadratic(res.x[None])[0])


def test_rastrigin_global_minimum():
    options = GAOptions(population_size=100, generations=500, seed=0)
    res = minimize_ga(rastrigin, always, [-5.12] * 2, [5.12] * 2, 1e-3, options)
    # local minima nearest the global one have f ~ 1
    assert res.fun < 0.05
    assert np.max(np.abs(res.x)) < 0.02
    # not one lucky seed: most seeds get there
    hits = sum(minimize_ga(rastrigin, always, [-5.12] * 2, [5.12] * 2, 1e-3,
                           GAOptions(population_size=100, generations=500, seed=s)).fun < 0.05
               for s in range(1, 9))
    assert hits >= 6


def test_deterministic_by_seed():
    def run(seed):
        return minimize_ga(rastrigin, in_disc, [-2.0] * 2, [2.0] * 2, 1e-3,
                           GAOptions(generations=30, seed=seed))
    a, b = run(3), run(3)
    np.testing.assert_array_equal(a.x, b.x)
    assert a.fun == b.fun and a.evaluations == b.evaluations
    np.testing.assert_array_equal(a.history, b.history)
    others = [run(s) for s in (4, 5, 6)]
    assert any(not np.array_equal(o.history, a.history) for o in others)


def test_no_feasible_start_when_nothing_is_feasible():
    options = GAOptions(population_size=10, max_init_attempts=95)
    with pytest.raises(NoFeasibleStart) as info:
        minimize_ga(quadratic, lambda x: np.zeros(len(x), bool), [-1.0] * 2, [1.0] * 2, 0.01, options)
    err = info.value
    assert isinstance(err, EdmError) and err.code == ErrorCode.INFEASIBLE
    assert (err.found, err.required, err.attempts, err.evaluations) == (0, 10, 95, 95)
    assert err.points.shape == (0, 2)
    assert "0 of 10" in str(err)


def test_no_feasible_start_reports_the_few_found():
    # feasible region: x0 > 1.9 in [-2, 2], about 2.5 % of the box
    def corner(x):
        return x[:, 0] > 1.9
    options = GAOptions(population_size=40, max_init_attempts=200, seed=2)
    with pytest.raises(NoFeasibleStart) as info:
        minimize_ga(quadratic, corner, [-2.0] * 2, [2.0] * 2, 0.01, options)
    err = info.value
    assert 0 < err.found < 40 and err.attempts == 200
    assert err.points.shape == (err.found, 2) and np.all(corner(err.points))
    # with enough attempts the same problem starts
    res = minimize_ga(quadratic, corner, [-2.0] * 2, [2.0] * 2, 0.01,
                      GAOptions(population_size=40, max_init_attempts=10000, generations=5, seed=2))
    assert corner(res.x[None])[0]


def test_seed_at_the_optimum_is_kept_by_elitism():
    coding = BinaryCoding.from_precision([-2.0] * 2, [2.0] * 2, 1e-3)
    target = coding.decode(coding.encode([0.3172, -1.4411]))    # a grid point

    def bowl(x):
        return np.sum((x - target) ** 2, axis=1)
    res = minimize_ga(bowl, always, [-2.0] * 2, [2.0] * 2, 1e-3, GAOptions(generations=20), seeds=[target])
    np.testing.assert_array_equal(res.x, target)
    assert res.fun == 0.0
    np.testing.assert_array_equal(res.history, 0.0)


def test_seed_is_used_and_encoded_to_nearest_code():
    # a needle: the objective is lowest at one grid point the search cannot find by chance
    coding = BinaryCoding.from_precision([-2.0] * 2, [2.0] * 2, 1e-3)
    seed = np.array([1.23456, -0.65432])
    needle = coding.decode(coding.encode(seed))

    def objective(x):
        at = np.all(x == needle, axis=1)
        return np.where(at, -1.0, np.sum(x ** 2, axis=1))
    options = GAOptions(generations=20, seed=1)
    without = minimize_ga(objective, always, [-2.0] * 2, [2.0] * 2, 1e-3, options)
    assert without.fun >= 0.0
    res = minimize_ga(objective, always, [-2.0] * 2, [2.0] * 2, 1e-3, options, seeds=[seed])
    np.testing.assert_array_equal(res.x, needle)
    assert res.fun == -1.0
    assert np.all(np.abs(res.x - seed) <= coding.step / 2)


def test_infeasible_seed_is_dropped():
    counter = Counting(quadratic, in_disc)
    res = minimize_ga(counter.objective, counter.feasible, [-2.0] * 2, [2.0] * 2, 0.01,
                      GAOptions(generations=3), seeds=[[1.9, 1.9], [0.1, 0.1]])
    assert res.evaluations == counter.feasible_rows
    assert in_disc(res.x[None])[0]


def test_elitism_monotone_history_and_switch_off():
    box = ([-5.12] * 2, [5.12] * 2)
    on = minimize_ga(rastrigin, always, *box, 1e-3, GAOptions(generations=60, seed=4))
    assert on.history.shape == (61,)
    assert np.all(np.diff(on.history) <= 0.0)
    assert on.fun == on.history[-1]
    off = minimize_ga(rastrigin, always, *box, 1e-3, GAOptions(generations=60, seed=4, elitism=False))
    # without elitism the population may lose its best; the result is the best seen
    assert off.fun == np.nanmin(off.history)
    assert np.any(np.diff(off.history) > 0.0)


def test_evaluations_counted():
    counter = Counting(rastrigin, always)
    options = GAOptions(population_size=12, generations=7)
    res = minimize_ga(counter.objective, counter.feasible, [-1.0] * 3, [1.0] * 3, 0.01, options)
    assert res.evaluations == counter.feasible_rows == 12 * 8
    assert counter.objective_calls == 8 and counter.objective_rows == 12 * 8
    assert res.generations == 7 and res.history.shape == (8,)

    # with infeasible individuals: every individual is evaluated once, the
    # objective sees only the feasible ones
    counter = Counting(quadratic, in_disc)
    res = minimize_ga(counter.objective, counter.feasible, [-2.0] * 2, [2.0] * 2, 0.01,
                      GAOptions(population_size=20, generations=10), seeds=[[0.5, 0.5]])
    assert res.evaluations == counter.feasible_rows
    assert counter.objective_rows < counter.feasible_rows
    assert counter.feasible_rows >= 20 * 11 + 1


def test_non_finite_objective_is_infeasible():
    def objective(x):
        return np.where(x[:, 0] < 0.0, np.nan, np.sum((x + 1.0) ** 2, axis=1))
    res = minimize_ga(objective, always, [-2.0] * 2, [2.0] * 2, 0.01,
                      GAOptions(generations=40, max_init_attempts=4000))
    assert res.x[0] >= 0.0 and np.isfinite(res.fun)


def test_callback_shapes_checked():
    with pytest.raises(ValueError, match="feasible"):
        minimize_ga(quadratic, lambda x: np.ones((len(x), 1), bool), [-1.0] * 2, [1.0] * 2, 0.1)
    with pytest.raises(ValueError, match="objective"):
        minimize_ga(lambda x: np.zeros((len(x), 2)), always, [-1.0] * 2, [1.0] * 2, 0.1)
    with pytest.raises(ValueError, match="seeds"):
        minimize_ga(quadratic, always, [-1.0] * 2, [1.0] * 2, 0.1, seeds=[[0.0, 0.0, 0.0]])
