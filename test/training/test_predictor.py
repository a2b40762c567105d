"""MP-RNN training: windows of trajectories, the three stages, the horizon errors."""

import numpy as np
import pytest
import torch

from dlmpc_ros.learning.features import Normalizer, features
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig
from dlmpc_ros.training.crbm import CRBMTrainConfig
from dlmpc_ros.training.predictor import (TrainConfig, evaluate_horizon_errors, mprnn_loss,
                                          train_single_step, train_three_stage)
from dlmpc_ros.training.windows import WindowBatch, WindowDataset

from test.mprnn_inputs import CFG, H, N, random_inputs


def test_windows_line_up_with_the_trajectories():
    rng = np.random.default_rng(0)
    n_traj, n_t = 2, H + N + 5
    measured = np.concatenate([rng.uniform(2, 4, (n_traj, n_t, 1)),
                               rng.uniform(20, 60, (n_traj, n_t, 1)),
                               rng.uniform(-1.5, 1.5, (n_traj, n_t, 4))], axis=-1)
    surrogate = rng.standard_normal((n_traj, n_t))
    data = WindowDataset(measured, surrogate, CFG)
    assert len(data) == n_traj * (n_t - H - N + 1)
    batch = data.batch()
    feats = features(torch.tensor(measured), CFG.normalizer).float()
    for w, (traj, t) in enumerate(data.index.tolist()):
        torch.testing.assert_close(batch.history[w], feats[traj, t - H + 1:t + 1])
        torch.testing.assert_close(batch.future_x[w], feats[traj, t + 1:t + N + 1])
        torch.testing.assert_close(batch.future_u[w],
                                   torch.tensor(measured[traj, t + 1:t + N + 1, 2:6]).float())
        torch.testing.assert_close(batch.future_s[w],
                                   torch.tensor(surrogate[traj, t + 1:t + N + 1]).float())
        torch.testing.assert_close(batch.past_s[w],
                                   torch.tensor(surrogate[traj, t - N + 1:t + 1]).float())
    assert len(data.subset(data.index[:, 0] == 1)) == len(data) // 2
    strided = WindowDataset(measured, surrogate, CFG, stride=3)
    assert len(strided) == n_traj * len(range(H - 1, n_t - N, 3))
    with pytest.raises(ValueError, match='shorter'):
        WindowDataset(measured[:, :H + N - 1], surrogate[:, :H + N - 1], CFG)


# -- tiny end-to-end on a synthetic driven system -----------------------------------------
def synthetic_laser(n_traj: int, n_t: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(E, M) relax towards targets set by the angles and a drifting K; the angles jump to
    random values at random steps. Returns measured (n_traj, n_t, 6) and a noisy K."""
    rng = np.random.default_rng(seed)
    measured = np.zeros((n_traj, n_t, 6))
    surrogate = np.zeros((n_traj, n_t))
    for i in range(n_traj):
        phase, period = rng.uniform(0, 2 * np.pi), rng.uniform(40, 80)
        alpha = rng.uniform(-np.pi / 2, np.pi / 2, 4)
        e, logm = 3.0, 3.5
        for t in range(n_t):
            if rng.random() < 0.3:
                alpha = rng.uniform(-np.pi / 2, np.pi / 2, 4)
            k = 0.25 * np.sin(2 * np.pi * t / period + phase)
            e_target = 3.0 + 0.8 * np.cos(2 * (alpha[0] - k)) + 0.4 * np.sin(2 * alpha[1])
            logm_target = 3.5 + 0.4 * np.cos(2 * alpha[2] + k)
            e += 0.4 * (e_target - e) + 0.02 * rng.standard_normal()
            logm += 0.4 * (logm_target - logm) + 0.01 * rng.standard_normal()
            measured[i, t] = [e, np.exp(logm), *alpha]
            surrogate[i, t] = k + 0.02 * rng.standard_normal()
    return measured, surrogate


@pytest.fixture(scope='module')
def trained():
    measured, surrogate = synthetic_laser(12, 150, seed=0)
    norm = Normalizer.fit(measured[..., 0], measured[..., 1])
    config = MPRNNConfig(window=2, horizon=4, n_hidden=32, n_latent=16, norm=norm.to_dict())
    train = WindowDataset(measured, surrogate, config)
    test = WindowDataset(*synthetic_laser(3, 100, seed=1), config)
    model = MPRNN(config, seed=0)
    settings = TrainConfig(crbm=CRBMTrainConfig(epochs=4), single_step_epochs=6,
                           horizon_epochs=5, batch_size=32, lr=3e-3)
    seen = []
    history = train_three_stage(model, train, settings,
                                progress=lambda stage, epoch, loss: seen.append(stage))
    return model, train, test, history, seen


def test_every_stage_lowers_its_loss(trained):
    _, _, _, history, seen = trained
    assert list(history) == ['crbm', 'single_step', 'receding_horizon']
    assert [len(h) for h in history.values()] == [4, 6, 5]
    for stage, losses in history.items():
        assert np.isfinite(losses).all(), stage
        assert losses[-1] < losses[0], stage
    assert seen == ['crbm'] * 4 + ['single_step'] * 6 + ['receding_horizon'] * 5


def test_beats_persistence_at_the_horizon(trained):
    model, train, test, _, _ = trained
    errors = evaluate_horizon_errors(model, test)
    for name in ('e', 'm', 'o'):
        model_err, persist = getattr(errors, name), getattr(errors, f'{name}_persistence')
        assert model_err.shape == persist.shape == (N,)
        assert model_err[-1] < 0.7 * persist[-1], name
    as_dict = errors.to_dict()
    assert as_dict['rmse_O_model'] == pytest.approx(errors.o.tolist())
    assert as_dict['rmse_M_persistence'] == pytest.approx(errors.m_persistence.tolist())
    assert len(as_dict) == 6
    batch = test.batch()
    fed_back = mprnn_loss(model(batch.history, batch.future_u), batch)
    assert torch.isfinite(fed_back)


def test_objective_term_adds_the_squared_error_of_o():
    model = MPRNN(CFG)
    history, future_u, future_x = random_inputs()
    out = model(history, future_u)
    batch = WindowBatch(history=history, future_x=future_x, future_u=future_u,
                        future_s=torch.zeros(3, N), past_s=torch.zeros(3, N))
    base = mprnn_loss(out, batch)
    norm = CFG.normalizer
    expected = ((out.objective - norm.objective(future_x[..., :2])) ** 2).sum(1).mean()
    with_o = mprnn_loss(out, batch, objective_weight=7.0, norm=norm)
    assert torch.isclose(with_o - base, 7.0 * expected, rtol=1e-4)


def test_cosine_schedule_shrinks_the_late_updates():
    """With ``cosine`` the learning rate falls to 0 over the stage, so the second of two
    epochs moves the weights much less than the first; at a constant rate it does not."""
    measured, surrogate = synthetic_laser(4, 60, seed=2)
    norm = Normalizer.fit(measured[..., 0], measured[..., 1])
    config = MPRNNConfig(window=2, horizon=4, n_hidden=16, n_latent=8, norm=norm.to_dict())
    data = WindowDataset(measured, surrogate, config)

    def late_over_early(cosine: bool) -> float:
        model = MPRNN(config, seed=0)
        snapshots = [torch.cat([p.detach().flatten() for p in model.parameters()])]
        settings = TrainConfig(single_step_epochs=2, batch_size=16, lr=3e-3, cosine=cosine)
        train_single_step(model, data, settings, progress=lambda *_: snapshots.append(
            torch.cat([p.detach().flatten() for p in model.parameters()])))
        first, second = (float((b - a).norm()) for a, b in zip(snapshots, snapshots[1:]))
        return second / first

    assert late_over_early(cosine=True) < 0.5 * late_over_early(cosine=False)
