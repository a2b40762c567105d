"""What every controller returns for one control period, and the protocol they share; what
the DL-MPC's modes (:mod:`~dlmpc_ros.control.dlmpc`) take and return in one."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    import torch

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
    """Measurement ``(E, M, alpha1..alpha_p)`` and the estimator's K surrogate for it (None:
    none, or the controller's ``uses_estimator`` is false) in, next angles out; the true K
    comes only by the oracle's ``observe_truth``."""

    name: str

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        ...


@dataclass(frozen=True)
class Period:
    """What the supervisor knows in one control period."""

    current: np.ndarray  # (4,) angles applied during the period [rad]
    objective: float     # measured O = E / M (NaN where M <= 0)
    surrogate: float     # the estimator's K surrogate for the measurement (NaN: none)
    energy: float        # measured E


@dataclass(frozen=True)
class Decision:
    """A mode's choice for the next period (the supervisor applies the servo limits)."""

    angles: np.ndarray            # (4,) wanted angles [rad]
    mode: str                     # name of the mode that decided
    surrogate: float | None = None  # the estimate to report (None: the period's surrogate)
    #: (N,) predicted O over the horizon, the plan's iterations, and the (2,) normalized
    #: state it predicts for the end of the next period (the outer loop's plans only)
    predicted_objective: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iterations: int = 0
    predicted_next: torch.Tensor | None = None
    travel: bool = False  # the angles only move the servos on (no measurement needed there)


class Mode:
    """One way of choosing the angles."""

    name = ''

    def decide(self, period: Period) -> Decision | None:
        """The angles for the next period, or None to pass to the next mode."""
        raise NotImplementedError

    def stand_down(self) -> None:
        """A mode before this one acted: drop what was under way (by default, nothing)."""
