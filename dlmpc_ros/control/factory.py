"""The built-in controllers' factories and helpers to build any controller by spec from
the shipped model files (used by the controller nodes and by the evaluation, so that
both run exactly the same objects).

The factories :func:`dlmpc`, :func:`esc`, :func:`ga`, :func:`passive`,
:func:`fixed_best`, :func:`oracle`, :func:`bo` and :func:`drl` are registered by name in
setup.py (entry-point group ``dlmpc_ros.controllers``), like any plug-in's
(:mod:`dlmpc_ros.control.plugins`).
A factory raises :class:`~dlmpc_ros.learning.checkpoint.ModelFileError` (missing or
corrupt file, with the command that regenerates it) or ValueError (bad settings);
:func:`make_controller` reports either as one line (ControllerSpecError). The
torch-based pieces (DL-MPC, estimator) are imported when they are built, so that a
baseline controller starts without loading torch (and the Bayesian optimization's
scikit-learn likewise).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dlmpc_ros.control.baselines import FixedBestController, OracleController, PassiveController
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.esc import ESCController
from dlmpc_ros.control.ga import GAConfig, GAController
from dlmpc_ros.control.step import AngleLimits, Controller
from dlmpc_ros.control.plugins import build
from dlmpc_ros.learning.tables import load_baselines

if TYPE_CHECKING:  # torch-based (and scikit-learn-based): imported where they are built
    from dlmpc_ros.control.bo import BOController
    from dlmpc_ros.control.dlmpc import DLMPCController
    from dlmpc_ros.control.drl import DRLController
    from dlmpc_ros.control.paper_loops import PaperDLMPC
    from dlmpc_ros.learning.estimator import SurrogateEstimator

CONTROLLERS = ('dlmpc', 'esc', 'ga', 'passive', 'fixed_best', 'oracle', 'bo', 'drl')
BASELINES_FILE = 'oracle.npz'


def load_estimator(models_dir: Path) -> SurrogateEstimator:
    """The run-time VAE estimator from ``models_dir/vae_encoder.npz`` (numpy; no torch)."""
    from dlmpc_ros.learning.estimator import SurrogateEstimator
    from dlmpc_ros.learning.encoder import load_encoder
    return SurrogateEstimator(load_encoder(Path(models_dir)))


def load_dlmpc(models_dir: Path, config: DLMPCConfig | None = None
               ) -> DLMPCController | PaperDLMPC:
    """The DL-MPC controller from ``models_dir``: with tracking settings (and a lock level in
    ``kmap.pt``'s metrics), the default strategy from ``track_curve.npz``,
    ``rotation_prior.npz`` and ``turn_correction.npz`` if a calibration left them, and
    (unless the planner is off) ``response.pt``; without, the paper's loops from ``kmap.pt``
    and ``mprnn.pt`` (no file holds the true K of a run or a plant's parameters)."""
    from dlmpc_ros.learning.checkpoint import ModelFileError, regenerate_hint
    from dlmpc_ros.learning.kmap import load_kmap
    config = config or DLMPCConfig()
    kmap, payload = load_kmap(Path(models_dir) / 'kmap.pt')
    metrics = payload.get('metrics')
    target = metrics.get('subset_mean_O') if isinstance(metrics, dict) else None
    if not isinstance(metrics, dict) or not (
            target is None or (isinstance(target, float) and np.isfinite(target)
                               and target > 0)):
        raise ModelFileError(f'model file {Path(models_dir) / "kmap.pt"} has malformed metrics '
                             f'(subset_mean_O must be a positive number); '
                             f'{regenerate_hint("kmap")}')
    if config.tracking is None or not target:
        from dlmpc_ros.control.paper_loops import PaperDLMPC
        from dlmpc_ros.learning.mprnn import load_mprnn
        return PaperDLMPC(kmap, load_mprnn(Path(models_dir) / 'mprnn.pt', kmap), config,
                          target_objective=float(target) if target else None)
    from dlmpc_ros.control.dlmpc import DLMPCController
    from dlmpc_ros.learning.curve import FILE_NAME, load_curve
    from dlmpc_ros.learning.rotation_prior import load_rotation_prior
    from dlmpc_ros.learning.turn_correction import load_turn_correction
    try:
        curve = load_curve(Path(models_dir) / FILE_NAME)
    except (FileNotFoundError, ValueError) as err:
        raise ModelFileError(f'{err} (or turn curve tracking off)') from None
    try:
        prior = load_rotation_prior(Path(models_dir))
        correction = load_turn_correction(Path(models_dir))
    except ValueError as err:
        raise ModelFileError(str(err)) from None
    response = None
    if config.planner is not None:
        from dlmpc_ros.learning.response_file import load_response
        response, _ = load_response(Path(models_dir) / 'response.pt')
    return DLMPCController(config, float(target), curve, response, prior, correction)


def oracle_table(baselines: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(K grid, angles) the oracle and the passive setting use: the branch-continuous
    tracking path (the point-wise arg-max jumps between branches and loses lock)."""
    return baselines['K'], baselines['tracking_angles']


def passive_angles(baselines: dict[str, np.ndarray], initial_k: float) -> np.ndarray:
    """The best angles for the initial K: what the passive baseline holds."""
    k_grid, table = oracle_table(baselines)
    return table[np.abs(k_grid - initial_k).argmin()].copy()


def dlmpc(models_dir: Path, limits: AngleLimits, *,
          dlmpc_config: DLMPCConfig | None = None) -> DLMPCController | PaperDLMPC:
    """The DL-MPC (:func:`load_dlmpc`) with ``dlmpc_config`` (default: the shipped
    settings) within ``limits``."""
    return load_dlmpc(models_dir, replace(dlmpc_config or DLMPCConfig(), limits=limits))


def dlmpc_paper(models_dir: Path, limits: AngleLimits) -> PaperDLMPC:
    """The paper's DL-MPC alone (section 3D: VAE + map inner loop, MP-RNN outer loop; no
    lock scan, curve tracking or planned turns) within ``limits``: the mpc_controller
    node's ``strategy:=paper``."""
    return load_dlmpc(models_dir, DLMPCConfig(limits=limits, acquisition=None,
                                              tracking=None, planner=None))


def esc(models_dir: Path, limits: AngleLimits) -> ESCController:
    """Extremum seeking (no model file)."""
    return ESCController(limits=limits)


def ga(models_dir: Path, limits: AngleLimits, *,
       ga_config: GAConfig | None = None) -> GAController:
    """The genetic algorithm with ``ga_config`` (no model file)."""
    return GAController(ga_config, limits)


def bo(models_dir: Path, limits: AngleLimits) -> BOController:
    """Bayesian optimization with the shipped :class:`~dlmpc_ros.control.bo.BOConfig`
    (no model file)."""
    from dlmpc_ros.control.bo import BOController
    return BOController(limits=limits)


def drl(models_dir: Path, limits: AngleLimits) -> DRLController:
    """The deep-RL baseline: the policy of ``models_dir/drl_policy.npz`` + ``.json``
    (``dlmpc-train drl``; numpy, no pickles)."""
    from dlmpc_ros.control.drl import DRLController
    from dlmpc_ros.learning.policy import load_policy
    return DRLController(load_policy(Path(models_dir)), limits)


def passive(models_dir: Path, limits: AngleLimits, *, angles: np.ndarray | None = None,
            initial_k: float | None = None) -> PassiveController:
    """Holds ``angles``, or the best angles for ``initial_k`` (the setting a person tuned
    for the start, then left alone; evaluation only)."""
    if angles is None:
        if initial_k is None:
            raise ValueError('passive needs its angles or the initial K they were tuned for')
        angles = passive_angles(load_baselines(Path(models_dir) / BASELINES_FILE), initial_k)
    return PassiveController(angles, limits)


def fixed_best(models_dir: Path, limits: AngleLimits) -> FixedBestController:
    """Holds the angles with the best worst-case O over the K range."""
    return FixedBestController(load_baselines(Path(models_dir) / BASELINES_FILE)
                               ['fixed_best_angles'], limits)


def oracle(models_dir: Path, limits: AngleLimits) -> OracleController:
    """The best angles for the true K (reads it through ``observe_truth``; evaluation
    only)."""
    return OracleController(*oracle_table(load_baselines(Path(models_dir) / BASELINES_FILE)),
                            limits)


def make_baseline(name: str, models_dir: Path, limits: AngleLimits | None = None,
                  angles: np.ndarray | None = None, initial_k: float | None = None,
                  ga_config: GAConfig | None = None) -> Controller:
    """A built-in baseline controller: ``esc``, ``ga`` (with ``ga_config``), ``passive``
    (``angles``, or the best for ``initial_k``), ``fixed_best``, ``oracle``, ``bo`` or
    ``drl``."""
    if name not in CONTROLLERS[1:]:
        raise ValueError(f'unknown baseline {name!r}; choose one of {CONTROLLERS[1:]}')
    return build(name, models_dir, limits, angles=angles, initial_k=initial_k,
                 ga_config=ga_config)


def make_controller(spec: str, models_dir: Path, limits: AngleLimits | None = None,
                    initial_k: float | None = None,
                    dlmpc_config: DLMPCConfig | None = None) -> Controller:
    """Any controller by spec (a registered name such as those of :data:`CONTROLLERS`, or
    ``package.module:factory``) within ``limits``; ``initial_k`` and ``dlmpc_config``
    reach the factories that name them (``passive``, ``dlmpc``)."""
    return build(spec, models_dir, limits, initial_k=initial_k, dlmpc_config=dlmpc_config)
