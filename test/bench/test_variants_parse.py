"""Every ``bench/*_variants.json`` still parses against the current settings.

Each DL-MPC variant goes through ``bench/dlmpc_variants.py``'s own
:func:`variant_config` (the controller's :class:`DLMPCConfig` and its tracking,
acquisition and planner configs) and its run settings through
:class:`~dlmpc_ros.evaluation.runs.RunSpec`; ``bench/mprnn_variants.json`` is built
into :class:`MPRNNConfig` and :class:`TrainConfig` as ``bench/mprnn_variants.py`` builds
it. A setting that no longer exists, or a value its config rejects, fails the test with
the file and the variant. Nothing is loaded or run.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'bench'
MPRNN_FILES = {'mprnn_variants.json'}  # read by bench/mprnn_variants.py, not dlmpc_variants
MPRNN_KEYS = {'model', 'train', 'extra_trajectories'}


def _bench_module(name: str):
    """A bench script as a module (bench/ is not a package)."""
    module_name = f'_bench_{name}'
    if module_name not in sys.modules:
        spec = importlib.util.spec_from_file_location(module_name, BENCH / f'{name}.py')
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
    return sys.modules[module_name]


def _variants(kind: str) -> list:
    """``(file, variant, overrides)`` of every variant of the ``kind`` of file."""
    files = sorted(BENCH.glob('*_variants.json'))
    return [pytest.param(path.name, name, overrides, id=f'{path.name}:{name}')
            for path in files if (path.name in MPRNN_FILES) == (kind == 'mprnn')
            for name, overrides in json.loads(path.read_text()).items()]


def test_there_are_variants_files():
    assert _variants('dlmpc') and _variants('mprnn')


@pytest.mark.parametrize('file, variant, overrides', _variants('dlmpc'))
def test_dlmpc_variant_builds_its_controller_config(file, variant, overrides):
    from dlmpc_ros.evaluation.runs import RunSpec
    variant_config = _bench_module('dlmpc_variants').variant_config
    spec = RunSpec('sinusoidal', 1, 'dlmpc')
    try:
        _, run, _ = variant_config(overrides, 'models', spec.max_step)
        replace(spec, **run)
    except (TypeError, ValueError) as err:
        pytest.fail(f'bench/{file}, variant {variant!r}: {err}')


@pytest.mark.parametrize('file, variant, overrides', _variants('mprnn'))
def test_mprnn_variant_builds_its_model_and_training_configs(file, variant, overrides):
    from dlmpc_ros.learning.mprnn import MPRNNConfig
    from dlmpc_ros.training.predictor import TrainConfig
    from dlmpc_ros.training.stages.mprnn import FULL
    try:
        unknown = set(overrides) - MPRNN_KEYS
        if unknown:
            raise TypeError(f'unknown keys {sorted(unknown)} (known: {sorted(MPRNN_KEYS)})')
        MPRNNConfig(**overrides.get('model', {}))
        TrainConfig(**{**FULL.__dict__, **overrides.get('train', {})})
    except (TypeError, ValueError) as err:
        pytest.fail(f'bench/{file}, variant {variant!r}: {err}')


def test_the_bench_readme_lists_every_script_and_variants_file():
    readme = (BENCH / 'README.md').read_text()
    missing = [p.name for p in sorted(BENCH.glob('*.py')) + sorted(BENCH.glob('*_variants.json'))
               if f'`{p.name}`' not in readme]
    assert not missing, f'bench/README.md does not list {missing}'
