"""What every controller returns for one control period, and the protocol they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: Modes a controller reports: the DL-MPC loops, holding (no usable input), baselines,
#: the DL-MPC's lock acquisition scan, its curve tracking, and the genetic algorithm.
MODES = ('inner', 'outer', 'hold', 'passive', 'fixed_best', 'esc', 'oracle', 'acquire',
         'track', 'ga')


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

    @property
    def mode_index(self) -> int:
        return MODES.index(self.mode)


class Controller(Protocol):
    """Measurement ``(E, M, alpha1, alpha2, alpha3, alpha_p)`` in, next angles out.

    ``surrogate`` is the estimator's K surrogate for the same measurement (None when the
    estimator is silent); controllers that do not use it ignore it. No controller is
    given the true birefringence through this verb (the oracle baseline, evaluation only,
    has a separate ``observe_truth``).
    """

    name: str

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        ...
