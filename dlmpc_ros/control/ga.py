"""A genetic-algorithm baseline: the method most used to mode-lock real benches
(Woodward and Kelleher, Sci. Rep. 2016; Pu et al. 2019).

A population of angle sets is tried on the laser one at a time: each individual is
commanded, the servos travel there, and after ``dwell`` more control periods the
measured objective O = E / M is its fitness. A generation is then bred by tournament
selection, uniform crossover and Gaussian mutation, keeping the ``elite`` best. After
``generations`` generations (or as soon as a generation brings no gain for
``patience`` generations) the controller holds the best individual if its O reached
``lock_objective`` (the O a lab calls mode-locked), else it starts a new search from a
fresh population. While holding, when the measured O falls below ``restart_level`` x the
O it held with for ``restart_periods`` periods, it searches again, from a population
around the held angles. It needs no model and no K, only the measurement. Angles in
radians; times in control periods.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from dlmpc_ros.control.step import AngleLimits, ControlStep, implausible
from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import wrap_angles


@dataclass(frozen=True)
class GAConfig:
    """Settings of the genetic algorithm: population and generations of the size bench GAs
    use, the rest tuned on the development plants (an Optuna study,
    ``bench/results/tune_baselines/ga.md``, confirmed on other cold starts)."""

    population: int = 10
    """Individuals per generation."""
    generations: int = 6
    """Generations of one search."""
    elite: int = 1
    """Best individuals copied unchanged into the next generation."""
    tournament: int = 5
    """Individuals drawn per tournament; the fittest is a parent."""
    crossover: float = 0.37
    """Chance that two parents are crossed (uniform crossover) rather than copied."""
    mutation: float = 0.51
    """Chance per angle of a Gaussian mutation."""
    mutation_sigma: float = 0.065
    """Standard deviation of a mutation [rad]."""
    dwell: int = 1
    """Periods an individual is held after the servos arrived, before its O is read."""
    travel_periods: int = 8
    """Periods after which an individual counts as arrived even if the servos are not
    there (a setting outside the angle limits)."""
    arrive_tolerance: float = 1e-3
    """Largest angle gap [rad] at which the servos count as arrived."""
    patience: int = 8
    """Generations without a gain in the best fitness that end a search early."""
    lock_objective: float = 0.1
    """O at and above which the best individual counts as mode-locked and is held (about
    half of this cavity's best steady O)."""
    restart_level: float = 0.6
    """Search again when O stays below this x the held O ..."""
    restart_periods: int = 5
    """... for this many periods."""
    restart_sigma: float = 0.3
    """Spread [rad] of a restarted population around the held angles (half of it is
    drawn uniformly instead, to find another branch)."""
    seed: int = 0
    """Seed of the draws."""

    def __post_init__(self) -> None:
        checks.counts(self, 'population', minimum=2)
        checks.counts(self, 'generations', 'tournament', 'dwell', 'travel_periods',
                      'patience', 'restart_periods')
        checks.counts(self, 'elite', 'seed', minimum=0)
        if self.elite >= self.population:
            raise ValueError(f'GAConfig.elite must be < population = {self.population}, '
                             f'got {self.elite}')
        checks.fraction(self, 'restart_level')
        for name in ('crossover', 'mutation'):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f'GAConfig.{name} must be in [0, 1], got '
                                 f'{getattr(self, name)!r}')
        checks.positive(self, 'mutation_sigma', 'arrive_tolerance', 'restart_sigma',
                        'lock_objective')


class GAController:
    """Genetic-algorithm search of the four angles, then hold the best (mode ``ga``).

    ``evaluations`` counts the individuals whose fitness was measured; ``searches`` the
    searches started (the first, then one per restart).
    """

    name = 'ga'

    def __init__(self, config: GAConfig | None = None, limits: AngleLimits | None = None
                 ) -> None:
        self.config = config or GAConfig()
        self.limits = limits or AngleLimits()
        self._rng = np.random.default_rng(self.config.seed)
        self.evaluations = 0
        self.searches = 0
        self.best: np.ndarray | None = None       # (4,) best angles found
        self.best_fitness = -math.inf
        self.holding = False
        self._held_objective = 0.0
        self._low = 0
        self._start(None)

    # -- the search --------------------------------------------------------------------
    def _start(self, centre: np.ndarray | None) -> None:
        """A new search: a uniform population, or one around ``centre``."""
        cfg = self.config
        uniform = self._rng.uniform(-np.pi / 2, np.pi / 2, (cfg.population, 4))
        if centre is not None:
            near = wrap_angles(centre + cfg.restart_sigma
                               * self._rng.standard_normal((cfg.population, 4)))
            uniform[: cfg.population // 2] = near[: cfg.population // 2]
            uniform[0] = wrap_angles(centre)
        self._population = uniform
        self._fitness = np.full(cfg.population, -np.inf)
        self._index = 0
        self._generation = 0
        self._stale = 0
        self._search_best = -math.inf
        self._arrive = self._dwelt = 0
        self.holding = False
        self.searches += 1

    def _breed(self) -> None:
        """The next generation from the measured one."""
        cfg = self.config
        order = np.argsort(self._fitness)[::-1]
        children = [self._population[i].copy() for i in order[:cfg.elite]]
        while len(children) < cfg.population:
            a, b = self._parent(), self._parent()
            child = a.copy()
            if self._rng.random() < cfg.crossover:
                take = self._rng.random(4) < 0.5
                child = np.where(take, a, b)
            mutate = self._rng.random(4) < cfg.mutation
            child = child + mutate * cfg.mutation_sigma * self._rng.standard_normal(4)
            children.append(wrap_angles(child))
        self._population = np.stack(children)
        self._fitness = np.full(cfg.population, -np.inf)
        self._index = 0

    def _parent(self) -> np.ndarray:
        picks = self._rng.integers(0, self.config.population, self.config.tournament)
        return self._population[picks[np.argmax(self._fitness[picks])]]

    def _record(self, fitness: float) -> None:
        """The current individual's fitness; moves on to the next (or the next
        generation, or holding the best)."""
        cfg = self.config
        self._fitness[self._index] = fitness
        self.evaluations += 1
        if fitness > self.best_fitness or self.best is None:
            self.best_fitness, self.best = fitness, self._population[self._index].copy()
        self._index += 1
        self._arrive = self._dwelt = 0
        if self._index < cfg.population:
            return
        generation_best = float(self._fitness.max())
        self._stale = 0 if generation_best > self._search_best + 1e-12 else self._stale + 1
        self._search_best = max(self._search_best, generation_best)
        self._generation += 1
        if self._generation < cfg.generations and self._stale < cfg.patience:
            self._breed()
        elif self.best_fitness >= cfg.lock_objective:
            self.holding, self._low, self._held_objective = True, 0, self.best_fitness
        else:  # no lock found: search afresh
            self.best_fitness = -math.inf
            self._start(None)

    # -- the verb ----------------------------------------------------------------------
    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        """One control period: measurement ``(E, M, alpha[4])`` in, next angles out."""
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        current = measurement[2:6]
        if implausible(measurement):  # a glitch scores no individual: keep the angles
            current = np.nan_to_num(current, nan=0.0)
            return ControlStep(angles=self.limits.apply(current, current), mode=self.name,
                               latency_ms=1e3 * (time.perf_counter() - started))
        objective = measurement[0] / measurement[1]
        if self.holding:
            wanted = self._hold(objective)
        else:
            wanted = self._search(objective, current)
        return ControlStep(angles=self.limits.apply(current, wanted), mode=self.name,
                           latency_ms=1e3 * (time.perf_counter() - started))

    def _hold(self, objective: float) -> np.ndarray:
        cfg = self.config
        self._low = self._low + 1 if objective < cfg.restart_level * self._held_objective else 0
        if self._low >= cfg.restart_periods:
            self.best_fitness = -math.inf  # the held best is stale: search afresh
            self._start(self.best)
            return self._population[0]
        return self.best

    def _search(self, objective: float, current: np.ndarray) -> np.ndarray:
        cfg = self.config
        target = self._population[self._index]
        gap = np.max(np.abs(wrap_angles(current - target)))
        if self._arrive < cfg.travel_periods and gap > cfg.arrive_tolerance:
            self._arrive += 1
            return target
        self._dwelt += 1
        if self._dwelt <= cfg.dwell:
            return target
        self._record(objective)
        return self.best if self.holding else self._population[self._index]
