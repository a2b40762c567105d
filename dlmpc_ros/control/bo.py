"""A Bayesian-optimization baseline: the method a lab reaches for when every evaluation of
the laser is expensive (each needs the servos to travel and the laser to settle).

Every control period's measurement ``(E, M, alpha[4])`` is one evaluation: the objective
O = E / M at the angles it reports (a later measurement at the same angles, while the
controller dwells there, replaces the earlier one: the laser has settled further). A
Gaussian process (scikit-learn's :class:`~sklearn.gaussian_process.GaussianProcessRegressor`)
models O over the four angles with a kernel that knows each element is pi-periodic: an
RBF on the features ``(cos 2 alpha_i, sin 2 alpha_i)``, which is the product over the four
angles of ``exp(-sin^2(alpha_i - beta_i) / (2 l^2))`` (periodic kernels of period pi, length
scale ``l`` [rad] for small differences), times a constant, plus white noise. The next
angle set is the one of a few hundred random candidates (uniform, and around the best
points) that maximizes the acquisition (expected improvement or an upper confidence
bound); the servos travel there (at most ``max_step`` per period, every period on the way
an evaluation too) and dwell ``dwell`` periods, then the next is chosen.

Once a measured O reaches ``lock_objective`` (the O a lab calls mode-locked) the
controller holds those angles; when O stays under ``restart_level`` x the best O of the
hold for ``restart_periods`` periods, it restarts: it forgets its data but the best
``restart_keep`` points and the latest measurement, and searches again from where it
is. At most ``window`` points are kept (the oldest are dropped: a drift makes old points
stale). The kernel's hyperparameters are fitted by maximum likelihood every
``refit_every`` choices on the latest ``refit_points`` points (a fit on all of them costs
more than a step should), and held in between. It needs no model and no K, only the
measurement. Angles in radians; times in control periods.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from threadpoolctl import ThreadpoolController

from dlmpc_ros.control.step import AngleLimits, ControlStep, implausible
from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import wrap_angles

#: Acquisition functions understood by :class:`BOConfig`.
ACQUISITIONS = ('ei', 'ucb')
#: Bounds of the kernel's length scale [rad], its amplitude (of the normalized O) and its
#: white-noise level (of the normalized O) in a hyperparameter fit.
LENGTH_SCALE_BOUNDS = (0.02, 5.0)
AMPLITUDE_BOUNDS = (1e-2, 1e2)
NOISE_BOUNDS = (1e-6, 1.0)
#: Iterations of one hyperparameter fit (L-BFGS-B).
FIT_ITERATIONS = 30

_threads: ThreadpoolController | None = None


def _one_thread():
    """A context in which BLAS runs on one thread: a GP of a few hundred points gains
    nothing from more, and on a loaded machine (Dask workers, other runs) a team of BLAS
    threads per step costs ten times as much as it saves."""
    global _threads
    if _threads is None:
        _threads = ThreadpoolController()
    return _threads.limit(limits=1, user_api='blas')


@dataclass(frozen=True)
class BOConfig:
    """Settings of the Bayesian-optimization baseline (angles in radians, times in control
    periods)."""

    window: int = 150
    """Most evaluations kept (the oldest are dropped first)."""
    initial: int = 5
    """Evaluations before the Gaussian process chooses: until then the targets are drawn
    uniformly."""
    acquisition: str = 'ei'
    """``'ei'`` (expected improvement over the best O kept) or ``'ucb'`` (mean plus
    ``kappa`` standard deviations)."""
    xi: float = 0.01
    """EI's margin: improvement counts above the best O plus ``xi`` x the standard
    deviation of the O kept (dimensionless, >= 0)."""
    kappa: float = 2.0
    """UCB's weight of the standard deviation (>= 0)."""
    candidates: int = 512
    """Candidates drawn uniformly per choice."""
    local_candidates: int = 256
    """Candidates drawn around the best few points per choice."""
    local_sigma: float = 0.15
    """Spread [rad] of the candidates around the best points."""
    length_scale: float = 0.3
    """The kernel's length scale [rad] before (and between) fits."""
    noise: float = 0.01
    """The kernel's white-noise level (of the normalized O) before (and between) fits."""
    refit_every: int = 20
    """Choices between two fits of the kernel's hyperparameters (0: never fit)."""
    refit_points: int = 60
    """Latest evaluations a hyperparameter fit uses."""
    dwell: int = 0
    """Periods held at a reached target after its first measurement (each measurement
    replaces the one before at the same angles). 0 locked 11 of 12 cold starts of the
    nominal cavity within 3,000 round trips, 1 locked 6 (lock benchmark starts of seed 1,
    not the benchmark's seed 0)."""
    travel_periods: int = 10
    """Periods after which a target counts as reached even if the servos are not there."""
    arrive_tolerance: float = 0.01
    """Largest angle gap [rad] at which the servos count as at a target (and two
    evaluations as at the same angles)."""
    lock_objective: float = 0.1
    """O at and above which the controller holds the angles it measured it at (about half
    of this cavity's best steady O, as the genetic algorithm's)."""
    restart_level: float = 0.6
    """Restart when O stays below this x the best O of the hold ..."""
    restart_periods: int = 5
    """... for this many periods."""
    restart_keep: int = 0
    """Best evaluations kept through a restart besides the latest (0: forget all
    others)."""
    seed: int = 0
    """Seed of the draws (targets and candidates)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'window', minimum=2)
        checks.counts(self, 'initial', 'candidates', 'travel_periods', 'restart_periods',
                      'refit_points')
        checks.counts(self, 'local_candidates', 'refit_every', 'dwell', 'restart_keep',
                      'seed', minimum=0)
        if self.initial > self.window:
            raise ValueError(f'BOConfig.initial must be <= window = {self.window}, '
                             f'got {self.initial}')
        if self.restart_keep >= self.window:
            raise ValueError(f'BOConfig.restart_keep must be < window = {self.window}, '
                             f'got {self.restart_keep}')
        if self.acquisition not in ACQUISITIONS:
            raise ValueError(f'BOConfig.acquisition must be one of {ACQUISITIONS}, '
                             f'got {self.acquisition!r}')
        checks.non_negative(self, 'xi', 'kappa')
        checks.positive(self, 'local_sigma', 'arrive_tolerance', 'lock_objective')
        checks.fraction(self, 'restart_level')
        for name, (low, high) in (('length_scale', LENGTH_SCALE_BOUNDS),
                                  ('noise', NOISE_BOUNDS)):
            checks.positive(self, name)
            if not low <= getattr(self, name) <= high:
                raise ValueError(f'BOConfig.{name} must be in [{low:g}, {high:g}], '
                                 f'got {getattr(self, name)!r}')


def features(angles: np.ndarray) -> np.ndarray:
    """Angles (..., 4) [rad] as the kernel's features (..., 8): ``cos 2 alpha_i`` and
    ``sin 2 alpha_i``, the same for every pi-equivalent angle set."""
    angles = np.asarray(angles, float)
    return np.concatenate([np.cos(2 * angles), np.sin(2 * angles)], axis=-1)


def _fit_hyperparameters(objective, theta, bounds):
    """L-BFGS-B on the negative log marginal likelihood, ``FIT_ITERATIONS`` at most."""
    result = minimize(objective, theta, jac=True, method='L-BFGS-B', bounds=bounds,
                      options={'maxiter': FIT_ITERATIONS})
    return result.x, result.fun


class BOController:
    """Bayesian optimization of the four angles, then hold what locked (mode ``bo``).

    ``evaluations`` counts the measurements recorded (one a period, less the glitches);
    ``choices`` the targets chosen; ``restarts`` the restarts after a hold was lost;
    ``holding`` says whether it holds a lock.
    """

    name = 'bo'

    def __init__(self, config: BOConfig | None = None, limits: AngleLimits | None = None
                 ) -> None:
        self.config = config or BOConfig()
        self.limits = limits or AngleLimits()
        self._rng = np.random.default_rng(self.config.seed)
        length = 2 * self.config.length_scale  # on the features: |f(a) - f(b)| ~ 2 |a - b|
        self._kernel = (ConstantKernel(1.0, AMPLITUDE_BOUNDS)
                        * RBF(length, tuple(2 * b for b in LENGTH_SCALE_BOUNDS))
                        + WhiteKernel(self.config.noise, NOISE_BOUNDS))
        self.angles = np.zeros((0, 4))   # evaluated angle sets [rad]
        self.objective = np.zeros(0)     # their O
        self.evaluations = self.choices = self.restarts = 0
        self.holding = False
        self._held = np.zeros(4)
        self._held_best = 0.0
        self._low = 0
        self._target: np.ndarray | None = None
        self._travelled = self._dwelt = 0

    # -- data ------------------------------------------------------------------------
    def _record(self, angles: np.ndarray, objective: float) -> None:
        """One evaluation: replaces the latest if at the same angles, else appended; the
        oldest beyond ``window`` are dropped."""
        cfg = self.config
        self.evaluations += 1
        if len(self.angles) and np.max(np.abs(wrap_angles(self.angles[-1] - angles))) \
                <= cfg.arrive_tolerance:
            self.objective[-1] = objective
            return
        self.angles = np.vstack([self.angles, angles])[-cfg.window:]
        self.objective = np.append(self.objective, objective)[-cfg.window:]

    def _restart(self) -> None:
        """Forget the data but the best ``restart_keep`` points and the latest (the
        measurement that called the restart); search again."""
        best = np.argsort(self.objective[:-1])[::-1][:self.config.restart_keep]
        keep = np.sort(np.r_[best, len(self.objective) - 1])
        self.angles, self.objective = self.angles[keep], self.objective[keep]
        self.holding, self._target, self._low = False, None, 0
        self.restarts += 1

    # -- the choice ------------------------------------------------------------------
    def _choose(self) -> np.ndarray:
        """The next target (4,) in [-pi/2, pi/2): uniform until ``initial`` evaluations
        are kept, then the acquisition's best candidate."""
        cfg = self.config
        self.choices += 1
        if len(self.objective) < cfg.initial:
            return self._rng.uniform(-np.pi / 2, np.pi / 2, 4)
        uniform = self._rng.uniform(-np.pi / 2, np.pi / 2, (cfg.candidates, 4))
        best = self.angles[np.argsort(self.objective)[::-1][:4]]
        near = best[self._rng.integers(0, len(best), cfg.local_candidates)] \
            + cfg.local_sigma * self._rng.standard_normal((cfg.local_candidates, 4))
        candidates = wrap_angles(np.vstack([uniform, near]))
        with _one_thread(), warnings.catch_warnings():
            warnings.simplefilter('ignore', ConvergenceWarning)
            if cfg.refit_every and self.choices % cfg.refit_every == 0:
                recent = slice(-cfg.refit_points, None)
                fitted = GaussianProcessRegressor(self._kernel, normalize_y=True,
                                                  optimizer=_fit_hyperparameters)
                fitted.fit(features(self.angles[recent]), self.objective[recent])
                self._kernel = fitted.kernel_
            gp = GaussianProcessRegressor(self._kernel, normalize_y=True, optimizer=None)
            gp.fit(features(self.angles), self.objective)
            mean, std = gp.predict(features(candidates), return_std=True)
        spread = float(np.std(self.objective))
        if cfg.acquisition == 'ucb':
            score = mean + cfg.kappa * std
        else:
            gain = mean - self.objective.max() - cfg.xi * spread
            z = gain / np.maximum(std, 1e-12)
            score = gain * ndtr(z) + std * np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)
        return candidates[int(np.argmax(score))]

    # -- the verb ----------------------------------------------------------------------
    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        """One control period: measurement ``(E, M, alpha[4])`` in, next angles out."""
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        current = measurement[2:6]
        if measurement.shape != (6,) or implausible(measurement):
            # a glitch is no evaluation: keep the angles
            current = np.nan_to_num(current, nan=0.0) if current.shape == (4,) \
                else np.zeros(4)
            return ControlStep(angles=self.limits.apply(current, current), mode=self.name,
                               latency_ms=1e3 * (time.perf_counter() - started))
        objective = float(measurement[0] / measurement[1])
        self._record(current, objective)
        wanted = self._hold(objective) if self.holding else None
        if wanted is None:
            wanted = self._search(objective, current)
        return ControlStep(angles=self.limits.apply(current, wanted), mode=self.name,
                           iterations=len(self.objective),
                           latency_ms=1e3 * (time.perf_counter() - started))

    def _hold(self, objective: float) -> np.ndarray | None:
        """The held angles, or None after a restart."""
        cfg = self.config
        self._held_best = max(self._held_best, objective)
        self._low = self._low + 1 if objective < cfg.restart_level * self._held_best else 0
        if self._low >= cfg.restart_periods:
            self._restart()
            return None
        return self._held

    def _search(self, objective: float, current: np.ndarray) -> np.ndarray:
        cfg = self.config
        if objective >= cfg.lock_objective:  # locked here: hold it
            self.holding, self._held, self._held_best, self._low = True, current.copy(), \
                objective, 0
            return self._held
        if self._target is not None:
            gap = np.max(np.abs(wrap_angles(current - self._target)))
            if gap > cfg.arrive_tolerance and self._travelled < cfg.travel_periods:
                self._travelled += 1
                return self._target
            self._dwelt += 1
            if self._dwelt <= cfg.dwell:
                return self._target
        self._target = self._choose()
        self._travelled = self._dwelt = 0
        return self._target
