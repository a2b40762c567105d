"""The tracking curve made from the baseline tables, and its file."""

import numpy as np
import pytest

from dlmpc_ros.learning.curve import load_curve, save_curve
from dlmpc_ros.training.stages.curve import curve_from_baselines

GRID = np.linspace(-0.3, 0.3, 61)
ANGLES = np.stack([2 * GRID, 0.1 + 0 * GRID, -0.2 + GRID, 0.3 + 0 * GRID], axis=1)


def test_curve_file_round_trip_and_errors(tmp_path):
    baselines = {'K': GRID, 'tracking_angles': ANGLES + np.pi * (GRID > 0)[:, None],
                 'tracking_O': 0.2 + 0 * GRID}
    curve = curve_from_baselines(baselines)
    assert set(curve) == {'grid', 'angles', 'objective', 'schema_version'}
    assert np.abs(np.diff(curve['angles'], axis=0)).max() < 0.05   # unwrapped: continuous
    path = save_curve(tmp_path / 'track_curve.npz', curve, 'test')
    grid, angles, objective = load_curve(path)
    np.testing.assert_allclose(objective, 0.2)
    np.testing.assert_allclose(grid, GRID)
    np.testing.assert_allclose(angles, curve['angles'])
    with pytest.raises(FileNotFoundError, match='dlmpc-train curve'):
        load_curve(tmp_path / 'missing.npz')
    (tmp_path / 'bad.npz').write_bytes(b'not a zip')
    with pytest.raises(ValueError, match='dlmpc-train curve'):
        load_curve(tmp_path / 'bad.npz')
    np.savez(tmp_path / 'short.npz', grid=GRID, angles=ANGLES[:, :2], objective=GRID,
             schema_version=np.array(1))
    with pytest.raises(ValueError, match='malformed'):
        load_curve(tmp_path / 'short.npz')
