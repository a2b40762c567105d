"""Birefringence drift scenarios: K as a pure, seeded function of the laser's round trip.

Every scenario is built by :func:`make_scenario` from the shared parameter names
(:data:`PARAMETER_NAMES`), whether they come from ROS parameters or from command-line
``KEY=VALUE`` settings (:func:`parse_settings`). Periods and times are in round trips.
A scenario is a callable ``K = scenario(round_trip)`` accepting an int or an int array;
the same scenario object gives the same K for the same round trip whatever the order of
the queries, so an evaluation can reproduce a ROS run without ROS.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dlmpc_ros.core.config import BIREFRINGENCE_RANGE

K_MIN, K_MAX = BIREFRINGENCE_RANGE
SCENARIOS = ('constant', 'sinusoidal', 'chirp', 'random_walk', 'steps', 'replay')
PARAMETER_NAMES = ('offset', 'amplitude', 'period', 'phase', 'sigma', 'correlation_time',
                   'seed', 'times', 'values', 'path')

# Defaults of each scenario's parameters (a scenario ignores parameters it does not list).
DEFAULTS: dict[str, dict[str, object]] = {
    'constant': {'offset': 0.0},
    'sinusoidal': {'offset': 0.0, 'amplitude': 0.2, 'period': 10000.0, 'phase': 0.0},
    # The authors' chirp: K = -0.075 + 0.175 sin(0.5 x^2), x from 0 to 7 over `period`.
    'chirp': {'offset': -0.075, 'amplitude': 0.175, 'period': 20000.0, 'phase': 0.0},
    'random_walk': {'offset': 0.0, 'sigma': 0.1, 'correlation_time': 2000.0, 'seed': 0},
    'steps': {'offset': 0.0, 'times': [1000.0], 'values': [0.1]},
    'replay': {'path': ''},
}

Scenario = Callable[[int | np.ndarray], float | np.ndarray]


def _check_range(name: str, low: float, high: float) -> None:
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f'{name}: K levels must be finite, got {low} .. {high}')
    if low < K_MIN - 1e-12 or high > K_MAX + 1e-12:
        raise ValueError(f'{name}: K would span [{low:.4g}, {high:.4g}], outside the model '
                         f'range [{K_MIN}, {K_MAX}]')


def _check_oscillation(name: str, offset: float, amplitude: float, period: float,
                       phase: float) -> None:
    if not period >= 1:  # a period shorter than a round trip samples nothing of the drift
        raise ValueError(f'{name}: period must be >= 1 round trip, got {period}')
    if not math.isfinite(period) or not math.isfinite(phase):
        raise ValueError(f'{name}: period and phase must be finite, got {period}, {phase}')
    _check_range(name, offset - abs(amplitude), offset + abs(amplitude))


def _as_round_trips(round_trip: int | np.ndarray) -> np.ndarray:
    r = np.asarray(round_trip, dtype=np.float64)
    if not np.isfinite(r).all() or (r < 0).any():
        raise ValueError('round trips must be finite and >= 0')
    return r


def _scalar_or_array(values: np.ndarray, like: int | np.ndarray) -> float | np.ndarray:
    return float(values) if np.ndim(like) == 0 else values


@dataclass(frozen=True)
class Constant:
    offset: float = 0.0

    def __post_init__(self) -> None:
        _check_range('constant', self.offset, self.offset)

    def __call__(self, round_trip):
        r = _as_round_trips(round_trip)
        return _scalar_or_array(np.full(r.shape, self.offset), round_trip)


@dataclass(frozen=True)
class Sinusoidal:
    """``K = offset + amplitude sin(2 pi r / period + phase)``."""

    offset: float = 0.0
    amplitude: float = 0.2
    period: float = 10000.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        _check_oscillation('sinusoidal', self.offset, self.amplitude, self.period,
                           self.phase)

    def __call__(self, round_trip):
        r = _as_round_trips(round_trip)
        k = self.offset + self.amplitude * np.sin(2 * np.pi * r / self.period + self.phase)
        return _scalar_or_array(k, round_trip)


@dataclass(frozen=True)
class Chirp:
    """``K = offset + amplitude sin(0.5 x^2 + phase)`` with ``x = 7 r / period``."""

    offset: float = -0.075
    amplitude: float = 0.175
    period: float = 20000.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        _check_oscillation('chirp', self.offset, self.amplitude, self.period, self.phase)

    def __call__(self, round_trip):
        x = 7.0 * _as_round_trips(round_trip) / self.period
        return _scalar_or_array(self.offset + self.amplitude * np.sin(0.5 * x * x + self.phase),
                                round_trip)


def _ou_extend(start: float, noise: np.ndarray, mean: float, decay: float, kick: float,
               low: float, high: float) -> np.ndarray:
    """Continue an Ornstein-Uhlenbeck path from ``start``, reflected into [low, high].

    A plain loop (about 30 ms per 65,536 steps): cheaper than loading a compiled kernel
    for the few chunks a run draws, and it keeps numba out of the nodes that import this.
    """
    out = []
    k = start
    for x in noise.tolist():
        k = mean + (k - mean) * decay + kick * x
        while k > high or k < low:
            k = 2 * high - k if k > high else 2 * low - k
        out.append(k)
    return np.array(out)


@dataclass
class RandomWalk:
    """Bounded, mean-reverting random walk: an Ornstein-Uhlenbeck process around
    ``offset`` with stationary standard deviation ``sigma`` and correlation time
    ``correlation_time`` round trips, reflected at the ends of [-0.3, 0.3]; K(0) = offset.

    The path is generated on demand in chunks from one seeded stream, so K(r) depends
    only on the seed and r. Memory stays bounded however far the round trips go: only a
    few recent chunks are kept, with a checkpoint (start value, generator state) per chunk
    from which an older one is made again exactly. The time to reach round trip r the
    first time grows with r (about 0.5 µs per round trip).
    """

    offset: float = 0.0
    sigma: float = 0.1
    correlation_time: float = 2000.0
    seed: int = 0
    _chunks: dict = field(init=False, repr=False)
    _checkpoints: list = field(init=False, repr=False)
    _rng: np.random.Generator = field(init=False, repr=False)

    CHUNK = 65536
    #: Chunks of the path kept in memory (least recently used ones are dropped).
    KEEP = 4
    #: Largest sigma and correlation time [round trips] of a walk within [-0.3, 0.3].
    MAX_SIGMA, MAX_CORRELATION_TIME = K_MAX - K_MIN, 1e9

    def __post_init__(self) -> None:
        _check_range('random_walk', self.offset, self.offset)
        if not 0 <= self.sigma <= self.MAX_SIGMA:
            raise ValueError(f'random_walk: sigma must be in [0, {self.MAX_SIGMA:g}] (the K '
                             f'range), got {self.sigma}')
        if not 0 < self.correlation_time <= self.MAX_CORRELATION_TIME:
            raise ValueError(f'random_walk: correlation_time must be in (0, '
                             f'{self.MAX_CORRELATION_TIME:g}] round trips, '
                             f'got {self.correlation_time}')
        self.seed = int(self.seed)
        self._rng = np.random.default_rng(self.seed)
        self._chunks = {}                                 # chunk -> K of its round trips
        self._checkpoints = [(self.offset, self._rng.bit_generator.state)]

    def _chunk(self, c: int) -> np.ndarray:
        """K at round trips ``c * CHUNK + 1 .. (c + 1) * CHUNK``."""
        if c in self._chunks:
            self._chunks[c] = self._chunks.pop(c)         # most recently used last
            return self._chunks[c]
        decay = math.exp(-1.0 / self.correlation_time)
        kick = self.sigma * math.sqrt(1.0 - decay * decay)
        first = min(c, len(self._checkpoints) - 1)
        start, state = self._checkpoints[first]
        rng = np.random.default_rng()
        rng.bit_generator.state = state
        for chunk in range(first, c + 1):
            values = _ou_extend(start, rng.standard_normal(self.CHUNK), self.offset, decay,
                                kick, K_MIN, K_MAX)
            start = values[-1]
            if chunk + 1 == len(self._checkpoints):
                self._checkpoints.append((start, rng.bit_generator.state))
        self._chunks[c] = values
        while len(self._chunks) > self.KEEP:
            self._chunks.pop(next(iter(self._chunks)))
        return values

    def __call__(self, round_trip):
        r = _as_round_trips(round_trip).astype(np.int64)
        out = np.full(r.shape, float(self.offset))
        later = r > 0
        chunk = (r - 1) // self.CHUNK
        for c in np.unique(chunk[later]):
            here = later & (chunk == c)
            out[here] = self._chunk(int(c))[(r[here] - 1) % self.CHUNK]
        return _scalar_or_array(out, round_trip)


@dataclass(frozen=True)
class Steps:
    """Piecewise constant: ``offset`` before ``times[0]``, then ``values[i]`` from ``times[i]``."""

    offset: float = 0.0
    times: tuple[float, ...] = (1000.0,)
    values: tuple[float, ...] = (0.1,)

    def __post_init__(self) -> None:
        times, values = np.asarray(self.times, float), np.asarray(self.values, float)
        if times.ndim != 1 or times.shape != values.shape or times.size == 0:
            raise ValueError('steps: times and values must be equally long, non-empty lists, '
                             f'got {len(self.times)} times and {len(self.values)} values')
        if not np.isfinite(times).all() or (np.diff(times) <= 0).any() or times[0] < 0:
            raise ValueError(f'steps: times must be increasing round trips >= 0, got {self.times}')
        if not np.isfinite(values).all():
            raise ValueError('steps: values must be finite')
        _check_range('steps', min(values.min(), self.offset), max(values.max(), self.offset))

    def __call__(self, round_trip):
        r = _as_round_trips(round_trip)
        levels = np.concatenate([[self.offset], np.asarray(self.values, float)])
        index = np.searchsorted(np.asarray(self.times, float), r, side='right')
        return _scalar_or_array(levels[index], round_trip)


@dataclass(frozen=True)
class Replay:
    """K read from a CSV of ``round_trip, K`` rows (a header line is allowed), linearly
    interpolated and held constant beyond the first and last rows."""

    path: str = ''
    round_trips: np.ndarray = field(init=False, repr=False)
    k_values: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rows = read_replay_csv(self.path)
        object.__setattr__(self, 'round_trips', rows[:, 0])
        object.__setattr__(self, 'k_values', rows[:, 1])

    def __call__(self, round_trip):
        r = _as_round_trips(round_trip)
        return _scalar_or_array(np.interp(r, self.round_trips, self.k_values), round_trip)


def read_replay_csv(path: str | Path) -> np.ndarray:
    """Read and check a replay CSV; returns (rows, 2) ``[round_trip, K]``."""
    if not str(path):
        raise ValueError('replay: set path=FILE.csv (rows of round_trip, K)')
    try:
        with open(path, newline='') as handle:
            lines = [row for row in csv.reader(handle) if row and not row[0].startswith('#')]
    except OSError as err:
        raise ValueError(f'replay: cannot read {path}: {err.strerror}') from None
    if lines and not _is_number(lines[0][0]):
        lines = lines[1:]  # header
    try:
        rows = np.array([[float(row[0]), float(row[1])] for row in lines])
    except (ValueError, IndexError):
        raise ValueError(f'replay: {path} must hold rows of two numbers: round_trip, K') from None
    if rows.shape[0] == 0:
        raise ValueError(f'replay: {path} holds no rows')
    if not np.isfinite(rows).all() or (np.diff(rows[:, 0]) <= 0).any():
        raise ValueError(f'replay: {path} needs finite values and increasing round trips')
    _check_range(f'replay {path}', rows[:, 1].min(), rows[:, 1].max())
    return rows


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


_CLASSES = {'constant': Constant, 'sinusoidal': Sinusoidal, 'chirp': Chirp,
            'random_walk': RandomWalk, 'steps': Steps, 'replay': Replay}


def make_scenario(name: str, **params: object) -> Scenario:
    """Build scenario ``name`` from shared parameters; unset ones take :data:`DEFAULTS`.

    Raises ValueError naming the problem for an unknown scenario, a parameter the
    scenario does not use, or values outside the model's K range.
    """
    if name not in _CLASSES:
        raise ValueError(f'unknown drift scenario {name!r}; choose one of {SCENARIOS}')
    allowed = DEFAULTS[name]
    extra = sorted(set(params) - set(allowed))
    if extra:
        raise ValueError(f'scenario {name!r} takes {sorted(allowed)}, not {extra}')
    values = {**allowed, **params}
    for key in ('times', 'values'):
        if key in values:
            values[key] = tuple(float(x) for x in values[key])  # type: ignore[union-attr]
    if 'seed' in values:
        seed = values['seed']
        if isinstance(seed, bool) or not isinstance(seed, (int, float)) or not (
                math.isfinite(seed) and seed == int(seed) and 0 <= seed < 2 ** 63):
            raise ValueError(f'{name}: seed must be an integer in [0, 2^63), got {seed!r}')
        values['seed'] = int(seed)
    return _CLASSES[name](**values)


def parse_settings(settings: Sequence[str]) -> dict[str, object]:
    """Parse ``KEY=VALUE`` strings: lists for times/values (comma separated), an int seed,
    a string path, floats otherwise."""
    parsed: dict[str, object] = {}
    for item in settings:
        key, sep, text = item.partition('=')
        key = key.strip()
        if not sep or key not in PARAMETER_NAMES:
            raise ValueError(f'bad scenario setting {item!r}: use KEY=VALUE with KEY one of '
                             f'{PARAMETER_NAMES}')
        try:
            if key in ('times', 'values'):
                parsed[key] = [float(x) for x in text.split(',') if x.strip()]
            elif key == 'seed':
                parsed[key] = int(text)
            elif key == 'path':
                parsed[key] = text
            else:
                parsed[key] = float(text)
        except ValueError:
            raise ValueError(f'bad value in scenario setting {item!r}') from None
        if key not in ('times', 'values', 'path', 'seed') and not math.isfinite(parsed[key]):
            raise ValueError(f'scenario setting {item!r} must be finite')
    return parsed
