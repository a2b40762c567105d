"""The DL-MPC's settings (:mod:`dlmpc_ros.control.dlmpc`; its parts' in the order they act,
then its own), each with its description and range (:func:`~dlmpc_ros.core.checks.setting`):
the ``mpc_controller`` node's parameters."""

from __future__ import annotations

from dataclasses import dataclass, field

from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.core.checks import in_range, setting

#: Factors on the estimate's step while the dither's comparisons agree in sign, and when
#: they flip (Rprop).
RPROP_GROW, RPROP_SHRINK = 1.5, 0.5
#: Smallest and largest change of the estimate per compared block (K units).
MIN_STEP, MAX_STEP = 0.005, 0.03
#: Recent periods whose log E and log M are averaged as the predictor's input.
MEASUREMENTS = 3
#: Recent periods whose one-step prediction errors the outer loop averages.
ERROR_MEMORY = 3


@dataclass(frozen=True)
class AcquisitionConfig:
    """Settings of the lock supervisor (times in control periods); the scan lets go at the
    first locked period (``bench/results/acquisition_confirm.md``)."""

    lock_fraction: float = setting(0.5, 'locked when O >= this x the mean O of the map\'s '
                                   'training targets', 1e-6, 0.999999)
    patience: int = setting(3, 'unlocked control periods before the scan starts '
                            '(bench/results/acquisition_pace.md)', 1, 1_000_000)
    relock_patience: int = setting(10, 'unlocked control periods before the scan starts once '
                                   'the laser has been locked in this run', 1, 1_000_000)
    dwell_periods: int = setting(3, 'control periods the scan waits at each point once the '
                                 'servos are there', 1, 1_000_000)

    def __post_init__(self) -> None:
        in_range(self)


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of the curve tracker (times in control periods; ``s`` in K's units)."""

    start: float = setting(-0.1, 'curve parameter of the first entry after locked periods '
                           'without a scan (K units; later ones start where a failed entry '
                           'left the angles)', -1.0, 1.0)
    dither: float = setting(0.03, 'half-amplitude of the dither on the curve parameter '
                            '(K units)', 1e-9, 1.0)
    block: int = setting(3, 'control periods per dither half', 1, 10_000)
    step: float = setting(0.015, 'first change of the estimate per compared dither block '
                          f'(K units); it grows by {RPROP_GROW} while the comparisons agree '
                          f'in sign and shrinks by {RPROP_SHRINK} when they flip (Rprop), '
                          f'within [{MIN_STEP}, {MAX_STEP}]', MIN_STEP, MAX_STEP)
    noise_deadband: float = setting(
        1.0, "the estimate moves only when the dither's O difference passes this many "
        'standard deviations of the measurement noise read off the run (0: off; '
        'bench/results/noise_deadband.md)', 0.0, 10.0)
    entry_patience: int = setting(3, 'locked control periods (angles held) before '
                                  'tracking takes over', 1, 1_000_000)
    settle: int = setting(20, 'control periods after entry before the guard judges O (for '
                          '2 x block periods) and the dither\'s comparisons count',
                          0, 1_000_000)
    guard: float = setting(0.85, 'right after an entry, stop tracking (hold the angles) '
                           'when O falls below this x the O at entry', 1e-6, 1.0)
    guard_periods: int = setting(3, 'consecutive control periods under the guard that hand '
                                 'back', 1, 1_000_000)
    mirror_margin: float = setting(0.03, 'how far past K = 0 the estimate must go before '
                                   'the tracker turns to the mirror branch (K units)',
                                   0.0, 1.0)
    turn_guard: float = setting(0.45, 'during a change of branch, or on trial after it, O '
                                'under this x the O before it turns back '
                                '(bench/results/entry_turn.md)', 1e-6, 1.0)
    trial_drop: float = setting(0.08, 'relative fall of O under its best on this branch '
                                'that makes the tracker try the other branch (0: only the '
                                'estimate decides)', 0.0, 0.999999)
    entry_trial_after: int = setting(6, 'control periods after an entry before the other '
                                     'branch is tried once (an entry may be on the weaker '
                                     'branch; bench/results/entry_turn.md)', 0, 1_000_000)
    entry_trial_below: float = setting(0.8, 'the entry trial is made only if O is under '
                                       "this x the curve's own steady O at the estimate "
                                       '(without that O, always; 0: never)', 0.0, 100.0)

    def __post_init__(self) -> None:
        in_range(self)


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of the rotation planner."""

    radius: float = setting(0.1, 'trust radius: largest turn of the curve per plan [rad]',
                            1e-3, 1.0)
    spread_penalty: float = setting(1.0, "weight of the predictor ensemble's spread against "
                                    'its mean gain (bench/results/planner_gate.md)', 0.0, 100.0)
    noise_gate: float = setting(
        1.0, 'a turn must be predicted to gain this many standard deviations of the noise of '
        f'its own measured gain, noise x sqrt(2 / {MEASUREMENTS}) (noise: one period\'s log O '
        'noise; 0: off; bench/results/noise_gate.md)', 0.0, 100.0)
    online: bool = setting(True, "correct the predictor online from the run's own turns")
    explore: bool = setting(False, 'calibration runs: a random turn within the trust radius '
                            'each plan instead of the planned one (seeded 0; the undo '
                            'guards); record a bag for `dlmpc-train adapt`')

    def __post_init__(self) -> None:
        in_range(self)


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
