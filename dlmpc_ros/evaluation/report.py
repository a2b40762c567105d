"""What ``dlmpc-evaluate`` writes: each run's metrics beside its record, and the tables of
all runs (``OUT/metrics.json``, ``OUT/table.md``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dlmpc_ros.evaluation.figures import surrogate_correlation
from dlmpc_ros.evaluation.metrics import run_metrics
from dlmpc_ros.evaluation.record import RunRecord

TABLE_KEYS = ('oracle_ratio', 'oracle_controller_ratio', 'locked_fraction',
              'acquisition_round_trips', 'recovery_round_trips_max', 'step_latency_ms_median',
              'step_latency_ms_p99', 'track_estimate_abs_r', 'estimator_abs_r')


def run_case(run: dict) -> str:
    """What a table's row names a run by: its suite condition, else its scenario."""
    return run.get('condition') or run['scenario']


def measure(record: RunRecord, envelope: dict, run_dir: Path, **extra) -> dict:
    """The run's metrics (plus ``extra``), saved with its record in ``run_dir``."""
    metrics = {**run_metrics(record, envelope), **extra,
               'surrogate_abs_r': surrogate_correlation(record),
               'track_estimate_abs_r': surrogate_correlation(record, tracking=True),
               # the estimator's own surrogate while the tracker tracked
               'estimator_abs_r': surrogate_correlation(record, tracking=True, estimator=True)}
    record.save(run_dir / 'record.npz')
    (run_dir / 'metrics.json').write_text(json.dumps({**record.meta, **metrics}, indent=2))
    return metrics


def summary_line(metrics: dict) -> str:
    """One line of a run's headline figures."""
    def text(key: str, form: str) -> str:
        value = metrics.get(key)
        return 'n/a' if value is None else format(value, form)
    return (f"oracle ratio {text('oracle_ratio', '.3f')}, locked "
            f"{text('locked_fraction', '.3f')}, acquisition "
            f"{text('acquisition_round_trips', 'd')}, latency median "
            f"{text('step_latency_ms_median', '.2f')} ms")


def markdown_table(rows: list[dict]) -> str:
    """Every run, one row each, with the :data:`TABLE_KEYS`."""
    head = ['scenario', 'seed', 'controller', *TABLE_KEYS]
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for row in rows:
        cells = [run_case(row), str(row['seed']), row['controller']]
        for key in TABLE_KEYS:
            value = row['metrics'].get(key)
            cells.append('-' if value is None else (f'{value:.3f}' if isinstance(value, float)
                                                    else str(value)))
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def add_oracle_controller_ratio(runs: list[dict]) -> None:
    """Add ``oracle_controller_ratio``: mean O over the mean O of the ``oracle``
    controller's run on the same scenario and seed (when the oracle ran too). The envelope
    O*(K) is the point-wise best over branches, which no controller holds; the oracle
    controller's branch-continuous path is the best reached in closed loop."""
    oracle = {(run_case(r), r['seed']): r['metrics']['mean_O'] for r in runs
              if r['controller'] == 'oracle'}
    for run in runs:
        reference = oracle.get((run_case(run), run['seed']))
        mean_o = run['metrics'].get('mean_O')
        if reference and mean_o is not None:
            run['metrics']['oracle_controller_ratio'] = mean_o / reference


def seed_summary(runs: list[dict]) -> str:
    """Markdown table of oracle_ratio per scenario or suite condition (rows) and
    controller (columns): the mean over seeds and, with several seeds, the range."""
    scenarios = list(dict.fromkeys(run_case(r) for r in runs))
    controllers = list(dict.fromkeys(r['controller'] for r in runs))
    lines = ['| scenario | ' + ' | '.join(controllers) + ' |',
             '|---|' + '---|' * len(controllers)]
    for scenario in scenarios:
        cells = []
        for controller in controllers:
            values = [r['metrics']['oracle_ratio'] for r in runs
                      if run_case(r) == scenario and r['controller'] == controller
                      and r['metrics'].get('oracle_ratio') is not None]
            if not values:
                cells.append('-')
            elif len(values) == 1:
                cells.append(f'{values[0]:.3f}')
            else:
                cells.append(f'{np.mean(values):.3f} ({min(values):.3f}-{max(values):.3f})')
        lines.append(f'| {scenario} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def write_summary(out: Path, runs: list[dict], plant: dict | None = None) -> None:
    """``OUT/metrics.json`` (every run) and ``OUT/table.md`` (per scenario and controller,
    then every run); ``plant`` (the physical parameters that differ from the nominal
    cavity) is written beside them."""
    add_oracle_controller_ratio(runs)
    summary: dict = {'plant': dict(plant or {}), 'runs': runs}
    if len(runs) == 1:
        summary.update(runs[0]['metrics'])
    (out / 'metrics.json').write_text(json.dumps(summary, indent=2))
    seeds = len({r['seed'] for r in runs})
    (out / 'table.md').write_text(
        f'oracle_ratio (mean O / mean O*(K)), mean over {seeds} seed(s)'
        + (' (min-max)' if seeds > 1 else '') + ':\n\n' + seed_summary(runs)
        + '\nEvery run:\n\n' + markdown_table(runs))


def plant_table(runs: list[dict], value: str = 'oracle_ratio') -> str:
    """Markdown: plant (rows) x controller (columns) per scenario, the mean of ``value``
    over seeds (min-max)."""
    lines = []
    for scenario in dict.fromkeys(run_case(r) for r in runs):
        mine = [r for r in runs if run_case(r) == scenario]
        controllers = list(dict.fromkeys(r['controller'] for r in mine))
        lines += [f'{scenario}:', '', '| plant | ' + ' | '.join(controllers) + ' |',
                  '|---|' + '---|' * len(controllers)]
        for plant in dict.fromkeys(r['plant'] for r in mine):
            cells = []
            for controller in controllers:
                values = [r['metrics'][value] for r in mine if r['plant'] == plant
                          and r['controller'] == controller
                          and r['metrics'].get(value) is not None]
                cells.append('-' if not values else f'{np.mean(values):.3f}' if len(values) == 1
                             else f'{np.mean(values):.3f} ({min(values):.3f}-{max(values):.3f})')
            lines.append(f'| {plant} | ' + ' | '.join(cells) + ' |')
        lines.append('')
    return '\n'.join(lines)


def write_plant_table(out: Path, runs: list[dict], plants: dict[str, dict],
                      wall_seconds: float, workers: int) -> None:
    """``OUT/metrics.json`` and ``OUT/table.md`` over every plant: each run's ratio is to
    its own plant's envelope."""
    (out / 'metrics.json').write_text(json.dumps(
        {'plants': plants, 'wall_seconds': wall_seconds, 'workers': workers, 'runs': runs},
        indent=2))
    (out / 'table.md').write_text(
        'oracle_ratio (mean O / mean O*(K), each plant\'s own envelope), mean over seeds '
        f'(min-max); {len(runs)} runs in {wall_seconds:.0f} s on {workers} worker(s):\n\n'
        + plant_table(runs) + '\nPlants (the physical parameters set on the nominal '
        'cavity):\n\n' + '\n'.join(f'- {label}: {json.dumps(params)}'
                                      for label, params in plants.items()) + '\n')


def lock_table(summary: dict) -> str:
    """Markdown of the lock benchmark: success rate and times per plant and controller."""
    s = summary['settings']
    held = f"K {s['drift']}" + ('' if s.get('K') is None else f" at {s['K']:+g}")
    lines = [f"Auto-mode-locking: {s['starts']} cold starts per plant (random angles, noise "
             f"field, {held}), budget {s['budget']} round trips; locked = O >= "
             f"{s['lock_fraction']} O*(K) for {s['hold_periods']} periods.", '',
             '| plant | controller | success | median round trips | p90 round trips | '
             'median periods |', '|---|---|---|---|---|---|']
    for plant, entry in summary['plants'].items():
        for controller, m in entry['controllers'].items():
            cells = ['-' if m[key] is None else f'{m[key]:.0f}' for key in (
                'median_round_trips', 'p90_round_trips', 'median_control_periods')]
            lines.append(f"| {plant} | {controller} | {100 * m['success_rate']:.0f} % | "
                         + ' | '.join(cells) + ' |')
    budgets = s.get('budgets') or [s['budget']]
    if len(budgets) > 1:
        lines += ['', f"Budget sweep: every start ran {max(budgets)} round trips once; a "
                  'smaller budget counts the starts whose hold ended within it. Control '
                  'periods to lock bound the angle settings a search method tried (one a '
                  'period at most).', '',
                  '| plant | controller | budget | success | median round trips | '
                  'p90 round trips | median periods | p90 periods |',
                  '|---|---|---|---|---|---|---|---|']
        for plant, entry in summary['plants'].items():
            for controller, m in entry['controllers'].items():
                for budget, b in m['budgets'].items():
                    cells = ['-' if b.get(key) is None else f'{b[key]:.0f}' for key in (
                        'median_round_trips', 'p90_round_trips', 'median_control_periods',
                        'p90_control_periods')]
                    lines.append(f"| {plant} | {controller} | {int(budget)} | "
                                 f"{100 * b['success_rate']:.0f} % | " + ' | '.join(cells)
                                 + ' |')
    return '\n'.join(lines) + '\n'
