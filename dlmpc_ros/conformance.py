"""Conformance of a laser node (the simulator or a hardware driver) with docs/interfaces.md.

The functional core of ``dlmpc-check-laser``, without rclpy: the command-line tool records
what arrives on the laser's topics and what it sent; the functions here make the test
commands and judge the records. Times in seconds, angles in radians. Each check returns a
:class:`CheckResult` whose status is FAIL when it found a problem, WARN when it found only
something worth a look, else PASS (SKIP when it was not run).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import SETTLE_TIMEOUT, SETTLE_TOLERANCE, AngleLimits

PASS, WARN, FAIL, SKIP = 'PASS', 'WARN', 'FAIL', 'SKIP'
STATE_LABEL = ','.join(itf.STATE_FIELDS)
STATUS_LABEL = ','.join(itf.LASER_STATUS_FIELDS)
ANGLES = slice(itf.STATE_FIELDS.index('alpha1'), itf.STATE_FIELDS.index('alpha_p') + 1)
_E, _M, _O = (itf.STATE_FIELDS.index(name) for name in ('E', 'M', 'O'))
_ENERGY = itf.STATE_FIELDS.index('energy')


@dataclass(frozen=True)
class Settings:
    """Pass criteria of the checks (the options of ``dlmpc-check-laser``)."""

    duration: float = 5.0
    """Window over which the state stream is measured [s]."""
    period: int = 10
    """Control period P [round trips]: the least time between the controllers' decisions
    (how long the check holds each command)."""
    min_rate: float = 10.0
    """Fewest /laser/state messages per second."""
    max_gap: float = 0.5
    """Longest time without a /laser/state message [s] (the controllers wait 0.5 s for an
    estimate)."""
    steadiness: float = 0.5
    """In every fifth of the window the message rate must reach this fraction of the mean."""
    tolerance: float = SETTLE_TOLERANCE
    """A state angle has reached its command when within this [rad] (the controllers'
    ``settle_tolerance``)."""
    max_round_trips: int = SETTLE_TIMEOUT
    """A command must show in the state within this many round trips (the controllers'
    ``settle_timeout``: a decision waits this long for its command)."""
    step: float = AngleLimits.max_step
    """Angle change of the full test commands [rad] (the controllers' ``max_step``; every
    other command moves half of it)."""
    angle_limit: float = 2 * math.pi
    """Interface range of an angle command [rad]: a larger |alpha| is malformed."""
    objective_tolerance: float = 1e-6
    """Relative tolerance of O = E / M and of /laser/objective against the state's O."""
    status_timeout: float = 2.0
    """/laser/status must arrive at least once per this many seconds."""
    status_required: bool = True
    """False: a laser without /laser/status gets a WARN instead of a FAIL."""


@dataclass(frozen=True)
class Sample:
    """One received message."""

    received: float
    """Reception time, monotonic clock [s]."""
    sent: float
    """The publisher's source timestamp [s] (reception time where the middleware gives
    none); only differences of it are used."""
    data: tuple[float, ...]
    label: str = ''
    """Label of the layout's first dimension ('' when the layout has none)."""
    sequence: int = 0
    """Publication sequence number of the publisher (0: unknown)."""

    @property
    def valid_state(self) -> bool:
        """A usable /laser/state vector (length, finite, round trip a count)."""
        return itf.state_fault(self.data) is None

    @property
    def angles(self) -> np.ndarray:
        """The state's alpha1, alpha2, alpha3, alpha_p [rad]."""
        return np.array(self.data[ANGLES], float)


@dataclass
class CommandTrial:
    """One valid angle command the checker sent and the states that followed it."""

    target: tuple[float, ...]
    """The commanded alpha1, alpha2, alpha3, alpha_p [rad]."""
    sent_round_trip: int
    """Round trip of the newest state received when the command was published."""
    sent_at: float
    """Monotonic time of publishing [s]."""
    states: list[Sample] = field(default_factory=list)
    """States received after publishing, until the next command."""
    purpose: str = 'test'


@dataclass
class CheckResult:
    """Outcome of one check: status, a one-line summary with figures, what went wrong."""

    key: str
    name: str
    status: str
    summary: str
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    figures: dict[str, float] = field(default_factory=dict)


def _result(key: str, name: str, summary: str, problems: list[str],
            notes: list[str] | None = None, figures: dict[str, float] | None = None,
            missing_is: str = FAIL) -> CheckResult:
    status = missing_is if problems else (WARN if notes else PASS)
    return CheckResult(key, name, status, summary, problems, notes or [], figures or {})


def fmt_angles(angles: Sequence[float]) -> str:
    """Angles as ``[a, b, c, d]`` with 4 decimals (non-finite values as written)."""
    return '[' + ', '.join(f'{a:.4f}' if math.isfinite(a) else str(a) for a in angles) + ']'


def reached(sample: Sample, target: Sequence[float], tolerance: float) -> bool:
    """True when a valid state's angles are all within ``tolerance`` of ``target``."""
    return sample.valid_state and bool(
        np.all(np.abs(sample.angles - np.asarray(target, float)) <= tolerance))


def _away_from_limits(angles: np.ndarray) -> np.ndarray:
    """+1 or -1 per angle: the direction towards 0 (test commands stay inside the range)."""
    return np.where(angles > 0, -1.0, 1.0)


def command_targets(angles: Sequence[float], step: float, count: int) -> list[tuple[float, ...]]:
    """Test commands from the laser's current angles: every angle moves towards 0 by
    ``step``, then ``step / 2``, alternately, ``count`` commands in all."""
    start = np.asarray(angles, float)
    direction = _away_from_limits(start)
    return [tuple(start + direction * step * (1.0 if k % 2 == 0 else 0.5))
            for k in range(count)]


def malformed_commands(angles: Sequence[float], step: float,
                       limit: float) -> list[tuple[str, list[float]]]:
    """Malformed /laser/angles_cmd vectors to send while the laser is at ``angles``.

    The finite, in-range values of the k-th message differ from ``angles`` by its own
    offset, so a laser that applied part of a message shows which one it was.
    """
    base = np.asarray(angles, float)
    direction = _away_from_limits(base)
    cases = [('empty', None), ('3 values', 3), ('5 values', 5), ('NaN', math.nan),
             ('+inf', math.inf), ('-inf', -math.inf), ('1e308', 1e308),
             ('above the range', limit + 1.0), ('below the range', -(limit + 1.0))]
    out = []
    for k, (name, bad) in enumerate(cases):
        good = list(base + direction * step * (k + 2) / 10)
        if bad is None:
            data: list[float] = []
        elif name.endswith('values'):
            data = (good + [0.0])[:int(bad)]
        else:
            data = good
            data[k % 4] = float(bad)
        out.append((name, data))
    return out


def _gaps(times: Sequence[float], start: float, end: float) -> float:
    """Longest interval between consecutive times, the window edges included [s]."""
    edges = np.r_[start, np.sort(np.asarray(times, float)), end]
    return float(np.diff(edges).max()) if edges.size > 1 else end - start


def _stream_gap(samples: Sequence[Sample], start: float, end: float) -> float:
    """Longest time without a message [s]: between two messages by the publisher's clock
    (a reader here that was late does not count), before the first and after the last by
    the reception clock (a stream that stopped does)."""
    if not samples:
        return end - start
    inner = np.diff([x.sent for x in samples]).max(initial=0.0)
    return float(max(inner, samples[0].received - start, end - samples[-1].received))


def _layout_problems(messages: Sequence, label: str, faults: Sequence[str | None],
                     what: str = 'messages') -> list[str]:
    """Problems with received messages' layout labels (expected ``label``) and contents
    (``faults``: one :func:`~dlmpc_ros.interfaces.vector_fault`-style entry per message)."""
    n = len(messages)
    problems = []
    labels = [x.label for x in messages if x.label != label]
    if labels:
        problems.append(f'{len(labels)} of {n} {what} have the layout label {labels[0]!r}; '
                        f'expected {label!r}')
    found = [f for f in faults if f is not None]
    if found:
        problems.append(f'{len(found)} of {n} {what} are malformed (first: {found[0]})')
    return problems


def _round_trip_problems(states: Sequence[Sample]) -> list[str]:
    """Round trips that do not increase (numbers may be skipped: a decision comes once the
    reported round trips at its command span the round trips its measurement averages)."""
    problems = []
    rts = np.array([s.data[0] for s in states if s.data and math.isfinite(s.data[0])])
    steps = np.diff(rts)
    back = np.flatnonzero(steps <= 0)
    if back.size:
        i = back[0]
        problems.append(f'round_trip did not increase {back.size} times '
                        f'(first: {rts[i]:g} then {rts[i + 1]:g})')
    return problems


def check_state_stream(states: Sequence[Sample], start: float, end: float, s: Settings,
                       publishers: int = 1, reliable: bool | None = True) -> CheckResult:
    """(a) /laser/state: layout, values, round trips, rate and its steadiness.

    Parameters
    ----------
    states
        Every state message received in the window ``[start, end]`` (monotonic seconds).
    publishers
        Number of publishers of /laser/state on the domain.
    reliable
        Whether their QoS is reliable (None: unknown).
    """
    key, name = 'a', 'state stream'
    problems: list[str] = []
    notes: list[str] = []
    if publishers != 1:
        problems.append(f'{publishers} nodes publish /laser/state; expected one laser')
    if reliable is False:
        problems.append('/laser/state is published best effort; the interface is reliable')
    n = len(states)
    if n < 2:
        return _result(key, name, f'{n} messages in {end - start:.1f} s',
                       [*problems, f'only {n} /laser/state messages in {end - start:.1f} s'])
    problems += _layout_problems(states, STATE_LABEL,
                                 [itf.state_fault(x.data) for x in states])
    problems += _round_trip_problems(states)
    sent = np.array([x.sent for x in states])
    intervals = np.diff(sent)
    span = max(float(sent[-1] - sent[0]), 1e-9)
    rate = (n - 1) / span
    rts = [x.data[0] for x in states if x.data and math.isfinite(x.data[0])]
    rt_rate = (rts[-1] - rts[0]) / span if len(rts) > 1 else math.nan
    jitter = float(intervals.std())
    max_gap = _stream_gap(states, start, end)
    bins = np.histogram(sent, bins=5, range=(sent[0], sent[0] + span))[0]
    bin_rates = bins / (span / 5)
    mean_rate = n / span
    if rate < s.min_rate:
        problems.append(f'{rate:.1f} messages/s is below --min-rate {s.min_rate:g}')
    if max_gap > s.max_gap:
        problems.append(f'no /laser/state for {max_gap:.3f} s (more than --max-gap '
                        f'{s.max_gap:g} s)')
    if bin_rates.min() < s.steadiness * mean_rate:
        problems.append(f'not steady: {bin_rates.min():.1f} messages/s in one fifth of the '
                        f'window against {mean_rate:.1f}/s on average')
    seq = np.array([x.sequence for x in states])
    lost = 0
    if publishers == 1 and seq.all():
        lost = int(np.sum(np.clip(np.diff(seq) - 1, 0, None)))
        if lost:
            notes.append(f'{lost} messages published but not received (sequence numbers): '
                         'a slow reader here, or a publisher history shorter than the '
                         'interface depth')
    step_text = 'round_trip +1 each' if rts and np.all(np.diff(rts) == 1) else \
        f'round_trip steps {min(np.diff(rts), default=0):g}..{max(np.diff(rts), default=0):g}'
    p99 = float(np.percentile(intervals, 99))
    summary = (f'{rate:.1f} msg/s ({rt_rate:.1f} RT/s), interval {1e3 * intervals.mean():.2f}'
               f' ms (p99 {1e3 * p99:.2f}, max {1e3 * intervals.max():.1f}), jitter (std) '
               f'{1e3 * jitter:.2f} ms, max gap {1e3 * max_gap:.1f} ms, {n} messages, '
               f'{step_text}')
    figures = {'messages': n, 'rate_hz': rate, 'round_trips_per_s': rt_rate,
               'interval_ms': 1e3 * float(intervals.mean()), 'jitter_ms': 1e3 * jitter,
               'interval_p99_ms': 1e3 * p99, 'max_interval_ms': 1e3 * float(intervals.max()),
               'max_gap_ms': 1e3 * max_gap, 'min_bin_rate_hz': float(bin_rates.min()),
               'lost': lost}
    return _result(key, name, summary, problems, notes, figures)


def check_objective(states: Sequence[Sample], objectives: Sequence[Sample],
                    s: Settings) -> CheckResult:
    """(b) O = E / M in every state, E >= 0, M >= 1, and /laser/objective carries the
    states' O (one message per state)."""
    key, name = 'b', 'objective'
    problems: list[str] = []
    notes: list[str] = []
    valid = np.array([x.data for x in states if x.valid_state])
    if valid.size == 0:
        return _result(key, name, 'no valid state', ['no valid /laser/state to compare with'])
    e, m, o = valid[:, _E], valid[:, _M], valid[:, _O]
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = e / m
        error = np.abs(o - ratio) / np.maximum(np.abs(ratio), 1e-300)
    error = np.where(np.isfinite(error), error, np.inf)
    bad = int(np.sum(error > s.objective_tolerance))
    if bad:
        problems.append(f'{bad} of {len(o)} states have O != E/M (largest relative error '
                        f'{error.max():.2g})')
    if np.any(e < 0):
        problems.append(f'{int(np.sum(e < 0))} states have E < 0')
    if np.any(m < 1):
        problems.append(f'{int(np.sum(m < 1))} states have M < 1 (a kurtosis is at least 1)')
    energy = valid[:, _ENERGY]
    off = np.abs(energy - e ** 2) > s.objective_tolerance * np.maximum(energy, 1e-300)
    if np.any(off):
        notes.append(f'{int(off.sum())} states have energy != E^2 (the model has E = '
                     'sqrt(energy))')
    n = len(objectives)
    matched = 0
    if n == 0:
        problems.append('no /laser/objective message')
    else:
        problems += _layout_problems(
            objectives, 'O', [itf.vector_fault(x.data, itf.OBJECTIVE_FIELDS, 1e300)
                              for x in objectives], 'objective messages')
        values = np.array([x.data[0] for x in objectives if len(x.data) == 1])
        known = np.sort(o)
        if values.size:
            where = np.clip(np.searchsorted(known, values), 1, max(known.size - 1, 1))
            near = np.minimum(np.abs(known[where - 1] - values),
                              np.abs(known[np.minimum(where, known.size - 1)] - values))
            matched = int(np.sum(near <= s.objective_tolerance * np.abs(values)))
        if matched < 0.95 * n or not 0.9 <= n / len(o) <= 1.1:
            problems.append(f'{matched} of {n} objective values equal the O of a state, for '
                            f'{len(o)} states (expected one objective per state)')
    summary = (f'O = E/M in {len(o) - bad}/{len(o)} states (max rel err {error.max():.1g}), '
               f'{matched}/{n} /laser/objective values match')
    figures = {'states': len(o), 'max_relative_error': float(error.max()),
               'objectives': n, 'objectives_matched': matched}
    return _result(key, name, summary, problems, notes, figures)


def settle(trial: CommandTrial, tolerance: float) -> int | None:
    """Index of the first state of ``trial`` at its target, or None."""
    return next((i for i, x in enumerate(trial.states) if reached(x, trial.target, tolerance)),
                None)


def check_commands(trials: Sequence[CommandTrial], s: Settings, reason: str = '',
                   reliable: bool | None = True) -> CheckResult:
    """(c) Every command shows in the state within ``tolerance`` and ``max_round_trips``,
    and the angles stay there until the next command.

    Parameters
    ----------
    reason
        Why no command could be sent (FAIL), when ``trials`` is empty.
    reliable
        Whether the laser's subscription of /laser/angles_cmd is reliable (None: unknown).
    """
    key, name = 'c', 'angle commands'
    if not trials:
        return _result(key, name, 'no command sent', [reason or 'no command sent'])
    problems: list[str] = []
    if reliable is False:
        problems.append('the laser subscribes /laser/angles_cmd best effort; the interface '
                        'is reliable')
    rts, times, full = [], [], []
    for i, trial in enumerate(trials, 1):
        what = f'command {i} ({trial.purpose}) {fmt_angles(trial.target)}'
        at = settle(trial, s.tolerance)
        if at is None:
            last = next((x for x in reversed(trial.states) if x.valid_state), None)
            seen = 'no valid state' if last is None else \
                f'angles {fmt_angles(last.angles)} at round trip {last.data[0]:g}'
            problems.append(f'{what} not reached within {s.tolerance:g} rad after '
                            f'{len(trial.states)} states: {seen}')
            continue
        state = trial.states[at]
        rts.append(int(state.data[0]) - trial.sent_round_trip)
        times.append(state.received - trial.sent_at)
        if rts[-1] > s.max_round_trips:
            pace = rts[-1] / max(times[-1], 1e-9)
            problems.append(f'{what} took {rts[-1]} round trips (more than '
                            f'--max-round-trips {s.max_round_trips}), {1e3 * times[-1]:.1f} ms '
                            f'at {pace:.0f} round trips/s: the controllers would decide '
                            f'before it is reached; set their settle_timeout above '
                            f'{rts[-1]} (bringup --controller-param settle_timeout='
                            f'{2 * rts[-1]}) and --max-round-trips here alike, or lower '
                            f'their max_step')
        left = next((x for x in trial.states[at:]
                     if x.valid_state and not reached(x, trial.target, s.tolerance)), None)
        if left is not None:
            problems.append(f'{what}: the angles left the command after reaching it '
                            f'(round trip {left.data[0]:g}: {fmt_angles(left.data[ANGLES])}); '
                            f'if the encoder reports them scattered, set the controllers\' '
                            f'settle_tolerance (and --tolerance here) above the scatter')
        if trial.purpose == 'full step':
            full.append(rts[-1])
    summary = f'{len(rts)}/{len(trials)} commands reached within {s.tolerance:g} rad'
    figures: dict[str, float] = {'commands': len(trials), 'reached': len(rts)}
    if full:
        summary += f'; a full step ({s.step:g} rad) settles in {max(full)} round trips'
        figures['full_step_settle_round_trips'] = max(full)
    if rts:
        summary += (f', all in {min(rts)}..{max(rts)} round trips (limit '
                    f'{s.max_round_trips}), {1e3 * min(times):.1f}..{1e3 * max(times):.1f} ms')
        figures.update(settle_round_trips_min=min(rts), settle_round_trips_max=max(rts),
                       settle_round_trips_median=float(np.median(rts)),
                       settle_ms_max=1e3 * max(times))
    return _result(key, name, summary, problems, figures=figures)


def check_malformed(sent: Sequence[tuple[str, Sequence[float]]], before: Sequence[float],
                    states: Sequence[Sample], start: float, end: float,
                    recovery: CommandTrial | None, s: Settings) -> CheckResult:
    """(d) After malformed commands the state stream goes on, finite, with the angles
    unchanged, and a valid command afterwards still takes effect.

    Parameters
    ----------
    sent
        The malformed commands (name, data), published at ``start``.
    before
        The angles the laser was at [rad].
    states
        States received from ``start`` until the valid command at ``end``.
    recovery
        That valid command (None: not sent).
    """
    key, name = 'd', 'malformed commands'
    problems: list[str] = []
    n = len(states)
    max_gap = _stream_gap(states, start, end)
    if n < 2:
        problems.append(f'the state stream stopped after the malformed commands ({n} states '
                        f'in {end - start:.2f} s)')
    elif max_gap > s.max_gap:
        problems.append(f'no /laser/state for {max_gap:.3f} s after the malformed commands')
    faults = [f for f in (itf.state_fault(x.data) for x in states) if f is not None]
    if faults:
        problems.append(f'{len(faults)} states after them are malformed (first: {faults[0]})')
    problems += _round_trip_problems(states)
    moved = next((x for x in states if x.valid_state and not reached(x, before, s.tolerance)),
                 None)
    if moved is not None:
        culprit = _which_applied(sent, moved.angles, s)
        problems.append(f'the angles changed from {fmt_angles(before)} to '
                        f'{fmt_angles(moved.angles)} at round trip {moved.data[0]:g}'
                        + (f' (it applied the {culprit} command)' if culprit else ''))
    if recovery is None:
        problems.append('no valid command was sent after the malformed ones')
    elif settle(recovery, s.tolerance) is None:
        problems.append('a valid command after the malformed ones did not take effect')
    summary = (f'{len(sent)} sent ({", ".join(x for x, _ in sent)}); then {n} states, '
               f'max gap {1e3 * max_gap:.1f} ms, angles '
               f'{"held" if moved is None else "CHANGED"}, '
               f'{"all finite" if not faults else "NON-FINITE"}')
    figures = {'sent': len(sent), 'states_after': n, 'max_gap_ms': 1e3 * max_gap}
    return _result(key, name, summary, problems, figures=figures)


def _which_applied(sent: Sequence[tuple[str, Sequence[float]]], angles: np.ndarray,
                   s: Settings) -> str:
    """Name of the malformed command whose usable values the angles show ('' if none)."""
    for label, data in sent:
        if len(data) == 0:
            continue
        usable = [(i, v) for i, v in enumerate(data[:4])
                  if math.isfinite(v) and abs(v) <= s.angle_limit]
        if usable and all(abs(angles[i] - v) <= s.tolerance for i, v in usable):
            return label
    return ''


def check_status(statuses: Sequence[Sample], start: float, end: float, s: Settings,
                 round_trip_rate: float = math.nan, first_command_at: float | None = None,
                 confirmed_sent: float | None = None,
                 expected: dict[str, int] | None = None) -> CheckResult:
    """(e) /laser/status: often enough, the documented fields, finite, counters that
    never go down, a rate like the measured one, and counters that saw the commands.

    Parameters
    ----------
    statuses
        Every status message received from ``start`` (the laser found) to ``end``.
    round_trip_rate
        Round trips per second measured on /laser/state.
    first_command_at
        Monotonic time the first command was published (None: none).
    confirmed_sent
        Source time of the state that showed the last command applied.
    expected
        Least increase of each counter between the last status before the first command
        and the first status published after ``confirmed_sent``.
    """
    key, name = 'e', 'status'
    missing_is = FAIL if s.status_required else WARN
    n = len(statuses)
    if n == 0:
        return _result(key, name, f'no /laser/status in {end - start:.1f} s',
                       [f'no /laser/status in {end - start:.1f} s'], missing_is=missing_is)
    problems: list[str] = []
    notes: list[str] = []
    max_gap = _gaps([x.received for x in statuses], start, end)
    if max_gap > s.status_timeout:
        problems.append(f'{max_gap:.2f} s without /laser/status (more than --status-timeout '
                        f'{s.status_timeout:g} s)')
    faults = [itf.vector_fault(x.data, itf.LASER_STATUS_FIELDS, 1e300) for x in statuses]
    problems += _layout_problems(statuses, STATUS_LABEL, faults)
    good = [x for x, fault in zip(statuses, faults) if fault is None]
    figures: dict[str, float] = {'messages': n, 'max_gap_s': max_gap}
    summary = f'{n} messages, max gap {max_gap:.2f} s'
    if good:
        table = np.array([x.data for x in good])
        for j, field_name in enumerate(itf.LASER_STATUS_FIELDS):
            if field_name != 'rate' and np.any(np.diff(table[:, j]) < 0):
                problems.append(f'{field_name} went down')
        rate = float(np.median(table[:, 1]))
        figures['rate'] = rate
        summary += f', rate field {rate:.1f} RT/s'
        if math.isfinite(round_trip_rate) and round_trip_rate > 0:
            summary += f' (measured {round_trip_rate:.1f})'
            if not 0.5 <= rate / round_trip_rate <= 2.0:
                problems.append(f'the rate field says {rate:.1f} round trips/s, but '
                                f'/laser/state showed {round_trip_rate:.1f}')
        counted = _counter_increase(good, first_command_at, confirmed_sent)
        if expected and counted is None:
            notes.append('no status before the first command and after the last one; '
                         'counters not compared with the commands sent')
        elif expected:
            parts = []
            for counter, least in expected.items():
                rise = counted[counter]
                parts.append(f'{counter} +{rise:g}')
                figures[f'{counter}_increase'] = rise
                if rise < least:
                    problems.append(f'{counter} rose by {rise:g} while {least} such commands '
                                    'were sent')
            summary += ', ' + ', '.join(parts)
    return _result(key, name, summary, problems, notes, figures)


def _counter_increase(statuses: Sequence[Sample], first_command_at: float | None,
                      confirmed_sent: float | None) -> dict[str, float] | None:
    if first_command_at is None or confirmed_sent is None:
        return None
    before = [x for x in statuses if x.received < first_command_at]
    after = [x for x in statuses if x.sent >= confirmed_sent]
    if not before or not after:
        return None
    return {name: after[0].data[j] - before[-1].data[j]
            for j, name in enumerate(itf.LASER_STATUS_FIELDS) if j >= 2}


def check_diagnostics(reports: Sequence[tuple[float, str, int, str]], lasers: Sequence[str],
                      start: float, end: float) -> CheckResult:
    """(f) /diagnostics of the laser node (optional): ``reports`` are (received
    [monotonic s], status name, level, message) of every status heard; ``lasers`` the
    names of the nodes publishing /laser/state. Absent: a warning; an ERROR from a laser
    that streams: a failure; else a pass, with the levels seen."""
    key, name = 'f', 'diagnostics'
    names = {laser.rsplit('/', 1)[-1] for laser in lasers}
    mine = [r for r in reports if r[1] in names and start <= r[0] <= end]
    if not mine:
        return CheckResult(key, name, WARN, 'no /diagnostics status from the laser', [],
                           [f'{", ".join(sorted(names)) or "the laser"} publishes no '
                            'diagnostic_msgs/DiagnosticArray status named after the node on '
                            '/diagnostics (optional; see docs/interfaces.md)'])
    levels = {lv: sum(1 for r in mine if r[2] == lv) for lv in sorted({r[2] for r in mine})}
    seen = ', '.join(f'{n} {("OK", "WARN", "ERROR", "STALE")[min(lv, 3)]}'
                     for lv, n in levels.items())
    span = max(end - start, 1e-9)
    summary = f'{len(mine)} statuses ({len(mine) / span:.1f}/s): {seen}; last: {mine[-1][3]}'
    problems = [f'the laser reports ERROR while it streams: {r[3]}' for r in mine if r[2] >= 2]
    return _result(key, name, summary, problems[-1:],
                   figures={'statuses': len(mine), 'rate_hz': len(mine) / span})


def skipped(key: str, name: str, why: str) -> CheckResult:
    """A check that was not run."""
    return CheckResult(key, name, SKIP, why)


def exit_code(results: Sequence[CheckResult]) -> int:
    """0 when no check failed, else 1."""
    return int(any(r.status == FAIL for r in results))


def format_report(results: Sequence[CheckResult]) -> str:
    """The compact report: one line per check, its problems and notes indented below."""
    lines = []
    for r in results:
        lines.append(f'({r.key}) {r.name:<19s}{r.status:<5s} {r.summary}')
        lines += [f'      - {p}' for p in r.problems]
        lines += [f'      ~ {p}' for p in r.notes]
    failed = [f'({r.key}) {r.name}' for r in results if r.status == FAIL]
    lines.append('result: ' + (f'FAIL: {", ".join(failed)}' if failed else 'PASS'))
    return '\n'.join(lines)


def report_dict(results: Sequence[CheckResult], settings: Settings,
                info: dict[str, object]) -> dict[str, object]:
    """JSON-ready report: what was checked with which settings, and every result."""
    return {'passed': exit_code(results) == 0, 'info': info, 'settings': asdict(settings),
            'checks': [asdict(r) for r in results]}
