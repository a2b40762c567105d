"""The exploring DL-MPC's own runs on training plants, which the predictor is aggregated
with."""

import numpy as np
import pytest

from dlmpc_ros.learning.curve import load_curve
from dlmpc_ros.paths import models_dir
from dlmpc_ros.training.adapt import AdaptConfig, laser_pairs
from dlmpc_ros.training.closed_loop import ClosedLoopConfig, closed_loop_runs


def test_config_keeps_plants_to_fit_and_refuses_bad_settings():
    cfg = ClosedLoopConfig(plants=3, first_seed=2001, validation_plants=1)
    assert cfg.seeds == [2001, 2002, 2003]
    assert ClosedLoopConfig().first_seed > 1000   # none of the evaluation's plants
    with pytest.raises(ValueError, match='validation_plants'):
        ClosedLoopConfig(plants=2, validation_plants=2)
    with pytest.raises(ValueError):
        ClosedLoopConfig(round_trips=0)


def test_runs_hold_only_what_a_laser_measures_and_are_kept(tmp_path):
    cfg = ClosedLoopConfig(plants=1, validation_plants=0, round_trips=3000)
    runs = closed_loop_runs(cfg, models_dir(), tmp_path, show_progress=False)
    run = runs[0]
    assert set(run) == {'round_trip', 'E', 'M', 'angles'}   # no K, no plant parameter
    n = run['round_trip'].size
    assert n > 200 and run['angles'].shape == (n, 4)
    assert np.all(run['E'] > 0) and np.all(np.diff(run['round_trip']) > 0)
    saved = list(tmp_path.glob('2001-3000-77-explore.npz'))
    assert len(saved) == 1
    again = closed_loop_runs(cfg, models_dir(), tmp_path, show_progress=False)
    assert np.array_equal(again[0]['E'], run['E'])          # read back, not run again
    grid, curve, _ = load_curve(models_dir() / 'track_curve.npz')
    x, y, states = laser_pairs(run, grid, curve, AdaptConfig())
    assert x.shape == (y.size, 5) and y.size > 0             # the exploring turns pair up
    assert np.ptp(x[:, 4]) > 0                               # turns of several sizes
