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
    """One-step prediction error (normalized state units, averaged over recent periods)
    above which the inner loop takes over."""
    accurate_error: float = 0.3
    """Errors below this count as accurate (iterations grow)."""
    error_memory: int = 3
    """Recent periods whose prediction errors are averaged."""
    apply_all: bool = False
    """Play out the whole N-period plan before re-planning (the paper) instead of only its
    first step."""
    monitor_prediction: bool = False
    """Score the predictor's one-step forecast in every mode, not only in the outer loop,
    so that the outer loop can take over again after a spell of poor predictions."""
    trust_radius: float | None = None
    """Largest distance [rad] of a planned angle from the current angle (None: no limit);
    keeps the plan where the predictor was trained, instead of where it is wrong."""
    objective_guard: float | None = None
    """If set: when the measured O under the outer loop falls below this fraction of the O
    last measured under the inner loop, go back to the inner loop for ``guard_cooldown``
    periods (the predictor's plans are trusted only while they do not lose objective)."""
    guard_cooldown: int = 50
    """Control periods the objective guard keeps the outer loop off."""
    acquisition: AcquisitionConfig | None = field(default_factory=AcquisitionConfig)
    """The lock acquisition scan (None: off)."""
    tracking: TrackingConfig | None = field(default_factory=TrackingConfig)
    """Curve tracking once locked (None: off; also off without a tracking curve)."""
    planner: PlannerConfig | None = field(default_factory=PlannerConfig)
    """Planning turns of the tracking curve with the steady-response predictor (None:
    off; also off without tracking or without the predictor)."""

    def __post_init__(self) -> None:
        if not 1 <= self.min_iterations <= self.start_iterations <= self.max_iterations:
            raise ValueError('need 1 <= min_iterations <= start_iterations <= max_iterations')
        if not (self.learning_rate > 0 and self.error_threshold > 0 and self.accurate_error > 0):
            raise ValueError('learning_rate, error_threshold and accurate_error must be > 0')
        if self.trust_radius is not None and not self.trust_radius > 0:
            raise ValueError('trust_radius must be > 0 (or None)')
        if self.objective_guard is not None and not 0 < self.objective_guard <= 1:
            raise ValueError('objective_guard must be in (0, 1] (or None)')
        if self.guard_cooldown < 1 or self.error_memory < 1:
            raise ValueError('guard_cooldown and error_memory must be >= 1')
