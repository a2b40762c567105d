"""Curve tracking for the DL-MPC: hold the laser on the best branch and follow K along it.

The estimator's surrogate reads the angles, not the laser (``dlmpc-train
check-estimator``), so the surrogate -> map loop cannot follow K by itself. Along the
best branch-continuous angle curve ``c(s)`` (the refined tracking path; ``s`` is a
birefringence estimate on the curve's own axis, in K's units) the steady objective peaks
near ``s = K`` and is flat close to it. The tracker therefore estimates ``s`` from the
measured O alone: it dithers ``s`` by ``+-dither`` in blocks of ``block`` control
periods, compares the O measured at the end of each block with the two blocks around it
(which cancels a linear drift of O), and steps its estimate toward the higher O. It never
reads the true K.

It takes over from the inner loop once the laser has been locked for ``entry_patience``
periods (moving onto the curve at ``start``), and hands back when O under tracking falls
below ``guard`` x the O measured just before it took over (then waits ``cooldown``
periods, twice as long after each failed entry, before trying again). Where the curve is
flat the estimate can rest on a plateau away from K; when O stays below ``survey_ratio``
x the curve's own steady O at the estimate, it surveys the whole curve once and
continues from the best point it saw.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from dlmpc_ros.learning.curve import check_curve


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of the curve tracker (times in control periods; ``s`` in K's units)."""

    start: float = -0.1
    """Curve parameter at which tracking starts (a point that locks from most pulses)."""
    dither: float = 0.03
    """Half-amplitude of the dither on ``s``."""
    block: int = 3
    """Control periods per dither half (the O of the block's last period is used)."""
    step: float = 0.015
    """First change of the estimate after a compared block; it grows by ``grow`` while the
    comparisons agree in sign and shrinks by ``shrink`` when they flip (Rprop), within
    [``min_step``, ``max_step``]."""
    min_step: float = 0.005
    """Smallest change of the estimate per compared block."""
    max_step: float = 0.03
    """Largest change of the estimate per compared block."""
    grow: float = 1.5
    """Factor on the step while the comparisons agree in sign (>= 1)."""
    shrink: float = 0.5
    """Factor on the step when they flip (in (0, 1])."""
    deadband: float = 5e-5
    """Relative O difference below which the estimate does not move."""
    entry_patience: int = 3
    """Locked periods under the inner loop before tracking takes over."""
    settle: int = 20
    """Periods after entry before the guard judges the objective."""
    guard: float = 0.85
    """Fraction of the O measured before entry under which tracking is failing."""
    guard_periods: int = 3
    """Consecutive periods below ``guard`` x the entry O that hand back to the inner loop."""
    cooldown: int = 50
    """Periods to wait after handing back before trying again (doubled, up to 64 x,
    after each failed entry)."""
    survey_ratio: float = 0.93
    """O below this fraction of the curve's own steady O at the estimate, for
    ``survey_patience`` periods, means the estimate sits on a plateau away from K: survey."""
    survey_patience: int = 20
    """Periods under the survey level before the survey starts."""
    survey_spacing: float = 0.05
    """Distance between the curve points the survey visits (K units)."""
    survey_dwell: int = 3
    """Periods the survey waits at each point (twice that at the first)."""
    survey_cooldown: int = 300
    """Periods after a survey before the next may start."""

    def __post_init__(self) -> None:
        if not (self.dither > 0 and 0 < self.min_step <= self.step <= self.max_step
                and self.deadband >= 0):
            raise ValueError('need dither > 0, 0 < min_step <= step <= max_step and '
                             'deadband >= 0')
        if not (self.grow >= 1 and 0 < self.shrink <= 1):
            raise ValueError('need grow >= 1 and 0 < shrink <= 1')
        if min(self.block, self.entry_patience, self.guard_periods, self.cooldown) < 1 \
                or self.settle < 0:
            raise ValueError('block, entry_patience, guard_periods and cooldown must be '
                             '>= 1 and settle >= 0')
        if not 0 < self.guard <= 1:
            raise ValueError(f'guard must be in (0, 1], got {self.guard}')
        if not (0 < self.survey_ratio <= 1 and self.survey_spacing > 0) \
                or min(self.survey_patience, self.survey_dwell, self.survey_cooldown) < 1:
            raise ValueError('survey_ratio must be in (0, 1], survey_spacing > 0 and the '
                             'survey periods >= 1')


class CurveTracker:
    """Per control period: None while the inner loop is in charge, else the angles (4,)
    [rad] on the curve.

    ``grid`` (n,) increasing curve parameters and ``angles`` (n, 4) [rad] the curve's
    angle sets, continuous along the grid; ``threshold`` is the objective at and above
    which the laser counts as locked (E/M units); ``expected`` (n,), the steady O on the
    curve at each grid point, enables the survey (None: no survey).
    """

    def __init__(self, grid: np.ndarray, angles: np.ndarray, threshold: float,
                 config: TrackingConfig | None = None,
                 expected: np.ndarray | None = None) -> None:
        self.grid, self.angles, self.expected = check_curve(grid, angles, expected)
        if not threshold > 0:
            raise ValueError(f'lock threshold must be > 0, got {threshold}')
        self.config = config or TrackingConfig()
        self.threshold = float(threshold)
        self.active = False
        self._locked = 0          # consecutive locked periods while not tracking
        self._recent: deque[float] = deque(maxlen=self.config.entry_patience)
        self._entry_objective = 0.0
        self._wait = 0            # cooldown periods left
        self._cooldown = self.config.cooldown
        self._blocks: deque[tuple[float, float]] = deque(maxlen=3)  # (sign, O)
        self._survey_wait = 0
        self._survey_seen: list[tuple[float, float]] = []  # (point, O)
        self._dwell = 0
        self._recentre()          # estimate at start; age, guard, dither and steps reset

    def curve(self, s: float) -> np.ndarray:
        """The curve's angles (4,) [rad] at parameter ``s`` (clipped to the grid)."""
        s = float(np.clip(s, self.grid[0], self.grid[-1]))
        return np.array([np.interp(s, self.grid, self.angles[:, j]) for j in range(4)])

    def interrupt(self) -> None:
        """Something else took over (the acquisition scan): stop and wait a cooldown."""
        self._survey = []
        if self.active:
            self._leave(failed=self._age <= self.config.settle + self.config.guard_periods)
        self._locked = 0
        self._recent.clear()

    def step(self, objective: float) -> np.ndarray | None:
        """This period's measured O -> the curve's angles for the next period, or None."""
        locked = bool(np.isfinite(objective) and objective >= self.threshold)
        if not self.active:
            return self._maybe_enter(objective, locked)
        self._age += 1
        if self._survey:
            return self._survey_step(float(objective))
        if self._age > self.config.settle:
            bad = not (np.isfinite(objective)
                       and objective >= self.config.guard * self._entry_objective)
            self._low = self._low + 1 if bad else 0
            if self._low >= self.config.guard_periods:
                if self._age > self.config.settle + 2 * self.config.block:
                    self._recentre()  # K moved off the estimate: start again on the curve
                else:
                    self._leave(failed=True)
                    return None
            if self._age == self.config.settle + 2 * self.config.block:
                self._cooldown = self.config.cooldown  # a successful entry resets it
            if self._should_survey(float(objective)):
                return self._start_survey()
        self._in_block += 1
        if self._in_block >= self.config.block:
            self._end_block(float(objective))
        return self.curve(self.estimate + self._sign * self.config.dither)

    def _should_survey(self, objective: float) -> bool:
        if self._survey_wait > 0:
            self._survey_wait -= 1
        if self.expected is None:
            return False
        level = self.config.survey_ratio * float(np.interp(self.estimate, self.grid,
                                                           self.expected))
        self._short = self._short + 1 if not objective >= level else 0
        return self._short >= self.config.survey_patience and self._survey_wait == 0

    def _start_survey(self) -> np.ndarray:
        """Visit the curve at ``survey_spacing`` from the end nearest the estimate."""
        points = np.arange(self.grid[0], self.grid[-1] + 1e-9, self.config.survey_spacing)
        if self.grid[-1] - self.estimate < self.estimate - self.grid[0]:
            points = points[::-1]
        self._survey, self._survey_seen = [float(p) for p in points], []
        self._dwell, self._short = -self.config.survey_dwell, 0  # first point: twice as long
        return self.curve(self._survey[0])

    def _survey_step(self, objective: float) -> np.ndarray:
        self._dwell += 1
        if self._dwell >= self.config.survey_dwell:
            self._survey_seen.append((self._survey.pop(0), objective))
            self._dwell = 0
            if not self._survey:  # done: continue from the best point seen
                best = max(self._survey_seen, key=lambda seen: seen[1])[0]
                self._recentre()
                self.estimate = best
                self._survey_wait = self.config.survey_cooldown
                return self.curve(self.estimate + self.config.dither)
        return self.curve(self._survey[0])

    def _maybe_enter(self, objective: float, locked: bool) -> np.ndarray | None:
        if self._wait > 0:
            self._wait -= 1
            return None
        self._locked = self._locked + 1 if locked else 0
        if locked:
            self._recent.append(float(objective))
        else:
            self._recent.clear()
        if self._locked < self.config.entry_patience:
            return None
        self.active = True
        self._entry_objective = float(np.median(self._recent))
        self._recentre()
        return self.curve(self.estimate + self.config.dither)

    def _recentre(self) -> None:
        """Put the estimate back to ``start`` and the dither to its first block."""
        # periods since entry; consecutive periods under the guard and under the survey level
        self._age, self._low, self._short = 0, 0, 0
        self._survey: list[float] = []  # survey points still to visit
        self.estimate = float(np.clip(self.config.start, self.grid[0], self.grid[-1]))
        self._sign, self._in_block = 1.0, 0  # sign of the dither in the current block
        self._blocks.clear()
        self._step, self._last_move = self.config.step, 0.0  # Rprop step and last sign

    def _leave(self, failed: bool) -> None:
        """Hand back and wait a cooldown (doubled, up to 64 x, after a failed entry)."""
        self.active = False
        self._locked = 0
        self._recent.clear()
        self._wait = self._cooldown
        if failed:
            self._cooldown = min(2 * self._cooldown, 64 * self.config.cooldown)

    def _end_block(self, objective: float) -> None:
        """Close a dither half: compare it with its neighbours and move the estimate."""
        self._blocks.append((self._sign, objective))
        self._in_block = 0
        self._sign = -self._sign
        if len(self._blocks) == 3 and self._age > self.config.settle:
            (_, before), (sign, middle), (_, after) = self._blocks
            difference = sign * (middle - 0.5 * (before + after))   # O(+) - O(-)
            scale = max(abs(middle), 1e-12)
            if abs(difference) > self.config.deadband * scale:
                move = float(np.sign(difference))
                cfg = self.config
                if self._last_move:
                    factor = cfg.grow if move == self._last_move else cfg.shrink
                    self._step = float(np.clip(self._step * factor, cfg.min_step,
                                               cfg.max_step))
                self._last_move = move
                self.estimate += self._step * move
                self.estimate = float(np.clip(self.estimate, self.grid[0], self.grid[-1]))
