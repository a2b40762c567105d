"""The DL-MPC's model-predictive step on the laser in front of it: the curve's learned rotation.

Off the nominal cavity, turning all four angles by one angle theta recovers most of the gap to
the best angles. :class:`CurveRotation` is theta(u) along the curve (one rotation serves both
branches: the twin at ``s`` is the curve at ``u = -s``). The :class:`RotationPlanner` takes the
turn the steady-response predictor (:mod:`dlmpc_ros.learning.response`) scores best, corrected
online for this laser (:class:`OnlineCorrection`), and undoes a move after which O fell.
"""
from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from dlmpc_ros.control.dlmpc_config import MEASUREMENTS, PlannerConfig

if TYPE_CHECKING:  # torch-based: the caller loads it
    from dlmpc_ros.learning.response import ResponseEnsemble


#: Turns tried per plan, evenly over [-radius, radius].
CANDIDATES = 21
#: Smallest predicted gain of log O worth a move (``bench/results/planner_gate.md``).
MIN_GAIN = 0.002
#: Recent moves the online correction is fit to.
MEMORY = 30
#: Weight, in moves of the run, of a calibrated correction (``turn_correction.npz`` of
#: ``dlmpc-train adapt``) in the online fit (without one: toward 0 with weight 1).
PRIOR_MOVES = 10.0
#: A move after which O fell under this fraction of its O before is taken back.
UNDO_BELOW = 0.85


class OnlineCorrection:
    """What the predictor got wrong on this laser: ``a + b * delta + c * |delta|``, a ridge fit
    to the errors of the last ``memory`` moves toward ``prior`` (3,) (None: 0) with weight
    ``ridge``, added to later plans less its value at 0 (``a`` absorbs K's drift)."""

    def __init__(self, memory: int, ridge: float = 1.0, prior: np.ndarray | None = None) -> None:
        self.moves: deque[tuple[float, float]] = deque(maxlen=memory)  # (delta, error)
        self.ridge = float(ridge)
        self.prior = np.zeros(3) if prior is None else np.asarray(prior, float)
        if self.prior.shape != (3,) or not np.all(np.isfinite(self.prior)):
            raise ValueError(f'the correction prior must be 3 finite values, got {prior}')
        self.coefficients = self.prior.copy()

    def _terms(self, delta: np.ndarray) -> np.ndarray:
        """(n, 3) regressors of turns (n,): 1, delta and |delta| in units of 0.1 rad."""
        d = np.asarray(delta, float).reshape(-1) / 0.1
        return np.stack([np.ones_like(d), d, np.abs(d)], axis=1)

    def extend(self, deltas, errors) -> None:
        """Moves' turns and errors (n,) (measured less predicted change of log O); refit."""
        self.moves.extend(zip(np.asarray(deltas, float).tolist(),
                              np.asarray(errors, float).tolist()))
        if not self.moves:
            return
        d, e = np.array(self.moves).T
        x = self._terms(d)
        self.coefficients = np.linalg.solve(x.T @ x + self.ridge * np.eye(3),
                                            x.T @ e + self.ridge * self.prior)

    def __call__(self, delta: np.ndarray) -> np.ndarray:
        return self._terms(delta) @ self.coefficients


class RotationPlanner:
    """Plans turns of the tracking curve with the steady-response predictor."""

    def __init__(self, model: ResponseEnsemble, config: PlannerConfig | None = None,
                 correction_prior: np.ndarray | None = None) -> None:
        self.model, self.config = model, config or PlannerConfig()
        self.recent: deque[tuple[float, float]] = deque(maxlen=MEASUREMENTS)  # (log E, log M)
        calibrated = correction_prior is not None
        self.correction = OnlineCorrection(MEMORY, ridge=PRIOR_MOVES if calibrated else 1.0,
                                           prior=correction_prior)
        self.moves, self.undone = 0, 0
        self._rng = np.random.default_rng(0)
        self._pending: tuple[float, float, float] | None = None  # (delta, predicted, log O)

    def observe(self, energy: float, kurtosis: float) -> None:
        """One period's measured E and M (a state with no pulse is not averaged in)."""
        if np.isfinite(energy) and np.isfinite(kurtosis) and energy > 0 and kurtosis > 0:
            self.recent.append((float(np.log(energy)), float(np.log(kurtosis))))

    def retract(self) -> float:
        """The last move [rad] if not judged yet (0: none), forgotten and counted as undone."""
        if self._pending is None:
            return 0.0
        delta, self._pending = self._pending[0], None
        self.undone += 1
        self.recent.clear()
        return delta

    def plan(self, u: float, theta: float, noise: float = 0.0, at_least: float = 0.0) -> float:
        """The turn [rad] to add at ``u`` (0: hold), rotated ``theta`` [rad]; ``noise``: a
        period's log O sigma (0: unknown); ``at_least``: least predicted gain worth it."""
        if not self.recent:
            return 0.0
        log_e, log_m = np.mean(np.array(self.recent), axis=0)
        log_o = log_e - log_m
        cfg = self.config
        pending, self._pending = self._pending, None
        if pending is not None:  # how did the last move do?
            delta, predicted, before = pending
            if cfg.online:
                self.correction.extend([delta], [(log_o - before) - predicted])
            if log_o - before < np.log(UNDO_BELOW):
                self.undone += 1
                self.recent.clear()
                return -delta
        deltas = np.linspace(-cfg.radius, cfg.radius, CANDIDATES)
        mean, spread = self.model.predict(u, theta, float(np.exp(log_e)), float(np.exp(log_m)),
                                          deltas)
        if cfg.online:
            mean = mean + self.correction(deltas) - self.correction(np.zeros(1))
        score = mean - cfg.spread_penalty * spread
        best = int(np.argmax(score))
        if cfg.explore:
            best = int(self._rng.integers(CANDIDATES))
        elif not (score[best] > max(MIN_GAIN, score[CANDIDATES // 2],
                                    cfg.noise_gate * noise * np.sqrt(2 / MEASUREMENTS))
                  and mean[best] - mean[CANDIDATES // 2] >= at_least):
            return 0.0
        self.moves += 1
        self._pending = (float(deltas[best]), float(mean[best]), log_o)
        self.recent.clear()  # the next plan reads the state after this move
        return float(deltas[best])


class CurveRotation:
    """theta(u) [rad], a learned turn of all four angles along the curve: ``knots`` >= 2
    points over ``low`` < ``high`` (K units) carry it, within +-``limit`` (see :meth:`move`)."""

    def __init__(self, low: float, high: float, knots: int, limit: float,
                 spread: float = 0.0) -> None:
        if not (np.isfinite([low, high]).all() and low < high and knots >= 2 and limit > 0
                and spread >= 0):
            raise ValueError('need finite low < high, knots >= 2, limit > 0 and spread >= 0')
        self.spread, self.limit = float(spread), float(limit)
        self.knots, self.values = np.linspace(low, high, knots), np.zeros(knots)
        self.explored = np.zeros(knots, bool)  # knots a move was planned next to
        self._start = self.values.copy()  # what :meth:`forget` returns to

    def start_from(self, knots: np.ndarray, values: np.ndarray) -> None:
        """Begin from a calibrated rotation, ``values`` [rad] at ``knots`` (within +-limit)."""
        self.values = np.clip(np.interp(self.knots, knots, values), -self.limit, self.limit)
        self._start = self.values.copy()

    def forget(self) -> None:
        """Back to the rotation the run began with, every knot unexplored again."""
        self.values = self._start.copy()
        self.explored[:] = False

    def __call__(self, u: float) -> float:
        """theta at ``u`` [rad] (u clipped to the knots' range)."""
        return float(np.interp(u, self.knots, self.values))

    def move(self, u: float, delta: float) -> None:
        """Change theta(u) by ``delta`` [rad]: unexplored knots first by ``delta`` x
        exp(-(knot - u)^2 / (2 spread^2)), then the two around ``u`` by what is lacking."""
        u = float(np.clip(u, self.knots[0], self.knots[-1]))
        right = int(np.clip(np.searchsorted(self.knots, u), 1, self.knots.size - 1))
        w_right = (u - self.knots[right - 1]) / (self.knots[right] - self.knots[right - 1])
        weights = np.array([1.0 - w_right, w_right])
        change = delta * weights / float(np.sum(weights ** 2))
        index = [right - 1, right]
        if self.spread > 0 and delta:  # the unexplored knots, then the rest at u's two
            shared = delta * np.exp(-0.5 * ((self.knots - u) / self.spread) ** 2)
            shared[self.explored] = 0.0
            self.values = np.clip(self.values + shared, -self.limit, self.limit)
            change = change * (1.0 - float(np.interp(u, self.knots, shared)) / delta)
        self.values[index] = np.clip(self.values[index] + change, -self.limit, self.limit)
        self.explored[index] |= weights > 0
