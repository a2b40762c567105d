"""The laser's own estimator and map from a bag: its windows, what it learns without
labels, and the models folder it writes (a recorded bag end to end: test_bringup)."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.training.adapt_estimator import (EstimatorAdaptConfig, calibrate_estimator,
                                                period_rows, pulse_windows)

MODELS = Path(__file__).resolve().parents[2] / 'models'


def _states(rows: np.ndarray, period: int = 10) -> np.ndarray:
    """``/laser/state`` messages (n, 10): every period's rows (period, 6) in round-trip
    order, as (round_trip, E, M, O, energy, peak, alpha[4])."""
    out = []
    for i, (e, m, *angles) in enumerate(rows.reshape(-1, 6)):
        out.append([i + 1, e, m, e / m, e, 1.0, *angles])
    return np.asarray(out, float)


def test_a_period_row_is_the_mean_of_its_round_trips_at_its_angles():
    rt = np.array([[4.0, 2.0, 0.1, 0.2, 0.3, 0.4]] * 10 + [[6.0, 2.0, 0.1, 0.2, 0.3, 0.4]] * 10)
    rt[15:, 2] = 0.5                               # new angles halfway through period 2
    states = _states(rt)[::-1]                     # any order of arrival
    rows = period_rows(states, period=10, round_trips=10)
    np.testing.assert_allclose(rows[0], [4.0, 2.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(rows[1], [6.0, 2.0, 0.5, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(period_rows(states, 10, 1), rows)  # no noise: same means


def test_windows_hold_a_pulse_in_every_period():
    rows = np.tile([5.0, 1.0, 0, 0, 0, 0], (10, 1))
    rows[4, 0] = 0.5                                  # one period without a pulse
    windows, ends = pulse_windows(rows, 3, 0.3)
    assert windows.shape == (5, 3, 6)                 # periods 0-2, 1-3, 5-7, 6-8, 7-9
    np.testing.assert_array_equal(ends, [2, 3, 7, 8, 9])
    assert np.all(windows[..., 0] == 5.0)
    assert pulse_windows(rows, 11, 0.3)[0].shape == (0, 11, 6)


def _dithered_laser(periods: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Period rows (P, 6) of a toy laser under a dither: the first angle steps +-0.05 in
    blocks of 3 periods, a hidden k drifts slowly in [0.05, 0.35], and E is highest
    where the angle equals k, so only E tells k. Returns the rows and k (P,)."""
    rng = np.random.default_rng(seed)
    t = np.arange(periods)
    k = 0.2 + 0.15 * np.sin(2 * np.pi * t / 400.0)
    angle = 0.05 * np.where((t // 3) % 2, 1.0, -1.0)
    energy = 5.0 - 10.0 * (angle - k) ** 2 + 0.01 * rng.standard_normal(periods)
    rows = np.zeros((periods, 6))
    rows[:, 0], rows[:, 1], rows[:, 2] = energy, 10.0, angle
    rows[:, 3:] = [0.2, 0.4, -0.3]
    return rows, k


def test_the_laser_estimator_learns_a_hidden_drift_from_windows_without_labels(tmp_path):
    """A toy laser whose E under the dither tells where k is: the VAE, trained on the
    windows alone, gives a surrogate that follows k on the windows held out (later in
    time), and the map and files are written where the controller reads them."""
    from dlmpc_ros.control.factory import load_dlmpc, load_estimator
    from dlmpc_ros.learning.kmap import load_kmap
    from dlmpc_ros.learning.vae import load_vae, surrogate_of
    rows, k = _dithered_laser(1600)
    out = tmp_path / 'models'
    shutil.copytree(MODELS, out)
    cfg = EstimatorAdaptConfig(epochs=40, map_steps=300)
    report = calibrate_estimator(_states(np.repeat(rows, 10, axis=0)), out, cfg, period=10,
                                 round_trips=10, pulse_fraction=0.3, validation=0.25)
    assert report['kept'] and report['windows'] == int(round(0.75 * (1600 - 11)))
    vae, payload = load_vae(out / 'vae.pt')
    assert vae.config.window == 12 and payload['metrics']['adapted']['kept']
    windows, _ = pulse_windows(rows, 12, 0.3)
    held = slice(report['windows'], None)
    s = surrogate_of(vae, windows[held])
    assert abs(np.corrcoef(s, k[11:][held])[0, 1]) > 0.8
    _, kmap_payload = load_kmap(out / 'kmap.pt')
    _, shipped = load_kmap(MODELS / 'kmap.pt')
    assert kmap_payload['metrics']['subset_mean_O'] == shipped['metrics']['subset_mean_O']
    estimator = load_estimator(out)                  # the exported encoder, numpy only
    assert estimator.encoder.window == 12
    for row in rows[-12:]:
        surrogate, _ = estimator.update(row)
    assert surrogate == pytest.approx(float(s[-1]), abs=1e-4)
    assert load_dlmpc(out, DLMPCConfig(tracking=None)).kmap is not None  # the paper's map


def test_too_few_windows_keep_the_shipped_estimator(tmp_path):
    rows, _ = _dithered_laser(100)
    out = tmp_path / 'models'
    shutil.copytree(MODELS, out)
    before = (out / 'vae.pt').read_bytes()
    report = calibrate_estimator(_states(np.repeat(rows, 10, axis=0)), out,
                                 EstimatorAdaptConfig(), period=10, round_trips=10,
                                 pulse_fraction=0.3, validation=0.25)
    assert not report['kept'] and '200 needed' in report['why']
    assert (out / 'vae.pt').read_bytes() == before


def test_invalid_settings_are_refused():
    with pytest.raises(ValueError, match='window'):
        EstimatorAdaptConfig(window=0)
    with pytest.raises(ValueError, match='beta'):
        EstimatorAdaptConfig(beta=0.0)
