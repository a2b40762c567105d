"""DL-MPC controller logic on small untrained models (the logic, not the performance)."""

import inspect

import numpy as np
import pytest
import torch

from dlmpc_ros.control.dlmpc import DLMPCController
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.paper_loops import PaperDLMPC
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.learning.kmap import KMap, KMapConfig
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig

from test.control.toy_curve import toy_curve


def _controller(curve=None, **config) -> DLMPCController | PaperDLMPC:
    """The paper's loops on small untrained models; with ``curve`` the default strategy on it
    (lock level O 0.2 x 0.5)."""
    if curve is not None:
        return DLMPCController(DLMPCConfig(**config), target_objective=0.2, curve=curve)
    kmap = KMap(KMapConfig(hidden=16), generator=torch.Generator().manual_seed(0))
    mprnn = MPRNN(MPRNNConfig(window=2, horizon=4, n_hidden=16, n_latent=8))
    return PaperDLMPC(kmap, mprnn, DLMPCConfig(**config))


def _measurement(rng, angles):
    return np.r_[3.0 + 0.1 * rng.standard_normal(), 30.0 * np.exp(0.05 * rng.standard_normal()),
                 angles]


def _run(ctrl: PaperDLMPC, periods: int, seed: int, surrogate: float | None = 0.05):
    """Drive the controller with noisy measurements at its own angles; (modes, last step)."""
    rng = np.random.default_rng(seed)
    angles = np.zeros(4)
    modes = []
    for _ in range(periods):
        step = ctrl.step(_measurement(rng, angles), surrogate)
        modes.append(step.mode)
        angles = step.angles
    return modes, step


def test_inner_loop_until_history_is_long_enough_then_outer_loop():
    ctrl = _controller(error_threshold=1e6)
    modes, step = _run(ctrl, ctrl.model.min_history() + 3, seed=0)
    need = ctrl.model.min_history()
    assert modes[:need - 1] == ['inner'] * (need - 1)
    assert set(modes[need - 1:]) == {'outer'}
    assert step.predicted_objective.shape == (4,) and step.iterations >= 1
    assert np.isfinite(step.prediction_error) and step.latency_ms > 0


def test_large_prediction_error_hands_control_to_the_inner_loop():
    ctrl = _controller(error_threshold=1e-6)
    modes, _ = _run(ctrl, ctrl.model.min_history() + 4, seed=1)
    need = ctrl.model.min_history()
    assert modes[need - 1] == 'outer'  # first plan: no prediction to check yet
    assert modes[need:] == ['inner'] * (len(modes) - need)


def test_commands_respect_angle_limits_and_step():
    limits = AngleLimits(-0.5, 1.0, 0.05)
    ctrl = _controller(limits=limits, error_threshold=1e6, learning_rate=0.5)
    rng = np.random.default_rng(2)
    angles = np.array([0.9, -0.45, 0.0, 0.3])
    for _ in range(ctrl.model.min_history() + 6):
        step = ctrl.step(_measurement(rng, angles), 0.1)
        assert (step.angles >= -0.5).all() and (step.angles <= 1.0).all()
        assert np.abs(step.angles - angles).max() <= 0.05 + 1e-9
        angles = step.angles


def test_silent_estimator_holds_the_angles_in_the_inner_loop():
    ctrl = _controller(error_threshold=1e6)
    rng = np.random.default_rng(3)
    angles = np.array([0.1, -0.2, 0.3, 0.4])
    step = ctrl.step(_measurement(rng, angles), None)
    assert step.mode == 'hold'
    np.testing.assert_array_equal(step.angles, angles)
    assert ctrl.step(_measurement(rng, angles), 0.2).mode == 'inner'


def test_controller_has_no_way_to_receive_the_true_birefringence():
    # its verb takes the measurement and the estimate only; that it decides without K is
    # tested by behaviour in test/evaluation/test_no_true_k.py
    for kind in (DLMPCController, PaperDLMPC):
        params = inspect.signature(kind.step).parameters
        assert list(params) == ['self', 'measurement', 'surrogate']
        assert not hasattr(kind, 'observe_truth')


@pytest.mark.parametrize('bad', [{'min_iterations': 0}, {'learning_rate': 0.0},
                                 {'start_iterations': 9, 'max_iterations': 8}])
def test_bad_controller_settings_are_rejected(bad):
    with pytest.raises(ValueError):
        DLMPCConfig(**bad)


def test_warm_up_leaves_the_controller_state_alone():
    ctrl = _controller(error_threshold=1e6)
    ctrl.warm_up()
    assert len(ctrl.monitor.history) == 0 and ctrl.outer.plan is None
    modes, _ = _run(ctrl, ctrl.model.min_history() + 1, seed=4)
    assert modes[-1] == 'outer'


def test_after_a_poor_forecast_the_predictor_is_no_longer_scored():
    """The outer loop hands over for good once its error passes the threshold."""
    ctrl = _controller(error_threshold=1e-6)
    need = ctrl.model.min_history()
    rng = np.random.default_rng(5)
    angles, errors = np.zeros(4), []
    for _ in range(need + 5):
        step = ctrl.step(_measurement(rng, angles), 0.05)
        errors.append(step.prediction_error)
        angles = step.angles
    assert np.isfinite(errors[need])
    assert np.isnan(errors[need + 1:]).all()


def test_with_a_curve_the_surrogate_moves_nothing_and_the_angles_hold_until_tracking():
    ctrl = _controller(toy_curve(), error_threshold=1e6)
    assert [mode.name for mode in ctrl.modes] == ['acquire', 'track', 'hold']
    angles = np.array([0.1, -0.2, 0.3, 0.4])
    patience = ctrl.config.tracking.entry_patience
    for surrogate in [0.5, -1.0, None][:patience - 1]:  # locked (O = 0.2), not yet tracking
        step = ctrl.step(np.r_[6.0, 30.0, angles], surrogate)
        assert step.mode == 'hold'
        np.testing.assert_array_equal(step.angles, angles)
    assert ctrl.step(np.r_[6.0, 30.0, angles], 0.5).mode == 'track'
