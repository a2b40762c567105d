"""The curve tracker's change of branch: from the tracking curve to its mirror twin and back.

The twin ``c(-s) + pi/2`` (:mod:`dlmpc_ros.core.symmetry`) is as good at K as the curve at
-K. A :class:`BranchTurn` turns all four angles a quarter turn over ``TURN_PERIODS`` periods
while the curve parameter runs from ``u`` to ``-|u|``. Under ``turn_guard`` x the O before,
it retraces and next time goes the other way round (within ``FREE_TURN`` of K = 0: toward
mid-range first); after ``VERIFY`` periods on trial it stays for ``BRANCH_GAIN`` more O, or
where ``turn_curve`` (the tracker's planner) turns the curve to make up what is short. Far
from K = 0 the one way that keeps the pulse winds the servos to an end: with no room left
that way, a turn goes the other and never retraces (the scan centres the servos).
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum

import numpy as np

from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.core.symmetry import QUARTER_TURN


class TurnEvent(Enum):
    """What a period of a turn ended with (:meth:`BranchTurn.step`)."""

    NONE = ''
    ARRIVED = 'arrived'      # on the other branch; on trial
    KEPT = 'kept'            # the other branch was better: the turn stays
    RETURNED = 'returned'    # it was not: back on the branch it started from
    ABANDONED = 'abandoned'  # the pulse was going: back where it started


class TurnPhase(Enum):
    """Where a turn is. Transitions (:meth:`BranchTurn.step`): IDLE -> GO (begin);
    GO -> VERIFY (arrived), GO -> LOST (O under the turn guard on the way); VERIFY ->
    IDLE (kept), VERIFY -> BACK (no better), VERIFY -> LANDED (O under the turn guard
    where it landed); BACK, LOST, LANDED -> IDLE once back; any -> IDLE (cancel)."""

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
#: Turn of all four angles per period while changing branch [rad] (<= the servo speed; 0.1
#: lost O, 0.25 measured nothing, ``bench/results/turn_step.md``), and the periods a turn takes.
TURN_STEP = 0.2
TURN_PERIODS = int(np.ceil(QUARTER_TURN / TURN_STEP - 1e-9))
#: Periods after a turn (made or given up) before the next may start.
TURN_COOLDOWN = 100
#: Periods on trial after a turn; the median O of their later half decides.
VERIFY = 6


class BranchTurn:
    """A change of branch under way, and what earlier ones taught.

    ``turn_guard``: the tracker's (:class:`~dlmpc_ros.control.dlmpc_config.TrackingConfig`);
    ``on_curve(u)``: the curve's angles (4,) [rad] at ``u`` (with any learned rotation);
    ``turn_curve(gain)``: turns the curve where the turn is expected to gain that much log O
    (whether it did; None: never)."""

    def __init__(self, turn_guard: float, limits: AngleLimits,
                 on_curve: Callable[[float], np.ndarray],
                 turn_curve: Callable[[float], bool] | None = None) -> None:
        self.turn_guard = float(turn_guard)
        self.limits = limits
        self.on_curve = on_curve
        self.turn_curve = turn_curve
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
        """Start a turn from ``current`` (4,) [rad] at curve point ``u`` to :attr:`landing`
        (``-|u|``), ``objective`` the O before it; False (and a cooldown) if no way round
        fits the limits. Tries first :attr:`direction` (within ``FREE_TURN``: toward mid-range)."""
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
        """The new branch stays."""
        self._phase, self.wait = TurnPhase.IDLE, TURN_COOLDOWN
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
