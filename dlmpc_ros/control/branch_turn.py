"""The curve tracker's change of branch: from the tracking curve to its mirror twin and back.

The twin of the curve, ``c(-s) + pi/2`` (:mod:`dlmpc_ros.core.symmetry`), is as good at K
as the curve is at -K. A :class:`BranchTurn` takes the laser from one to the other
without losing the pulse: over ``ceil(pi/2 / TURN_STEP)`` periods all four angles turn
together by a quarter turn while the curve parameter runs from the point ``u`` the
tracker is at to ``-|u|``, on the curve's good side (K < 0). On the nominal cavity the
estimate follows K, and a tracker past the margin on the wrong side (``u > 0``) lands at
the mirror image of its point, keeping its estimate; on other lasers the best point
often sits at the end of the curve whatever K is, and a tracker there (``u < 0``) keeps
its point and only turns. Measured on the simulator (nominal cavity and family plants 2
and 6): the first keeps the pulse at every K up to |K| = 0.3 (O never under 0.73 of its
start), the second up to |K| = 0.15 from the good side (O over 0.92 of its start); both
end 2 to 14 % higher where the twin is the better branch. At K = 0, where the fiber is
isotropic, the turn is an exact symmetry.

Two checks make it safe on a laser that is not the simulator:

- turning one way keeps the pulse, the other way loses it for |K| > 0.1 on the
  simulator, and a real laser's sign conventions are not known: if O falls under
  ``turn_guard`` x its O before the turn, the turn goes back the way it came and the
  other way is tried next time (near K = 0, within ``FREE_TURN``, either way keeps the
  pulse and the turn goes the way that brings the servos back toward the middle of their
  range);
- the turn is a trial: ``VERIFY`` periods after it, O is compared with O before it, and
  unless the new branch gives ``BRANCH_GAIN`` more, the laser is turned back (at once
  if O falls under ``turn_guard`` x its O before the turn while
  it is on trial: a pulse that held on the way can still die where it lands).
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
#: Within this distance of K = 0 (K units) both ways round keep the pulse; a turn there
#: goes the way that unwinds the servos toward the middle of their range.
FREE_TURN = 0.06
#: Relative gain of O the new branch must bring to be kept.
BRANCH_GAIN = 0.005
#: Turn of all four angles per period while changing branch [rad] (at most the servo
#: speed).
TURN_STEP = 0.2
#: Periods after a turn (made or given up) before the next may start.
TURN_COOLDOWN = 100
#: Periods after a turn; the median O of their later half decides whether the new branch
#: is kept.
VERIFY = 6


class BranchTurn:
    """A change of branch under way, and what earlier ones taught.

    ``turn_guard`` is the tracker's (:class:`~dlmpc_ros.control.tracking.TrackingConfig`);
    ``on_curve(u)`` gives the curve's angles (4,) [rad] at ``u`` (with any learned
    rotation)."""

    def __init__(self, turn_guard: float, limits: AngleLimits,
                 on_curve: Callable[[float], np.ndarray]) -> None:
        self.turn_guard = float(turn_guard)
        self.limits = limits
        self.on_curve = on_curve
        self.direction = -1.0    # the way round that kept the pulse last
        self.made = 0            # turns kept
        self.abandoned = 0       # turns given up because O fell (pulse going)
        self.rejected = 0        # turns taken back because the other branch was no better
        self.blocked = 0         # turns the servo limits did not allow
        self.wait = 0            # periods before the next turn may start
        self._path: list[np.ndarray] = []    # commands still to send
        self._issued: list[np.ndarray] = []  # commands of this turn sent so far
        self._from = np.zeros(4)             # the angles it started from
        self._before = 0.0                   # O just before it
        self._way = -1.0
        self._phase = TurnPhase.IDLE
        self.landing = 0.0                   # curve point the turn under way lands at
        self._checked: list[float] = []      # O measured while verifying
        #: the last turn ended with the pulse going where it landed (until one is kept)
        self.lost_landing = False

    @property
    def busy(self) -> bool:
        return self._phase is not TurnPhase.IDLE

    def tick(self) -> None:
        """One period passed (the cooldown runs down)."""
        if self.wait > 0:
            self.wait -= 1

    def cancel(self) -> None:
        """Something else took over: forget the turn under way."""
        self._phase, self._path = TurnPhase.IDLE, []

    def begin(self, current: np.ndarray, u: float, objective: float) -> bool:
        """Start a turn from the angles ``current`` (4,) [rad] at curve point ``u``, with
        ``objective`` the O before it (what its guard and verification judge by); False
        (and a cooldown) if no way round stays inside the limits. The turn lands at the
        curve point :attr:`landing` (``-|u|``).

        Every turn goes in the same direction, so turns one after the other wind the
        servos toward an end of their range. A turn near K = 0 (``|u| <= FREE_TURN``)
        goes the way that brings them back toward the middle first, any other the way that
        kept the pulse last first; the other way is the fallback where the first leaves
        the range."""
        steps = int(np.ceil(QUARTER_TURN / TURN_STEP - 1e-9))
        start = self.on_curve(u)
        self.landing = -abs(u)
        fractions = (np.arange(steps) + 1) / steps
        middle = 0.5 * (self.limits.low + self.limits.high)
        if abs(u) > FREE_TURN:
            ways: tuple[float, ...] = (self.direction, -self.direction)
        else:
            ways = tuple(sorted((-1.0, 1.0), key=lambda d: abs(
                np.mean(current) + d * QUARTER_TURN - middle)))
        for way in ways:
            path = [current + self.on_curve(u + (self.landing - u) * t) - start
                    + way * QUARTER_TURN * t for t in fractions]
            if all(np.all(a >= self.limits.low) and np.all(a <= self.limits.high)
                   for a in path):
                self._way, self._path, self._issued = way, path, []
                self._from = np.asarray(current, float)
                self._before = float(objective)
                self._phase = TurnPhase.GO
                return True
        self.blocked += 1
        self.wait = TURN_COOLDOWN
        return False

    def _retrace(self, phase: TurnPhase) -> None:
        """Go back the way the turn came (its commands so far in reverse, then the angles
        it started from), as ``phase``: BACK (no better), LOST or LANDED (the pulse going
        on the way or where it landed)."""
        self._phase, self._path = phase, self._issued[-2::-1] + [self._from]

    def step(self, objective: float) -> tuple[np.ndarray | None, TurnEvent]:
        """This period's O -> the command of the turn (None while verifying: the tracker
        holds the new branch's point) and what the period ended with."""
        if (self._phase is TurnPhase.VERIFY
                and not objective >= self.turn_guard * self._before):  # going where it landed
            self._retrace(TurnPhase.LANDED)
            self.lost_landing = True
        elif self._phase is TurnPhase.VERIFY:
            if np.isfinite(objective):
                self._checked.append(float(objective))
            if len(self._checked) < VERIFY:
                return None, TurnEvent.NONE
            settled = self._checked[-max(1, VERIFY // 2):]  # the later half: settled
            if np.median(settled) >= (1 + BRANCH_GAIN) * self._before:
                self._phase, self.wait = TurnPhase.IDLE, TURN_COOLDOWN
                self.made += 1
                self.lost_landing = False
                return None, KEPT
            self._retrace(TurnPhase.BACK)
        elif (self._phase is TurnPhase.GO and self._issued
              and not objective >= self.turn_guard * self._before):  # the pulse is going
            self._retrace(TurnPhase.LOST)
        command = self._path.pop(0)
        self._issued.append(command)
        if self._path:
            return command, TurnEvent.NONE
        if self._phase is TurnPhase.GO:
            self._phase, self._checked = TurnPhase.VERIFY, []
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
