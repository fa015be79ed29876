"""Huang & Liu's binary-coded adaptive genetic algorithm (section III.C), as written.

Huang solves, at every path node, ``min Objfun(X)`` subject to the
non-interference constraints (eq. 6), ``X = [m_y, m_z, r_c, h]`` in the box of
eq. 7, with a genetic algorithm in six steps. This module implements them
for any objective and feasibility test so that results can be compared with
the paper's method:

* Coding, eq. 8: each variable ``x_j in [L_j, U_j]`` gets ``N_j`` bits, with
  ``D = (U - L) / precision``. The printed ``2^m < D < 2^N`` is read as
  "N is the smallest integer with ``2^N >= D``" (m = N - 1); see
  :func:`bit_counts`. The chromosome is the concatenation of the variables'
  bit strings, each written most significant bit first (like the paper's
  example "01001001101").
* Decoding, eq. 9: ``S = L + Dec * (U - L) / (2^N - 1)``. The printed
  ``Dec = sum_0^{N-1} 2^i`` omits the bits; the integer of the string is
  ``Dec = sum_i b_i 2^i`` (b_i the bit of weight 2^i), which is used here.
  All zeros decode to L, all ones to U.
* Initial population: random bit strings, keeping only feasible ones ("this
  procedure eliminates the individuals that produce interference until the
  initial population of individuals meets the required number"). If
  :attr:`GAOptions.max_init_attempts` random draws do not give enough,
  :class:`NoFeasibleStart` is raised. Optional seed points (warm start) are
  encoded to their nearest code and, if feasible, included first.
* Competition: roulette (fitness-proportional) selection. The problem is a
  minimisation with infeasible individuals penalised; see :func:`fitness`.
* Crossover: single-point crossover of consecutive selected pairs, with the
  adaptive probability of Srinivas & Patnaik (1994); see :func:`adaptive_rate`.
* Mutation: bit flips with the adaptive per-bit probability of the same rule.

What the paper does not say, and is chosen here (all documented at the
place of use): the adaptive-rate formula (it only says "adaptive"), the
penalty of infeasible individuals after the initial population, elitism
(on by default, switchable off), the stopping rule (a fixed number of
generations) and which individual is returned (the best feasible one
evaluated).

Determinism: every random draw comes from one ``numpy.random.Generator``
seeded with :attr:`GAOptions.seed`, and the callbacks are called in a fixed
order, so equal inputs and seed give equal results.
"""

import logging
from dataclasses import dataclass, field

import numpy as np

from ..errors import EdmError, ErrorCode

_LOG = logging.getLogger(__name__)

#: largest bit count per variable: decoding in float64 is exact up to 2^52
MAX_BITS = 52


class NoFeasibleStart(EdmError):
    """Fewer feasible individuals than the population size after the allowed random draws.

    Parameters
    ----------
    found : int
        Feasible individuals found (feasible seeds included).
    required : int
        Population size asked for.
    attempts : int
        Random individuals drawn (seeds not counted).
    evaluations : int
        Individuals passed to the feasibility test (seeds included).
    points : (found, d) float
        The feasible individuals found, decoded.

    Attributes
    ----------
    found, required, attempts, evaluations, points
        As the parameters. ``code`` is :attr:`ErrorCode.INFEASIBLE`.
    """

    def __init__(self, found, required, attempts, evaluations, points):
        self.found = int(found)
        self.required = int(required)
        self.attempts = int(attempts)
        self.evaluations = int(evaluations)
        self.points = np.asarray(points, dtype=np.float64)
        super().__init__(
            ErrorCode.INFEASIBLE,
            f"genetic algorithm: only {self.found} of {self.required} initial individuals "
            f"feasible after {self.attempts} random draws")


@dataclass(frozen=True)
class GAOptions:
    """Settings of :func:`minimize_ga`.

    The adaptive rates follow Srinivas & Patnaik (1994) with fitness to be
    maximised (:func:`adaptive_rate`); their recommended constants are
    ``k1 = k3 = 1.0`` and ``k2 = k4 = 0.5``, the defaults here. The rates
    are bounded by ``0 <= pc <= max(k1, k3)`` and ``0 <= pm <= max(k2, k4)``.

    Attributes
    ----------
    population_size : int
        Individuals per generation (>= 2).
    generations : int
        Generations after the initial population (>= 0); the only stopping rule.
    crossover_k1 : float
        pc at the average fitness, falling linearly to 0 at the best (in [0, 1]).
    crossover_k3 : float
        pc below the average fitness (in [0, 1]).
    mutation_k2 : float
        Per-bit pm at the average fitness, falling linearly to 0 at the best (in [0, 1]).
    mutation_k4 : float
        Per-bit pm below the average fitness (in [0, 1]).
    elitism : bool
        Carry the best individual found into every new generation, replacing
        the worst one.
    max_init_attempts : int
        Random individuals drawn at most for the initial population.
    fitness_epsilon : float
        Fitness of the worst feasible individual, relative to the spread of
        the feasible objective values (> 0); see :func:`fitness`.
    infeasible_fitness : float
        Fitness of an infeasible individual, same scale (0 < it <= fitness_epsilon).
    seed : int or None
        Seed of the random generator; None draws fresh entropy (not reproducible).
    """

    population_size: int = 40
    generations: int = 60
    crossover_k1: float = 1.0
    crossover_k3: float = 1.0
    mutation_k2: float = 0.5
    mutation_k4: float = 0.5
    # The paper does not mention elitism. It is on by default (so that the
    # adaptive rule's protection of the best individual, pc = pm = 0, is not
    # undone by the roulette) and can be switched off to run the steps
    # exactly as listed.
    elitism: bool = True
    max_init_attempts: int = 4000
    fitness_epsilon: float = 1e-3
    infeasible_fitness: float = 1e-6
    seed: int | None = 0

    def __post_init__(self):
        if int(self.population_size) != self.population_size or self.population_size < 2:
            raise ValueError(f"population_size must be an integer >= 2, got {self.population_size}")
        if int(self.generations) != self.generations or self.generations < 0:
            raise ValueError(f"generations must be an integer >= 0, got {self.generations}")
        for name in ("crossover_k1", "crossover_k3", "mutation_k2", "mutation_k4"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {value}")
        if int(self.max_init_attempts) != self.max_init_attempts or self.max_init_attempts < 0:
            raise ValueError(f"max_init_attempts must be an integer >= 0, got {self.max_init_attempts}")
        if not self.fitness_epsilon > 0.0:
            raise ValueError(f"fitness_epsilon must be > 0, got {self.fitness_epsilon}")
        if not 0.0 < self.infeasible_fitness <= self.fitness_epsilon:
            raise ValueError(
                f"infeasible_fitness must lie in (0, fitness_epsilon={self.fitness_epsilon}], "
                f"got {self.infeasible_fitness}")


@dataclass(frozen=True)
class GAResult:
    """Outcome of :func:`minimize_ga`.

    Attributes
    ----------
    x : (d,) float
        Best feasible individual evaluated, decoded (eq. 9).
    fun : float
        Its objective value.
    feasible : bool
        Whether x is feasible (always True: without a feasible start
        :class:`NoFeasibleStart` is raised; kept for a uniform interface).
    evaluations : int
        Individuals passed to the feasibility test (every evaluated
        individual once; the objective sees only the feasible ones).
    generations : int
        Generations run after the initial population.
    history : (generations + 1,) float
        Best objective value of the population in each generation, the
        initial population first; NaN where no individual was feasible.
    n_bits : (d,) int
        Bits per variable (eq. 8).
    """

    x: np.ndarray
    fun: float
    feasible: bool
    evaluations: int
    generations: int
    history: np.ndarray
    n_bits: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


# ---------------------------------------------------------------- coding (eq. 8, 9)

def bit_counts(lower, upper, precision):
    """Eq. 8: bits per variable, the smallest N with ``2^N >= D = (U - L) / precision``.

    The decoded step ``(U - L) / (2^N - 1)`` is then at most ``precision``
    except when D is a power of two, where it exceeds it by the factor
    ``2^N / (2^N - 1)``, as the paper's rule implies. At least one bit is
    used (a variable with U = L decodes to L either way).

    Parameters
    ----------
    lower, upper : (d,) float
        Bounds L, U of each variable (U >= L, finite).
    precision : (d,) float or float
        Precision of each variable (> 0).

    Returns
    -------
    (d,) int64
        N for each variable.
    """
    lower, upper, precision = _box(lower, upper, precision)
    ratio = (upper - lower) / precision
    n_bits = np.empty(ratio.shape, dtype=np.int64)
    for j, d in enumerate(ratio):
        # D computed in floating point, e.g. 2 / 0.001, may miss an integer
        # by an ulp; snap it so that hand-computed cases come out as expected
        nearest = np.rint(d)
        if abs(d - nearest) <= 1e-9 * max(1.0, d):
            d = nearest
        n = 1
        while 2.0 ** n < d:
            n += 1
        if n > MAX_BITS:
            raise ValueError(
                f"variable {j}: (U - L) / precision = {d:.6g} needs {n} bits, more than {MAX_BITS}")
        n_bits[j] = n
    return n_bits


@dataclass(frozen=True, eq=False)
class BinaryCoding:
    """The binary coding of a box (eq. 8, 9): concatenated bit strings, MSB first.

    Attributes
    ----------
    lower, upper : (d,) float
        Bounds of the variables.
    n_bits : (d,) int
        Bits per variable.
    """

    lower: np.ndarray
    upper: np.ndarray
    n_bits: np.ndarray

    @classmethod
    def from_precision(cls, lower, upper, precision):
        """The coding with the bit counts of eq. 8.

        Parameters
        ----------
        lower, upper : (d,) float
        precision : (d,) float or float

        Returns
        -------
        BinaryCoding
        """
        lower, upper, precision = _box(lower, upper, precision)
        return cls(lower, upper, bit_counts(lower, upper, precision))

    @property
    def length(self):
        """Total chromosome length B = sum(n_bits)."""
        return int(self.n_bits.sum())

    @property
    def step(self):
        """(d,) float: decoded resolution ``(U - L) / (2^N - 1)``."""
        return (self.upper - self.lower) / (2.0 ** self.n_bits - 1.0)

    def _weights(self):
        # (B, d): weight 2^(N_j - 1 - k) of bit k of variable j's segment
        weights = np.zeros((self.length, self.n_bits.size), dtype=np.int64)
        start = 0
        for j, n in enumerate(self.n_bits):
            weights[start:start + n, j] = 2 ** np.arange(n - 1, -1, -1, dtype=np.int64)
            start += n
        return weights

    def integers(self, bits):
        """Dec of each variable: ``sum_i b_i 2^i`` over its bit string.

        Parameters
        ----------
        bits : (n, B) or (B,) {0, 1}

        Returns
        -------
        (n, d) int64 (or (d,) for one chromosome)
        """
        bits = np.asarray(bits)
        return bits.astype(np.int64) @ self._weights()

    def decode(self, bits):
        """Eq. 9: ``S = L + Dec * (U - L) / (2^N - 1)``.

        Parameters
        ----------
        bits : (n, B) or (B,) {0, 1}

        Returns
        -------
        (n, d) float (or (d,) for one chromosome)
        """
        dec = self.integers(bits).astype(np.float64)
        # eq. 9; the clip only removes rounding (an ulp beyond U at all ones)
        return np.clip(self.lower + dec * self.step, self.lower, self.upper)

    def encode(self, x):
        """The nearest code of each point (inverse of :meth:`decode` on the grid).

        Points outside the box are clipped to it.

        Parameters
        ----------
        x : (n, d) or (d,) float

        Returns
        -------
        (n, B) uint8 (or (B,) for one point)
        """
        x = np.asarray(x, dtype=np.float64)
        single = x.ndim == 1
        x = np.atleast_2d(x)
        if x.shape[1] != self.n_bits.size:
            raise ValueError(f"points must have {self.n_bits.size} columns, got shape {x.shape}")
        top = 2.0 ** self.n_bits - 1.0
        span = self.upper - self.lower
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.where(span > 0, (x - self.lower) / np.where(span > 0, span, 1.0), 0.0)
        dec = np.clip(np.rint(u * top), 0.0, top).astype(np.int64)
        bits = np.empty((x.shape[0], self.length), dtype=np.uint8)
        start = 0
        for j, n in enumerate(self.n_bits):
            shifts = np.arange(n - 1, -1, -1, dtype=np.int64)
            bits[:, start:start + n] = (dec[:, j, None] >> shifts) & 1
            start += n
        return bits[0] if single else bits


def _box(lower, upper, precision):
    lower = np.atleast_1d(np.asarray(lower, dtype=np.float64))
    upper = np.atleast_1d(np.asarray(upper, dtype=np.float64))
    if lower.ndim != 1 or lower.shape != upper.shape or lower.size == 0:
        raise ValueError(
            f"lower and upper must be (d,) arrays of one shape, got {lower.shape}, {upper.shape}")
    precision = np.broadcast_to(np.asarray(precision, dtype=np.float64), lower.shape).copy()
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise ValueError("lower and upper must be finite")
    if np.any(upper < lower):
        raise ValueError(f"upper must be >= lower, got lower={lower}, upper={upper}")
    if not np.all(precision > 0) or not np.all(np.isfinite(precision)):
        raise ValueError(f"precision must be finite and > 0, got {precision}")
    return lower, upper, precision


# ---------------------------------------------------------------- fitness and rates

def fitness(fun, feasible, epsilon=1e-3, infeasible=1e-6):
    """Roulette fitness of a minimisation with infeasible individuals penalised.

    For a feasible individual ``F = (f_worst - f) / s + epsilon``, with
    f_worst the largest feasible objective value of the population and
    ``s = f_worst - f_best`` (1 if all feasible values are equal); for an
    infeasible one ``F = infeasible``. This is ``(f_worst - f) + epsilon s``
    scaled by ``1 / s``: the roulette (proportional) and the adaptive rates
    (ratios of fitness differences) do not change under that scaling, and
    the scaled form keeps epsilon meaningful for any objective's units. The
    worst feasible individual keeps a small chance ``epsilon`` to be
    selected, an infeasible one a smaller one, so infeasible individuals
    die out without being removed outright (the paper removes them only
    from the initial population and says nothing for later generations).

    Parameters
    ----------
    fun : (n,) float
        Objective values (ignored where infeasible).
    feasible : (n,) bool
    epsilon : float
        Fitness of the worst feasible individual (> 0).
    infeasible : float
        Fitness of an infeasible individual (0 < infeasible <= epsilon).

    Returns
    -------
    (n,) float
        Fitness in ``[infeasible, 1 + epsilon]``, to be maximised.
    """
    fun = np.asarray(fun, dtype=np.float64)
    feasible = np.asarray(feasible, dtype=bool)
    out = np.full(fun.shape, float(infeasible))
    if np.any(feasible):
        f = fun[feasible]
        worst, best = f.max(), f.min()
        spread = worst - best if worst > best else 1.0
        out[feasible] = (worst - f) / spread + epsilon
    return out


def adaptive_rate(f, f_max, f_avg, k_high, k_low):
    """Adaptive crossover or mutation probability of Srinivas & Patnaik (1994).

    M. Srinivas, L. M. Patnaik, "Adaptive probabilities of crossover and
    mutation in genetic algorithms", IEEE Trans. Systems, Man, and
    Cybernetics 24(4):656-667, 1994, eq. (for fitness to be maximised)::

        pc = k1 (f_max - f') / (f_max - f_avg)   if f' >= f_avg,   else k3
        pm = k2 (f_max - f)  / (f_max - f_avg)   if f  >= f_avg,   else k4

    with f' the larger fitness of the two parents and f the fitness of the
    individual to be mutated. Called with ``(k_high, k_low) = (k1, k3)`` for
    pc and ``(k2, k4)`` for pm. Good individuals are disturbed little (the
    best not at all), poor ones a lot.

    When the population has converged (``f_max <= f_avg``, all fitnesses
    equal) the formula is 0/0; every individual is then at the average and
    gets ``k_high``, the formula's value at ``f = f_avg``, which keeps the
    population from freezing.

    Parameters
    ----------
    f : (n,) float or float
        Fitness f' (crossover) or f (mutation).
    f_max, f_avg : float
        Largest and mean fitness of the population.
    k_high : float
        Rate at the average fitness (k1 or k2).
    k_low : float
        Rate below the average fitness (k3 or k4).

    Returns
    -------
    (n,) float or float
        Probabilities in ``[0, max(k_high, k_low)]``; exactly 0 at f_max
        (unless converged), ``k_low`` below the average.
    """
    f = np.asarray(f, dtype=np.float64)
    denominator = f_max - f_avg
    if not denominator > 0.0:
        rate = np.full(f.shape, float(k_high))
    else:
        above = k_high * np.clip((f_max - f) / denominator, 0.0, 1.0)
        rate = np.where(f >= f_avg, above, k_low)
    return rate if rate.ndim else float(rate)


# ---------------------------------------------------------------- the algorithm

class _Evaluator:
    """Calls the batch callbacks and counts the individuals evaluated."""

    def __init__(self, objective, feasible):
        self._objective = objective
        self._feasible = feasible
        self.count = 0
        self._warned_nan = False

    def __call__(self, x):
        """Return (feasible (n,) bool, fun (n,) float, NaN where infeasible)."""
        n = x.shape[0]
        ok = np.asarray(self._feasible(x))
        if ok.shape != (n,):
            raise ValueError(f"feasible(X) must return shape ({n},), got {ok.shape}")
        ok = ok.astype(bool)
        self.count += n
        fun = np.full(n, np.nan)
        if np.any(ok):
            values = np.asarray(self._objective(x[ok]), dtype=np.float64)
            if values.shape != (int(ok.sum()),):
                raise ValueError(
                    f"objective(X) must return shape ({int(ok.sum())},), got {values.shape}")
            fun[ok] = values
            bad = ok & ~np.isfinite(fun)
            if np.any(bad):
                if not self._warned_nan:
                    _LOG.warning("objective not finite at %d feasible individuals; "
                                 "treated as infeasible", int(bad.sum()))
                    self._warned_nan = True
                ok = ok & ~bad
                fun[bad] = np.nan
        return ok, fun


def _initial_population(coding, evaluate, rng, options, seeds):
    """Feasible seeds first, then feasible random individuals (paper's elimination)."""
    size = options.population_size
    parts_bits, parts_fun = [], []
    found = 0
    if seeds is not None:
        seeds = np.atleast_2d(np.asarray(seeds, dtype=np.float64))
        if seeds.size:
            if seeds.ndim != 2 or seeds.shape[1] != coding.n_bits.size:
                raise ValueError(f"seeds must be (k, {coding.n_bits.size}), got shape {seeds.shape}")
            outside = np.any((seeds < coding.lower) | (seeds > coding.upper), axis=1)
            if np.any(outside):
                _LOG.warning("%d seed point(s) outside the box, clipped to it", int(outside.sum()))
            bits = coding.encode(seeds[:size])
            ok, fun = evaluate(coding.decode(bits))
            if not np.all(ok):
                _LOG.debug("%d of %d seed point(s) infeasible, dropped", int((~ok).sum()), ok.size)
            parts_bits.append(bits[ok])
            parts_fun.append(fun[ok])
            found += int(ok.sum())
    attempts = 0
    while found < size and attempts < options.max_init_attempts:
        batch = min(size, options.max_init_attempts - attempts)
        bits = rng.integers(0, 2, size=(batch, coding.length), dtype=np.uint8)
        attempts += batch
        ok, fun = evaluate(coding.decode(bits))
        keep = np.flatnonzero(ok)[:size - found]
        parts_bits.append(bits[keep])
        parts_fun.append(fun[keep])
        found += keep.size
    bits = np.concatenate(parts_bits) if parts_bits else np.zeros((0, coding.length), np.uint8)
    fun = np.concatenate(parts_fun) if parts_fun else np.zeros(0)
    if found < size:
        raise NoFeasibleStart(found, size, attempts, evaluate.count, coding.decode(bits))
    _LOG.debug("initial population: %d feasible after %d random draws", size, attempts)
    return bits, np.ones(size, dtype=bool), fun


def _offspring(bits, fit, rng, options):
    """Roulette selection, single-point crossover and bit-flip mutation with adaptive rates."""
    size, length = bits.shape
    f_max, f_avg = fit.max(), fit.mean()
    # competition: fitness-proportional (roulette) selection
    parents = rng.choice(size, size=size, replace=True, p=fit / fit.sum())
    children = bits[parents].copy()
    parent_fit = fit[parents]
    # crossover of consecutive pairs; an odd last one is copied unchanged
    n_pairs = size // 2
    first = 2 * np.arange(n_pairs)
    pc = adaptive_rate(np.maximum(parent_fit[first], parent_fit[first + 1]), f_max, f_avg,
                       options.crossover_k1, options.crossover_k3)
    draw = rng.random(n_pairs)
    points = rng.integers(1, max(length, 2), size=n_pairs)
    if length >= 2:
        cross = draw < pc
        tail = np.arange(length)[None, :] >= points[:, None]
        swap = tail & cross[:, None]
        a, b = children[first], children[first + 1]
        children[first] = np.where(swap, b, a)
        children[first + 1] = np.where(swap, a, b)
    # mutation: per-bit flips; the child is not evaluated yet, so its rate
    # follows the fitness of the parent whose place (and head) it takes
    pm = adaptive_rate(parent_fit, f_max, f_avg, options.mutation_k2, options.mutation_k4)
    flips = rng.random((size, length)) < pm[:, None]
    children ^= flips.astype(np.uint8)
    return children


def minimize_ga(objective, feasible, lower, upper, precision, options=None, seeds=None):
    """Minimise ``objective(X)`` subject to ``feasible(X)`` over a box with Huang's binary GA.

    Steps (Huang & Liu III.C, see the module docstring): coding (eq. 8),
    feasible initial population, then per generation roulette selection,
    adaptive single-point crossover, adaptive bit-flip mutation, decoding
    (eq. 9) and evaluation; optional elitism. Runs exactly
    ``options.generations`` generations.

    Parameters
    ----------
    objective : callable
        ``objective(X (n, d)) -> (n,) float``; called only on feasible
        individuals, once per batch.
    feasible : callable
        ``feasible(X (n, d)) -> (n,) bool``; called once per batch on every
        individual evaluated.
    lower, upper : (d,) float
        The box (e.g. eq. 7), U >= L.
    precision : (d,) float or float
        Precision of each variable for eq. 8.
    options : GAOptions, optional
        Defaults to ``GAOptions()``.
    seeds : (k, d) float, optional
        Warm-start points, encoded to their nearest code (clipped to the
        box); the feasible ones among the first ``population_size`` join
        the initial population.

    Returns
    -------
    GAResult
        The best feasible individual evaluated (with elitism it is also in
        the final population).

    Raises
    ------
    NoFeasibleStart
        Fewer than ``population_size`` feasible individuals after
        ``options.max_init_attempts`` random draws (plus the seeds).
    ValueError
        Bad box, options or callback output shapes.
    """
    options = GAOptions() if options is None else options
    coding = BinaryCoding.from_precision(lower, upper, precision)
    rng = np.random.default_rng(options.seed)
    evaluate = _Evaluator(objective, feasible)

    bits, ok, fun = _initial_population(coding, evaluate, rng, options, seeds)
    masked = np.where(ok, fun, np.inf)
    i_best = int(np.argmin(masked))
    best_bits, best_fun = bits[i_best].copy(), float(fun[i_best])
    history = [best_fun]

    for generation in range(options.generations):
        fit = fitness(fun, ok, options.fitness_epsilon, options.infeasible_fitness)
        bits = _offspring(bits, fit, rng, options)
        ok, fun = evaluate(coding.decode(bits))
        masked = np.where(ok, fun, np.inf)
        i_gen = int(np.argmin(masked))
        gen_best = float(masked[i_gen])
        if options.elitism and not gen_best <= best_fun:
            # replace the worst individual (an infeasible one if any) by the elite
            i_worst = int(np.argmax(masked))
            bits[i_worst], ok[i_worst], fun[i_worst] = best_bits, True, best_fun
            gen_best = best_fun
        elif gen_best < best_fun:
            best_bits, best_fun = bits[i_gen].copy(), gen_best
        history.append(gen_best if np.isfinite(gen_best) else np.nan)
        _LOG.debug("generation %d: best %.6g, feasible %d/%d",
                   generation + 1, gen_best, int(ok.sum()), ok.size)

    return GAResult(
        x=coding.decode(best_bits),
        fun=best_fun,
        feasible=True,
        evaluations=evaluate.count,
        generations=options.generations,
        history=np.asarray(history, dtype=np.float64),
        n_bits=coding.n_bits.copy(),
    )
