"""Curve tracking for the DL-MPC: hold the laser on the better branch and follow K along it.

Along the learned curve ``c(s)`` (``s`` in K units) the steady O peaks near ``s = K``: the
:class:`CurveTracker` estimates ``s`` by dithering it (:class:`Dither`), turns to the twin
``c(-s) + pi/2`` (better for K > 0, :mod:`dlmpc_ros.core.symmetry`) by a quarter turn that
keeps the pulse (:class:`BranchTurn`), and turns the curve where its planner expects more O
(:mod:`~dlmpc_ros.control.rotation_planner`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from enum import Enum

import numpy as np

from dlmpc_ros.control.dlmpc_config import (MAX_STEP, MIN_STEP, RPROP_GROW, RPROP_SHRINK,
                                           TrackingConfig)
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.control.rotation_planner import CurveRotation, RotationPlanner
from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.symmetry import HALF_WAVE, QUARTER_TURN
from dlmpc_ros.learning.curve import check_curve


#: Dither blocks between two requests for a turn of the curve (with a planner).
PLAN_EVERY = 4
#: Points along the curve that carry the learned rotation.
ROTATION_KNOTS = 13
#: Largest learned rotation [rad].
ROTATION_LIMIT = 1.0
#: Width (K units) of the Gaussian share of a turn unturned knots take (``rotation_spread.md``).
ROTATION_SPREAD = 0.1
#: How far past its ends (K units) the tracker follows the curve, along straight lines fitted
#: to the curve's last REACH at each end (its best point often lies past an end).
REACH = 0.1
#: Relative O difference below which the estimate does not move.
DEADBAND = 5e-5
#: Periods to wait after handing back before trying again (doubled after each failed entry).
COOLDOWN = 50
#: A branch turn is judged against the median O of this many latest periods (a pulse just
#: formed swings by a factor of two; ``bench/results/entry_turn.md``), or the latest if lower.
TURN_REFERENCE = 3
#: The branch trial compares the mean O of the last this many blocks (both dither signs)
#: with the best such mean on the branch (``bench/results/noise_levels.md``).
TRIAL_BLOCKS = 2


class TrackerState(Enum):
    """What the tracker does; transitions: :data:`TRACKER_TRANSITIONS` (docs/architecture.md)."""

    IDLE = 'idle'      # not tracking: waiting for a lock and the cooldown
    DITHER = 'dither'  # on the curve, dithering the estimate (and planning turns)
    TURN = 'turn'      # changing branch (BranchTurn)


#: The tracker's changes of state from one period to the next (:class:`TrackerState`).
TRACKER_TRANSITIONS = frozenset({
    (TrackerState.IDLE, TrackerState.DITHER), (TrackerState.DITHER, TrackerState.TURN),
    (TrackerState.TURN, TrackerState.DITHER), (TrackerState.DITHER, TrackerState.IDLE),
    (TrackerState.TURN, TrackerState.IDLE)})


class CurveTracker:
    """Per control period: None while not tracking (the angles hold), else the angles (4,)
    [rad] on the curve. It enters after ``entry_patience`` periods locked (O >= ``threshold``)
    or where the scan locked; an entry under its guard hands back for a cooldown. ``grid`` (n,),
    ``angles`` (n, 4) [rad]: the curve; ``expected`` (n,): its steady O (None: the entry trial
    always runs); ``limits``: the servos'; ``planner`` turns the curve (None: never)."""

    def __init__(self, grid: np.ndarray, angles: np.ndarray, threshold: float,
                 config: TrackingConfig | None = None, expected: np.ndarray | None = None,
                 limits: AngleLimits | None = None, planner: RotationPlanner | None = None
                 ) -> None:
        self.grid, self.angles, self.expected = check_curve(grid, angles, expected)
        self.low, self.high = self.grid[0] - REACH, self.grid[-1] + REACH  # the estimate's range
        ends = (self.grid <= self.grid[0] + REACH, self.grid >= self.grid[-1] - REACH)
        self._slopes = [np.polyfit(self.grid[e], self.angles[e], 1)[0] for e in ends]  # (4,)
        if not threshold > 0:
            raise ValueError(f'lock threshold must be > 0, got {threshold}')
        self.config, self.threshold = config or TrackingConfig(), float(threshold)
        self.limits = limits or AngleLimits()
        self.active, self.branch = False, 1  # tracking; 1: on the curve, -1: on its mirror twin
        self.turner = BranchTurn(self.config.turn_guard, self.limits, self.on_curve,
                                 self._turn_curve)
        self._before_turn = (1, 0.0)  # (branch, estimate) where the latest turn began
        self._turn_side = 0.0     # sign of the estimate where the last turn began (0: lost)
        #: O of the consecutive locked periods while not tracking (the latest few)
        self._recent: deque[float] = deque(maxlen=self.config.entry_patience)
        self._entry_objective = 0.0
        self._wait, self._cooldown = 0, COOLDOWN  # cooldown periods left; the next cooldown
        self.dither, self.planner = Dither(self.config), planner
        #: O of the latest ``TURN_REFERENCE`` periods (a turn is judged against their median)
        self._latest: deque[float] = deque(maxlen=TURN_REFERENCE)
        self.rotation = CurveRotation(self.grid[0], self.grid[-1], ROTATION_KNOTS,
                                      ROTATION_LIMIT, ROTATION_SPREAD)
        self._turn_at, self.planned = 0.0, 0.0  # u of the latest planned turn; this period's
        #: 0, or a quarter turn where the scan locked with the half-wave plate turned so
        self._half_wave_frame = 0.0
        self._recentre()          # estimate at start; age, guard, dither and steps reset

    @property
    def state(self) -> TrackerState:
        """What the tracker is doing (:class:`TrackerState`)."""
        if not self.active:
            return TrackerState.IDLE
        return TrackerState.TURN if self.turner.busy else TrackerState.DITHER

    def curve(self, s: float) -> np.ndarray:
        """The angles (4,) [rad] at ``s`` on the tracker's branch (twin: ``c(-s) + pi/2``)."""
        on_curve = self.on_curve(self.branch * s)
        on_curve[HALF_WAVE] += self._half_wave_frame
        return on_curve if self.branch == 1 else on_curve + QUARTER_TURN

    def on_curve(self, u: float) -> np.ndarray:
        """The curve's angles (4,) [rad] at ``u`` (past its ends: fitted lines), turned."""
        u = float(np.clip(u, self.low, self.high))
        inside = float(np.clip(u, self.grid[0], self.grid[-1]))
        return np.array([np.interp(inside, self.grid, self.angles[:, j]) for j in range(4)]) \
            + (u - inside) * self._slopes[int(u > inside)] + self.rotation(u)

    def enter_at(self, estimate: float, branch: int, objective: float,
                 current: np.ndarray | None = None) -> None:
        """Start tracking at ``estimate`` on ``branch`` where the scan just locked (O =
        ``objective``, servos at ``current`` (4,) [rad]), with no patience, cooldown or wait;
        if the scan locked with the half-wave plate a quarter turn from the curve's (the same
        setting), in that frame."""
        if branch not in (1, -1):
            raise ValueError(f'branch must be 1 or -1, got {branch}')
        self.active, self._wait, self.branch = True, 0, branch
        self.turner.cancel()
        self.turner.wait = 0
        self._recentre()
        self.estimate = float(np.clip(estimate, self.low, self.high))
        self._entry_objective = float(objective) if np.isfinite(objective) else 0.0
        self._entry_trial, self._half_wave_frame = True, 0.0
        if current is not None:
            gap = float(current[HALF_WAVE]) - self.curve(self.estimate)[HALF_WAVE]
            self._half_wave_frame = QUARTER_TURN * float(abs(wrap_angles(gap)) > np.pi / 4)

    def interrupt(self) -> None:
        """Something else took over (the acquisition scan): stop and wait a cooldown. The
        pulse was lost on the turned curve: its rotation goes back to the run's start."""
        self.turner.cancel()
        self._left_at = None  # the scan moves the angles
        if self.active:
            self._forget_unjudged_turn()
            self.rotation.forget()
            self._leave(failed=self._age <= self.config.settle + self.config.guard_periods)
        self._recent.clear()

    def step(self, objective: float, current: np.ndarray | None = None) -> np.ndarray | None:
        """This period's O and angles (4,) [rad] (None: no turns) -> the next angles, or None."""
        locked = bool(np.isfinite(objective) and objective >= self.threshold)
        self._latest.append(float(objective) if np.isfinite(objective) else 0.0)
        self.planned = 0.0  # the planner's turn this period [rad]
        if self.state is TrackerState.IDLE:
            return self._maybe_enter(objective, locked)
        self._age += 1
        if self._age <= self.config.settle and np.isfinite(objective):
            self._settling.append(float(objective))
            if self._age == self.config.settle:  # the guard judges against the settled O too
                self._entry_objective = max(self._entry_objective,
                                            float(np.median(self._settling)))
        self.turner.tick()
        if self.state is TrackerState.TURN:
            return self._turning(float(objective))
        if self.config.settle < self._age <= self.config.settle + 2 * self.config.block:
            bad = not (np.isfinite(objective)
                       and objective >= self.config.guard * self._entry_objective)
            self._low = self._low + 1 if bad else 0
            if self._low >= self.config.guard_periods:  # the entry failed
                self._forget_unjudged_turn()
                self._leave(failed=True)
                self._left_at = self.estimate  # the angles hold there: the next entry too
                return None
            if self._age == self.config.settle + 2 * self.config.block:
                self._cooldown = COOLDOWN  # a successful entry resets it
        if self._entry_trial and self._age > self.config.entry_trial_after \
                and current is not None:
            self._entry_trial = False
            weak = (self.expected is None or objective < self.config.entry_trial_below
                    * np.interp(self.branch * self.estimate, self.grid, self.expected))
            if weak and self.turner.wait == 0 and not self.turner.lost_landing \
                    and self._begin_turn(current):
                return self._turning(float(objective))
        move = self.dither.add(float(objective), compare=self._age > self.config.settle)
        if move is not None:  # a dither block closed
            self._end_block(float(objective), move)
            reference = self._branch_trial() if current is not None else None
            if reference is not None and self._begin_turn(current, reference):
                return self._turning(float(objective))
        return self.curve(self.estimate + self.dither.sign * self.config.dither)

    def _begin_turn(self, current: np.ndarray, reference: float | None = None) -> bool:
        """Begin a turn from ``current`` (4,) [rad] against ``reference`` (None: median O)."""
        self._turn_side, self._before_turn = np.sign(self.estimate), (self.branch, self.estimate)
        reference = float(np.median(self._latest)) if reference is None else reference
        return self.turner.begin(current, self.branch * self.estimate, reference)

    def _branch_trial(self) -> float | None:
        """The O to judge a try of the other branch against (None: no try): past K = 0 by
        ``mirror_margin``, the recent median O; O fell ``trial_drop`` under its best on the
        branch, the O it fell to if lower. Not in a turn's wait, but for a crossing of 0."""
        cfg = self.config
        past_zero = self.branch * self.estimate > cfg.mirror_margin
        if self.turner.wait > 0 and not (past_zero and np.sign(self.estimate) == -self._turn_side):
            return None
        median = float(np.median(self._latest))
        if past_zero:
            return median
        values = self._trial_values  # cleared with the best: no values, no best yet
        if values and sum(values) / len(values) < (1 - cfg.trial_drop) * self._branch_best:
            return min(median, self._latest[-1])
        return None

    def _turning(self, objective: float) -> np.ndarray:
        """A period of a branch turn: its command (on trial: the new branch's point at the
        estimate); the branch flips on arrival, and back to where it began if it retraces."""
        command, event = self.turner.step(objective)
        if event == ARRIVED:  # on the other branch, at the curve point the turn landed at
            self.branch = -self.branch
            self.estimate = self.branch * self.turner.landing
        elif event in (RETURNED, ABANDONED):  # retraced: back where it began
            self.branch, self.estimate = self._before_turn
        if event == ABANDONED:  # the turn itself lost O: its wait holds on either side
            self._turn_side = 0.0
        if event in (KEPT, RETURNED, ABANDONED):
            self.dither.restart()
            if event != ABANDONED or self.turner.arrived:  # one lost on the way compared nothing
                self._branch_best = 0.0  # the branch is chosen anew: its best from here on
                self._trial_values.clear()
        return self.curve(self.estimate) if command is None else command

    def _maybe_enter(self, objective: float, locked: bool) -> np.ndarray | None:
        if self._wait > 0:
            self._wait -= 1
            return None
        if locked:
            self._recent.append(float(objective))
        else:
            self._recent.clear()
        if len(self._recent) < self.config.entry_patience:
            return None
        self.active, self._entry_objective = True, float(np.median(self._recent))
        self._recentre(self._left_at)
        self._entry_trial = True
        return self.curve(self.estimate + self.dither.sign * self.config.dither)

    def _recentre(self, at: float | None = None) -> None:
        """Put the estimate at ``at`` (None: back to ``start``), the dither to its first block."""
        # periods since entry; consecutive periods under the guard; where a failed entry left
        self._age, self._low, self._left_at = 0, 0, None
        self._settling: list[float] = []  # O measured while settling after entry
        self._branch_best = 0.0  # best block O since the branch was last chosen
        #: O of the last ``TRIAL_BLOCKS`` blocks since then (their mean: the trial's O)
        self._trial_values: deque[float] = deque(maxlen=TRIAL_BLOCKS)
        self._entry_trial = False  # the other branch is still to be tried after entry
        # the start point on the branch the tracker is on (its twin on the mirror branch)
        start = self.branch * float(np.clip(self.config.start, self.low, self.high))
        self.estimate = start if at is None else at
        self.dither.restart()

    def _forget_unjudged_turn(self) -> None:
        """Take back the planner's latest, unjudged turn, from theta too."""
        turn = self.planner.retract() if self.planner is not None else 0.0
        if turn:
            self.rotation.move(self._turn_at, -turn)
            self.planned = -float(turn)

    def _leave(self, failed: bool) -> None:
        """Hand back and wait a cooldown (doubled, up to 64 x, after a failed entry)."""
        self.active, self._wait = False, self._cooldown
        self._recent.clear()
        if failed:
            self._cooldown = min(2 * self._cooldown, 64 * COOLDOWN)

    def _end_block(self, objective: float, move: float) -> None:
        """A dither block closed with O = ``objective``: record it for the branch trial, move
        the estimate by ``move``; every ``PLAN_EVERY`` blocks, let the planner turn the curve."""
        cfg = self.config
        if cfg.trial_drop > 0 and np.isfinite(objective):
            self._trial_values.append(objective)
            if len(self._trial_values) == TRIAL_BLOCKS:
                self._branch_best = max(self._branch_best, sum(self._trial_values)
                                        / TRIAL_BLOCKS)
        if move:
            self.estimate = float(np.clip(self.estimate + move, self.low, self.high))
        if self._age > cfg.settle and self.dither.blocks % PLAN_EVERY == 0:
            self._turn_curve()

    def _turn_curve(self, at_least: float = 0.0) -> bool:
        """Turn the curve if the planner expects ``at_least`` more log O; whether it did."""
        if self.planner is None:
            return False
        u = float(np.clip(self.branch * self.estimate, self.grid[0], self.grid[-1]))  # on the grid
        undone = self.planner.undone
        turn = self.planner.plan(u, self.rotation(u), self.dither.noise(), at_least)
        if not turn:
            return False
        self.rotation.move(u, turn)
        self.planned, self._turn_at = float(turn), u
        self.dither.compared.clear()  # O moves with the turn: compare blocks after it
        return self.planner.undone == undone  # an earlier turn taken back is no gain


class Dither:
    """Where the laser sits on the curve, read off the measured O: the tracker commands the
    estimate plus ``sign x dither``, the sign flipping every ``block`` periods; the estimate
    moves by an Rprop step toward the higher O of a closed block against the mean of its
    neighbours (which cancels a linear drift), unless under the deadband."""

    def __init__(self, config: TrackingConfig) -> None:
        self.config = config
        #: |change of log O| between consecutive periods of a block (same angles): noise
        self._jitter: deque[float] = deque(maxlen=64)
        #: (sign, O) of the latest closed blocks (cleared when O moves for another reason)
        self.compared: deque[tuple[float, float]] = deque(maxlen=3)
        self.restart()

    def restart(self) -> None:
        """First block, no blocks recorded, first Rprop step (the noise read stays)."""
        self.sign, self._in_block = 1.0, 0   # sign of the dither in the current block
        self._previous: float | None = None  # O of the block's previous period
        self.compared.clear()
        self.blocks = 0                      # blocks closed since (for the plans)
        self._step, self._last_move = self.config.step, 0.0  # Rprop step and last sign

    def add(self, objective: float, compare: bool) -> float | None:
        """One period's O -> None while its block runs; once it closes, the move of the
        estimate (K units; 0: none; with ``compare`` False the block is only recorded)."""
        self._in_block += 1
        previous = self._previous
        if self._in_block > 1 and previous is not None and objective > 0 and previous > 0:
            self._jitter.append(abs(float(np.log(objective / previous))))
        self._previous = objective
        if self._in_block < self.config.block:
            return None
        self.compared.append((self.sign, objective))
        self._in_block, self._previous = 0, None
        self.blocks += 1
        self.sign = -self.sign
        if len(self.compared) < 3 or not compare:
            return 0.0
        (_, before), (sign, middle), (_, after) = self.compared
        difference = sign * (middle - 0.5 * (before + after))   # O(+) - O(-)
        if not abs(difference) > self.deadband() * max(abs(middle), 1e-12):
            return 0.0
        way = float(np.sign(difference))  # Rprop: the step grows while the way repeats
        if self._last_move:                # and shrinks when it flips, within the bounds
            self._step = float(np.clip(self._step * (
                RPROP_GROW if way == self._last_move else RPROP_SHRINK), MIN_STEP, MAX_STEP))
        self._last_move = way
        return self._step * way

    def deadband(self) -> float:
        """Relative O difference the estimate ignores: ``DEADBAND``, or noise sigmas."""
        cfg = self.config
        if cfg.noise_deadband <= 0 or len(self._jitter) < 8:
            return DEADBAND
        return max(DEADBAND, cfg.noise_deadband * self.noise() * np.sqrt(1.5))

    def noise(self) -> float:
        """Standard deviation of a period's log O, from changes within blocks (0: < 8 seen)."""
        if len(self._jitter) < 8:
            return 0.0
        # median |difference of two periods| -> one period's standard deviation
        return 1.4826 * float(np.median(self._jitter)) / np.sqrt(2.0)


class TurnEvent(Enum):
    """What a period of a turn ended with (:meth:`BranchTurn.step`)."""

    NONE = ''
    ARRIVED = 'arrived'      # on the other branch; on trial
    KEPT = 'kept'            # the other branch was better: the turn stays
    RETURNED = 'returned'    # it was not: back on the branch it started from
    ABANDONED = 'abandoned'  # the pulse was going: back where it started


class TurnPhase(Enum):
    """Where a turn is (:meth:`BranchTurn.step`; its transitions: docs/architecture.md)."""

    IDLE = ''
    GO = 'go'          # turning toward the other branch
    VERIFY = 'verify'  # on the other branch, on trial
    BACK = 'back'      # retracing: the other branch was no better
    LOST = 'lost'      # retracing: the pulse was going on the way
    LANDED = 'landed'  # retracing: the pulse was going where it landed


ARRIVED, KEPT, RETURNED, ABANDONED = (TurnEvent.ARRIVED, TurnEvent.KEPT, TurnEvent.RETURNED,
                                      TurnEvent.ABANDONED)
#: Within this distance of K = 0 (K units) either way keeps the pulse; turns unwind the servos.
FREE_TURN = 0.06
#: Relative gain of O the new branch must bring to be kept.
BRANCH_GAIN = 0.005
#: Turn of all four angles per period of a branch turn [rad] (``turn_step.md``), and its periods.
TURN_STEP = 0.2
TURN_PERIODS = int(np.ceil(QUARTER_TURN / TURN_STEP - 1e-9))
#: Periods before the next turn after one turned back, given up or with no room (kept: none).
TURN_COOLDOWN = 100
#: Periods on trial after a turn; the median O of their later half decides.
VERIFY = 6


class BranchTurn:
    """A change of branch: all four angles turn a quarter turn in ``TURN_PERIODS`` periods as
    the curve parameter runs from ``u`` to ``-|u|`` (``on_curve(u)``: angles (4,) [rad]). Under
    ``turn_guard`` x the O before it retraces (next time the other way round); after ``VERIFY``
    periods it stays for ``BRANCH_GAIN`` more O, or if ``turn_curve(gain)`` turns the curve to
    make up the rest. With no room left the way that keeps the pulse, it goes the other: kept."""

    def __init__(self, turn_guard: float, limits: AngleLimits,
                 on_curve: Callable[[float], np.ndarray],
                 turn_curve: Callable[[float], bool] | None = None) -> None:
        self.turn_guard, self.limits = float(turn_guard), limits
        self.on_curve, self.turn_curve = on_curve, turn_curve
        self.direction = -1.0    # the way round that kept the pulse last
        # turns kept; given up because O fell (pulse going); taken back (the other no better)
        self.made = self.abandoned = self.rejected = 0
        self.wait = 0            # periods before the next turn may start
        self._path: list[np.ndarray] = []    # commands still to send
        self._issued: list[np.ndarray] = []  # commands of this turn sent so far
        self._from, self._before = np.zeros(4), 0.0  # the angles and O it started from
        self._way, self._forced = -1.0, False  # its way round; True: the kept way had no room
        self._phase = TurnPhase.IDLE
        self.landing = 0.0                   # curve point the turn under way lands at
        self._checked: list[float] = []      # O measured while verifying
        self.lost_landing = False  # the last turn lost the pulse where it landed (till kept)
        self.arrived = False       # the latest turn reached the other branch

    @property
    def busy(self) -> bool:
        return self._phase is not TurnPhase.IDLE

    def tick(self) -> None:
        """One period passed (the cooldown runs down)."""
        self.wait = max(self.wait - 1, 0)

    def cancel(self) -> None:
        """Something else took over: forget the turn under way."""
        self._phase, self._path = TurnPhase.IDLE, []

    def begin(self, current: np.ndarray, u: float, objective: float) -> bool:
        """Start a turn from ``current`` (4,) [rad] at ``u`` to ``-|u|``, from O ``objective``,
        first :attr:`direction` (near K = 0: toward mid-range); False (a wait) if none fits."""
        start = self.on_curve(u)
        self.landing = -abs(u)
        fractions = (np.arange(TURN_PERIODS) + 1) / TURN_PERIODS
        middle = 0.5 * (self.limits.low + self.limits.high)
        if abs(u) > FREE_TURN:
            ways: tuple[float, ...] = (self.direction, -self.direction)
        else:
            ways = tuple(sorted((-1.0, 1.0), key=lambda d: abs(
                np.mean(current) + d * QUARTER_TURN - middle)))
        for way in ways:
            path = [current + self.on_curve(u + (self.landing - u) * t) - start
                    + way * QUARTER_TURN * t for t in fractions]
            if all(np.all(a >= self.limits.low) and np.all(a <= self.limits.high) for a in path):
                self._forced = abs(u) > FREE_TURN and way != self.direction  # no room
                self._way, self._path, self._issued = way, path, []
                self._from = np.asarray(current, float)
                self._before = float(objective)
                self._phase, self.arrived = TurnPhase.GO, False
                return True
        self.wait = TURN_COOLDOWN
        return False

    def _retrace(self, phase: TurnPhase) -> None:
        """Retrace the turn's commands to its start, as ``phase`` (BACK, LOST or LANDED)."""
        self._phase, self._path = phase, self._issued[-2::-1] + [self._from]

    def _keep(self) -> tuple[None, TurnEvent]:
        """The new branch stays, no wait: its best O starts afresh (a fall is new evidence)."""
        self._phase, self.wait = TurnPhase.IDLE, 0
        self.made += 1
        self.lost_landing = False
        return None, KEPT

    def step(self, objective: float) -> tuple[np.ndarray | None, TurnEvent]:
        """This period's O -> the turn's command (None while verifying) and its event."""
        if self._phase is TurnPhase.VERIFY and self._forced:  # no way back worth taking
            return self._keep()
        if (self._phase is TurnPhase.VERIFY
                and not objective >= self.turn_guard * self._before):  # going where it landed
            self._retrace(TurnPhase.LANDED)
            self.lost_landing = True
        elif self._phase is TurnPhase.VERIFY:
            if np.isfinite(objective):
                self._checked.append(float(objective))
            if len(self._checked) < VERIFY:
                return None, TurnEvent.NONE
            level = float(np.median(self._checked[-max(1, VERIFY // 2):]))  # settled half
            wanted = (1 + BRANCH_GAIN) * self._before
            if level >= wanted or (self.turn_curve is not None and level > 0
                                   and self.turn_curve(float(np.log(wanted / level)))):
                return self._keep()
            self._retrace(TurnPhase.BACK)
        elif (self._phase is TurnPhase.GO and self._issued and not self._forced
              and not objective >= self.turn_guard * self._before):  # the pulse is going
            self._retrace(TurnPhase.LOST)
        command = self._path.pop(0)
        self._issued.append(command)
        if self._path:
            return command, TurnEvent.NONE
        if self._phase is TurnPhase.GO:
            self._phase, self._checked, self.arrived = TurnPhase.VERIFY, [], True
            return command, ARRIVED
        event = RETURNED if self._phase is TurnPhase.BACK else ABANDONED
        if event == ABANDONED:
            self.abandoned += 1
            if self._phase is TurnPhase.LOST and self._way == self.direction:
                self.direction = -self._way  # the other way round next time
        else:
            self.rejected += 1
        self._phase, self.wait = TurnPhase.IDLE, TURN_COOLDOWN
        return command, event
