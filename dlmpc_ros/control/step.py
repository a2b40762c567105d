"""What every controller returns for one control period, and the protocol they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: Modes a controller reports (``plan``: tracking periods with a planned turn; ``custom``: a
#: plug-in's own, docs/controllers.md). The index is published: a new mode goes at the end.
MODES = ('inner', 'outer', 'hold', 'passive', 'fixed_best', 'esc', 'oracle', 'acquire',
         'track', 'ga', 'plan', 'custom', 'bo', 'drl')


@dataclass(frozen=True)
class ControlStep:
    """One control period's decision: ``angles`` (4,) [rad], applied from the next round
    trip on, and diagnostics published on the controller's status topic."""

    angles: np.ndarray
    mode: str
    surrogate: float = float('nan')
    prediction_error: float = float('nan')  # NaN until a prediction could be checked
    predicted_objective: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,)
    iterations: int = 0
    latency_ms: float = 0.0
    measure: bool = True
    """Whether the next decision needs a measurement at ``angles`` (False: it only moves
    the servos on, and decides again as soon as they report the command reached)."""

    @property
    def mode_index(self) -> int:
        return MODES.index(self.mode)


#: Bounds of a laser's E = sqrt(energy) and spectral kurtosis M; a state outside them is a
#: glitch, on which a learning controller holds and keeps it out of its history.
E_RANGE = (0.0, 1e4)
M_RANGE = (1.0, 1e5)
#: Largest |angle| a servo may report [rad].
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

    ``surrogate``: the estimator's K surrogate for it (None: silent estimator, or no true
    ``uses_estimator``); the true K comes only by the oracle's ``observe_truth``."""

    name: str

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        ...
