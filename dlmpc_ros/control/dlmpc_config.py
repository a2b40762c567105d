"""Settings of the DL-MPC controller (:mod:`dlmpc_ros.control.dlmpc`) and its modes."""

from __future__ import annotations

from dataclasses import dataclass, field

from dlmpc_ros.control.acquisition import AcquisitionConfig
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.control.rotation_planner import PlannerConfig
from dlmpc_ros.control.tracking import TrackingConfig


@dataclass(frozen=True)
class DLMPCConfig:
    """Settings of the controller (angles in radians)."""

    limits: AngleLimits = field(default_factory=AngleLimits)
    """Angle range and servo speed every command obeys."""
    min_iterations: int = 1
    """Fewest gradient-ascent iterations of a plan."""
    max_iterations: int = 8
    """Most gradient-ascent iterations of a plan."""
    start_iterations: int = 3
    """Iterations of the first plan."""
    learning_rate: float = 0.05
    """Adam step of the plan optimization [rad]."""
    error_threshold: float = 1.0
    """One-step prediction error (normalized state units, mean of the last
    ``planner.ERROR_MEMORY`` periods) above which the inner loop takes over."""
    accurate_error: float = 0.3
    """Errors below this count as accurate (iterations grow)."""
    acquisition: AcquisitionConfig | None = field(default_factory=AcquisitionConfig)
    """The lock acquisition scan (None: off)."""
    tracking: TrackingConfig | None = field(default_factory=TrackingConfig)
    """Curve tracking once locked (None: off; also off without a tracking curve)."""
    planner: PlannerConfig | None = field(default_factory=PlannerConfig)
    """Planned curve turns (None: off; also off without tracking or the predictor)."""

    @classmethod
    def paper(cls, **settings) -> DLMPCConfig:
        """The paper's DL-MPC (section 3D) only: inner and outer loop; no acquisition scan,
        curve tracking or planned turns."""
        return cls(acquisition=None, tracking=None, planner=None, **settings)

    def __post_init__(self) -> None:
        if not 1 <= self.min_iterations <= self.start_iterations <= self.max_iterations:
            raise ValueError('need 1 <= min_iterations <= start_iterations <= max_iterations')
        if not (self.learning_rate > 0 and self.error_threshold > 0 and self.accurate_error > 0):
            raise ValueError('learning_rate, error_threshold and accurate_error must be > 0')
