"""How each node is doing, as a diagnostic level, a one-line message and key/values
(no ROS here: the nodes hand in what they count, :mod:`dlmpc_ros.ros.diagnostics`
publishes it on ``/diagnostics`` once a second).

Levels mean one thing everywhere:

- ``OK``: the node does its job;
- ``WARN``: it works, but something needs a look: messages dropped as malformed, an input
  it can do without is silent (the controller's estimator), a lockstep timeout, a field
  reset after a blow-up, or it is still waiting for its first input;
- ``ERROR``: it cannot do its job: the simulation stopped, or the laser it controls or
  estimates went silent after it had been heard.

The keys of every node are listed in ``docs/interfaces.md``.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from dlmpc_ros.interfaces import RateLimitedLog

OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = ('OK', 'WARN', 'ERROR')
#: An input heard before and silent for longer than this is silent [s].
SILENT_AFTER = 2.0
#: A node may wait this long for its first input before it says so [s].
FIRST_INPUT_GRACE = 10.0


@dataclass(frozen=True)
class Health:
    """One node's status: ``level`` (OK, WARN, ERROR), ``message`` (the problems, or
    what it is doing) and ``values`` (key, text) pairs."""

    level: int
    message: str
    values: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        if self.level not in (OK, WARN, ERROR):
            raise ValueError(f'Health.level must be OK, WARN or ERROR, got {self.level}')

    def value(self, key: str) -> str:
        return dict(self.values)[key]


@dataclass
class Findings:
    """Problems found so far (errors and warnings) and the values to report."""

    values: dict[str, object] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def health(self, doing: str) -> Health:
        """ERROR with the errors, else WARN with the warnings, else OK with ``doing``."""
        level = ERROR if self.errors else WARN if self.warnings else OK
        message = '; '.join(self.errors or self.warnings) or doing
        return Health(level, message, tuple((k, _text(v)) for k, v in self.values.items()))

    def new_drops(self, window: CounterWindow, log: RateLimitedLog) -> None:
        """Report the messages ``log`` dropped as malformed (per topic, with the last
        reason) and warn about those dropped since the last report."""
        dropped, reasons = dict(log.dropped_counts), dict(log.last_fault)
        fresh = window.delta({f'dropped {t}': n for t, n in dropped.items()})
        self.values['messages_dropped'] = sum(dropped.values())
        for topic in sorted(dropped):
            if fresh.get(f'dropped {topic}'):
                self.warnings.append(f"{fresh[f'dropped {topic}']} malformed messages on "
                                     f'{topic} dropped ({reasons.get(topic, "?")})')

    def input(self, topic: str, last_heard: float | None, started: float, now: float,
              silent_level: int = ERROR) -> None:
        """Judge an input topic by when it was last heard (monotonic s; None: never)."""
        if last_heard is None:
            self.values[f'{topic} age_s'] = 'never'
            if now - started > FIRST_INPUT_GRACE:
                self.warnings.append(f'waiting for {topic} ({now - started:.0f} s so far)')
            return
        age = now - last_heard
        self.values[f'{topic} age_s'] = age
        if age > SILENT_AFTER:
            text = f'no {topic} for {age:.1f} s'
            (self.errors if silent_level == ERROR else self.warnings).append(text)


class CounterWindow:
    """Growth of counters between two reports (a counter seen first grows from 0)."""

    def __init__(self) -> None:
        self._last: dict[str, int] = {}

    def delta(self, counts: Mapping[str, int]) -> dict[str, int]:
        out = {k: int(v) - self._last.get(k, 0) for k, v in counts.items()}
        self._last.update({k: int(v) for k, v in counts.items()})
        return out


def laser_health(findings: Findings, window: CounterWindow, round_trip: int,
                 rate_hz: float, counts: Mapping[str, int], running: bool) -> Health:
    """laser_sim (or a driver): its counters (``interfaces.LASER_STATUS_FIELDS[2:]``)."""
    findings.values.update(round_trip=round_trip, rate_hz=rate_hz, **counts)
    fresh = window.delta(counts)
    if not running:
        findings.errors.append(f'the simulation stopped at round trip {round_trip}')
    if fresh.get('resets'):
        findings.warnings.append(f"{fresh['resets']} field resets after a blow-up")
    if fresh.get('lockstep_timeouts'):
        findings.warnings.append(f"{fresh['lockstep_timeouts']} lockstep timeouts")
    return findings.health(f'round trip {round_trip} at {rate_hz:.0f} round trips/s')


def controller_health(findings: Findings, mode: str | None, objective: float | None,
                      lock_threshold: float | None, commands: int,
                      estimate_age_periods: float | None, uses_estimator: bool,
                      recent_modes: Sequence[str] = ()) -> Health:
    """A controller node: its last mode, the share of each mode in its ``recent_modes``
    (the modes of its latest decisions, so that a laser that keeps losing its pulse shows),
    the measured O against its lock threshold (when it has one), commands published, and
    the age of the estimate it last used."""
    findings.values.update(mode=mode or 'none yet', commands_published=commands)
    if recent_modes:
        counts = Counter(recent_modes)
        findings.values[f'modes_last_{len(recent_modes)}_decisions'] = ', '.join(
            f'{m} {100 * n / len(recent_modes):.0f} %' for m, n in counts.most_common())
    if objective is not None:
        findings.values['objective'] = objective
    if lock_threshold is not None and objective is not None:
        locked = math.isfinite(objective) and objective >= lock_threshold
        findings.values.update(lock_threshold=lock_threshold, locked=locked)
        if not locked:
            findings.warnings.append(f'not mode-locked (O = {objective:.4g} below '
                                     f'{lock_threshold:.4g}); mode {mode}')
    if uses_estimator:
        findings.values['estimate_age_periods'] = ('none yet' if estimate_age_periods is None
                                                   else estimate_age_periods)
    doing = f'mode {mode}, {commands} commands' if mode else 'waiting for the first period'
    return findings.health(doing)


class SettleWatch:
    """How fast a controller's commands are reached: the settle times [round trips] of
    its latest moves, and the decisions it had to make before its servos settled."""

    def __init__(self, keep: int = 50) -> None:
        self.times: deque[int] = deque(maxlen=keep)
        self.unsettled = 0
        self._window = CounterWindow()

    def add(self, settled: bool, settle_round_trips: int | None) -> None:
        """One decision: whether its measurement was settled, and the settle time of the
        command before it (None: it did not move the servos, or was not reached)."""
        if settle_round_trips is not None:
            self.times.append(settle_round_trips)
        self.unsettled += not settled

    def report(self, findings: Findings, timeout: int, tolerance: float) -> None:
        """Add the settle times to ``findings``; warn about decisions made unsettled
        since the last report, with the measured settle time and what to set."""
        median = float(sorted(self.times)[len(self.times) // 2]) if self.times else None
        longest = max(self.times) if self.times else None
        findings.values.update(
            settle_round_trips_median='none yet' if median is None else median,
            settle_round_trips_max='none yet' if longest is None else longest,
            decisions_unsettled=self.unsettled)
        fresh = self._window.delta({'unsettled': self.unsettled})['unsettled']
        if fresh:
            measured = ('no command was reached yet' if median is None else
                        f'commands were reached after {median:g} round trips (median), '
                        f'{longest} at most')
            findings.warnings.append(
                f'{fresh} decisions made before the servos reached the command within '
                f'settle_timeout = {timeout} round trips ({measured}); set settle_timeout '
                f'above the settle time, or settle_tolerance above the encoder\'s noise if '
                f'the reported angles scatter more than {tolerance:g} rad')


def _text(value: object) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return f'{value:.6g}'
    return str(value)
