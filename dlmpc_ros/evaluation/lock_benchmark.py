"""The auto-mode-locking benchmark: N cold starts, success rate and time to lock.

The experimental literature scores auto-mode-locking by random cold starts (genetic
algorithms: Woodward and Kelleher, Sci. Rep. 2016; Pu et al. 2019; deep RL: Li et al.,
Photonics Research 2022). Here every start has random angles (uniform in [-pi/2, pi/2))
and the ``noise`` initial field (a real laser starts from spontaneous emission), a K
drawn uniformly from [-0.3, 0.3] (or one fixed K: ``LockSpec.k``), held or drifting
slowly (a random walk around it, the ``drift`` option), and a budget of round trips. A
start is locked once O >= 0.5 O*(K(t)) has held for 20 control periods; its time to lock
is the round trip at which that hold began. The same start (angles, K, field) is given
to every controller.

A budget sweep (:func:`sweep_metrics`) runs each start once, at the largest budget, and
scores every smaller budget B from it: the loop is causal (K(r), the noise and every
controller's decisions up to round trip B do not depend on the budget), and a start
counts as locked within B exactly when its first hold ended by then (time to lock + the
hold <= B), which is what a run of B round trips would have found.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.factory import load_estimator, make_controller
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.core import checks
from dlmpc_ros.core.bench import BenchConfig
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import Constant, RandomWalk
from dlmpc_ros.core.plants import NOMINAL, PHYSICS_FIELDS
from dlmpc_ros.evaluation.closed_loop import run_closed_loop
from dlmpc_ros.evaluation.metrics import first_hold
from dlmpc_ros.learning.tables import envelope_objective

if TYPE_CHECKING:
    from dlmpc_ros.learning.estimator import SurrogateEstimator
    from dlmpc_ros.control.step import Controller

DRIFTS = ('held', 'drift')


@dataclass(frozen=True)
class LockSpec:
    """One controller's benchmark on one plant."""

    controller: str
    """Controller spec: a registered name (:data:`~dlmpc_ros.control.factory.CONTROLLERS`)
    or ``package.module:factory`` (:mod:`dlmpc_ros.control.plugins`)."""
    starts: int = 100
    """Cold starts."""
    budget: int = 1000
    """Round trips per start."""
    hold_periods: int = 20
    """Control periods O must stay at or above the lock level to count as locked."""
    lock_fraction: float = 0.5
    """The lock level, as a fraction of O*(K(t))."""
    period: int = 10
    """Control period P [round trips]."""
    max_step: float = 0.25
    """Servo speed [rad per period]."""
    drift: str = 'held'
    """``held``: K stays at its draw; ``drift``: a random walk around it (sigma 0.05,
    correlation time 5,000 round trips)."""
    seed: int = 0
    """Seed of the starts (the same for every controller)."""
    k: float | None = None
    """K of every start (held, or where its drift starts) instead of the uniform draw
    (None); the angles and noise fields are the same either way."""
    plant: dict = field(default_factory=dict)
    """Physical parameters of the simulated cavity that differ from the nominal one."""

    bench: dict = field(default_factory=dict)
    """The lab bench's settings that differ from an ideal one
    (:class:`~dlmpc_ros.core.bench.BenchConfig`)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'starts', 'budget', 'hold_periods', 'period')
        checks.counts(self, 'seed', minimum=0)
        checks.fraction(self, 'lock_fraction')
        checks.positive(self, 'max_step')
        if self.drift not in DRIFTS:
            raise ValueError(f'LockSpec.drift must be one of {DRIFTS}, got {self.drift!r}')
        BenchConfig(**self.bench)
        if self.k is not None and not -0.3 <= self.k <= 0.3:
            raise ValueError(f'LockSpec.k must be in [-0.3, 0.3] or None, got {self.k!r}')
        if not set(self.plant) <= set(PHYSICS_FIELDS):
            raise ValueError(f'LockSpec.plant sets {sorted(set(self.plant) - set(PHYSICS_FIELDS))}'
                             f', not physical parameters {PHYSICS_FIELDS}')

    @property
    def cavity(self) -> CavityConfig:
        return replace(NOMINAL, **self.plant)

    def to_dict(self) -> dict:
        return asdict(self)


def start_conditions(seed: int, index: int) -> tuple[np.ndarray, float, int]:
    """Start ``index`` of ``seed``: angles (4,) [rad], K, and the seed of its noise field."""
    rng = np.random.default_rng([int(seed), int(index)])
    angles = rng.uniform(-np.pi / 2, np.pi / 2, 4)
    return angles, float(rng.uniform(-0.3, 0.3)), int(rng.integers(2 ** 31))


@dataclass(frozen=True)
class LockTask:
    """A block of starts of one benchmark (the unit of work of a worker)."""

    spec: LockSpec
    indices: tuple[int, ...]
    models_dir: str
    envelope_k: np.ndarray
    envelope_o: np.ndarray
    config: DLMPCConfig | None = None
    """The DL-MPC's settings (None: the shipped ones; ``max_step`` is the spec's either
    way); other controllers ignore it."""


def run_starts(task: LockTask) -> list[dict]:
    """Run the task's starts; per start ``index``, ``K``, ``locked``, ``round_trips``
    (to lock; None when it did not lock within the budget). The controller is built here
    (on the worker) from its spec for each start, with that start's K as ``initial_k``;
    one with a ``fresh()`` method (the DL-MPC) is built once and each start gets
    ``fresh()``."""
    spec = task.spec
    models = Path(task.models_dir)
    envelope = {'K': task.envelope_k, 'O_star': task.envelope_o}
    limits = AngleLimits(max_step=spec.max_step)
    estimator = None
    prototype = None
    out = []
    for index in task.indices:
        if prototype is None:
            controller = make_controller(spec.controller, models, limits,
                                         initial_k=start_k(spec, index),
                                         dlmpc_config=task.config)
            if hasattr(controller, 'fresh'):  # models loaded once, a controller per start
                prototype = controller
        if prototype is not None:
            controller = prototype.fresh()
        if estimator is None and getattr(controller, 'uses_estimator', False):
            estimator = load_estimator(models)
        out.append(run_start(controller, spec, envelope, index, estimator))
    return out


def start_k(spec: LockSpec, index: int) -> float:
    """The K that start ``index`` of ``spec`` begins at (``spec.k`` where it is set)."""
    return start_conditions(spec.seed, index)[1] if spec.k is None else float(spec.k)


def run_start(controller: Controller, spec: LockSpec, envelope: dict, index: int,
              estimator: SurrogateEstimator | None = None) -> dict:
    """One cold start ``index`` of ``spec`` under ``controller``: K held at
    :func:`start_k` or drifting slowly around it (``spec.drift``); ``index``, ``K`` (at
    the start), ``locked``, ``round_trips`` (to the first hold of the lock level; None
    when none within the budget)."""
    angles, _, noise_seed = start_conditions(spec.seed, index)
    k0 = start_k(spec, index)
    scenario = (Constant(offset=k0) if spec.drift == 'held' else
                RandomWalk(offset=k0, sigma=0.05, correlation_time=5000.0, seed=noise_seed))
    if estimator is not None:
        estimator.reset()
    record = run_closed_loop(controller, scenario, spec.budget, spec.period, angles,
                             cavity_config=spec.cavity, estimator=estimator,
                             initial='noise', initial_seed=noise_seed,
                             bench=BenchConfig(**spec.bench), noise_seed=noise_seed)
    o = np.nan_to_num(record.O, nan=0.0)
    locked = o >= spec.lock_fraction * envelope_objective(envelope, record.K)
    start = first_hold(locked, 0, spec.hold_periods * spec.period)
    return {'index': int(index), 'K': k0, 'locked': start is not None,
            'round_trips': None if start is None else int(start)}


def lock_metrics(starts: list[dict], spec: LockSpec) -> dict:
    """Success rate and time to lock of a benchmark's starts.

    ``median_round_trips`` and ``median_control_periods`` are over the starts that
    locked; ``p90_round_trips`` and ``p90_control_periods`` are over all starts, one that
    never locked counting as longer than any (None when fewer than 90 % locked). Control
    periods to lock are decisions to lock: for a search method (``ga``, ``esc``, ``bo``)
    an upper bound on the angle settings it tried, each period commanding at most one."""
    times = np.array([s['round_trips'] for s in starts if s['locked']], float)
    success = times.size / max(len(starts), 1)
    ordered = np.sort(np.r_[times, np.full(len(starts) - times.size, np.inf)])
    p90 = ordered[int(np.ceil(0.9 * len(ordered))) - 1] if len(ordered) else np.inf
    return {'starts': len(starts), 'locked': int(times.size), 'success_rate': success,
            'median_round_trips': float(np.median(times)) if times.size else None,
            'p90_round_trips': float(p90) if np.isfinite(p90) else None,
            'median_control_periods': (float(np.median(times)) / spec.period
                                       if times.size else None),
            'p90_control_periods': float(p90) / spec.period if np.isfinite(p90) else None,
            'round_trips_to_lock': [s['round_trips'] for s in starts]}


def within_budget(starts: list[dict], budget: int, spec: LockSpec) -> list[dict]:
    """The starts of a run of ``spec.budget`` round trips as a run of ``budget`` (at most
    ``spec.budget``) would have scored them: locked only where the first hold ended
    within ``budget`` (time to lock + ``hold_periods`` periods <= ``budget``)."""
    if not 1 <= budget <= spec.budget:
        raise ValueError(f'a budget of the sweep must be in [1, {spec.budget}] (the run\'s), '
                         f'got {budget}')
    hold = spec.hold_periods * spec.period
    out = []
    for s in starts:
        locked = bool(s['locked']) and s['round_trips'] + hold <= budget
        out.append({**s, 'locked': locked, 'round_trips': s['round_trips'] if locked else None})
    return out


def sweep_metrics(starts: list[dict], spec: LockSpec, budgets: Sequence[int]) -> dict:
    """:func:`lock_metrics` at every budget of ``budgets`` (each at most ``spec.budget``,
    the budget the starts ran with), keyed by the budget as a str (JSON keys)."""
    return {str(b): lock_metrics(within_budget(starts, b, spec), spec)
            for b in sorted(set(int(b) for b in budgets))}


def plot_lock_times(results: dict[str, dict], budget: int, title: str, path: Path,
                    budgets: Sequence[int] = ()) -> Path:
    """The share of starts locked by each round trip (its time to lock), one line per
    controller, over ``budget`` round trips. With ``budgets`` (a sweep) the round trips
    are on a log axis, with a dotted line at each budget."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    grid = np.arange(budget + 1)
    for name, metrics in results.items():
        times = np.sort([t for t in metrics['round_trips_to_lock'] if t is not None])
        share = np.searchsorted(times, grid, side='right') / max(metrics['starts'], 1)
        within = f' within {budget}' if budgets else ''
        ax.step(grid, share, where='post',
                label=f"{name} ({100 * metrics['success_rate']:.0f} %{within})")
    if budgets:
        ax.set_xscale('log')
        ax.set_xlim(10, budget)
        for b in sorted(budgets):
            ax.axvline(b, color='0.5', linestyle=':', linewidth=1)
    ax.set_xlabel('round trip' + (' (dotted: the budgets)' if budgets else ''))
    ax.set_ylabel('share of cold starts locked')
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
