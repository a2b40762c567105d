"""How big the DL-MPC is to read (issue 32's design targets), measured from the code.

Prints, and with ``--out`` writes as JSON:

- **settings**: the fields of the controller's config classes (``DLMPCConfig``,
  ``TrackingConfig``, ``AcquisitionConfig``, ``PlannerConfig``, ``AngleLimits``; the
  nested configs themselves not counted), and the ``mpc_controller`` node's own
  parameters (those of its base class, common to every controller node, left out);
- **control law**: the lines of ``dlmpc_ros/control/`` without the baselines (ESC, GA,
  BO, DRL and its observation, the table baselines) and the plug-in registry
  (``plugins.py``, ``factory.py``);
- **per-period path**: the modules a control period of the default strategy runs
  through, from the node's callback to the published command (``PER_PERIOD``, read off
  the code: the decision loop, the period's measurement, the supervisor with its
  modes, their parts, the learned models' forward passes), and their lines (also by kind:
  code, docstrings, comments, blank).

Usage::

    python bench/controller_size.py [--out bench/results/controller_size.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import fields
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CONTROL = ROOT / 'dlmpc_ros' / 'control'
#: control/ modules that are not the DL-MPC's control law.
NOT_CONTROL_LAW = {'__init__.py', 'esc.py', 'ga.py', 'bo.py', 'drl.py', 'observation.py',
                   'baselines.py', 'plugins.py', 'factory.py'}
#: Modules a control period of the default strategy runs through, from the callback (the
#: decision loop's ``on_state``) to the published command (the paper's loops add
#: ``control/paper_loops.py``, ``learning/kmap.py``, ``learning/features.py``,
#: ``learning/mprnn.py`` and the estimates, ``ros/estimates.py``). Not among them: the
#: nodes' modules (``nodes/mpc_controller_node.py``, ``ros/controller_base.py``), which turn
#: parameters into a controller and its loop at start and report /diagnostics once a second,
#: and the settings (``control/dlmpc_config.py``), which the modules read but which do
#: nothing.
PER_PERIOD = ('ros/decision_loop.py', 'control/step.py', 'control/dlmpc.py',
              'control/tracking.py', 'control/rotation_planner.py',
              'learning/response.py')


def lines(path: Path) -> int:
    return len(path.read_text().splitlines())


def line_kinds(path: Path) -> dict[str, int]:
    """A module's lines by kind: docstrings, comments, blank, and the rest (code)."""
    import ast
    source = path.read_text()
    docs: set[int] = set()
    for node in ast.walk(ast.parse(source)):  # string statements: docstrings, attribute docs
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) \
                and isinstance(node.value.value, str):
            docs.update(range(node.lineno, node.end_lineno + 1))
    kinds = {'code': 0, 'docstring': 0, 'comment': 0, 'blank': 0}
    for number, line in enumerate(source.splitlines(), 1):
        kind = ('docstring' if number in docs else 'blank' if not line.strip()
                else 'comment' if line.lstrip().startswith('#') else 'code')
        kinds[kind] += 1
    return kinds


def settings() -> dict[str, list[str]]:
    """Config class -> its setting names (nested configs left out)."""
    from dlmpc_ros.control.dlmpc_config import (AcquisitionConfig, DLMPCConfig, PlannerConfig,
                                               TrackingConfig)
    from dlmpc_ros.control.step import AngleLimits
    out = {}
    for kind in (DLMPCConfig, TrackingConfig, AcquisitionConfig, PlannerConfig, AngleLimits):
        nested = {f.name for f in fields(kind) if f.name in ('limits', 'acquisition',
                                                             'tracking', 'planner')}
        out[kind.__name__] = [f.name for f in fields(kind) if f.name not in nested]
    return out


def node_parameters() -> list[str]:
    from dlmpc_ros.nodes import mpc_controller_node as node
    return sorted({'strategy', *node.DEFAULTS, *node.ACQUISITION_DEFAULTS,
                   *node.TRACKING_DEFAULTS, *node.PLANNER_DEFAULTS})


def measure() -> dict:
    per_class = settings()
    law = {p.name: lines(p) for p in sorted(CONTROL.glob('*.py'))
           if p.name not in NOT_CONTROL_LAW}
    path = {m: lines(ROOT / 'dlmpc_ros' / m) for m in PER_PERIOD}
    kinds = [line_kinds(ROOT / 'dlmpc_ros' / m) for m in PER_PERIOD]
    return {'settings': {k: len(v) for k, v in per_class.items()},
            'settings_total': sum(len(v) for v in per_class.values()),
            'setting_names': per_class,
            'node_parameters': node_parameters(),
            'control_law_lines': sum(law.values()), 'control_law': law,
            'per_period_modules': len(path), 'per_period_lines': sum(path.values()),
            'per_period': path,
            'per_period_kinds': {k: sum(c[k] for c in kinds) for k in kinds[0]}}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--out', type=Path, help='write the figures as JSON here')
    args = p.parse_args(argv)
    m = measure()
    print(f"settings: {m['settings_total']} ("
          + ', '.join(f'{k} {v}' for k, v in m['settings'].items())
          + f"); node parameters: {len(m['node_parameters'])}")
    print(f"control law: {m['control_law_lines']} lines in {len(m['control_law'])} modules")
    print(f"per-period path: {m['per_period_modules']} modules, {m['per_period_lines']} lines ("
          + ', '.join(f'{k} {v}' for k, v in m['per_period_kinds'].items()) + ')')
    if args.out:
        args.out.write_text(json.dumps(m, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
