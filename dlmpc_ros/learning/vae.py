"""The birefringence estimator: a variational autoencoder (paper section 3B).

Unsupervised: it never sees K. The encoder reads a window of ``w`` recent measurements
``(E, M, alpha)`` (as :func:`features`) and returns a Gaussian posterior over a small
latent z. Two decoders are offered:

- conditional: the decoder reconstructs the window's ``(E_n, logM_n)`` from z *and the
  angles*, so z only has to carry what the angles leave unexplained;
- plain (the paper's): the decoder reconstructs every feature, angles included, from z.

One latent coordinate is the K surrogate (:attr:`VAEConfig.surrogate_dim`, chosen by the
training stage without labels, :mod:`dlmpc_ros.training.stages.vae`). The surrogate is
published standardized (zero mean, unit variance on the training data), not in K's units.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import load_model
from dlmpc_ros.learning.encoder import FILE_NAME as ENCODER_FILE
from dlmpc_ros.learning.encoder import save_encoder
from dlmpc_ros.learning.features import N_FEATURES, Normalizer, angle_features, features
from dlmpc_ros.learning.seeding import reset_linear_layers


@dataclass(frozen=True)
class VAEConfig:
    """Architecture of the estimator and how its surrogate is read (stored in its file)."""

    window: int = 1
    """w: measurements per encoder input window."""
    latent: int = 2
    """Size of the latent z."""
    conditional: bool = True
    """True: the decoder gets the angles and reconstructs (E, M); False (the paper's
    plain VAE): it reconstructs every feature, angles included, from z alone."""
    hidden: int = 64
    """Units of the encoder's and the decoder's hidden layers."""
    beta: float = 0.1
    """Weight of the KL term of the loss."""
    normalizer: dict = field(default_factory=lambda: Normalizer().to_dict())
    """Normalizer of E and log M, as :meth:`Normalizer.to_dict`."""
    surrogate_dim: int = 0
    """The latent coordinate that is the K surrogate (chosen after training)."""
    surrogate_mean: float = 0.0
    """Mean of that coordinate on the training data (the surrogate is standardized)."""
    surrogate_std: float = 1.0
    """Its standard deviation there (> 0)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'window', 'latent', 'hidden')
        checks.counts(self, 'surrogate_dim', minimum=0)
        if self.surrogate_dim >= self.latent:
            raise ValueError(f'VAEConfig.surrogate_dim must be < latent = {self.latent}, '
                             f'got {self.surrogate_dim}')
        if not isinstance(self.conditional, bool):
            raise ValueError(f'VAEConfig.conditional must be a bool, got {self.conditional!r}')
        checks.non_negative(self, 'beta')
        checks.finite(self, 'surrogate_mean')
        checks.positive(self, 'surrogate_std')
        Normalizer(**self.normalizer)

    def to_dict(self) -> dict:
        return asdict(self)


class ConditionalVAE(nn.Module):
    """Encoder q(z | window of features), decoder p(window of states | z, angles).

    ``generator`` (optional) draws the initial weights (PyTorch's default scheme).
    """

    def __init__(self, config: VAEConfig, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.config = config
        self.norm = Normalizer(**config.normalizer)
        w, h, z = config.window, config.hidden, config.latent
        self.encoder = nn.Sequential(nn.Linear(w * N_FEATURES, h), nn.ReLU(), nn.Linear(h, h),
                                     nn.ReLU(), nn.Linear(h, 2 * z))
        n_in = z + w * 8 if config.conditional else z
        n_out = w * 2 if config.conditional else w * N_FEATURES
        self.decoder = nn.Sequential(nn.Linear(n_in, h), nn.ReLU(), nn.Linear(h, h),
                                     nn.ReLU(), nn.Linear(h, n_out))
        if generator is not None:
            reset_linear_layers(self, generator)

    def encode(self, measured: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Posterior mean and log-variance (B, latent) of measurements (B, w, 6)."""
        x = features(measured, self.norm).flatten(1)  # (B, w * 10)
        mu, logvar = self.encoder(x).chunk(2, dim=-1)
        return mu, logvar.clamp(-12.0, 8.0)

    def decode(self, z: torch.Tensor, measured: torch.Tensor) -> torch.Tensor:
        """Reconstruction (B, w, 2) of the normalized states from z and the window's angles
        (conditional), or (B, w, 10) of all features from z alone (plain)."""
        if not self.config.conditional:
            return self.decoder(z).view(-1, self.config.window, N_FEATURES)
        angles = angle_features(measured[..., 2:6]).flatten(1)  # (B, w * 8)
        return self.decoder(torch.cat([z, angles], dim=-1)).view(-1, self.config.window, 2)

    def loss(self, measured: torch.Tensor, generator: torch.Generator | None = None
             ) -> tuple[torch.Tensor, dict[str, float]]:
        """Negative ELBO per sample: squared reconstruction error + beta * KL."""
        mu, logvar = self.encode(measured)
        eps = torch.randn(mu.shape, generator=generator)
        z = mu + torch.exp(0.5 * logvar) * eps
        target = (self.norm.states(measured[..., 0], measured[..., 1])  # (B, w, 2)
                  if self.config.conditional else features(measured, self.norm))
        recon = ((self.decode(z, measured) - target) ** 2).sum(dim=(1, 2)).mean()
        kl = (-0.5 * (1 + logvar - mu ** 2 - logvar.exp())).sum(dim=1).mean()
        return recon + self.config.beta * kl, {'recon': float(recon.detach()),
                                               'kl': float(kl.detach())}

    @torch.no_grad()
    def surrogate(self, measured: torch.Tensor) -> torch.Tensor:
        """Standardized K surrogate (B,) of measurement windows (B, w, 6)."""
        mu, _ = self.encode(measured)
        c = self.config
        return (mu[:, c.surrogate_dim] - c.surrogate_mean) / c.surrogate_std


def load_vae(path: str | Path) -> tuple[ConditionalVAE, dict]:
    """The estimator and its file's payload (config, metrics, fingerprint); raises
    :class:`~dlmpc_ros.learning.checkpoint.ModelFileError`."""
    return load_model(path, 'vae', lambda config: ConditionalVAE(VAEConfig(**config)))


def surrogate_of(vae: ConditionalVAE, measured: np.ndarray) -> np.ndarray:
    """Surrogate (B,) of measurement windows (B, w, 6)."""
    return vae.surrogate(torch.as_tensor(measured, dtype=torch.float32)).numpy()


def export_encoder(vae: ConditionalVAE, models_dir: Path, note: dict) -> Path:
    """Write the encoder of ``vae`` as ``models_dir/vae_encoder.npz`` (plain arrays, read
    without torch by :func:`dlmpc_ros.learning.encoder.load_encoder`)."""
    layers = [(m.weight.detach().numpy(), m.bias.detach().numpy())
              for m in vae.encoder if isinstance(m, nn.Linear)]
    c, n = vae.config, vae.norm
    settings = {'window': c.window, 'latent': c.latent, 'surrogate_dim': c.surrogate_dim,
                'surrogate_mean': c.surrogate_mean, 'surrogate_std': c.surrogate_std,
                'e_mean': n.e_mean, 'e_std': n.e_std, 'logm_mean': n.logm_mean,
                'logm_std': n.logm_std}
    return save_encoder(Path(models_dir) / ENCODER_FILE, layers, settings, note)


def windows(measured: np.ndarray, window: int) -> np.ndarray:
    """Sliding windows (lanes * (T - w + 1), w, 6) of trajectories (lanes, T, 6)."""
    lanes, steps, _ = measured.shape
    idx = np.arange(window)[None, :] + np.arange(steps - window + 1)[:, None]
    return measured[:, idx].reshape(-1, window, measured.shape[-1])


def steady_windows(measured: np.ndarray, window: int) -> np.ndarray:
    """Steady states (B, 6) as windows of ``window`` identical measurements."""
    return np.repeat(measured[:, None, :], window, axis=1)
