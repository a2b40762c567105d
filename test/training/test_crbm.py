import numpy as np
import pytest
import torch

from dlmpc_ros.training.crbm import CRBM, CRBMTrainConfig, pretrain_input_layers
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig

B = 2  # window rows
D = B * 10


def correlated_windows(n: int = 3000, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Gaussian (current, past) windows (n, b, 10) driven by 3 shared factors, with
    non-zero means and unequal scales (so the standardization matters)."""
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n, 3))
    mix_v, mix_c = rng.standard_normal((3, D)), rng.standard_normal((3, D))
    scale = rng.uniform(0.2, 3.0, D)
    v = (z @ mix_v + 0.2 * rng.standard_normal((n, D))) * scale + rng.uniform(-2, 2, D)
    c = 0.8 * z @ mix_c + 0.3 * rng.standard_normal((n, D))
    return (torch.tensor(v, dtype=torch.float32).reshape(n, B, 10),
            torch.tensor(c, dtype=torch.float32).reshape(n, B, 10))


def test_cd1_lowers_reconstruction_error():
    v, c = correlated_windows()
    crbm = CRBM(D, D, 16, seed=0)
    crbm.set_standardization(v, c)
    before = crbm.reconstruction_error(v, c)
    history = crbm.fit(v, c, CRBMTrainConfig(epochs=5, max_samples=None))
    after = crbm.reconstruction_error(v, c)
    assert before == pytest.approx(1.0, abs=0.05)  # untrained: each column's variance
    assert after < 0.5 * before
    assert history[-1] < history[0] and len(history) == 5
    assert crbm.reconstruct(v, c).shape == (len(v), D)


def test_fit_is_seeded():
    v, c = correlated_windows(600)
    config = CRBMTrainConfig(epochs=2, seed=3)
    a, b = CRBM(D, D, 8, seed=1), CRBM(D, D, 8, seed=1)
    a.fit(v, c, config)
    b.fit(v, c, config)
    for key, value in a.state_dict().items():
        assert torch.equal(value, b.state_dict()[key]), key
    other = CRBM(D, D, 8, seed=1)
    other.fit(v, c, CRBMTrainConfig(epochs=2, seed=4))
    assert not torch.equal(other.weight, a.weight)


def test_pretrain_copies_folded_weights_into_the_input_layers():
    v, c = correlated_windows(1500)
    model = MPRNN(MPRNNConfig(window=B, horizon=3, n_hidden=12, n_latent=6))
    untouched = {name: p.detach().clone() for name, p in model.named_parameters()
                 if not name.startswith(('cell.cur.', 'cell.lcur.', 'cell.past.'))}
    crbm, history = pretrain_input_layers(model, v, c, CRBMTrainConfig(epochs=2))
    assert len(history) == 2
    cell = model.cell
    with torch.no_grad():
        # the cell's two long-term pre-activations add up to the machine's hidden input
        v_s = (v.flatten(1) - crbm.v_mean) / crbm.v_std
        c_s = (c.flatten(1) - crbm.c_mean) / crbm.c_std
        machine = v_s @ crbm.weight.T + c_s @ crbm.cond_hidden.T + crbm.hidden_bias
        torch.testing.assert_close(cell.lcur(v.flatten(1)) + cell.past(c.flatten(1)), machine,
                                   atol=1e-4, rtol=1e-4)
    assert torch.equal(cell.cur.weight, cell.lcur.weight)
    assert torch.equal(cell.cur.bias, cell.lcur.bias)
    for name, p in model.named_parameters():
        if name in untouched:
            assert torch.equal(p, untouched[name]), name


def test_rejects_windows_of_the_wrong_size():
    v, c = correlated_windows(100)
    model = MPRNN(MPRNNConfig(window=3, horizon=2, n_hidden=4, n_latent=4))
    with pytest.raises(ValueError, match='windows must hold'):
        pretrain_input_layers(model, v, c)
    crbm = CRBM(D, D, 4)
    with pytest.raises(ValueError, match='visible and'):
        crbm.reconstruction_error(v[:, :1], c)
    with pytest.raises(ValueError, match='as many'):
        crbm.fit(v, c[:50])
    with pytest.raises(ValueError, match='epochs'):
        CRBMTrainConfig(epochs=0)
