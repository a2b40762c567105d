"""One closed-loop run of the evaluation matrix (scenario x seed x controller), in one
process (``fast``) or through the node graph, described by a :class:`RunSpec`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from dlmpc_ros.learning.estimator import SurrogateEstimator
from dlmpc_ros.control.factory import load_estimator, make_controller
from dlmpc_ros.control.step import (MEASUREMENT_ROUND_TRIPS, SETTLE_TIMEOUT, SETTLE_TOLERANCE,
                                    AngleLimits, Controller)
from dlmpc_ros.core import checks
from dlmpc_ros.core.bench import BenchConfig
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.plants import (NOMINAL, PHYSICS_FIELDS, plant_fingerprint,
                                   plant_parameters)
from dlmpc_ros.evaluation.closed_loop import random_initial_angles, run_closed_loop
from dlmpc_ros.evaluation.presets import PRESETS, preset_scenario, run_settings
from dlmpc_ros.evaluation.record import RunRecord

#: How a run is executed.
MODES = ('fast', 'graph-lockstep', 'graph-free-run')


@dataclass(frozen=True)
class RunSpec:
    """One run of the matrix."""

    scenario: str
    """Drift preset (:data:`~dlmpc_ros.evaluation.presets.PRESETS`)."""
    seed: int
    """Seed of the random initial angles and of the random walk."""
    controller: str
    """Controller spec: a registered name (:data:`~dlmpc_ros.control.factory.CONTROLLERS`)
    or ``package.module:factory`` (:mod:`dlmpc_ros.control.plugins`), built where the run
    runs (a Dask worker resolves it there)."""
    settings: dict = field(default_factory=dict)
    """The scenario's settings (empty: the preset's)."""
    round_trips: int = 20000
    """Round trips of the run."""
    period: int = 10
    """Control period P [round trips]."""
    max_step: float = 0.25
    """Servo speed: largest angle change per period [rad]."""
    measurement_noise: float = 0.0
    """Relative Gaussian noise on the E and M the estimator and controller see (fast)."""
    mode: str = 'fast'
    """One of :data:`MODES`."""
    plant: dict = field(default_factory=dict)
    """Physical parameters of the simulated cavity that differ from the nominal one
    (:mod:`dlmpc_ros.core.plants`); they reach the simulator, never the controller."""
    measurement_round_trips: int = MEASUREMENT_ROUND_TRIPS
    """The estimator and controller see the mean E and M of the period's last this many
    round trips at its angles, each with its own measurement noise."""
    bench: dict = field(default_factory=dict)
    """The lab bench's settings that differ from an ideal one (servos, encoders,
    detectors: :class:`~dlmpc_ros.core.bench.BenchConfig`); fast runs emulate them, graph
    runs pass them to laser_sim."""
    settle_tolerance: float = SETTLE_TOLERANCE
    """A state counts for a decision once its angles are this close to the command [rad]."""
    settle_timeout: int = SETTLE_TIMEOUT
    """Round trips after a decision by which the next is made even if unsettled."""
    condition: str = ''
    """Label of the suite condition the run belongs to
    (:mod:`~dlmpc_ros.evaluation.suites`; empty outside a suite): it names the run's
    folder, so two conditions on one scenario keep their runs apart."""

    def __post_init__(self) -> None:
        if self.scenario not in PRESETS:
            raise ValueError(f'RunSpec.scenario must be one of {tuple(PRESETS)}, '
                             f'got {self.scenario!r}')
        if self.mode not in MODES:
            raise ValueError(f'RunSpec.mode must be one of {MODES}, got {self.mode!r}')
        checks.counts(self, 'round_trips', 'period', 'measurement_round_trips',
                      'settle_timeout')
        checks.non_negative(self, 'settle_tolerance')
        checks.positive(self, 'max_step')
        checks.non_negative(self, 'measurement_noise')
        unknown = set(self.plant) - set(PHYSICS_FIELDS)
        if unknown:
            raise ValueError(f'RunSpec.plant sets {sorted(unknown)}, which are not physical '
                             f'parameters of the cavity {PHYSICS_FIELDS}')
        self.cavity  # noqa: B018 (a plant the simulator cannot run raises here)
        self.bench_config  # noqa: B018 (likewise a bench)

    @property
    def cavity(self) -> CavityConfig:
        """The simulated cavity: the nominal one with the plant's parameters."""
        return replace(NOMINAL, **self.plant)

    @property
    def bench_config(self) -> BenchConfig:
        """The emulated bench (ideal unless :attr:`bench` says otherwise)."""
        return BenchConfig(**self.bench)

    @property
    def run_settings(self) -> dict:
        """The scenario settings the run uses (the random walk's seed filled in)."""
        return run_settings(self.scenario, self.seed, self.settings or None)

    def meta(self, models_dir: Path | None = None) -> dict:
        """What the run's record and metrics say about it (and the models folder the
        controller was built from, when given)."""
        models = {} if models_dir is None else {'models_dir': str(Path(models_dir).resolve())}
        return {**models, 'scenario': self.scenario, 'settings': self.run_settings,
                'controller': self.controller, 'seed': self.seed,
                'round_trips': self.round_trips, 'period': self.period, 'mode': self.mode,
                'initial_angles': random_initial_angles(self.seed).tolist(),
                'measurement_noise': self.measurement_noise,
                'measurement_round_trips': self.measurement_round_trips,
                **({'bench': dict(self.bench)} if self.bench else {}),
                **({'settle_tolerance': self.settle_tolerance}
                   if self.settle_tolerance != SETTLE_TOLERANCE else {}),
                **({'settle_timeout': self.settle_timeout}
                   if self.settle_timeout != SETTLE_TIMEOUT else {}),
                **({'condition': self.condition} if self.condition else {}),
                'plant': plant_parameters(self.cavity),
                'plant_fingerprint': plant_fingerprint(self.cavity)}


def run_fast(spec: RunSpec, models_dir: Path, controller: Controller | None = None,
             estimator: SurrogateEstimator | None = None,
             progress: Callable[[int], None] | None = None) -> RunRecord:
    """The run in one process. ``controller`` (default: built by name from
    ``models_dir``) and ``estimator`` (default: the VAE for a controller whose
    ``uses_estimator`` is true: the paper's DL-MPC) may be given, e.g.
    a DL-MPC with other settings."""
    scenario = preset_scenario(spec.scenario, spec.seed, spec.settings or None)
    if controller is None:
        controller = make_controller(spec.controller, models_dir,
                                     AngleLimits(max_step=spec.max_step),
                                     initial_k=float(scenario(1)))
    if estimator is None and getattr(controller, 'uses_estimator', False):
        estimator = load_estimator(models_dir)
    return run_closed_loop(controller, scenario, spec.round_trips, spec.period,
                           random_initial_angles(spec.seed), cavity_config=spec.cavity,
                           estimator=estimator, meta=spec.meta(models_dir), progress=progress,
                           measurement_noise=spec.measurement_noise, noise_seed=spec.seed,
                           measurement_round_trips=spec.measurement_round_trips,
                           bench=spec.bench_config, settle_tolerance=spec.settle_tolerance,
                           settle_timeout=spec.settle_timeout)


def run_spec(spec: RunSpec, models_dir: Path, run_dir: Path, domain_id: int = 88,
             progress: Callable[[int], None] | None = None) -> RunRecord:
    """The run in its mode: in one process, or through the bringup (its files in
    ``run_dir``, on ROS domain ``domain_id``)."""
    if spec.mode == 'fast':
        return run_fast(spec, models_dir, progress=progress)
    from dlmpc_ros.evaluation.graph_run import run_graph
    if spec.measurement_noise:
        raise ValueError('measurement noise applies to fast runs only')
    return run_graph(run_dir, spec.controller, spec.scenario, setting_strings(spec.run_settings),
                     spec.round_trips, spec.period, random_initial_angles(spec.seed),
                     domain_id, lockstep=spec.mode == 'graph-lockstep',
                     models_dir=models_dir, meta=spec.meta(models_dir),
                     plant=[f'{k}={v!r}' for k, v in spec.plant.items()],
                     measurement_round_trips=spec.measurement_round_trips,
                     bench=[f'{k}={v!r}' for k, v in spec.bench.items()])


def setting_strings(settings: dict[str, object]) -> list[str]:
    """``KEY=VALUE`` strings of scenario settings (lists as comma-separated floats)."""
    out = []
    for key, value in settings.items():
        if isinstance(value, (list, tuple)):
            value = ','.join(repr(float(v)) for v in value)
        out.append(f'{key}={value}')
    return out


@dataclass(frozen=True)
class RunTask:
    """A fast run as a task of :func:`dlmpc_ros.scaleout.run_tasks`."""

    spec: RunSpec
    models_dir: str


def run_task(task: RunTask) -> RunRecord:
    """The task's run in this process (a worker's unit of work)."""
    return run_fast(task.spec, Path(task.models_dir))
