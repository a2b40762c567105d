"""Settings of the simulated cavity: the spec's physical parameters, grid and solver.

Units are the normalized units of the cavity model (``shared/spec/laser-model.md``):
time in units of the window's scale (``window`` = T), distance in round-trip fiber
lengths (``fiber_length`` = Z), energies in the model's normalized units.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

from dlmpc_ros.core.schemes import DEFAULT_SCHEME, DEFAULT_STEPS, ORDER, SCHEMES

#: The birefringence range the model is specified and trained for.
BIREFRINGENCE_RANGE = (-0.3, 0.3)


@dataclass(frozen=True)
class CavityConfig:
    """Every parameter of the cavity model and its solver, with the spec's defaults."""

    dispersion: float = -0.4
    """D, averaged group-velocity dispersion (normal dispersion < 0)."""
    cross_phase: float = 2.0 / 3.0
    """A, cross-phase modulation coefficient; ``cross_phase + four_wave == 1``."""
    four_wave: float = 1.0 / 3.0
    """B, four-wave-mixing coefficient."""
    pump: float = 1.73
    """g0, pump strength of the saturable gain ``g = 2 g0 / (1 + energy / E0)``."""
    saturation_energy: float = 4.23
    """E0, gain saturation energy (> 0)."""
    gain_bandwidth: float = 0.1
    """tau, parabolic gain bandwidth: gain ``g (1 - tau k^2)``."""
    loss: float = 0.1
    """Gamma, distributed fiber loss."""
    fiber_length: float = 1.5
    """Z, fiber length of one round trip."""
    window: float = 60.0
    """T, width of the periodic time window."""
    points: int = 256
    """n, number of time (and wavenumber) grid points; at least 16."""
    steps_per_round_trip: int = 0
    """Steps of the fiber pass (each one composition of ``scheme``'s symmetric split
    steps); 0 (the default): the scheme's own, :data:`DEFAULT_STEPS` (richardson4 6,
    strang 32), each within 1e-3 of a DOP853 solution (docs/solver.md). :attr:`steps` is
    the number that runs."""
    scheme: str = DEFAULT_SCHEME
    """Integration scheme of the fiber pass, one of :data:`SCHEMES`: 'richardson4' (the
    default, fourth order), 'strang' (the symmetric split step, second order; the
    default before 2026-12-05), 'suzuki4' or 'yoshida4'."""
    steady_tolerance: float = 1e-6
    """A laser is at steady state when the relative L2 change of its amplitude ``phi``
    between consecutive round trips is below this value."""

    def __post_init__(self) -> None:
        problems = config_problems(asdict(self))
        if problems:
            raise ValueError('invalid cavity configuration: ' + '; '.join(problems))

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> CavityConfig:
        """Build from a mapping of field names, rejecting unknown names."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f'unknown cavity parameter(s) {unknown}; known: {sorted(known)}')
        return cls(**values)

    @property
    def order(self) -> int:
        """Order of convergence of the scheme in the step size."""
        return ORDER[self.scheme]

    @property
    def steps(self) -> int:
        """Steps of the fiber pass that run: ``steps_per_round_trip``, or the scheme's own."""
        return self.steps_per_round_trip or DEFAULT_STEPS[self.scheme]

    def to_dict(self) -> dict[str, float | int | str]:
        """The fields, with the steps that run (a record says what ran)."""
        return {**asdict(self), 'steps_per_round_trip': self.steps}


#: The values each parameter may take: (low, high), both inclusive except where a
#: parameter must be > 0. Within them the solver stays finite (checked from random angles
#: at both ends); beyond the highs lie values that are physically meaningless here or
#: overflow (a pump of 1e308 blows the field up every round trip; a window of 5e-324
#: divides by zero).
RANGES: dict[str, tuple[float, float]] = {
    'dispersion': (-10.0, 10.0), 'cross_phase': (0.0, 1.0), 'four_wave': (0.0, 1.0),
    'pump': (0.0, 100.0), 'saturation_energy': (0.0, 1000.0), 'gain_bandwidth': (0.0, 10.0),
    'loss': (0.0, 10.0), 'fiber_length': (0.0, 10.0), 'window': (1.0, 1000.0),
    'points': (16, 4096), 'steps_per_round_trip': (0, 1024), 'steady_tolerance': (0.0, 1.0),
}
#: Parameters that must be > their low (not >=).
POSITIVE = frozenset({'saturation_energy', 'fiber_length', 'steady_tolerance'})


def config_problems(values: dict[str, Any]) -> list[str]:
    """Return a list of human-readable problems with cavity parameter values (empty if valid).

    Used both by :class:`CavityConfig` and by the ROS parameter callback, which must give
    a reason instead of raising.
    """
    problems: list[str] = []
    for name, value in values.items():
        if name in ('points', 'steps_per_round_trip'):
            if isinstance(value, bool) or not isinstance(value, int):
                problems.append(f'{name} must be an integer, got {value!r}')
        elif name == 'scheme':
            if not isinstance(value, str) or value not in SCHEMES:
                problems.append(f'scheme must be one of {tuple(SCHEMES)}, got {value!r}')
        elif isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            problems.append(f'{name} must be a finite number, got {value!r}')
    if problems:
        return problems

    def need(cond: bool, message: str) -> None:
        if not cond:
            problems.append(message)

    get = values.get
    for name, (low, high) in RANGES.items():
        if name not in values:
            continue
        value = get(name)
        if name in POSITIVE:
            need(value > low, f'{name} must be > {low:g}, got {value}')
        else:
            need(value >= low, f'{name} must be >= {low:g}, got {value}')
        need(value <= high, f'{name} must be <= {high:g} (beyond it the model is '
                            f'meaningless or overflows), got {value:g}')
    if 'cross_phase' in values and 'four_wave' in values:
        total = get('cross_phase') + get('four_wave')
        need(abs(total - 1.0) < 1e-9,
             f'cross_phase + four_wave must equal 1 (the model assumes it), got {total}')
    return problems
