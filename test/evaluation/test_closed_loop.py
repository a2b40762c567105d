"""The in-process closed loop: order of events, limits, reproducibility."""

import numpy as np

from dlmpc_ros.control.baselines import FixedBestController, OracleController
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import make_scenario
from dlmpc_ros.evaluation.closed_loop import random_initial_angles, run_closed_loop

SMALL = CavityConfig(points=64, steps_per_round_trip=8, scheme='strang')


def test_commands_apply_from_the_next_round_trip_at_servo_speed():
    target = np.array([0.5, -0.5, 0.2, 0.1])
    ctrl = FixedBestController(target, AngleLimits(max_step=0.1))
    record = run_closed_loop(ctrl, make_scenario('constant', offset=0.1), 60, period=10,
                             initial_angles=np.zeros(4), cavity_config=SMALL)
    assert record.O.size == 60 and list(record.control_round_trip) == [10, 20, 30, 40, 50, 60]
    np.testing.assert_array_equal(record.angles[:10], 0.0)  # until the first decision
    np.testing.assert_allclose(record.angles[10], [0.1, -0.1, 0.1, 0.1])
    steps = np.abs(np.diff(record.angles, axis=0)).max(axis=1)
    assert steps.max() <= 0.1 + 1e-12
    np.testing.assert_allclose(record.angles[-1], target)


def test_with_slow_servos_a_decision_waits_until_the_encoders_read_the_command():
    from dlmpc_ros.core.bench import BenchConfig
    target = np.array([0.5, -0.5, 0.2, 0.1])
    bench = BenchConfig(servo_lag=6, slew_rate=0.04, encoder_noise=0.001)
    record = run_closed_loop(FixedBestController(target, AngleLimits(max_step=0.25)),
                             make_scenario('constant', offset=0.1), 200, period=10,
                             initial_angles=np.zeros(4), cavity_config=SMALL, bench=bench,
                             settle_tolerance=0.005)
    decided = record.control_round_trip
    # each 0.25 rad move: 6 round trips of lag, reached on the 7th of turning, settled
    # for 10 round trips counting that one
    np.testing.assert_array_equal(np.diff(decided[:3]), [22, 22])
    moving = np.abs(np.diff(record.angles, axis=0)).max(axis=1)
    assert 0.0 < moving.max() <= 0.04 + 1e-12                  # the optic turns at the slew
    np.testing.assert_allclose(record.angles[-1], target)       # the record: the true angles
    assert record.meta['bench']['servo_lag'] == 6


def test_same_seed_same_run_and_the_oracle_sees_the_true_k():
    scenario = make_scenario('steps', times=[20.0], values=[0.2])
    table_k = np.array([-0.3, 0.0, 0.3])
    table = np.array([[0.0, 0.0, 0.0, 0.0], [0.1, 0.1, 0.1, 0.1], [0.3, 0.3, 0.3, 0.3]])
    limits = AngleLimits(max_step=10.0)
    runs = [run_closed_loop(OracleController(table_k, table, limits), scenario, 40, 10,
                            random_initial_angles(3), SMALL) for _ in range(2)]
    np.testing.assert_array_equal(runs[0].O, runs[1].O)
    np.testing.assert_array_equal(runs[0].K[:19], 0.0)
    np.testing.assert_array_equal(runs[0].K[19:], 0.2)
    # K = 0 -> row 1 until round trip 20; from K = 0.2 on -> row 2 (nearest grid K)
    np.testing.assert_allclose(runs[0].angles[-1], 0.3)


class _Recorder:
    """A controller that holds the angles and keeps what it was shown."""

    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def step(self, measurement, surrogate=None):
        from dlmpc_ros.control.step import ControlStep
        self.seen.append(np.array(measurement))
        return ControlStep(angles=np.array(measurement[2:6]), mode='passive')


def test_measurement_noise_reaches_the_controller_not_the_record():
    scenario = make_scenario('constant', offset=0.1)
    clean, noisy = _Recorder(), _Recorder()
    a = run_closed_loop(clean, scenario, 50, 10, np.zeros(4), SMALL)
    b = run_closed_loop(noisy, scenario, 50, 10, np.zeros(4), SMALL, measurement_noise=0.01,
                        noise_seed=4)
    np.testing.assert_array_equal(a.O, b.O)  # held angles: the laser itself is the same
    shown_clean, shown_noisy = np.array(clean.seen), np.array(noisy.seen)
    ratio = shown_noisy[:, :2] / shown_clean[:, :2] - 1
    assert 0 < np.abs(ratio).max() < 0.05 and np.std(ratio) > 1e-3
    np.testing.assert_array_equal(shown_noisy[:, 2:], shown_clean[:, 2:])  # angles exact
    with np.testing.assert_raises(ValueError):
        run_closed_loop(clean, scenario, 10, 10, measurement_noise=-0.1)


def test_evaluate_takes_measurement_noise_in_fast_mode_only(capsys):
    import pytest

    from dlmpc_ros.cli.evaluate import parse_args
    assert parse_args(['--fast', '--measurement-noise', '0.01', '--out', 'x']) \
        .measurement_noise == 0.01
    assert parse_args(['--fast', '--measurement-round-trips', '3', '--out', 'x']) \
        .measurement_round_trips == 3
    for bad in (['--measurement-noise', '0.01'], ['--fast', '--measurement-noise', '1.5'],
                ['--fast', '--measurement-round-trips', '0']):
        with pytest.raises(SystemExit):
            parse_args([*bad, '--out', 'x'])
    assert '--measurement-noise' in capsys.readouterr().err


def test_a_period_measurement_averaging_its_round_trips_divides_the_noise():
    scenario = make_scenario('constant', offset=0.1)
    shown = {}
    for n in (1, 10):
        clean, noisy = _Recorder(), _Recorder()
        run_closed_loop(clean, scenario, 600, 10, np.zeros(4), SMALL, measurement_round_trips=n)
        run_closed_loop(noisy, scenario, 600, 10, np.zeros(4), SMALL, measurement_noise=0.01,
                        noise_seed=4, measurement_round_trips=n)
        shown[n] = np.array(noisy.seen)[:, :2] / np.array(clean.seen)[:, :2] - 1
    # 60 periods: the standard error of a standard deviation is about 9 %
    assert 0.007 < np.std(shown[1]) < 0.013
    assert 0.5 * np.std(shown[1]) / np.sqrt(10) < np.std(shown[10]) < 0.5 * np.std(shown[1])


def test_a_run_records_how_its_measurements_were_formed_so_a_replay_forms_them_alike():
    from dlmpc_ros.control.esc import ESCController
    from dlmpc_ros.core.bench import BenchConfig
    from dlmpc_ros.evaluation.closed_loop import replay_decisions
    scenario = make_scenario('constant', offset=0.1)
    for n in (1, 4):                    # no meta given: the loop records its own
        record = run_closed_loop(ESCController(np.zeros(4)), scenario, 200, 10,
                                 np.zeros(4), SMALL, measurement_round_trips=n)
        assert record.meta == {'period': 10, 'measurement_round_trips': n,
                               'settle_tolerance': 0.005, 'settle_timeout': 100,
                               'bench': BenchConfig().to_dict()}
        steps = replay_decisions(ESCController(np.zeros(4)), record)
        commanded = record.angles[record.control_round_trip[:-1]]
        np.testing.assert_array_equal(np.stack([s.angles for s in steps[:-1]]), commanded)
