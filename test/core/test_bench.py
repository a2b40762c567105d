"""The lab bench: servos, encoders and detectors around the cavity."""

import numpy as np
import pytest

from dlmpc_ros.core.bench import BENCH_PRESETS, Bench, BenchConfig, parse_bench

START = np.array([0.1, -0.2, 0.3, 0.4])


def _moves(config: BenchConfig, target: np.ndarray, round_trips: int) -> np.ndarray:
    bench = Bench(config, START)
    bench.command(target)
    return np.array([bench.advance() for _ in range(round_trips)])


def test_an_ideal_bench_reaches_a_command_on_the_next_round_trip_and_reads_exactly():
    bench = Bench(BenchConfig(), START)
    target = START + np.array([0.3, -0.1, 0.0, 1e-9])
    bench.command(target)
    np.testing.assert_array_equal(bench.advance(), target)  # exactly: no a + (b - a)
    np.testing.assert_array_equal(bench.read_angles(), target)
    assert bench.read_detectors(1, 3.2, 18.0, 1.5) == (3.2, 18.0, 1.5)
    assert BenchConfig().ideal and BenchConfig().instant_servos


def test_servos_start_after_their_lag_and_turn_at_their_slew_rate():
    target = START + np.array([0.25, -0.05, 0.0, 0.0])
    path = _moves(BenchConfig(servo_lag=6, slew_rate=0.04), target, 13)
    np.testing.assert_array_equal(path[:6], np.tile(START, (6, 1)))  # 6 round trips idle
    np.testing.assert_allclose(path[6, :2], START[:2] + [0.04, -0.04])
    np.testing.assert_array_equal(path[-1], target)                   # 6 + 7 round trips
    assert not np.array_equal(path[-2], target)
    assert BenchConfig(servo_lag=6, slew_rate=0.04).full_step_round_trips(0.25) == 13
    bench = Bench(BenchConfig(servo_lag=3), START)
    bench.command(target)
    bench.advance()
    bench.command(target)  # the same command again does not restart the lag
    assert [bench.advance() is not None and bench.settled for _ in range(3)] == [False, False,
                                                                                  True]


def test_backlash_leaves_the_optic_short_of_the_drive_after_a_reversal():
    bench = Bench(BenchConfig(backlash=0.02), START)
    bench.command(START + 0.1)
    optic = bench.advance()
    np.testing.assert_allclose(optic, START + 0.09)       # dragged by the far side of the play
    np.testing.assert_allclose(bench.read_angles(), START + 0.1)  # the encoder reads the drive
    bench.command(START + 0.05)
    np.testing.assert_allclose(bench.advance(), START + 0.06)


def test_encoders_and_detectors_report_with_noise_steps_a_ceiling_and_slow_spectra():
    config = BenchConfig(encoder_noise=0.001, encoder_resolution=np.radians(0.05),
                         detector_noise=0.01, detector_saturation=3.0, spectrum_refresh=5)
    bench = Bench(config, START, seed=3)
    readings = np.array([bench.read_angles() for _ in range(2000)])
    steps = readings / np.radians(0.05)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    assert 0.0008 < np.std(readings[:, 0]) < 0.0014
    rows = np.array([bench.read_detectors(r, 3.2 if r % 2 else 2.0, 18.0, 1.0)
                     for r in range(1, 2001)])
    assert rows[:, 0].max() == 3.0                         # the ceiling
    odd = rows[1::2, 0]                                     # true E = 2.0
    assert 0.008 < np.std(odd / 2.0) < 0.012
    m = rows[:, 1]
    assert np.all(m[1:5] == m[0]) and m[5] != m[4]         # a new M every 5 round trips
    np.testing.assert_allclose(rows[1::2, 2], (odd / 2.0) ** 2)  # peak scales as E squared


def test_presets_and_settings_parse_and_bad_ones_are_refused():
    assert parse_bench(['lab']) == BenchConfig(**BENCH_PRESETS['lab'])
    assert parse_bench(['servo-6', 'servo_lag=2']).servo_lag == 2
    assert parse_bench([]) == BenchConfig()
    for bad, match in ((['warp'], 'unknown bench'), (['lag=2'], 'unknown bench setting'),
                       (['servo_lag=2.5'], 'integer'), (['slew_rate=x'], 'number'),
                       (['slew_rate=-1'], '>= 0'), (['backlash=3'], r'\[0, 0.5\]')):
        with pytest.raises(ValueError, match=match):
            parse_bench(bad)
