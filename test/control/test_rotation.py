"""The learned rotation of the tracking curve and the planner that turns it."""

import numpy as np
import pytest
import torch

from dlmpc_ros.control.dlmpc_config import PlannerConfig, TrackingConfig
from dlmpc_ros.control.rotation_planner import CurveRotation, OnlineCorrection, RotationPlanner
from dlmpc_ros.control.tracking import CurveTracker
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.response import ResponseEnsemble
from dlmpc_ros.learning.response_file import ResponseModelConfig

from test.control.toy_curve import ANGLES, GRID


def test_a_move_turns_the_rotation_at_its_point_by_exactly_that_much():
    rotation = CurveRotation(-0.3, 0.3, knots=7, limit=1.0)
    assert rotation(0.05) == 0.0
    rotation.move(0.05, 0.1)            # between the knots 0.0 and 0.1
    assert rotation(0.05) == pytest.approx(0.1)
    assert rotation(-0.3) == 0.0 and rotation(0.3) == 0.0   # far knots untouched
    rotation.move(0.1, -0.04)           # on a knot
    assert rotation(0.1) == pytest.approx(rotation.values[4])
    rotation.move(0.2, 5.0)
    assert np.abs(rotation.values).max() == 1.0             # within the limit
    assert rotation(9.0) == rotation(0.3)                    # clipped to the range


def test_a_spread_move_turns_the_unexplored_curve_less_with_distance():
    rotation = CurveRotation(-0.3, 0.3, knots=7, limit=1.0, spread=0.1)
    rotation.move(-0.2, 0.1)            # on a knot
    assert rotation(-0.2) == pytest.approx(0.1)
    assert rotation(-0.3) == pytest.approx(0.1 * np.exp(-0.5))
    assert rotation(-0.1) == pytest.approx(0.1 * np.exp(-0.5))
    assert rotation(0.3) == pytest.approx(0.1 * np.exp(-12.5))
    assert np.all(np.diff(rotation.values[1:]) < 0)       # less the farther from -0.2
    rotation.move(-0.2, -0.1)           # the undo takes all of it back
    np.testing.assert_allclose(rotation.values, 0.0, atol=1e-15)
    before = rotation(0.05)
    rotation.move(0.05, 0.1)            # between knots: theta(u) moves by exactly delta
    assert rotation(0.05) == pytest.approx(before + 0.1)


def test_a_spread_into_unexplored_knots_leaves_what_was_learned_there():
    rotation = CurveRotation(-0.3, 0.3, knots=7, limit=1.0, spread=0.1)
    rotation.move(-0.2, 0.1)
    assert list(rotation.explored) == [False, True, False, False, False, False, False]
    assert rotation(-0.1) == pytest.approx(0.1 * np.exp(-0.5))   # a prior where unexplored
    rotation.move(0.0, -0.05)           # explores the knot at 0
    assert rotation.explored[3] and rotation(0.0) == pytest.approx(
        0.1 * np.exp(-2.0) - 0.05)
    assert rotation(-0.2) == pytest.approx(0.1)                 # its own, untouched
    assert rotation(-0.1) == pytest.approx(0.1 * np.exp(-0.5) - 0.05 * np.exp(-0.5))


def test_forgetting_returns_to_the_rotation_the_run_began_with():
    rotation = CurveRotation(-0.3, 0.3, knots=7, limit=1.0, spread=0.1)
    rotation.move(-0.2, 0.1)
    rotation.forget()
    assert not rotation.values.any() and not rotation.explored.any()
    rotation.start_from(np.array([-0.3, 0.3]), np.array([0.2, -0.2]))   # calibrated
    rotation.move(0.0, 0.3)
    rotation.forget()
    np.testing.assert_allclose(rotation.values, np.linspace(0.2, -0.2, 7))


@pytest.mark.parametrize('bad', [dict(low=0.3, high=-0.3), dict(knots=1), dict(limit=0.0),
                                 dict(low=np.nan), dict(spread=-0.1)])
def test_bad_rotation_settings_are_rejected(bad):
    args = {'low': -0.3, 'high': 0.3, 'knots': 5, 'limit': 1.0, **bad}
    with pytest.raises(ValueError):
        CurveRotation(**args)


def _best_turn(log_e: float) -> float:
    """The toy laser's best rotation: more energy, turn the other way."""
    return 0.2 * (1.0 - log_e)


def _toy_gain(theta: np.ndarray, log_e: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Change of log O of the toy laser when the rotation goes theta -> theta + delta."""
    best = _best_turn(log_e)
    return -4.0 * ((theta + delta - best) ** 2 - (theta - best) ** 2)


@pytest.fixture(scope='module')
def toy_model() -> ResponseEnsemble:
    """A small real ensemble fit to the toy laser's response."""
    rng = np.random.default_rng(0)
    n = 4000
    x = np.stack([rng.uniform(-0.3, 0.0, n), rng.uniform(-0.5, 0.5, n),
                  rng.uniform(0.0, 2.0, n), rng.uniform(2.5, 3.5, n),
                  rng.uniform(-0.2, 0.2, n)], axis=1)
    y = _toy_gain(x[:, 1], x[:, 2], x[:, 4])
    config = ResponseModelConfig(members=2, hidden=32, mean=x.mean(0).tolist(),
                                 std=x.std(0).tolist())
    model = ResponseEnsemble(config, torch.Generator().manual_seed(0))
    samples = torch.as_tensor(np.c_[x, y], dtype=torch.float32)
    for m, member in enumerate(model.members):
        def loss(batch, _g, member=member):
            z = (batch[:, :-1] - model.mean) / model.std
            return torch.mean((member(z)[:, 0] - batch[:, -1]) ** 2), {}
        fit(member, loss, samples, epochs=40, batch=256, lr=3e-3, seed=m, show_progress=False)
    return model.eval()


def test_the_planner_turns_toward_the_best_rotation_within_its_trust_radius(toy_model):
    config = PlannerConfig(radius=0.05, spread_penalty=0.0, online=False)
    for log_e in (0.2, 1.8):                     # best turn +0.16 and -0.16
        planner = RotationPlanner(toy_model, config)
        theta = 0.0
        for _ in range(8):
            planner.observe(np.exp(log_e), np.exp(3.0))
            turn = planner.plan(-0.1, theta)
            assert abs(turn) <= config.radius + 1e-12
            theta += turn
        assert theta == pytest.approx(_best_turn(log_e), abs=0.04)
        assert planner.moves >= 3
    # at the best rotation it holds; without a measurement it holds too
    planner = RotationPlanner(toy_model, PlannerConfig(spread_penalty=0.0, online=False))
    assert planner.plan(-0.1, 0.0) == 0.0
    planner.observe(np.exp(1.0), np.exp(3.0))
    assert planner.plan(-0.1, _best_turn(1.0)) == 0.0
    # asked for at least a gain of log O: it turns only where it expects that much
    gain = float(_toy_gain(0.0, 0.2, 0.1))       # the toy's gain of its best turn, +0.1 rad
    for at_least, turns in ((0.5 * gain, True), (2.0 * gain, False)):
        planner = RotationPlanner(toy_model, PlannerConfig(spread_penalty=0.0, online=False))
        planner.observe(np.exp(0.2), np.exp(3.0))
        assert (planner.plan(-0.1, 0.0, at_least=at_least) != 0.0) == turns


def test_under_noise_the_planner_holds_where_the_gain_would_be_lost_in_the_noise(toy_model):
    """A turn predicted to gain ``g`` of log O: the gated planner makes it while the noise
    of its measured gain (one period's noise x sqrt(2 / 3), means of 3 periods before and
    after) is under ``g``, and holds once it is over."""
    deltas = np.linspace(-0.1, 0.1, 21)
    gain = float(np.max(toy_model.predict(-0.1, 0.06, np.exp(1.0), np.exp(3.0), deltas)[0]))
    assert gain > 0.01
    at_gain = gain / np.sqrt(2 / 3)  # one period's noise that makes the gain's spread g

    def first_turn(noise: float, gate: float) -> float:
        planner = RotationPlanner(toy_model, PlannerConfig(spread_penalty=0.0, online=False,
                                                           noise_gate=gate))
        planner.observe(np.exp(1.0), np.exp(3.0))
        return planner.plan(-0.1, 0.06, noise)

    assert first_turn(0.0, 1.0) < -0.01              # no noise: turns toward the best
    assert first_turn(0.8 * at_gain, 1.0) < -0.01
    assert first_turn(1.2 * at_gain, 1.0) == 0.0     # the gain is under the noise: holds
    assert first_turn(1.2 * at_gain, 0.0) < -0.01    # gate off: turns as without noise
    with pytest.raises(ValueError, match='noise_gate'):
        PlannerConfig(noise_gate=-1.0)


def test_the_online_correction_learns_what_the_predictor_gets_wrong_on_this_laser():
    correction = OnlineCorrection(memory=10)
    assert correction(np.array([0.1]))[0] == 0.0
    for delta in (0.1, -0.1, 0.05, -0.05, 0.1, -0.1):   # turns do 0.03 per 0.1 rad worse
        correction.extend([delta], [-0.3 * delta])
    slope = correction(np.array([0.1]))[0] - correction(np.array([0.0]))[0]
    assert -0.03 < slope < -0.01  # shrunk toward 0 by the ridge
    assert correction(np.array([-0.1]))[0] - correction(np.array([0.0]))[0] > 0.01


def test_the_online_correction_learns_that_no_turn_pays_on_this_laser():
    """A predictor that promises a gain for every turn, on a laser whose best rotation
    is the curve's own: the |turn| term learns that turns either way lose (a line in the
    turn alone could not: its slope stays 0), and its slope stays 0."""
    correction = OnlineCorrection(memory=10)
    for delta in (0.1, -0.1, 0.05, -0.05, 0.1, -0.1):  # 0.02 lost per 0.1 rad either way
        correction.extend([delta], [0.001 - 0.2 * abs(delta)])
    turned = correction(np.array([-0.1, 0.1])) - correction(np.array([0.0]))
    assert (turned < -0.005).all()
    assert abs(turned[0] - turned[1]) < 1e-3


def test_a_calibrated_correction_is_where_the_online_fit_starts_and_what_it_is_pulled_to():
    prior = np.array([0.0, -0.02, -0.01])     # from a bag: turning up, and turning at all, lose
    correction = OnlineCorrection(memory=10, ridge=10.0, prior=prior)
    np.testing.assert_allclose(correction.coefficients, prior)
    correction.extend([0.1], [0.0])           # one move that disagrees barely moves it
    assert abs(correction.coefficients[1] - prior[1]) < 0.005
    unpulled = OnlineCorrection(memory=10)
    unpulled.extend([0.1], [0.0])
    np.testing.assert_allclose(unpulled.coefficients, 0.0, atol=1e-12)
    batch = OnlineCorrection(memory=10)       # extend fits as the same adds one by one do
    batch.extend([0.1, -0.05, 0.1], [-0.03, 0.01, -0.02])
    single = OnlineCorrection(memory=10)
    for delta, error in zip([0.1, -0.05, 0.1], [-0.03, 0.01, -0.02]):
        single.extend([delta], [error])
    np.testing.assert_allclose(batch.coefficients, single.coefficients)
    with pytest.raises(ValueError, match='3 finite'):
        OnlineCorrection(memory=10, prior=np.array([0.0, np.nan, 0.0]))


def test_a_move_not_yet_judged_can_be_retracted_once(toy_model):
    planner = RotationPlanner(toy_model, PlannerConfig(radius=0.05, spread_penalty=0.0))
    assert planner.retract() == 0.0                       # nothing moved yet
    planner.observe(np.exp(0.2), np.exp(3.0))
    turn = planner.plan(-0.1, 0.0)
    assert turn > 0 and planner.retract() == turn and planner.undone == 1
    assert planner.retract() == 0.0                       # forgotten: not retracted twice
    planner.observe(np.exp(0.2), np.exp(3.0))
    assert planner.plan(-0.1, 0.0) > 0                    # no stale move judged next
    assert len(planner.correction.moves) == 0


def _toy_tracker(config: TrackingConfig,
                 planner: RotationPlanner | None = None) -> CurveTracker:
    """A tracker on the toy curve, locked above O = 0.1."""
    return CurveTracker(GRID, ANGLES, threshold=0.1, config=config, planner=planner)


def test_a_turn_that_loses_the_laser_before_it_is_judged_is_taken_back(toy_model):
    config = TrackingConfig(entry_patience=1, settle=2, block=1, guard=0.8,
                            guard_periods=2, start=-0.1)
    planner = RotationPlanner(toy_model, PlannerConfig(radius=0.05, spread_penalty=0.0,
                                                       online=False, noise_gate=0.0))
    tracker = _toy_tracker(config, planner)
    for _ in range(20):                 # a steady laser: the planner turns once
        planner.observe(np.exp(0.2), np.exp(3.0))
        tracker.step(0.2)
        if tracker.planned:
            break
    turn, u = tracker.planned, tracker.branch * tracker.estimate
    assert turn > 0 and tracker.rotation(u) == pytest.approx(turn)
    planner.observe(np.exp(0.2), np.exp(3.0))
    tracker.step(0.05)                  # the pulse goes before the next plan,
    tracker.interrupt()                 # and the scan takes over
    assert tracker.rotation(u) == pytest.approx(0.0, abs=1e-12)
    assert planner.undone == 1 and tracker.planned == pytest.approx(-turn)


def test_a_lost_pulse_forgets_the_rotation_learned_in_the_run():
    tracker = _toy_tracker(TrackingConfig(entry_patience=1, start=-0.1))
    tracker.step(0.2)                   # entered
    tracker.rotation.move(-0.1, 0.2)    # a turn kept earlier in the run
    tracker.interrupt()                 # the pulse is lost: the scan takes over
    assert not tracker.rotation.values.any()
    tracker.rotation.move(-0.1, 0.2)
    tracker.interrupt()                 # not tracking: nothing was lost on the curve
    assert tracker.rotation(-0.1) == pytest.approx(0.2)
