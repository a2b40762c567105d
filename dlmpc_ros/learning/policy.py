"""The deep-RL baseline's policy at run time, in numpy: its input features, its network's
deterministic forward pass and its files (no torch, no pickles).

``dlmpc-train drl`` (:mod:`dlmpc_ros.training.drl`) trains the policy with
Stable-Baselines3 on ``ModeLockedLaser-v0`` and exports the policy network's weights to
``models/drl_policy.npz`` (plain arrays, read with ``allow_pickle=False``) and its
architecture, input features and action scaling to ``models/drl_policy.json``; the
training's SB3 archive (which holds pickles) is never shipped or loaded. The forward
pass here equals SB3's deterministic action (tested to 1e-5).

The policy observes the environment's observation (``control/observation.py``: a window
of the latest periods' ``(E, M, alpha[4])``) through :class:`PolicyFeatures` and outputs
an action in [-1, 1]^4, which times ``action_scale`` [rad] is the change of the angles.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.learning.model_files import ModelFileError, regenerate_hint
from dlmpc_ros.learning.tables import read_npz, write_npz

FILE_NAME = 'drl_policy.npz'
SPEC_NAME = 'drl_policy.json'
SCHEMA_VERSION = 1
#: Activations of the hidden layers and what the last layer's output goes through:
#: ``clip`` to [-1, 1] (PPO's Gaussian mean, as SB3's ``predict`` clips it) or ``tanh``
#: (SAC's squashed mean).
ACTIVATIONS = ('tanh', 'relu')
OUTPUTS = ('clip', 'tanh')
#: Features per period (:meth:`PolicyFeatures.__call__`).
PER_PERIOD = 20


def hint() -> str:
    return regenerate_hint('drl')


@dataclass(frozen=True)
class PolicyFeatures:
    """The network's inputs from an observation (B, window * 6) of raw measurements.

    Per period, oldest first: E / ``e_scale``, log M / ``log_m_scale``, O / ``o_scale``
    (O = E / M, at most ``o_clip``), sin 2 alpha and cos 2 alpha (each angle is
    pi-periodic), alpha / ``angle_scale`` (where the angle is in the servo range), and the
    change from the period before: of O / ``o_scale`` times ``o_change_gain`` and of the
    angles / ``step_scale`` (zero for the oldest period). Fixed constants, no fitted
    normalization: the same features for every plant.
    """

    window: int = 4
    e_scale: float = 4.0
    log_m_scale: float = 3.0
    o_scale: float = 0.2
    o_clip: float = 10.0
    o_change_gain: float = 5.0
    angle_scale: float = 2 * math.pi
    step_scale: float = 0.25

    def __post_init__(self) -> None:
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < 1:
            raise ValueError(f'PolicyFeatures.window must be an integer >= 1, got {self.window!r}')
        for name, value in asdict(self).items():
            if name != 'window' and not (math.isfinite(value) and value > 0):
                raise ValueError(f'PolicyFeatures.{name} must be a positive number, got {value!r}')

    @property
    def size(self) -> int:
        return self.window * PER_PERIOD

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        obs = np.asarray(observation, np.float64)
        if obs.ndim != 2 or obs.shape[1] != self.window * 6:
            raise ValueError(f'policy observations must have shape (B, {self.window * 6}), '
                             f'got {obs.shape}')
        m = obs.reshape(obs.shape[0], self.window, 6)
        e, mm, angles = m[..., 0], np.clip(m[..., 1], 1.0, None), m[..., 2:6]
        o = np.clip(e / mm, 0.0, self.o_clip) / self.o_scale
        d_o = np.zeros_like(o)
        d_o[:, 1:] = np.diff(o, axis=1) * self.o_change_gain
        d_a = np.zeros_like(angles)
        d_a[:, 1:] = np.diff(angles, axis=1) / self.step_scale
        x = np.concatenate([(e / self.e_scale)[..., None],
                            (np.log(mm) / self.log_m_scale)[..., None], o[..., None],
                            np.sin(2 * angles), np.cos(2 * angles), angles / self.angle_scale,
                            d_o[..., None], d_a], axis=-1)
        return x.reshape(obs.shape[0], -1).astype(np.float32)


class LearnedPolicy:
    """The deterministic policy: features, a multilayer perceptron, its output's squashing.

    ``layers`` are the (weight (out, in), bias (out,)) pairs, ``activation`` between them;
    ``spec`` the file's JSON (:func:`policy_spec`)."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]], spec: dict) -> None:
        self.layers = [(np.asarray(w, np.float32), np.asarray(b, np.float32)) for w, b in layers]
        self.spec = spec
        self.features = PolicyFeatures(**spec['features'])
        self.activation = spec['architecture']['activation']
        self.output = spec['architecture']['output']
        self.action_scale = float(spec['action']['scale'])
        if self.activation not in ACTIVATIONS or self.output not in OUTPUTS:
            raise ValueError(f'activation must be one of {ACTIVATIONS} and output one of '
                             f'{OUTPUTS}, got {self.activation!r}, {self.output!r}')
        if not (math.isfinite(self.action_scale) and self.action_scale > 0):
            raise ValueError(f'action scale must be positive, got {self.action_scale!r}')

    @property
    def window(self) -> int:
        return self.features.window

    def act(self, observation: np.ndarray) -> np.ndarray:
        """The actions (B, 4) in [-1, 1] for observations (B, window * 6)."""
        x = self.features(observation)
        hidden = np.tanh if self.activation == 'tanh' else (lambda v: np.maximum(v, 0.0))
        for i, (w, b) in enumerate(self.layers):
            x = x @ w.T + b
            if i < len(self.layers) - 1:
                x = hidden(x)
        return np.clip(x, -1.0, 1.0) if self.output == 'clip' else np.tanh(x)

    def deltas(self, observation: np.ndarray) -> np.ndarray:
        """The changes of the angles (B, 4) [rad] for observations (B, window * 6)."""
        return self.act(observation).astype(np.float64) * self.action_scale


def policy_spec(algorithm: str, activation: str, output: str, features: PolicyFeatures,
                action_scale: float, environment: dict, training: dict) -> dict:
    """The JSON beside the weights: the architecture, the features, the action's scale,
    the environment's observation settings (``window``, ``low``, ``high``) and a note of
    the training."""
    return {'schema_version': SCHEMA_VERSION,
            'architecture': {'algorithm': algorithm, 'activation': activation,
                             'output': output},
            'features': asdict(features), 'action': {'scale': float(action_scale)},
            'environment': environment, 'training': training}


def save_policy(models_dir: Path, layers: list[tuple[np.ndarray, np.ndarray]],
                spec: dict) -> Path:
    """Write ``drl_policy.npz`` (the weights) and ``drl_policy.json`` (``spec``) in
    ``models_dir``; returns the weights' path."""
    arrays: dict[str, np.ndarray] = {}
    for i, (w, b) in enumerate(layers):
        arrays[f'w{i}'], arrays[f'b{i}'] = np.asarray(w, np.float32), np.asarray(b, np.float32)
    arrays['schema_version'] = np.array(SCHEMA_VERSION)
    spec = {**spec, 'architecture': {**spec['architecture'],
                                     'layers': [list(np.shape(w)) for w, _ in layers]}}
    return write_npz(Path(models_dir) / FILE_NAME, arrays, spec)


def load_policy(models_dir: Path) -> LearnedPolicy:
    """The policy of ``models_dir``; :class:`ModelFileError` naming ``dlmpc-train drl``
    when either file is missing, unreadable or malformed."""
    path = Path(models_dir) / FILE_NAME
    spec_path = Path(models_dir) / SPEC_NAME
    try:
        arrays = read_npz(path, 'DRL policy weights', hint())
    except (FileNotFoundError, ValueError) as err:
        raise ModelFileError(str(err)) from None
    if not spec_path.is_file():
        raise ModelFileError(f'DRL policy description {spec_path} is missing; {hint()}')
    try:
        spec = json.loads(spec_path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ModelFileError(f'DRL policy description {spec_path} cannot be read ({err}); '
                             f'{hint()}') from None
    try:
        for name, version in (('weights', arrays['schema_version']),
                              ('description', spec['schema_version'])):
            if int(version) != SCHEMA_VERSION:
                raise ValueError(f'{name} of schema {int(version)}, this version reads '
                                 f'{SCHEMA_VERSION}')
        n = sum(1 for k in arrays if k.startswith('w'))
        layers = [(arrays[f'w{i}'], arrays[f'b{i}']) for i in range(n)]
        policy = LearnedPolicy(layers, spec)
        shapes = [list(w.shape) for w, _ in layers]
        if n < 1 or shapes != spec['architecture']['layers']:
            raise ValueError(f'weights of shapes {shapes}, described as '
                             f'{spec["architecture"]["layers"]}')
        sizes = [policy.features.size] + [w.shape[0] for w, _ in layers]
        if any(w.ndim != 2 or b.shape != (w.shape[0],) or w.shape[1] != sizes[i]
               for i, (w, b) in enumerate(layers)) or sizes[-1] != 4:
            raise ValueError('the layers do not chain from the features to 4 actions')
        if not all(np.isfinite(w).all() and np.isfinite(b).all() for w, b in layers):
            raise ValueError('a weight is not finite')
        env = spec['environment']
        if int(env['window']) != policy.window or not float(env['low']) < float(env['high']):
            raise ValueError('the environment settings do not fit the features')
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as err:
        raise ModelFileError(f'DRL policy {path} is malformed ({type(err).__name__}: {err}); '
                             f'{hint()}') from None
    return policy
