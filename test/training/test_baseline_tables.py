"""Baseline tables: fixed best angle set, branch-continuous tracking path, file loader."""

import numpy as np
import pytest

from dlmpc_ros.core.angles import angle_distance
from dlmpc_ros.learning.tables import REQUIRED_KEYS, load_baselines, save_baselines
from dlmpc_ros.training.baseline_tables import (PathConfig, fixed_best_angles, sweep_grid,
                                                tracking_path)

K_GRID = np.linspace(-0.3, 0.3, 7)


def synthetic_sweep(chains: dict[int, tuple[list[float], list[float]]]) -> dict[str, np.ndarray]:
    """A sweep from ``{chain: (angles (4,), O per K (7,))}``; O <= 0 marks a point that
    did not converge."""
    rows = {name: [] for name in ('chain', 'K', 'alpha', 'O', 'converged', 'finite',
                                  'pulses')}
    for chain, (angles, o) in chains.items():
        for k, value in zip(K_GRID, o):
            rows['chain'].append(chain)
            rows['K'].append(k)
            rows['alpha'].append(angles)
            rows['O'].append(max(value, 0.01))
            rows['converged'].append(value > 0)
            rows['finite'].append(True)
            rows['pulses'].append(1)
    return {name: np.asarray(values) for name, values in rows.items()}


def test_fixed_best_takes_the_best_worst_case_and_counts_failures_as_zero():
    sweep = synthetic_sweep({
        0: ([0.1, 0.2, 0.3, 0.4], [0.30, 0.30, 0.30, 0.30, 0.30, 0.30, -1]),  # best mean, fails
        1: ([0.5, 0.6, 0.7, 0.8], [0.15, 0.16, 0.17, 0.18, 0.17, 0.16, 0.15]),
        2: ([-0.5, 0.0, 0.5, 1.0], [0.12, 0.20, 0.25, 0.25, 0.25, 0.20, 0.12]),
    })
    best = fixed_best_angles(sweep)
    assert best['chain'] == 1
    np.testing.assert_allclose(best['angles'], [0.5, 0.6, 0.7, 0.8])
    assert best['worst_O'] == pytest.approx(0.15)
    assert best['mean_O'] == pytest.approx(np.mean([0.15, 0.16, 0.17, 0.18, 0.17, 0.16, 0.15]))


def test_tracking_path_stays_on_a_branch_where_the_pointwise_best_jumps():
    # Chains 0 and 1 are far apart in angle; each is best on half of the K range, so the
    # point-wise best jumps from one to the other. Chain 2 is close to chain 0 (a change
    # of chain there is allowed) and good on the right. The path must not jump far.
    sweep = synthetic_sweep({
        0: ([0.0, 0.0, 0.0, 0.0], [0.30, 0.30, 0.30, 0.20, 0.20, 0.20, 0.20]),
        1: ([1.2, -1.0, 0.8, 1.5], [0.10, 0.10, 0.10, 0.10, 0.30, 0.30, 0.30]),
        2: ([0.05, 0.05, 0.0, 0.0], [-1, -1, 0.18, 0.22, 0.25, 0.25, 0.25]),
    })
    grid = sweep_grid(sweep)
    assert list(grid.chains[grid.O.argmax(axis=0)]) == [0, 0, 0, 2, 1, 1, 1]  # jumps to 1
    path = tracking_path(sweep, PathConfig(candidates=3))
    assert path['breaks'] == 0
    assert path['jump'].max() <= PathConfig().max_jump
    assert set(path['chain'][:3]) == {0} and set(path['chain'][4:]) == {2}
    # One chain switch (0 -> 2) where both are converged at both K, pi-periodic distance.
    assert np.count_nonzero(path['chain'][1:] != path['chain'][:-1]) == 1
    np.testing.assert_allclose(path['O'][4:], 0.25)


def test_tracking_path_counts_breaks_when_no_continuous_path_exists():
    sweep = synthetic_sweep({
        0: ([0.0, 0.0, 0.0, 0.0], [0.3, 0.3, 0.3, -1, -1, -1, -1]),
        1: ([1.2, -1.0, 0.8, 1.5], [-1, -1, -1, 0.3, 0.3, 0.3, 0.3]),
    })
    path = tracking_path(sweep)
    assert path['breaks'] == 1
    assert list(path['chain']) == [0, 0, 0, 1, 1, 1, 1]


def test_angle_distance_is_pi_periodic():
    a = np.array([1.5, 0.0, 0.0, 0.0])
    b = np.array([-1.5, 0.0, 0.0, 0.0])
    assert angle_distance(a, b) == pytest.approx(np.pi - 3.0)


def _tables() -> dict[str, np.ndarray]:
    return {'K': K_GRID, 'O_star': np.full(7, 0.2), 'angles': np.zeros((7, 4)),
            'tracking_angles': np.zeros((7, 4)), 'tracking_O': np.full(7, 0.19),
            'fixed_best_angles': np.zeros(4), 'fixed_best_worst_O': np.array(0.17),
            'fixed_best_mean_O': np.array(0.18)}


def test_baselines_file_round_trips_without_pickle(tmp_path):
    path = save_baselines(tmp_path / 'oracle.npz', _tables(), {'how': 'test'})
    assert path.with_suffix('.json').is_file()
    loaded = load_baselines(path)
    assert set(REQUIRED_KEYS) <= set(loaded)
    with np.load(path, allow_pickle=False) as data:
        assert data['tracking_angles'].shape == (7, 4)


def test_loader_names_the_command_for_a_missing_file_or_key(tmp_path):
    with pytest.raises(FileNotFoundError, match='missing.*dlmpc-train baselines'):
        load_baselines(tmp_path / 'oracle.npz')
    tables = _tables()
    del tables['tracking_angles']
    np.savez(tmp_path / 'old.npz', **tables)
    with pytest.raises(ValueError, match='tracking_angles.*dlmpc-train baselines'):
        load_baselines(tmp_path / 'old.npz')
    (tmp_path / 'bad.npz').write_bytes(b'not a zip file')
    with pytest.raises(ValueError, match='dlmpc-train baselines'):
        load_baselines(tmp_path / 'bad.npz')
