"""No controller sees the true K, tested by behaviour: a fresh controller fed a recorded
run's measurements decides exactly as it did in the run, while the process's true K is
changed (another scenario has run since) and then removed (the drift scenarios and the
simulator raise if anything asks them). A plugged-in controller (the example of
docs/controllers.md) is held to the same test."""

import numpy as np
import pytest

from dlmpc_ros.control.factory import load_estimator, make_controller
from dlmpc_ros.control.step import MODES, AngleLimits
from dlmpc_ros.core import drift
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.plants import PlantFamily, plant_parameters
from dlmpc_ros.evaluation.closed_loop import replay_decisions
from dlmpc_ros.evaluation.runs import RunSpec, run_fast
from dlmpc_ros.paths import models_dir

ROUND_TRIPS = 1500
#: A development plant of the family, where the planner turns the curve (on the nominal
#: cavity the shipped predictor sees no turn worth making).
PLANT = plant_parameters(PlantFamily().draw(1))


def _no_truth(*_args, **_kwargs):
    raise AssertionError('a controller asked for the true K or the simulator')


@pytest.mark.parametrize('name', ['dlmpc', 'esc', 'fixed_best', 'bo', 'drl',
                                  'dlmpc_ros.examples.hill_climber:make'])
def test_replayed_measurements_give_the_same_decisions_without_the_true_k(name, monkeypatch):
    models = models_dir()
    spec = RunSpec('random_walk', 1, name, round_trips=ROUND_TRIPS, plant=PLANT)
    record = run_fast(spec, models)
    if name == 'dlmpc':  # the replay covers holding, the tracker and the planner
        assert {MODES.index(m) for m in ('hold', 'track', 'plan')} <= set(record.mode.tolist())
    # the true K changes: another drift and laser run in the process before the replay ...
    run_fast(RunSpec('steps', 3, name, round_trips=200), models)
    # ... and then it is gone: no scenario can be built or asked, no laser stepped
    monkeypatch.setattr(drift, 'make_scenario', _no_truth)
    for cls in (drift.Sinusoidal, drift.Steps, drift.RandomWalk, drift.Chirp,
                drift.Constant):
        monkeypatch.setattr(cls, '__call__', _no_truth)
    monkeypatch.setattr(Cavity, 'run', _no_truth)
    controller = make_controller(name, models, AngleLimits(max_step=spec.max_step))
    estimator = load_estimator(models) if name == 'dlmpc' else None
    steps = replay_decisions(controller, record, estimator)
    assert [MODES.index(s.mode) for s in steps] == record.mode.tolist()
    commanded = record.angles[record.control_round_trip[:-1]]  # applied from r + 1 on
    np.testing.assert_array_equal(np.stack([s.angles for s in steps[:-1]]), commanded)


def test_the_replay_tells_a_controller_that_reads_the_true_k():
    """The oracle baseline reads K (``observe_truth``, evaluation only): replayed without
    it, it cannot repeat its run, so the check above would catch a controller that did."""
    models = models_dir()
    record = run_fast(RunSpec('sinusoidal', 2, 'oracle', round_trips=ROUND_TRIPS), models)
    steps = replay_decisions(make_controller('oracle', models), record)
    commanded = record.angles[record.control_round_trip[:-1]]
    assert not np.array_equal(np.stack([s.angles for s in steps[:-1]]), commanded)
