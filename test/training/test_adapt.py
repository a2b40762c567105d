"""Calibration from a bag: where the recorded angles lie on the rotated curve, the pairs
that correct and fine-tune the predictor, the turn correction and its file, and the
rotation prior (the bag itself: test_bringup)."""

import numpy as np
import pytest
import torch

from dlmpc_ros.learning.curve import load_curve, locate
from dlmpc_ros.paths import models_dir
from dlmpc_ros.learning.response_file import load_response
from dlmpc_ros.learning.turn_correction import load_turn_correction, save_turn_correction
from dlmpc_ros.training.adapt import (AdaptConfig, fine_tune, laser_pairs, prediction_rmse,
                                      rotation_prior, split_periods, turn_correction)


@pytest.fixture(scope='module')
def curve():
    grid, angles, _ = load_curve(models_dir() / 'track_curve.npz')
    return grid, angles


def test_recorded_angles_are_placed_on_the_rotated_curve_and_its_twin(curve):
    grid, angles = curve
    rng = np.random.default_rng(0)
    index = rng.integers(0, grid.size, 20)
    theta = rng.uniform(-0.5, 0.5, 20)
    twin = rng.random(20) < 0.5
    recorded = angles[index] + theta[:, None] + np.where(twin, np.pi / 2, 0.0)[:, None] \
        + np.pi * rng.integers(-1, 2, (20, 4))          # any pi-equivalent a servo is at
    branch, u, got, misfit = locate(recorded, grid, angles)
    np.testing.assert_array_equal(branch, np.where(twin, -1, 1))
    located = angles[np.searchsorted(grid, u - 1e-9)]      # the curve repeats in places
    np.testing.assert_allclose(located, angles[index])
    np.testing.assert_allclose(got, theta, atol=1e-9)
    assert misfit.max() < 1e-9
    far = locate(recorded + np.array([0.3, -0.3, 0.0, 0.0]), grid, angles)[3]
    assert far.min() > 0.05                              # off the family: a large misfit


def _run(grid, angles, thetas, u=-0.2, hold=3):
    """Control periods at one curve point, each rotation held ``hold`` periods, with a
    toy laser whose O peaks at a rotation of 0.15."""
    point = angles[np.argmin(np.abs(grid - u))]
    theta = np.repeat(np.asarray(thetas, float), hold)
    objective = 0.2 - 0.5 * (theta - 0.15) ** 2
    energy = np.full(theta.size, 3.0)
    return {'round_trip': 10.0 * np.arange(1, theta.size + 1), 'E': energy,
            'M': energy / objective, 'angles': point + theta[:, None]}


def test_pairs_are_settled_states_at_the_same_point_and_their_change_of_log_o(curve):
    grid, angles = curve
    periods = _run(grid, angles, [0.0, 0.05, 0.1, 0.05])
    x, y, states = laser_pairs(periods, grid, angles, AdaptConfig(window=4))
    # the first period of each hold follows a change (the very first has no period
    # before it): not settled; 2 settled per hold
    assert states['u'].size == 8
    assert np.all(np.abs(x[:, 0] + 0.2) < 1e-9)          # all at u = -0.2
    for row, target in zip(x, y):
        theta_a, delta = row[1], row[4]
        o = lambda t: 0.2 - 0.5 * (t - 0.15) ** 2          # noqa: E731
        assert target == pytest.approx(np.log(o(theta_a + delta) / o(theta_a)), abs=1e-9)
    assert np.any(x[:, 4] > 0) and np.any(x[:, 4] == 0)  # turns and holds
    assert np.all(np.abs(x[:, 4]) <= 0.1 + 1e-9)


def test_the_rotation_prior_takes_the_best_rotation_bin_where_it_beats_the_shipped_one(curve):
    grid, angles = curve
    periods = _run(grid, angles, [0.0, 0.15, 0.3, 0.15, 0.0], hold=8)
    _, _, states = laser_pairs(periods, grid, angles, AdaptConfig())
    knots = np.linspace(-0.3, 0.3, 13)
    values = rotation_prior(states, knots, AdaptConfig(prior_samples=5))
    assert values[np.argmin(np.abs(knots + 0.2))] == pytest.approx(0.15)  # O +6 % over 0
    assert np.count_nonzero(values) == 1                # no data elsewhere: 0 there
    assert not np.any(rotation_prior(states, knots, AdaptConfig(prior_margin=0.1)))
    assert not np.any(rotation_prior(states, knots, AdaptConfig(prior_samples=1000)))
    no_zero = _run(grid, angles, [0.15, 0.3, 0.15], hold=8)   # nothing at the shipped 0
    _, _, states = laser_pairs(no_zero, grid, angles, AdaptConfig())
    assert not np.any(rotation_prior(states, knots, AdaptConfig()))


def test_split_periods_holds_out_the_last_share_in_time():
    periods = {'round_trip': 10.0 * np.arange(1, 21), 'E': np.ones(20)}
    train, held = split_periods(periods, 0.25)
    assert train['round_trip'].max() < held['round_trip'].min()
    assert (train['E'].size, held['E'].size) == (15, 5)


def _pairs(rng, n, shift):
    """Pairs of the predictor's inputs with targets its shipped model misses by ``shift``."""
    model, _ = load_response(models_dir() / 'response.pt')
    x = np.c_[rng.uniform(-0.2, 0.2, n), rng.uniform(-0.1, 0.1, n), rng.uniform(0.5, 1.5, n),
              rng.uniform(3.0, 4.0, n), rng.uniform(-0.1, 0.1, n)]
    with torch.no_grad():
        shipped = model(torch.as_tensor(x, dtype=torch.float32)).mean(-1).numpy()
    return x, shipped + shift


def test_fine_tune_keeps_what_helps_on_held_out_pairs_and_the_shipped_weights_otherwise():
    rng = np.random.default_rng(0)
    cfg = AdaptConfig(epochs=8, lr=2e-3)
    x, y = _pairs(rng, 300, 0.3)             # this laser: log O 0.3 above the prediction
    x_val, y_val = _pairs(rng, 100, 0.3)
    model, _ = load_response(models_dir() / 'response.pt')
    kept = fine_tune(model, x, y, x_val, y_val, cfg, show_progress=False)
    assert all(epoch > 0 for epoch in kept)
    assert prediction_rmse(model, x_val, y_val) < 0.5 * 0.3
    x_val, y_val = _pairs(rng, 100, -0.3)    # held-out pairs that contradict the fit
    model, _ = load_response(models_dir() / 'response.pt')
    shipped = [p.detach().clone() for p in model.parameters()]
    assert fine_tune(model, x, y, x_val, y_val, cfg, show_progress=False) == [0] * len(kept)
    assert all(torch.equal(p, q) for p, q in zip(model.parameters(), shipped))


def test_the_turn_correction_is_fit_to_what_the_predictor_misses_and_kept_if_it_predicts():
    rng = np.random.default_rng(1)
    model, _ = load_response(models_dir() / 'response.pt')
    x, y = _pairs(rng, 300, 0.0)
    x_val, y_val = _pairs(rng, 100, 0.0)
    y, y_val = y - 0.2 * x[:, 4], y_val - 0.2 * x_val[:, 4]   # turning up loses here
    coefficients, corrected = turn_correction(model, x, y, x_val, y_val, AdaptConfig())
    slope = coefficients[1] / 0.1                               # per rad
    assert -0.21 < slope < -0.19 and abs(coefficients[2]) < 0.01
    assert corrected < 0.01 < prediction_rmse(model, x_val, y_val)
    # held-out pairs where turning up gains instead: the correction does not carry over
    coefficients, corrected = turn_correction(model, x, y, x_val, y_val + 0.4 * x_val[:, 4],
                                              AdaptConfig())
    assert not coefficients.any()
    assert corrected == pytest.approx(prediction_rmse(model, x_val, y_val + 0.4 * x_val[:, 4]))


def test_a_turn_correction_file_round_trips_and_a_malformed_one_stops_the_controller(tmp_path):
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.learning.checkpoint import ModelFileError
    import shutil
    folder = tmp_path / 'models'
    shutil.copytree(models_dir(), folder)
    save_turn_correction(folder, np.array([0.001, -0.02, -0.01]), {'bag': 'test'})
    np.testing.assert_allclose(load_turn_correction(folder), [0.001, -0.02, -0.01])
    controller = load_dlmpc(folder)
    np.testing.assert_allclose(controller.planner.correction.coefficients, [0.001, -0.02, -0.01])
    np.savez(folder / 'turn_correction.npz', coefficients=np.zeros(2), schema_version=1)
    with pytest.raises(ModelFileError, match='turn correction .* is malformed; remake it'):
        load_dlmpc(folder)
    (folder / 'turn_correction.npz').write_bytes(b'not a zip')
    with pytest.raises(ModelFileError, match='turn correction'):
        load_dlmpc(folder)
