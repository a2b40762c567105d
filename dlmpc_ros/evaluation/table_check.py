"""Closed-loop check of angle tables: a fixed angle set or an oracle table over K, run
against the envelope on the check set of scenarios (:data:`~dlmpc_ros.evaluation.presets.
CHECK_CASES`). ``dlmpc-train baselines`` records it for its tables."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dlmpc_ros.control.baselines import FixedBestController, OracleController
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.evaluation.closed_loop import random_initial_angles, run_closed_loop
from dlmpc_ros.evaluation.metrics import run_metrics
from dlmpc_ros.evaluation.presets import CHECK_CASES, preset_scenario


def closed_loop_check(tables: dict[str, np.ndarray], envelope: dict[str, np.ndarray],
                      cases: dict[str, tuple[str, int]] | None = None,
                      round_trips: int = 20000, initial_seed: int = 1,
                      cavity_cfg: CavityConfig | None = None,
                      progress: Callable[[str], None] | None = None) -> dict:
    """Closed-loop runs of table controllers against the envelope O*(K).

    ``tables`` maps a name to angles: (4,) runs a fixed-angle controller, (n_k, 4) an
    oracle controller over ``envelope['K']`` (true K to the nearest grid point's angles).
    Every run starts from :func:`random_initial_angles` of ``initial_seed``.
    Returns ``{case: {name: {oracle_ratio, locked_fraction, acquisition_round_trips}}}``.
    """
    out: dict[str, dict] = {}
    for label, (preset, seed) in (cases or CHECK_CASES).items():
        out[label] = {}
        for name, table in tables.items():
            table = np.asarray(table, float)
            controller = (FixedBestController(table) if table.ndim == 1
                          else OracleController(envelope['K'], table))
            record = run_closed_loop(controller, preset_scenario(preset, seed), round_trips,
                                     initial_angles=random_initial_angles(initial_seed),
                                     cavity_config=cavity_cfg)
            m = run_metrics(record, envelope)
            out[label][name] = {key: m[key] for key in (
                'oracle_ratio', 'locked_fraction', 'acquisition_round_trips')}
            if progress is not None:
                progress(f'{label} {name}: O/O* {m["oracle_ratio"]:.3f}')
    return out
