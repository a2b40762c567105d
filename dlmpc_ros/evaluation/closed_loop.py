"""The closed loop in one process: simulator, drift, estimator and controller objects
stepped in the same order as the node graph in lockstep.

Round trip r runs with K = scenario(r) and the angles the bench's servos have reached by
then (with ideal servos: the angles commanded after round trip r - 1). At every round
trip r at which a decision is due (at least a period after the last one, once the
readings are settled at its command: :mod:`dlmpc_ros.control.step`) the
measurement ``(E, M, alpha[4])`` goes to the estimator and the controller, whose command
goes to the servos from r + 1.
:func:`replay_decisions` feeds a recorded run's measurements to a controller again.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from dlmpc_ros.learning.estimator import SurrogateEstimator
from dlmpc_ros.control.step import (MEASUREMENT_ROUND_TRIPS, SETTLE_TIMEOUT, SETTLE_TOLERANCE,
                                    ControlStep, Controller, PeriodMeasurement)
from dlmpc_ros.core.bench import Bench, BenchConfig
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import Scenario
from dlmpc_ros.evaluation.record import RecordBuilder, RunRecord


def random_initial_angles(seed: int) -> np.ndarray:
    """A cold start: four angles uniform in [-pi/2, pi/2) [rad] from ``seed``."""
    return np.random.default_rng(seed).uniform(-np.pi / 2, np.pi / 2, 4)


def run_closed_loop(controller: Controller, scenario: Scenario, round_trips: int,
                    period: int = 10, initial_angles: np.ndarray | None = None,
                    cavity_config: CavityConfig | None = None,
                    estimator: SurrogateEstimator | None = None,
                    meta: dict | None = None,
                    progress: Callable[[int], None] | None = None,
                    measurement_noise: float = 0.0, noise_seed: int = 0,
                    initial: str = 'sech', initial_seed: int | None = None,
                    measurement_round_trips: int = MEASUREMENT_ROUND_TRIPS,
                    bench: BenchConfig | None = None,
                    settle_tolerance: float = SETTLE_TOLERANCE,
                    settle_timeout: int = SETTLE_TIMEOUT) -> RunRecord:
    """Run ``round_trips`` round trips of the closed loop; returns the record.

    ``estimator`` (optional) supplies the surrogate the controller gets with each
    measurement; a controller with ``observe_truth`` (the oracle) is shown the true K.
    ``progress`` is called with the number of round trips done, after every decision.
    ``bench`` emulates the lab's servos, encoders and detectors
    (:class:`~dlmpc_ros.core.bench.BenchConfig`; default ideal); ``measurement_noise``
    is its detector noise (the relative standard deviation of independent Gaussian errors
    on the E and M read each round trip; seeded by ``noise_seed``). The record keeps the
    laser's true E, M, O and the angles its optics ran with; the estimator and the
    controller see only what the bench reports.
    ``initial`` is the laser's initial field (the spec's ``'sech'`` pulse, or ``'noise'``,
    seeded by ``initial_seed``: a cold start from spontaneous emission).
    ``measurement_round_trips``, ``settle_tolerance`` and ``settle_timeout`` form each
    decision's measurement (:class:`~dlmpc_ros.control.step.PeriodMeasurement`:
    the mean E and M of the latest settled round trips; ``period`` is the least time
    between decisions).
    """
    if round_trips < 1 or period < 1:
        raise ValueError('round_trips and period must be >= 1')
    if not 0 <= measurement_noise < 1:
        raise ValueError(f'measurement_noise must be in [0, 1), got {measurement_noise}')
    bench_config = bench or BenchConfig()
    if measurement_noise:
        if bench_config.detector_noise:
            raise ValueError('give the detector noise once: measurement_noise or '
                             'bench.detector_noise')
        bench_config = replace(bench_config, detector_noise=measurement_noise)
    periods = PeriodMeasurement(period, measurement_round_trips, settle_tolerance,
                                settle_timeout)
    angles = np.zeros(4) if initial_angles is None else np.asarray(initial_angles, float)
    lab = Bench(bench_config, angles, seed=noise_seed)
    # With instant servos and a spectrum read every round trip, a round trip that cannot
    # enter a measurement need not be read (its noise is not drawn).
    read_every = not bench_config.instant_servos or bench_config.spectrum_refresh > 1
    cavity = Cavity(cavity_config, batch=1, angles=angles, birefringence=scenario(1),
                    initial=initial, seed=initial_seed)
    # what defines the run's measurements, so that a replay forms the same ones
    builder = RecordBuilder({**(meta or {}), 'period': period,
                             'measurement_round_trips': measurement_round_trips,
                             'settle_tolerance': settle_tolerance,
                             'settle_timeout': settle_timeout,
                             'bench': bench_config.to_dict()})
    observe_truth = getattr(controller, 'observe_truth', None)
    for r in range(1, round_trips + 1):
        k = float(scenario(r))
        cavity.set_birefringence(k)
        if not bench_config.instant_servos:
            cavity.set_angles(lab.advance())
        applied = cavity.angles[0]
        result = cavity.step()
        if not result.finite[0]:  # as the node does: reset, publish nothing, go on
            cavity.reset()
            builder.add_round_trip(r, k, np.nan, np.nan, np.nan, applied)
            continue
        e, m, o = float(result.E[0]), float(result.M[0]), float(result.O[0])
        builder.add_round_trip(r, k, e, m, o, applied)
        if not (read_every or periods.wanted(r)):
            continue
        e_read, m_read, _ = lab.read_detectors(r, e, m, float(result.peak[0]))
        measurement = periods.add(r, np.array([e_read, m_read, *lab.read_angles()]))
        if measurement is None:
            continue
        started = time.perf_counter()
        surrogate = None if estimator is None else estimator.update(measurement)[0]
        estimate_ms = 1e3 * (time.perf_counter() - started)
        if observe_truth is not None:
            observe_truth(k)
        step = controller.step(measurement, surrogate)
        periods.command(step.angles, step.measure)
        lab.command(step.angles)
        if bench_config.instant_servos:
            cavity.set_angles(lab.advance())
        builder.add_step(r, step, estimate_ms, surrogate)
        if progress is not None:
            progress(r)
    return builder.build()


def replay_decisions(controller: Controller, record: RunRecord,
                     estimator: SurrogateEstimator | None = None) -> list[ControlStep]:
    """The controller's decisions on a recorded run's measurements, in order.

    Every control period of ``record`` gives the measurement ``(E, M, alpha[4])`` of its
    round trips (the mean over the last ``meta['measurement_round_trips']`` at its
    angles, which :func:`run_closed_loop` records; 1 in records from before it did), as
    :func:`run_closed_loop` gave it, from the recorded E, M and angles of every round
    trip; nothing else of the run (no K, no simulator) is used. A noiseless run's
    controller that reads only its measurements decides exactly as it did in the run.
    """
    meta = record.meta
    periods = PeriodMeasurement(int(meta.get('period', 10)),
                                int(meta.get('measurement_round_trips', 1)),
                                float(meta.get('settle_tolerance', SETTLE_TOLERANCE)),
                                int(meta.get('settle_timeout', SETTLE_TIMEOUT)))
    steps = []
    for r, e, m, angles in zip(record.round_trip.tolist(), record.E, record.M,
                               record.angles):
        if not (np.isfinite(e) and periods.wanted(r)):
            continue
        measurement = periods.add(r, np.array([e, m, *angles]))
        if measurement is None:
            continue
        surrogate = None if estimator is None else estimator.update(measurement)[0]
        steps.append(controller.step(measurement, surrogate))
        periods.command(steps[-1].angles, steps[-1].measure)
    return steps
