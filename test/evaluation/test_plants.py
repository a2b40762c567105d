"""Plants reach the simulator and the evaluation only: a controller fed a plant run's
measurements decides exactly as in the run without being told the plant, and no model
file changes."""

import hashlib

import numpy as np
import pytest

from dlmpc_ros.control.factory import load_estimator, make_controller
from dlmpc_ros.control.step import MODES, AngleLimits
from dlmpc_ros.core.plants import PlantFamily, parse_plant, plant_fingerprint
from dlmpc_ros.evaluation.closed_loop import replay_decisions
from dlmpc_ros.evaluation.runs import RunSpec, run_fast
from dlmpc_ros.paths import models_dir


def _digest(directory) -> str:
    digest = hashlib.sha256()
    for path in sorted(directory.rglob('*')):
        if path.is_file():
            digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()


@pytest.mark.parametrize('name', ['dlmpc', 'esc'])
def test_a_plant_run_replays_exactly_into_a_controller_that_knows_no_plant(name):
    models = models_dir()
    before = _digest(models)
    spec = RunSpec('sinusoidal', 2, name, round_trips=1200,
                   plant={'pump': 1.6, 'loss': 0.12, 'dispersion': -0.35})
    record = run_fast(spec, models)
    assert record.meta['plant']['pump'] == 1.6
    assert record.meta['plant_fingerprint'] == plant_fingerprint(spec.cavity)
    controller = make_controller(name, models, AngleLimits(max_step=spec.max_step))
    estimator = load_estimator(models) if name == 'dlmpc' else None
    steps = replay_decisions(controller, record, estimator)
    assert [MODES.index(s.mode) for s in steps] == record.mode.tolist()
    np.testing.assert_array_equal(np.stack([s.angles for s in steps[:-1]]),
                                  record.angles[record.control_round_trip[:-1]])
    assert _digest(models) == before  # no model file learnt of the plant


def test_the_plant_changes_the_laser_not_the_controller_inputs_path():
    nominal = run_fast(RunSpec('steps', 3, 'fixed_best', round_trips=400), models_dir())
    weak = run_fast(RunSpec('steps', 3, 'fixed_best', round_trips=400,
                            plant={'pump': 1.5}), models_dir())
    assert not np.allclose(nominal.O, weak.O)
    np.testing.assert_array_equal(nominal.K, weak.K)


def test_plant_settings_are_physical_parameters_only():
    assert parse_plant(['pump=1.6', 'cross_phase=0.7']).four_wave == pytest.approx(0.3)
    for bad, message in ((['points=128'], 'KEY one of'), (['pump=x'], 'bad value'),
                         (['loss=-1'], 'loss must be >= 0')):
        with pytest.raises(ValueError, match=message):
            parse_plant(bad)
    with pytest.raises(ValueError, match='not physical'):
        RunSpec('steps', 1, 'esc', plant={'steps_per_round_trip': 8})


def test_family_draws_are_seeded_and_stay_in_their_ranges():
    family = PlantFamily()
    a, b, c = family.draw(5), family.draw(5), family.draw(5, attempt=1)
    assert a == b and a != c
    for seed in range(20):
        p = family.draw(seed)
        assert 0.88 * 1.73 <= p.pump <= 1.12 * 1.73
        assert 0.8 * 4.23 <= p.saturation_energy <= 1.2 * 4.23
        assert 0.08 <= p.loss <= 0.13 and -0.5 <= p.dispersion <= -0.3
        assert 0.08 <= p.gain_bandwidth <= 0.12
    assert plant_fingerprint(a) == plant_fingerprint(b) != plant_fingerprint(c)
