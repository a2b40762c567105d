"""What every controller returns for one control period, and the protocol they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: Modes a controller reports: the DL-MPC loops, holding (no usable input), baselines,
#: the DL-MPC's lock acquisition scan, its curve tracking, the genetic algorithm, the
#: DL-MPC's planned turns of its curve (tracking periods in which the planner moved it),
#: ``custom`` for a plug-in controller's own (docs/controllers.md), Bayesian
#: optimization, and the deep-RL policy (``control/drl.py``). The index is published: a
#: new mode goes at the end.
MODES = ('inner', 'outer', 'hold', 'passive', 'fixed_best', 'esc', 'oracle', 'acquire',
         'track', 'ga', 'plan', 'custom', 'bo', 'drl')


@dataclass(frozen=True)
class ControlStep:
    """One control period's decision.

    ``angles`` (4,) [rad] are applied from the next round trip on; the other fields are
    diagnostics published on the controller's status topic.
    """

    angles: np.ndarray
    mode: str
    surrogate: float = float('nan')
    prediction_error: float = float('nan')  # NaN until a prediction could be checked
    predicted_objective: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,)
    iterations: int = 0
    latency_ms: float = 0.0
    measure: bool = True
    """Whether the next decision needs a measurement at ``angles`` (False: the controller
    only moves the servos on, and decides again as soon as they report the command
    reached, without waiting for the round trips a measurement averages)."""

    @property
    def mode_index(self) -> int:
        return MODES.index(self.mode)


#: Bounds of a laser's measurement: E = sqrt(energy) and the spectral kurtosis M (a
#: kurtosis is at least 1; at most about the grid's point count). A state outside them
#: (E < 0, M < 1, 1e300: a glitch or a corrupt driver) is no laser's; a controller that
#: learns from its inputs holds the angles on it and keeps it out of its history.
E_RANGE = (0.0, 1e4)
M_RANGE = (1.0, 1e5)
#: Largest |angle| a servo may report [rad] (the angles are pi-periodic; no mount turns
#: a thousand radians).
ANGLE_BOUND = 1e3


def implausible(measurement: np.ndarray) -> str | None:
    """Why a measurement ``(E, M, alpha1..alpha_p)`` is no laser's, or None."""
    e, m = float(measurement[0]), float(measurement[1])
    if not np.isfinite(measurement).all():
        return 'a value is not finite'
    if not E_RANGE[0] <= e <= E_RANGE[1]:
        return f'E = {e:g} is outside [{E_RANGE[0]:g}, {E_RANGE[1]:g}]'
    if not M_RANGE[0] <= m <= M_RANGE[1]:
        return f'M = {m:g} is outside [{M_RANGE[0]:g}, {M_RANGE[1]:g}]'
    if np.abs(measurement[2:6]).max() > ANGLE_BOUND:
        return f'an angle exceeds {ANGLE_BOUND:g} rad'
    return None


class Controller(Protocol):
    """Measurement ``(E, M, alpha1, alpha2, alpha3, alpha_p)`` in, next angles out.

    ``surrogate`` is the estimator's K surrogate for the same measurement (None when the
    estimator is silent); controllers that do not use it ignore it. No controller is
    given the true birefringence through this verb (the oracle baseline, evaluation only,
    has a separate ``observe_truth``). A controller with a true ``uses_estimator``
    attribute (the DL-MPC) is given the VAE estimator's surrogate by every harness;
    the others get None.
    """

    name: str

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        ...
