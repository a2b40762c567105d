"""Plants: lasers that are not the model's nominal cavity.

A plant is the set of physical parameters of the cavity (the physics fields of
:class:`~dlmpc_ros.core.config.CavityConfig`; the grid and solver settings stay). It is
given to the simulator and to the evaluation only: no controller, estimator or model file
ever sees it. ``KEY=VALUE`` settings (:func:`parse_plant`) set some of them; a
:class:`PlantFamily` draws whole plants from seeded ranges, the spread to which a real
bench is known (pump power, losses, dispersion and gain bandwidth to perhaps 10 to 20 %).
Whether a draw can mode-lock at every K needs the simulator; the redraw rule that uses it
is :func:`dlmpc_ros.training.envelope.draw_plant`.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from dlmpc_ros.core.config import CavityConfig

#: The physical parameters of a cavity: what a plant sets.
PHYSICS_FIELDS = ('dispersion', 'cross_phase', 'four_wave', 'pump', 'saturation_energy',
                  'gain_bandwidth', 'loss', 'fiber_length')
NOMINAL = CavityConfig()


def plant_parameters(cavity: CavityConfig) -> dict[str, float]:
    """The physics fields of a cavity configuration."""
    return {name: float(getattr(cavity, name)) for name in PHYSICS_FIELDS}


def plant_fingerprint(cavity: CavityConfig) -> str:
    """Short SHA-256 of the physics fields (rounded to 12 significant digits), the key of
    a plant's cached envelope."""
    text = json.dumps({k: float(f'{v:.12g}') for k, v in plant_parameters(cavity).items()},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def is_nominal(cavity: CavityConfig) -> bool:
    return plant_parameters(cavity) == plant_parameters(NOMINAL)


def parse_plant(settings: Sequence[str], base: CavityConfig = NOMINAL) -> CavityConfig:
    """The plant of ``KEY=VALUE`` strings (physics fields only) over ``base``; ValueError
    naming the problem for an unknown key, a bad number or an invalid cavity."""
    values: dict[str, float] = {}
    for item in settings:
        key, sep, text = item.partition('=')
        key = key.strip()
        if not sep or key not in PHYSICS_FIELDS:
            raise ValueError(f'bad plant setting {item!r}: use KEY=VALUE with KEY one of '
                             f'{PHYSICS_FIELDS}')
        try:
            values[key] = float(text)
        except ValueError:
            raise ValueError(f'bad value in plant setting {item!r}') from None
    if 'cross_phase' in values and 'four_wave' not in values:
        values['four_wave'] = 1.0 - values['cross_phase']
    if 'four_wave' in values and 'cross_phase' not in values:
        values['cross_phase'] = 1.0 - values['four_wave']
    return replace(base, **values)


@dataclass(frozen=True)
class PlantFamily:
    """Ranges of the plants drawn by :meth:`draw` (uniform in each)."""

    pump_factor: tuple[float, float] = (0.88, 1.12)
    """Pump strength g0 as a factor on the nominal one."""
    saturation_factor: tuple[float, float] = (0.8, 1.2)
    """Saturation energy E0 as a factor on the nominal one."""
    loss: tuple[float, float] = (0.08, 0.13)
    """Distributed loss Gamma."""
    dispersion: tuple[float, float] = (-0.5, -0.3)
    """Averaged dispersion D (normal)."""
    gain_bandwidth: tuple[float, float] = (0.08, 0.12)
    """Gain bandwidth tau."""

    def __post_init__(self) -> None:
        for f in fields(self):
            low, high = getattr(self, f.name)
            if not (np.isfinite([low, high]).all() and low <= high):
                raise ValueError(f'PlantFamily.{f.name} must be a finite (low, high) pair '
                                 f'with low <= high, got {getattr(self, f.name)!r}')
        for name in ('pump_factor', 'saturation_factor', 'gain_bandwidth'):
            if not getattr(self, name)[0] > 0:
                raise ValueError(f'PlantFamily.{name} must stay > 0, got '
                                 f'{getattr(self, name)!r}')

    def draw(self, seed: int, attempt: int = 0, base: CavityConfig = NOMINAL
             ) -> CavityConfig:
        """Plant number ``attempt`` of ``seed``: one uniform draw per range from a
        generator seeded by ``(seed, attempt)``."""
        rng = np.random.default_rng([int(seed), int(attempt)])
        u = rng.uniform(size=5)

        def pick(bounds: tuple[float, float], x: float) -> float:
            return float(bounds[0] + (bounds[1] - bounds[0]) * x)

        return replace(base, pump=base.pump * pick(self.pump_factor, u[0]),
                       saturation_energy=base.saturation_energy
                       * pick(self.saturation_factor, u[1]),
                       loss=pick(self.loss, u[2]), dispersion=pick(self.dispersion, u[3]),
                       gain_bandwidth=pick(self.gain_bandwidth, u[4]))

    def to_dict(self) -> dict:
        return asdict(self)
