"""The evaluation's drift scenarios: one preset table for every caller (``dlmpc-evaluate``,
the baseline tables' closed-loop check, the bench scripts).

Every preset keeps K within [-0.3, 0.3]; ``--scenario-param KEY=VALUE`` overrides its
settings. ``random_walk`` draws its path from the run's seed unless a seed is set.
"""

from __future__ import annotations

from collections.abc import Mapping

from dlmpc_ros.core.drift import DEFAULTS, Scenario, make_scenario

#: The presets' scenarios, in the order tables list them.
SCENARIOS = ('sinusoidal', 'chirp', 'random_walk', 'steps', 'constant')
#: Settings of each preset (the rest are :data:`dlmpc_ros.core.drift.DEFAULTS`).
PRESETS: dict[str, dict[str, object]] = {
    'sinusoidal': {'amplitude': 0.25, 'period': 10000.0},
    'chirp': {},
    'random_walk': {'sigma': 0.1, 'correlation_time': 2000.0},
    'steps': {'times': [5000.0, 10000.0, 15000.0], 'values': [0.2, -0.2, 0.1]},
    'constant': {'offset': 0.1},
}
#: The check set of the baseline tables and of the ESC tuning: label -> (preset, seed),
#: two random walks with their own seeds (the initial angles come from seed 1).
CHECK_CASES: dict[str, tuple[str, int]] = {
    'sinusoidal': ('sinusoidal', 1), 'random_walk_11': ('random_walk', 11),
    'random_walk_12': ('random_walk', 12), 'chirp': ('chirp', 1), 'steps': ('steps', 1),
}


def preset_settings(name: str, overrides: Mapping[str, object] | None = None
                    ) -> dict[str, object]:
    """The settings of preset ``name`` with the ``overrides`` it takes (others ignored);
    ValueError for an unknown preset or settings it cannot run with."""
    if name not in PRESETS:
        raise ValueError(f'unknown scenario preset {name!r}; one of {SCENARIOS}')
    settings = {**PRESETS[name], **{k: v for k, v in (overrides or {}).items()
                                    if k in DEFAULTS[name]}}
    make_scenario(name, **{**settings, **({'seed': 1} if name == 'random_walk' else {})})
    return settings


def run_settings(name: str, seed: int, settings: Mapping[str, object] | None = None
                 ) -> dict[str, object]:
    """The settings a run of ``seed`` uses: ``settings`` (default: the preset's) with the
    random walk's seed filled in."""
    settings = dict(PRESETS[name] if settings is None else settings)
    if name == 'random_walk':
        settings.setdefault('seed', seed)
    return settings


def preset_scenario(name: str, seed: int, settings: Mapping[str, object] | None = None
                    ) -> Scenario:
    """The scenario of preset ``name`` (or of ``settings``) for a run of ``seed``."""
    return make_scenario(name, **run_settings(name, seed, settings))
