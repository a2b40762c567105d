"""The training stages of the VAE estimator and the K-to-angles map (the tiny dataset),
the model files they write, and the ``dlmpc-train`` command."""

import json

import numpy as np
import pytest
import torch

from dlmpc_ros.cli.data import QUICK_EXTRA_LANES
from dlmpc_ros.learning.checkpoint import ModelFileError, load_checkpoint, save_checkpoint
from dlmpc_ros.learning.features import Normalizer
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.kmap import KMapConfig, load_kmap
from dlmpc_ros.learning.vae import ConditionalVAE, VAEConfig, load_vae, windows
from dlmpc_ros.training.stages.kmap import (SubsetRule, train_kmap, train_kmap_stage,
                                            training_subset)
from dlmpc_ros.training.stages.vae import choose_surrogate, train_vae_stage
from dlmpc_ros.training.trajectories import load_trajectories
from dlmpc_ros.training.workspace import Workspace


def _synthetic(lanes=4, steps=300, seed=0):
    rng = np.random.default_rng(seed)
    k = np.cumsum(rng.normal(0, 0.02, (lanes, steps)), axis=1)
    alpha = rng.uniform(-1.5, 1.5, (lanes, steps, 4))
    e = 3 + np.sin(2 * alpha[..., 0]) + 2 * k
    m = 25 * np.exp(0.3 * np.cos(2 * alpha[..., 1]) - k)
    return np.concatenate([e[..., None], m[..., None], alpha], -1).astype(np.float32), k


def test_vae_loss_decreases_and_surrogate_tracks_the_hidden_factor():
    measured, k = _synthetic()
    norm = Normalizer.fit(measured[..., 0], measured[..., 1])
    model = ConditionalVAE(VAEConfig(window=1, normalizer=norm.to_dict()),
                           generator=torch.Generator().manual_seed(0))
    history = fit(model, model.loss, windows(measured, 1), epochs=30, batch=128,
                  show_progress=False)
    assert history[-1] < 0.5 * history[0]
    dim, scores = choose_surrogate(model, measured)
    mu, _ = model.encode(torch.as_tensor(windows(measured, 1)))
    r = np.corrcoef(mu[:, dim].detach().numpy(), k.ravel())[0, 1]
    assert abs(r) > 0.8, (r, scores)


def test_checkpoint_round_trip_and_clear_errors(tmp_path):
    model = ConditionalVAE(VAEConfig())
    path = save_checkpoint(tmp_path / 'vae.pt', 'vae', model.state_dict(),
                           model.config.to_dict(), {'a': 1.0}, 'abc')
    loaded, payload = load_vae(path)
    x = torch.rand(5, 1, 6) + 1
    assert torch.equal(loaded.surrogate(x), model.surrogate(x))
    assert payload['metrics'] == {'a': 1.0} and payload['data_fingerprint'] == 'abc'
    with pytest.raises(ModelFileError, match='missing.*dlmpc-train vae'):
        load_checkpoint(tmp_path / 'nope.pt', 'vae')
    (tmp_path / 'bad.pt').write_bytes(b'not a model')
    with pytest.raises(ModelFileError, match='corrupt.*dlmpc-train vae'):
        load_checkpoint(tmp_path / 'bad.pt', 'vae')
    with pytest.raises(ModelFileError, match='not a kmap model'):
        load_checkpoint(path, 'kmap')
    torch.save({'kind': 'vae', 'evil': torch.nn.Linear(1, 1)}, tmp_path / 'pickled.pt')
    with pytest.raises(ModelFileError, match='corrupt'):  # weights_only refuses modules
        load_checkpoint(tmp_path / 'pickled.pt', 'vae')


def test_subset_rule_takes_best_per_interval_and_avoids_jumps():
    s = np.repeat(np.linspace(-1, 1, 5), 3)
    o = np.tile([0.10, 0.11, 0.05], 5)
    base = np.zeros((15, 4))
    base[1::3] = 1.2  # the slightly better candidate is on another branch ...
    base[4] = 0.0     # ... except in interval 1, where the branches swap
    base[3] = 1.2
    centres, angles, chosen_o = training_subset(
        s, o, base, SubsetRule(intervals=5, delta=0.4, top=2, jump_penalty=0.0))
    assert centres.size == 5 and np.allclose(chosen_o, 0.11)
    _, smooth, _ = training_subset(s, o, base, SubsetRule(intervals=5, delta=0.4, top=2,
                                                          jump_penalty=1.0))
    assert np.ptp(smooth, axis=0).max() < 1e-12  # one branch throughout


def test_kmap_fit_reduces_loss():
    centres = np.linspace(-2, 2, 40)
    targets = np.stack([0.3 * centres, -0.2 * centres, 0.1 + 0 * centres, 0.4 * np.tanh(centres)],
                       axis=1)
    model, losses = train_kmap(centres, targets, KMapConfig(), steps=600)
    assert losses[-1] < 0.05 * losses[0]
    with torch.no_grad():
        got = model(torch.as_tensor(centres, dtype=torch.float32)[:, None]).numpy()
    assert np.abs(got - targets).max() < 0.1


def test_training_stages_on_the_tiny_dataset(quick_data, tmp_path):
    ws = Workspace(quick_data, tmp_path / 'models')
    vae_metrics = train_vae_stage(ws, epochs=2, show_progress=False)
    assert 0 <= vae_metrics['abs_pearson_r_heldout'] <= 1
    assert (ws.figures / 'vae_surrogate.png').stat().st_size > 10_000
    kmap_metrics = train_kmap_stage(ws, steps=100)
    assert len(kmap_metrics['per_k_ratio_from_oracle_state']) == 7
    model, payload = load_kmap(ws.model('kmap'))
    assert payload['metrics']['vae_fingerprint'] == load_vae(ws.model('vae'))[1][
        'data_fingerprint']
    assert model(torch.zeros(3, 1)).shape == (3, 4)


def test_train_command_builds_every_model_file_and_the_card(quick_data, tmp_path):
    from dlmpc_ros.cli.train import main as train_main
    from dlmpc_ros.learning.mprnn import load_mprnn

    models = tmp_path / 'models'
    assert train_main(['all', '--quick', '--no-progress', '--workers', '1', '--data-dir',
                       str(quick_data), '--models-dir', str(models)]) == 0
    for name in ('vae.pt', 'vae_encoder.npz', 'kmap.pt', 'mprnn.pt', 'track_curve.npz',
                 'response.pt', 'metrics.json', 'MODEL_CARD.md'):
        assert (models / name).is_file(), name
    kmap, _ = load_kmap(models / 'kmap.pt')
    model = load_mprnn(models / 'mprnn.pt', kmap=kmap)
    history = torch.zeros(2, model.min_history(), 10)
    out = model(history)  # controls from the map
    assert out.u.shape == (2, model.config.horizon, 4)
    card = (models / 'MODEL_CARD.md').read_text()
    assert '| vae |' in card and '| mprnn |' in card
    metrics = json.loads((models / 'metrics.json').read_text())
    held_out = load_trajectories(quick_data / 'trajectories')['held_out']
    assert metrics['mprnn']['train_trajectories'] == (~held_out).sum() + QUICK_EXTRA_LANES
    closed_loop = metrics['response']['closed_loop']   # aggregated with its own runs
    assert closed_loop['held_out_plants'] == [2002] and closed_loop['pairs'] > 0
    assert metrics['response']['data']['training_pairs'] > closed_loop['pairs']

    report = tmp_path / 'check'
    assert train_main(['check-estimator', '--quick', '--no-progress', '--data-dir',
                       str(quick_data), '--models-dir', str(models), '--out', str(report)]) == 0
    result = json.loads((report / 'metrics.json').read_text())
    assert set(result['surrogate_abs_r']) == {'trajectories', 'trajectories_angles_only',
                                              'trajectories_E_M_only', 'sweep'}
    assert 'angles only' in (report / 'report.md').read_text()
    assert (report / 'surrogate_sources.png').stat().st_size > 10_000


def test_train_command_says_how_to_make_missing_inputs(tmp_path, capsys):
    from dlmpc_ros.cli.train import main as train_main

    assert train_main(['kmap', '--data-dir', str(tmp_path), '--models-dir',
                       str(tmp_path)]) == 2
    assert 'dlmpc-train vae' in capsys.readouterr().err


def test_the_numpy_encoder_gives_the_vae_surrogate_without_torch(tmp_path):
    """The estimator node loads vae_encoder.npz (no torch); it must say what vae.pt says."""
    import subprocess
    import sys

    from dlmpc_ros.learning.encoder import load_encoder
    from dlmpc_ros.learning.vae import export_encoder
    vae = ConditionalVAE(VAEConfig(window=3, surrogate_dim=1, surrogate_mean=0.2,
                                   surrogate_std=1.5), torch.Generator().manual_seed(0))
    export_encoder(vae, tmp_path, {'test': True})
    encoder = load_encoder(tmp_path)
    rng = np.random.default_rng(0)
    measured = np.concatenate([rng.uniform(1, 5, (40, 3, 1)), rng.uniform(10, 200, (40, 3, 1)),
                               rng.uniform(-3, 3, (40, 3, 4))], axis=-1).astype(np.float32)
    np.testing.assert_allclose(encoder.surrogate(measured),
                               vae.surrogate(torch.as_tensor(measured)).numpy(), atol=1e-5)
    code = ('import sys; import dlmpc_ros.nodes.vae_estimator_node, '
            'dlmpc_ros.nodes.baseline_controller_node; print("torch" in sys.modules)')
    assert subprocess.run([sys.executable, '-c', code], capture_output=True,
                          text=True).stdout.strip() == 'False'
