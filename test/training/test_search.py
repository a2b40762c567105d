"""The shared searches: the dynamic program over candidates and the compass search."""

import itertools

import numpy as np

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.training.search import best_path, compass_search, steady_scores


def test_best_path_equals_the_brute_force_optimum():
    rng = np.random.default_rng(0)
    values = [rng.random(n) for n in (3, 4, 2, 3)]
    costs = {i: rng.random((values[i - 1].size, values[i].size)) for i in range(1, 4)}

    def total(pick):
        return (sum(v[p] for v, p in zip(values, pick))
                - sum(costs[i][pick[i - 1], pick[i]] for i in range(1, 4)))

    brute = max(itertools.product(*(range(v.size) for v in values)), key=total)
    assert tuple(best_path(values, costs.__getitem__)) == brute


def test_compass_search_never_loses_objective_and_stops_at_its_smallest_step():
    cfg = CavityConfig()
    start = np.array([[-0.39, -0.25, 0.52, -0.14], [-0.35, -0.25, 0.5, -0.1]])
    k = np.array([0.1, 0.0])
    objective, fields = steady_scores(cfg, start, k, cap=300)
    assert np.isfinite(objective).all()  # both start on a converged pulse
    steps = []
    found = compass_search(start, k, objective, fields, cfg, first_step=0.08, min_step=0.02,
                           max_iterations=6, cap=100, chunk=5, wrap=True,
                           progress=lambda *args: steps.append(args))
    assert (found.objective >= objective).all()
    assert found.iterations == len(steps) <= 6
    assert found.angles.shape == (2, 4) and (np.abs(found.angles) <= np.pi / 2).all()
    again, _ = steady_scores(cfg, found.angles, k, (found.u, found.v), cap=100)
    np.testing.assert_allclose(again, found.objective, rtol=1e-4)  # its state is steady
