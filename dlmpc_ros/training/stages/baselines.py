"""``dlmpc-train baselines``: the baseline angle tables of ``models/oracle.npz``.

Builds the fixed-best angle set, the tracking path and its refinement
(:mod:`dlmpc_ros.training.baseline_tables`) from ``data/sweep`` and ``data/oracle.npz``,
runs each table in closed loop on the check set of scenarios
(:mod:`dlmpc_ros.evaluation.table_check`), and writes ``models/oracle.npz`` with
``models/oracle.json``.
"""

from __future__ import annotations

import time

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.evaluation.presets import CHECK_CASES
from dlmpc_ros.evaluation.table_check import closed_loop_check
from dlmpc_ros.learning.tables import SCHEMA_VERSION, load_envelope, save_baselines
from dlmpc_ros.training import shards
from dlmpc_ros.training.baseline_tables import (PathConfig, RefineConfig, build_baselines,
                                                summarize)
from dlmpc_ros.training.workspace import Workspace

HOW = ('fixed_best: the sweep chain with the highest worst-case steady O over K '
       '(non-converged = 0). tracking: dynamic program over the K grid through the top sweep '
       'states per K, maximizing sum O - jump_penalty * angle change - switch_penalty per '
       'change of chain; a change of chain only between states converged at both K with '
       'equal pulse counts and angles within max_jump. tracking_refined: per-K compass '
       'search on the steady O warm-started from the path\'s continuation state, kept where '
       'continuation up and down reproduces it. angles / O_star: the oracle envelope, '
       'mirrored (at each K the better of its search and the mirror of the search at -K; '
       'O_star_own: the search alone).')


def train_baselines_stage(ws: Workspace, quick: bool = False,
                          cavity_cfg: CavityConfig | None = None,
                          show_progress: bool = True) -> dict:
    """Build, check and write the tables; returns the stage's metrics. ``quick`` (tests)
    skips the refinement and checks one scenario for 1,000 round trips."""
    started = time.monotonic()

    def say(text: str) -> None:
        if show_progress:
            print(f'baselines: {text}', flush=True)

    envelope = load_envelope(ws.oracle)
    sweep = shards.load_dataset(ws.sweep)
    path_cfg = PathConfig()
    refine_cfg = None if quick else RefineConfig()
    arrays = build_baselines(sweep, envelope, cavity_cfg, path_cfg, refine_cfg, say)
    summary = summarize(arrays)
    tables = {'oracle_pointwise': arrays['angles'], 'oracle_tracking': arrays['tracking_angles'],
              'fixed_best': arrays['fixed_best_angles']}
    if 'tracking_refined_angles' in arrays:
        tables['oracle_tracking_refined'] = arrays['tracking_refined_angles']
    cases = dict(list(CHECK_CASES.items())[:1]) if quick else CHECK_CASES
    round_trips = 1000 if quick else 20000
    check = closed_loop_check(tables, envelope, cases, round_trips, 1, cavity_cfg, say)
    metrics = {**summary, 'closed_loop': check, 'quick': quick,
               'wall_seconds': round(time.monotonic() - started, 1)}
    meta = {
        'schema_version': SCHEMA_VERSION,
        'made_by': 'dlmpc-train baselines (dlmpc_ros.training.stages.baselines)',
        'how': HOW,
        'sweep_fingerprint': shards.metadata(ws.sweep).get('fingerprint'),
        'oracle_envelope': str(ws.oracle),
        'path_settings': path_cfg.to_dict(),
        'refine_settings': None if refine_cfg is None else refine_cfg.to_dict(),
        'closed_loop_check': {'round_trips': round_trips, 'initial_angles_seed': 1,
                              'cases': {label: {'preset': preset, 'seed': seed}
                                        for label, (preset, seed) in cases.items()}},
        'quick': quick, 'summary': summary, 'closed_loop': check,
        'wall_seconds': metrics['wall_seconds'],
    }
    save_baselines(ws.baselines, arrays, meta)
    return metrics
