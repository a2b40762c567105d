"""Settings of the DL-MPC controller (:mod:`dlmpc_ros.control.dlmpc`) and its modes."""

from __future__ import annotations

from dataclasses import dataclass, field

from dlmpc_ros.control.acquisition import AcquisitionConfig
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.control.rotation_planner import PlannerConfig
from dlmpc_ros.control.tracking import TrackingConfig
from dlmpc_ros.core.checks import in_range, setting

#: Recent periods whose one-step prediction errors the outer loop averages.
ERROR_MEMORY = 3


@dataclass(frozen=True)
class DLMPCConfig:
    """Settings of the controller (angles in radians)."""

    limits: AngleLimits = field(default_factory=AngleLimits)
    """Angle range and servo speed every command obeys."""
    min_iterations: int = setting(1, 'MP-RNN outer loop (strategy paper, or track false): '
                                  'fewest gradient-ascent iterations per plan', 1, 10_000)
    max_iterations: int = setting(8, 'MP-RNN outer loop: most gradient-ascent iterations per '
                                  'plan', 1, 10_000)
    start_iterations: int = setting(3, 'MP-RNN outer loop: iterations of the first plan',
                                    1, 10_000)
    learning_rate: float = setting(0.05, 'MP-RNN outer loop: Adam step of the plan '
                                   'optimization [rad]', 1e-9, 10.0)
    error_threshold: float = setting(
        1.0, 'MP-RNN outer loop: one-step prediction error (normalized state units, mean of '
        f'the last {ERROR_MEMORY} periods) above which the VAE + map inner loop takes over',
        1e-12, 1e6)
    accurate_error: float = setting(0.3, 'MP-RNN outer loop: prediction errors below this '
                                    'count as accurate (one iteration more)', 1e-12, 1e6)
    acquisition: AcquisitionConfig | None = field(default_factory=AcquisitionConfig)
    """The lock acquisition scan (None: off)."""
    tracking: TrackingConfig | None = field(default_factory=TrackingConfig)
    """Curve tracking once locked (None: off; also off without a tracking curve)."""
    planner: PlannerConfig | None = field(default_factory=PlannerConfig)
    """Planned curve turns (None: off; also off without tracking or the predictor)."""

    def __post_init__(self) -> None:
        in_range(self)
        if not self.min_iterations <= self.start_iterations <= self.max_iterations:
            raise ValueError('need min_iterations <= start_iterations <= max_iterations')
