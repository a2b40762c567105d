"""DL-MPC controller logic on small untrained models (the logic, not the performance)."""

import inspect

import numpy as np
import pytest
import torch

from dlmpc_ros.control.dlmpc import DLMPCController
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.learning.kmap import KMap, KMapConfig
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig


def _controller(**config) -> DLMPCController:
    kmap = KMap(KMapConfig(hidden=16), generator=torch.Generator().manual_seed(0))
    mprnn = MPRNN(MPRNNConfig(window=2, horizon=4, n_hidden=16, n_latent=8))
    return DLMPCController(kmap, mprnn, DLMPCConfig(**config))


def _measurement(rng, angles):
    return np.r_[3.0 + 0.1 * rng.standard_normal(), 30.0 * np.exp(0.05 * rng.standard_normal()),
                 angles]


def _run(ctrl: DLMPCController, periods: int, seed: int, surrogate: float | None = 0.05):
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
    params = inspect.signature(DLMPCController.step).parameters
    assert list(params) == ['self', 'measurement', 'surrogate']
    assert not hasattr(DLMPCController, 'observe_truth')


@pytest.mark.parametrize('bad', [{'min_iterations': 0}, {'learning_rate': 0.0},
                                 {'start_iterations': 9, 'max_iterations': 8},
                                 {'trust_radius': 0.0}, {'objective_guard': 1.5},
                                 {'guard_cooldown': 0}])
def test_bad_controller_settings_are_rejected(bad):
    with pytest.raises(ValueError):
        DLMPCConfig(**bad)


def test_warm_up_leaves_the_controller_state_alone():
    ctrl = _controller(error_threshold=1e6)
    ctrl.warm_up()
    assert len(ctrl.monitor.history) == 0 and ctrl.outer.plan is None
    modes, _ = _run(ctrl, ctrl.model.min_history() + 1, seed=4)
    assert modes[-1] == 'outer'


def test_monitoring_keeps_scoring_the_predictor_in_the_inner_loop():
    need = _controller().model.min_history()
    latched = _controller(error_threshold=1e-6)
    monitored = _controller(error_threshold=1e-6, monitor_prediction=True)
    errors = {}
    for name, ctrl in (('latched', latched), ('monitored', monitored)):
        rng = np.random.default_rng(5)
        angles, errors[name] = np.zeros(4), []
        for _ in range(need + 5):
            step = ctrl.step(_measurement(rng, angles), 0.05)
            errors[name].append(step.prediction_error)
            angles = step.angles
    # after the first plan's error sends both to the inner loop, only the monitored one
    # goes on scoring its predictor (so that it can hand back to the outer loop)
    assert np.isnan(errors['latched'][need + 1:]).all()
    assert np.isfinite(errors['monitored'][need:]).all()


def test_trust_radius_keeps_the_plan_near_the_current_angles():
    ctrl = _controller(error_threshold=1e6, learning_rate=0.5, trust_radius=0.01,
                       limits=AngleLimits(max_step=1.0))
    rng = np.random.default_rng(6)
    angles = np.array([0.2, -0.3, 0.4, 0.1])
    for _ in range(ctrl.model.min_history() + 5):
        step = ctrl.step(_measurement(rng, angles), 0.1)
        if step.mode == 'outer':
            assert np.abs(step.angles - angles).max() <= 0.01 + 1e-6
        angles = step.angles


def test_objective_guard_returns_to_the_inner_loop_when_the_outer_loop_loses_O():
    ctrl = _controller(error_threshold=1e6, objective_guard=0.9, guard_cooldown=4)
    rng = np.random.default_rng(7)
    angles, modes = np.zeros(4), []
    for period in range(ctrl.model.min_history() + 8):
        measurement = _measurement(rng, angles)
        if period >= ctrl.model.min_history():
            measurement[0] *= 0.5  # O halves once the outer loop has taken over
        step = ctrl.step(measurement, 0.05)
        modes.append(step.mode)
        angles = step.angles
    first_outer = modes.index('outer')
    # one outer period loses O: four inner periods follow before the outer loop may return
    assert modes[first_outer + 1:first_outer + 5] == ['inner'] * 4
    assert modes[first_outer + 5] == 'outer'
