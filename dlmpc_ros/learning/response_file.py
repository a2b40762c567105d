"""The steady-response predictor's file (``response.pt``, :mod:`dlmpc_ros.learning.response`):
the sizes and input scaling stored in it (:class:`ResponseModelConfig`), and the predictor
read back from it (:func:`load_response`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import load_model
from dlmpc_ros.learning.response import FEATURES, ResponseEnsemble


@dataclass(frozen=True)
class ResponseModelConfig:
    """Sizes and input scaling of the predictor (stored in its file)."""

    members: int = 5
    """Networks in the ensemble."""
    hidden: int = 64
    """Units of every hidden layer."""
    layers: int = 3
    """Linear layers per network (tanh between them)."""
    mean: list = field(default_factory=lambda: [0.0] * len(FEATURES))
    """Mean of each input on the training data."""
    std: list = field(default_factory=lambda: [1.0] * len(FEATURES))
    """Standard deviation of each input on the training data (> 0)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'members', 'hidden', 'layers')
        if len(self.mean) != len(FEATURES) or len(self.std) != len(FEATURES) \
                or not all(np.isfinite(self.mean)) or not all(s > 0 for s in self.std):
            raise ValueError(f'ResponseModelConfig needs {len(FEATURES)} finite means and '
                             'positive standard deviations')

    def to_dict(self) -> dict:
        return asdict(self)


def load_response(path: str | Path) -> tuple[ResponseEnsemble, dict]:
    """The steady-response predictor and its file's payload; raises
    :class:`~dlmpc_ros.learning.checkpoint.ModelFileError`."""
    return load_model(path, 'response',
                      lambda config: ResponseEnsemble(ResponseModelConfig(**config)))
