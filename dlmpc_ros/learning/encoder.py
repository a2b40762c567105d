"""The estimator's encoder at run time, in numpy: the VAE's posterior mean without torch.

The VAE (:mod:`dlmpc_ros.learning.vae`) is trained with torch; at run time only its
encoder's mean is needed, a three-layer network. ``models/vae_encoder.npz`` holds its
weights as plain arrays (written beside ``vae.pt`` by ``dlmpc-train vae``, loaded without
pickles), so the estimator node starts without importing torch (about 2 s of CPU on the
machines this runs on). It computes the same surrogate as
:meth:`~dlmpc_ros.learning.vae.ConditionalVAE.surrogate` (tested to 1e-5).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dlmpc_ros.learning.model_files import ModelFileError, regenerate_hint
from dlmpc_ros.learning.tables import read_npz, write_npz

FILE_NAME = 'vae_encoder.npz'
SCHEMA_VERSION = 1
#: The encoder's settings stored in the file (besides its weights).
SETTINGS = ('window', 'latent', 'surrogate_dim', 'surrogate_mean', 'surrogate_std',
            'e_mean', 'e_std', 'logm_mean', 'logm_std')


class Encoder:
    """Posterior mean (B, latent) of measurement windows (B, w, 6) ``(E, M, alpha[4])``.

    ``layers`` are the (weight (out, in), bias (out,)) pairs of the network, ReLU between
    them; ``settings`` the values of :data:`SETTINGS`."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]], settings: dict) -> None:
        self.layers = [(np.asarray(w, np.float32), np.asarray(b, np.float32))
                       for w, b in layers]
        self.settings = {k: float(settings[k]) for k in SETTINGS}
        self.window = int(self.settings['window'])
        self.latent = int(self.settings['latent'])

    def features(self, measured: np.ndarray) -> np.ndarray:
        """(B, w * 10) network inputs: normalized E and log M, sin and cos of 2 alpha."""
        s = self.settings
        m = np.asarray(measured, np.float32)
        states = np.stack([(m[..., 0] - s['e_mean']) / s['e_std'],
                           (np.log(m[..., 1]) - s['logm_mean']) / s['logm_std']], axis=-1)
        angles = m[..., 2:6]
        x = np.concatenate([states, np.sin(2 * angles), np.cos(2 * angles)], axis=-1)
        return x.reshape(x.shape[0], -1).astype(np.float32)

    def mean(self, measured: np.ndarray) -> np.ndarray:
        x = self.features(measured)
        for i, (w, b) in enumerate(self.layers):
            x = x @ w.T + b
            if i < len(self.layers) - 1:
                x = np.maximum(x, 0.0)
        return x[:, :self.latent]

    def surrogate(self, measured: np.ndarray) -> np.ndarray:
        """Standardized K surrogate (B,) of measurement windows (B, w, 6)."""
        s = self.settings
        mu = self.mean(measured)[:, int(s['surrogate_dim'])]
        return (mu - s['surrogate_mean']) / s['surrogate_std']


def save_encoder(path: Path, layers: list[tuple[np.ndarray, np.ndarray]],
                 settings: dict, note: dict) -> Path:
    """Write an encoder file (and a .json note beside it)."""
    arrays = {f'w{i}': w for i, (w, _) in enumerate(layers)}
    arrays.update({f'b{i}': b for i, (_, b) in enumerate(layers)})
    arrays['settings'] = np.array([float(settings[k]) for k in SETTINGS])
    arrays['schema_version'] = np.array(SCHEMA_VERSION)
    return write_npz(path, arrays, note)


def load_encoder(models_dir: Path) -> Encoder:
    """The encoder of ``models_dir``; raises :class:`ModelFileError` saying how to remake
    it when the file is missing, unreadable or malformed."""
    path = Path(models_dir) / FILE_NAME
    hint = regenerate_hint('vae')
    try:
        arrays = read_npz(path, 'VAE encoder', hint)
    except (FileNotFoundError, ValueError) as err:
        raise ModelFileError(str(err)) from None
    try:
        if int(arrays['schema_version']) != SCHEMA_VERSION:
            raise ValueError(f'schema {int(arrays["schema_version"])}')
        settings = dict(zip(SETTINGS, arrays['settings'].tolist(), strict=True))
        n = sum(1 for k in arrays if k.startswith('w'))
        layers = [(arrays[f'w{i}'], arrays[f'b{i}']) for i in range(n)]
        encoder = Encoder(layers, settings)
        probe = np.ones((1, encoder.window, 6), np.float32)
        if n < 1 or not np.all(np.isfinite(encoder.surrogate(probe))) \
                or layers[0][0].shape[1] != encoder.window * 10 \
                or layers[-1][0].shape[0] < encoder.latent:
            raise ValueError('layers do not fit the settings')
    except (KeyError, ValueError, TypeError) as err:
        raise ModelFileError(f'VAE encoder {path} is malformed ({err}); {hint}') from None
    return encoder


def note_of(path: Path) -> dict:
    """The .json note beside an encoder file ({} without one)."""
    note = Path(path).with_suffix('.json')
    return json.loads(note.read_text()) if note.exists() else {}
