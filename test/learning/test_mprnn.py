"""The MP-RNN model: shapes, causality, feedback, the map for missing controls, its file."""

import pytest
import torch
from torch import nn

from dlmpc_ros.learning.checkpoint import ModelFileError, save_checkpoint
from dlmpc_ros.learning.features import angle_features
from dlmpc_ros.learning.kmap import KMap, KMapConfig
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig, load_mprnn, save_mprnn

from test.mprnn_inputs import CFG, H, N, random_inputs


class CellInputs:
    """Records the current window given to every cell call (encoder calls first)."""

    def __init__(self, model: MPRNN) -> None:
        self.x_cur: list[torch.Tensor] = []
        self.handle = model.cell.register_forward_pre_hook(self._record)

    def _record(self, module, args):
        self.x_cur.append(args[1].detach().clone())

    def decoder(self, j: int) -> torch.Tensor:
        return self.x_cur[N + j]


def test_config_and_history_length():
    assert CFG.min_history() == N + 2 * CFG.window == MPRNN(CFG).min_history()
    assert MPRNNConfig.from_dict(CFG.to_dict()) == CFG
    with pytest.raises(ValueError, match='unknown'):
        MPRNNConfig.from_dict({**CFG.to_dict(), 'extra': 1})
    with pytest.raises(ValueError, match='window'):
        MPRNNConfig(window=0)
    with pytest.raises(ValueError, match='history must be'):
        MPRNN(CFG)(random_inputs(rows=H - 1)[0], random_inputs(rows=H - 1)[1])


def test_output_shapes_and_longer_history():
    model = MPRNN(CFG)
    history, future_u, _ = random_inputs(batch=5, rows=H + 7)
    out = model(history, future_u)
    assert out.v.shape == (5, N, 2) and out.k.shape == (5, N, 1) and out.u.shape == (5, N, 4)
    assert out.objective.shape == (5, N)
    assert out.v_enc.shape == (5, N, 2) and out.k_enc.shape == (5, N, 1)
    torch.testing.assert_close(out.objective, model.norm.objective(out.v))
    torch.testing.assert_close(out.u, future_u)
    only_needed = model(history[:, -H:], future_u)  # older rows are not used
    torch.testing.assert_close(only_needed.v, out.v)


def test_objective_gradient_reaches_every_future_control():
    model = MPRNN(CFG)
    history, future_u, _ = random_inputs(batch=4)
    future_u.requires_grad_(True)
    model(history, future_u).objective.sum().backward()
    grad = future_u.grad
    assert grad is not None and torch.isfinite(grad).all()
    assert (grad.abs().sum(dim=(0, 2)) > 0).all()  # each of the N steps


def test_encoder_is_causal():
    """Encoder cell j predicts v_{t-N+j+1} from rows up to t-N+j and control u_{t-N+j+1}."""
    model = MPRNN(CFG)
    history, future_u, _ = random_inputs()
    out = model(history, future_u)
    other_u = random_inputs(seed=1)[1]
    torch.testing.assert_close(model(history, other_u).v_enc, out.v_enc)
    target_row = H - N  # the row of v_{t-N+1}, the first encoder cell's target
    changed = history.clone()
    changed[:, target_row, :2] += 1.0  # its states, not its control
    out2 = model(changed, future_u)
    torch.testing.assert_close(out2.v_enc[:, 0], out.v_enc[:, 0])
    assert not torch.allclose(out2.v_enc[:, 1], out.v_enc[:, 1])


def test_receding_horizon_feeds_predictions_back():
    model = MPRNN(CFG)
    history, future_u, future_x = random_inputs()
    rec = CellInputs(model)
    out = model(history, future_u, feed_back=True)
    for j in range(1, N):  # the newest row of decoder cell j's window is step t+j
        fed = torch.cat([out.v[:, j - 1], angle_features(out.u[:, j - 1])], dim=-1)
        torch.testing.assert_close(rec.decoder(j)[:, -1], fed)
    rec.x_cur.clear()
    model(history, future_u, feed_back=False, future_x=future_x)
    for j in range(1, N):
        torch.testing.assert_close(rec.decoder(j)[:, -1], future_x[:, j - 1])
    rec.handle.remove()


def test_perturbing_the_first_prediction_moves_only_fed_back_steps():
    model = MPRNN(CFG)
    history, future_u, future_x = random_inputs()
    calls = []

    def nudge_first_decoder_output(module, args, output):
        calls.append(None)
        return output + 0.5 if len(calls) == N + 1 else output

    results = {}
    for feed_back in (True, False):
        plain = model(history, future_u, feed_back=feed_back, future_x=future_x)
        calls.clear()
        handle = model.cell.out.register_forward_hook(nudge_first_decoder_output)
        nudged = model(history, future_u, feed_back=feed_back, future_x=future_x)
        handle.remove()
        results[feed_back] = plain, nudged
    plain, nudged = results[True]
    torch.testing.assert_close(nudged.v[:, 0], plain.v[:, 0] + 0.5)
    assert not torch.allclose(nudged.v[:, 1:], plain.v[:, 1:])
    assert not torch.allclose(nudged.k[:, 1:], plain.k[:, 1:])
    plain, nudged = results[False]  # teacher forcing: later inputs are the true rows
    torch.testing.assert_close(nudged.v[:, 1:], plain.v[:, 1:])
    torch.testing.assert_close(nudged.k, plain.k)


def test_future_x_is_ignored_when_feeding_back_and_used_otherwise():
    model = MPRNN(CFG)
    history, future_u, future_x = random_inputs()
    other_x = random_inputs(seed=7)[2]
    a = model(history, future_u, feed_back=True, future_x=future_x)
    b = model(history, future_u, feed_back=True, future_x=other_x)
    c = model(history, future_u, feed_back=True)
    torch.testing.assert_close(a.v, b.v)
    torch.testing.assert_close(a.v, c.v)
    forced = model(history, future_u, feed_back=False, future_x=future_x)
    torch.testing.assert_close(forced.v[:, 0], a.v[:, 0])  # step 1 sees only the history
    assert not torch.allclose(forced.v[:, 1:], a.v[:, 1:])
    with pytest.raises(ValueError, match='future_x'):
        model(history, future_u, feed_back=False)


def test_kmap_seeds_missing_controls():
    kmap = nn.Linear(1, 4)
    model = MPRNN(CFG, kmap=kmap)
    history, future_u, _ = random_inputs()
    out = model(history)
    torch.testing.assert_close(out.u, kmap(out.k))
    partial = model(history, future_u[:, :2])
    torch.testing.assert_close(partial.u[:, :2], future_u[:, :2])
    torch.testing.assert_close(partial.u[:, 2:], kmap(partial.k[:, 2:]))
    assert all(key.startswith('cell.') for key in model.state_dict())
    assert not any(p is kmap.weight for p in model.parameters())
    model.kmap = None
    with pytest.raises(ValueError, match='kmap'):
        model(history)
    with pytest.raises(ValueError, match='kmap'):
        model(history, future_u[:, :2])


def test_save_load_round_trip_and_bad_files(tmp_path):
    model = MPRNN(CFG, seed=3)
    kmap = nn.Linear(1, 4)
    path = save_mprnn(tmp_path / 'mprnn.pt', model, {'rmse_o_h4': 0.01}, 'abc123')
    loaded = load_mprnn(path, kmap=kmap)
    assert loaded.kmap is kmap and loaded.config == model.config
    history, future_u, _ = random_inputs(batch=16, seed=4)
    with torch.no_grad():
        a, b = model(history, future_u), loaded(history, future_u)
    assert torch.equal(a.v, b.v) and torch.equal(a.k, b.k)

    corrupt = tmp_path / 'corrupt.pt'
    corrupt.write_bytes(path.read_bytes()[:200])
    with pytest.raises(ModelFileError, match='corrupt'):
        load_mprnn(corrupt)
    with pytest.raises(ModelFileError, match='missing'):
        load_mprnn(tmp_path / 'absent.pt')
    wrong = save_checkpoint(tmp_path / 'wrong.pt', 'mprnn', {'x': torch.zeros(1)},
                            model.config.to_dict(), {}, 'f')
    with pytest.raises(ModelFileError, match='valid MP-RNN'):
        load_mprnn(wrong)


def test_assigning_kmap_sets_it_without_registering_it():
    model = MPRNN(MPRNNConfig(window=2, horizon=3, n_hidden=8, n_latent=4))
    keys = set(model.state_dict())
    kmap = KMap(KMapConfig(hidden=8))
    model.kmap = kmap
    assert model.kmap is kmap and set(model.state_dict()) == keys
