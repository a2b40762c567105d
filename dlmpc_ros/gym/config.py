"""Settings of the laser environment (:class:`LaserEnvConfig`) and what they resolve to:
each episode's drift scenario, plant and envelope.

Every setting is checked when the configuration is made, so a bad option stops
``gymnasium.make`` with one line naming it; nothing here imports gymnasium.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from dlmpc_ros.control.step import MEASUREMENT_ROUND_TRIPS, SETTLE_TOLERANCE, AngleLimits
from dlmpc_ros.core.bench import BENCH_PRESETS, BenchConfig, parse_bench
from dlmpc_ros.core.cavity import INITIAL_CONDITIONS
from dlmpc_ros.core.config import BIREFRINGENCE_RANGE, CavityConfig
from dlmpc_ros.core.drift import DEFAULTS, SCENARIOS, Constant, RandomWalk, Scenario, make_scenario
from dlmpc_ros.core.plants import NOMINAL, PHYSICS_FIELDS, PlantFamily, is_nominal

#: Scenarios drawn per reset besides :data:`dlmpc_ros.core.drift.SCENARIOS`: ``held``, K
#: uniform in [-0.3, 0.3] held for the episode; ``drift``, a random walk around such a K
#: (sigma 0.05, correlation time 5,000 round trips), as in the lock benchmark.
DRAWN_SCENARIOS = ('held', 'drift')
ENV_SCENARIOS = DRAWN_SCENARIOS + SCENARIOS
#: Plant choices besides a mapping of physical values.
PLANTS = ('nominal', 'family')
ACTIONS = ('delta', 'absolute')
#: Grid and solver settings of :class:`CavityConfig` (``solver``); the plant sets the rest.
SOLVER_FIELDS = tuple(f.name for f in fields(CavityConfig) if f.name not in PHYSICS_FIELDS)

#: ``plant_source(seed) -> (cavity, envelope or None)``: a plant for a family seed (for
#: instance checked to mode-lock, with its envelope ``{'K': (n,), 'O_star': (n,)}``).
PlantSource = Callable[[int], tuple[CavityConfig, Mapping[str, np.ndarray] | None]]


def _fail(name: str, wanted: str, value: object) -> None:
    raise ValueError(f'ModeLockedLaser option {name} must be {wanted}, got {value!r}')


def _count(name: str, value: object, minimum: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        _fail(name, f'an integer >= {minimum}', value)


def _number(name: str, value: object, low: float, high: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not low <= value <= high:
        _fail(name, f'a number in [{low:g}, {high:g}]', value)


@dataclass(frozen=True)
class LaserEnvConfig:
    """Every option of ``ModeLockedLaser-v0`` (keyword arguments of ``gymnasium.make``)."""

    period: int = 10
    """P: round trips per control period, i.e. per env step."""
    measurement_round_trips: int = MEASUREMENT_ROUND_TRIPS
    """n: the observation's E and M are the mean of the period's last min(n, P) round
    trips (``control/step.py``, ``PeriodMeasurement``)."""
    episode_periods: int = 200
    """Env steps of an episode (then ``truncated``; an episode never terminates)."""
    window: int = 1
    """Periods in the observation (the latest last; at reset the first one repeated)."""
    action: str = 'delta'
    """``delta``: the action (4,) is the change of the angles [rad], in
    [-max_step, max_step], the result clipped into [low, high]; ``absolute``: the action
    is the wanted angles in [low, high], reached through the servo limits
    (:meth:`AngleLimits.apply`: the nearest pi-equivalent, at most max_step per period)."""
    low: float = AngleLimits.low
    """Lowest angle [rad] (servo range)."""
    high: float = AngleLimits.high
    """Highest angle [rad]."""
    max_step: float = AngleLimits.max_step
    """Largest change of any angle per period [rad]."""
    scenario: str = 'held'
    """Drift of K: one of :data:`ENV_SCENARIOS`; a preset's name
    (``evaluation/presets.py``) takes the preset's settings."""
    scenario_settings: Mapping[str, Any] = field(default_factory=dict)
    """Settings of the scenario (``core/drift.py`` names) over the preset's; a random
    walk without ``seed`` draws one per reset."""
    plant: str | Mapping[str, float] = 'nominal'
    """``nominal``, a mapping of physical values (``core/plants.py`` PHYSICS_FIELDS), or
    ``family``: a plant drawn per reset from ``family`` (no mode-lock check, no envelope)
    or by ``plant_source``."""
    family: PlantFamily = field(default_factory=PlantFamily)
    """Ranges of the family's plants."""
    plant_source: PlantSource | None = None
    """With ``plant='family'``: makes the plant of a family seed drawn per reset (for
    instance :func:`dlmpc_ros.training.gym_plants.checked_plants`: checked to mode-lock,
    with its envelope; minutes per new plant, cached)."""
    envelope: str | Mapping[str, np.ndarray] | None = 'auto'
    """O*(K) for ``info``: ``auto`` (the nominal plant: ``models/oracle.npz``; another
    plant: what ``plant_source`` gives, else none), a mapping ``{'K', 'O_star'}``, a
    ``.npz`` path, or None. Without one ``info['O_star']`` is NaN."""
    solver: Mapping[str, Any] = field(default_factory=dict)
    """Grid and solver settings of the cavity (:data:`SOLVER_FIELDS`, e.g. ``points``)."""
    detector_noise: float = 0.0
    """Relative standard deviation of Gaussian noise on each round trip's E and M."""
    bench: str | Sequence[str] | Mapping[str, float] | BenchConfig = 'ideal'
    """Servos, encoders and detectors (``core/bench.py``): a preset name, ``KEY=VALUE``
    strings, a mapping or a :class:`BenchConfig`."""
    initial: str = 'noise'
    """Initial field of an episode: ``noise`` (a cold start) or ``sech``."""
    initial_angles: str | Sequence[float] = 'random'
    """``random``: uniform in [-pi/2, pi/2) per reset; or four fixed angles [rad]."""
    settle_tolerance: float = SETTLE_TOLERANCE
    """Largest |reported angle - command| [rad] of a round trip counted in the measurement."""

    def __post_init__(self) -> None:
        for name in ('period', 'measurement_round_trips', 'episode_periods', 'window'):
            _count(name, getattr(self, name))
        if self.action not in ACTIONS:
            _fail('action', f'one of {ACTIONS}', self.action)
        try:
            AngleLimits(self.low, self.high, self.max_step)
        except (ValueError, TypeError) as err:
            raise ValueError(f'ModeLockedLaser options low/high/max_step: {err}') from None
        _number('detector_noise', self.detector_noise, 0.0, 0.5)
        _number('settle_tolerance', self.settle_tolerance, 0.0, 1.0)
        if self.initial not in INITIAL_CONDITIONS:
            _fail('initial', f'one of {INITIAL_CONDITIONS}', self.initial)
        if not (isinstance(self.initial_angles, str) and self.initial_angles == 'random'):
            angles = np.asarray(self.initial_angles, dtype=object)
            if isinstance(self.initial_angles, str) or angles.shape != (4,) or not all(
                    isinstance(a, (int, float)) and not isinstance(a, bool)
                    and math.isfinite(a) for a in angles):
                _fail('initial_angles', "'random' or four finite angles [rad]",
                      self.initial_angles)
        if not isinstance(self.family, PlantFamily):
            _fail('family', 'a PlantFamily', self.family)
        if self.plant_source is not None and not callable(self.plant_source):
            _fail('plant_source', 'a callable seed -> (CavityConfig, envelope)',
                  self.plant_source)
        if self.plant_source is not None and self.plant != 'family':
            raise ValueError("ModeLockedLaser option plant_source needs plant='family'")
        self.base_cavity  # noqa: B018  (a bad plant or solver setting raises here)
        self.bench_config  # noqa: B018
        self.scenario_for(np.random.default_rng(0))  # a bad scenario raises here
        if self.plant == 'family' and not (self.envelope is None or self.envelope == 'auto'):
            raise ValueError("ModeLockedLaser option envelope applies to one plant; with "
                             "plant='family' give plant_source (it returns each envelope)")
        self.fixed_envelope  # noqa: B018

    # -- the cavity --------------------------------------------------------------------
    @property
    def limits(self) -> AngleLimits:
        return AngleLimits(self.low, self.high, self.max_step)

    @property
    def base_cavity(self) -> CavityConfig:
        """The cavity of a fixed plant (of ``family``: the nominal physics, whose grid and
        solver each drawn plant keeps)."""
        if not isinstance(self.solver, Mapping):
            _fail('solver', f'a mapping of {SOLVER_FIELDS}', self.solver)
        unknown = sorted(set(self.solver) - set(SOLVER_FIELDS))
        if unknown:
            raise ValueError(f'ModeLockedLaser option solver sets {unknown}; it takes '
                             f'{SOLVER_FIELDS} (physical values go in plant)')
        physics: Mapping[str, float] = {}
        if isinstance(self.plant, Mapping):
            unknown = sorted(set(self.plant) - set(PHYSICS_FIELDS))
            if unknown:
                raise ValueError(f'ModeLockedLaser option plant sets {unknown}; it takes '
                                 f'{PHYSICS_FIELDS}')
            physics = dict(self.plant)
            if 'cross_phase' in physics and 'four_wave' not in physics:
                physics['four_wave'] = 1.0 - physics['cross_phase']
            if 'four_wave' in physics and 'cross_phase' not in physics:
                physics['cross_phase'] = 1.0 - physics['four_wave']
        elif self.plant not in PLANTS:
            _fail('plant', f"one of {PLANTS} or a mapping of {PHYSICS_FIELDS}", self.plant)
        try:
            return replace(NOMINAL, **physics, **self.solver)
        except (ValueError, TypeError) as err:
            raise ValueError(f'ModeLockedLaser options plant/solver: {err}') from None

    @property
    def bench_config(self) -> BenchConfig:
        """The bench, with ``detector_noise`` in it."""
        bench = self.bench
        try:
            if isinstance(bench, BenchConfig):
                config = bench
            elif isinstance(bench, str):
                config = parse_bench([bench])
            elif isinstance(bench, Mapping):
                config = parse_bench([f'{k}={v}' for k, v in bench.items()])
            elif isinstance(bench, Sequence):
                config = parse_bench(list(bench))
            else:
                raise ValueError(f'use a preset ({", ".join(BENCH_PRESETS)}), KEY=VALUE '
                                 f'strings, a mapping or a BenchConfig, not {bench!r}')
        except (ValueError, TypeError) as err:
            raise ValueError(f'ModeLockedLaser option bench: {err}') from None
        if self.detector_noise:
            if config.detector_noise:
                raise ValueError('ModeLockedLaser: give the detector noise once '
                                 '(detector_noise or bench)')
            config = replace(config, detector_noise=float(self.detector_noise))
        return config

    # -- the drift ---------------------------------------------------------------------
    def scenario_for(self, rng: np.random.Generator, k0: float | None = None,
                     seed: int | None = None) -> Scenario:
        """The episode's K(round trip) from a reset's draws (``k0`` uniform in the K range
        and ``seed``; drawn from ``rng`` where not given)."""
        k0 = float(rng.uniform(*BIREFRINGENCE_RANGE)) if k0 is None else k0
        seed = int(rng.integers(2 ** 31)) if seed is None else seed
        name, settings = self.scenario, self.scenario_settings
        if not isinstance(settings, Mapping):
            _fail('scenario_settings', 'a mapping of drift settings', settings)
        if name not in ENV_SCENARIOS:
            _fail('scenario', f'one of {ENV_SCENARIOS}', name)
        if name in DRAWN_SCENARIOS:
            if settings:
                raise ValueError(f'ModeLockedLaser scenario {name!r} takes no settings, got '
                                 f'{sorted(settings)}')
            return (Constant(offset=k0) if name == 'held' else
                    RandomWalk(offset=k0, sigma=0.05, correlation_time=5000.0, seed=seed))
        from dlmpc_ros.evaluation.presets import PRESETS
        values = {**PRESETS.get(name, DEFAULTS[name]), **settings}
        if name == 'random_walk':
            values.setdefault('seed', seed)
        try:
            return make_scenario(name, **values)
        except (ValueError, TypeError) as err:
            raise ValueError(f'ModeLockedLaser option scenario_settings: {err}') from None

    # -- the envelope ------------------------------------------------------------------
    @property
    def fixed_envelope(self) -> dict[str, np.ndarray] | None:
        """The envelope of a fixed plant (None: none known)."""
        env = self.envelope
        if env is None or self.plant == 'family':
            return None
        if isinstance(env, str) and env == 'auto':
            if not is_nominal(self.base_cavity):
                return None
            from dlmpc_ros.paths import models_dir
            return _read_envelope(models_dir() / 'oracle.npz')
        if isinstance(env, (str, Path)):
            return _read_envelope(Path(env))
        if isinstance(env, Mapping):
            return checked_envelope(env)
        _fail('envelope', "'auto', None, a {'K', 'O_star'} mapping or an .npz path", env)
        return None


def checked_envelope(env: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """``{'K', 'O_star'}`` as float arrays of one length with increasing K; ValueError."""
    try:
        k = np.asarray(env['K'], float)
        o = np.asarray(env['O_star'], float)
    except (KeyError, TypeError, ValueError):
        raise ValueError("ModeLockedLaser envelope must hold arrays 'K' and 'O_star'") \
            from None
    if k.ndim != 1 or k.shape != o.shape or k.size < 2 or (np.diff(k) <= 0).any() \
            or not np.isfinite(o).all():
        raise ValueError('ModeLockedLaser envelope needs equally long K (increasing, >= 2 '
                         'points) and finite O_star')
    return {'K': k, 'O_star': o}


_ENVELOPES: dict[Path, dict[str, np.ndarray]] = {}


def _read_envelope(path: Path) -> dict[str, np.ndarray]:
    path = Path(path).resolve()
    if path not in _ENVELOPES:
        from dlmpc_ros.learning.tables import load_envelope
        try:
            _ENVELOPES[path] = checked_envelope(load_envelope(path))
        except (FileNotFoundError, ValueError) as err:
            raise ValueError(f'ModeLockedLaser option envelope: {err}') from None
    return _ENVELOPES[path]
