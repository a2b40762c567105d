"""The lab bench around the cavity: servos that take time to reach a command, encoders
that report their angles inexactly, and detectors with noise, a resolution, a ceiling and
an optical spectrum analyser that refreshes M only every few round trips.

Everything is off by default (:class:`BenchConfig` ``()`` is the ideal bench: a command
is reached on the next round trip and every reading is exact), so the simulator and the
fast closed loop behave as before unless a setting asks otherwise. Units: angles in rad,
times in round trips, E and M in the model's units (``E = sqrt(energy)``).

Per round trip, :class:`Bench` gives the angles the cavity runs with
(:meth:`Bench.advance`) and turns the laser's true E, M and peak into what the detectors
report, and the true angles into what the encoders report (:meth:`Bench.read`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from dlmpc_ros.core import checks

#: What each setting may be (inclusive); the laser_sim node declares these ranges.
RANGES: dict[str, tuple[float, float]] = {
    'servo_lag': (0, 100_000), 'slew_rate': (0.0, 100.0), 'backlash': (0.0, 0.5),
    'encoder_noise': (0.0, 0.1), 'encoder_resolution': (0.0, 0.1),
    'detector_noise': (0.0, 0.5), 'detector_resolution': (0.0, 10.0),
    'detector_saturation': (0.0, 1e4), 'spectrum_refresh': (1, 100_000),
}


@dataclass(frozen=True)
class BenchConfig:
    """The bench's imperfections; the defaults are an ideal bench."""

    servo_lag: int = 0
    """Round trips between a command's arrival and the servos starting to move."""
    slew_rate: float = 0.0
    """Largest angle change per round trip of each servo [rad]; 0: no limit (a move
    completes in one round trip)."""
    backlash: float = 0.0
    """Play of each mount [rad]: on reversing, the drive turns this far before the
    optic follows, so the optic rests up to half of it short of the drive's angle. The
    encoder reads the drive (a motor encoder), so it does not see the play."""
    encoder_noise: float = 0.0
    """Standard deviation of the Gaussian noise on each reported angle [rad]."""
    encoder_resolution: float = 0.0
    """Step of the reported angles [rad] (0: continuous); 0.05 degrees is 8.7e-4 rad."""
    detector_noise: float = 0.0
    """Relative standard deviation of independent Gaussian noise on the E and M read each
    round trip (the peak and energy carry E's factor)."""
    detector_resolution: float = 0.0
    """Step of the reported E and M [model units] (0: continuous)."""
    detector_saturation: float = 0.0
    """Largest E the energy detector reports (0: no ceiling); above it E reads the
    ceiling."""
    spectrum_refresh: int = 1
    """M is a new reading every this many round trips (an optical spectrum analyser's
    sweep); in between it repeats the last one."""

    def __post_init__(self) -> None:
        checks.counts(self, 'servo_lag', minimum=0)
        checks.counts(self, 'spectrum_refresh')
        checks.non_negative(self, 'slew_rate', 'backlash', 'encoder_noise',
                            'encoder_resolution', 'detector_noise', 'detector_resolution',
                            'detector_saturation')
        for f in fields(self):
            low, high = RANGES[f.name]
            if not low <= getattr(self, f.name) <= high:
                raise ValueError(f'BenchConfig.{f.name} must be in [{low:g}, {high:g}], '
                                 f'got {getattr(self, f.name)!r}')

    @property
    def instant_servos(self) -> bool:
        """Whether a command is reached exactly on the next round trip."""
        return self.servo_lag == 0 and self.slew_rate == 0 and self.backlash == 0

    @property
    def ideal(self) -> bool:
        """Whether the bench changes nothing (every setting at its default)."""
        return self == BenchConfig()

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def full_step_round_trips(self, step: float) -> int:
        """Round trips from a command to reaching a move of ``step`` rad (lag and slew)."""
        moving = 1 if self.slew_rate == 0 else math.ceil(step / self.slew_rate - 1e-12)
        return self.servo_lag + max(moving, 1)


#: Fields of :class:`BenchConfig`, in order (the laser_sim node's parameter names).
BENCH_FIELDS = tuple(f.name for f in fields(BenchConfig))


class Bench:
    """One laser's servos, encoders and detectors.

    Parameters
    ----------
    config
        The bench's imperfections.
    angles
        The angles (4,) [rad] the mounts start at (drive and optic alike).
    seed
        Seeds the detector's noise (``default_rng(seed)``, two normal draws per reading:
        E then M) and, separately, the encoders' noise.
    """

    def __init__(self, config: BenchConfig, angles: np.ndarray, seed: int = 0) -> None:
        self.config = config
        self.drive = np.array(angles, float)       # (4,) the drive's (motor's) angles
        self.optic = self.drive.copy()              # (4,) what the light sees
        self.target = self.drive.copy()             # (4,) the latest command
        self._start = 0                             # round trips until the drive moves
        self._detector_rng = np.random.default_rng(seed)
        self._encoder_rng = np.random.default_rng([seed, 1])
        self._last_m = math.nan

    def command(self, angles: np.ndarray) -> None:
        """A new command (4,) [rad]; the drive starts after ``servo_lag`` round trips. A
        command equal to the current target changes nothing (a resent command does not
        restart the lag)."""
        angles = np.asarray(angles, float)
        if np.array_equal(angles, self.target):
            return
        self.target = angles.copy()
        self._start = self.config.servo_lag

    def advance(self) -> np.ndarray:
        """Move the servos by one round trip; the optic's angles (4,) [rad] this round
        trip runs with."""
        c = self.config
        if self._start > 0:
            self._start -= 1
        else:
            gap = self.target - self.drive
            if c.slew_rate > 0:  # the last stretch lands on the target exactly
                self.drive = np.where(np.abs(gap) <= c.slew_rate, self.target,
                                      self.drive + np.clip(gap, -c.slew_rate, c.slew_rate))
            else:
                self.drive = self.target.copy()
        if c.backlash > 0:  # the optic follows once the drive has taken up the play
            half = c.backlash / 2
            self.optic = np.clip(self.optic, self.drive - half, self.drive + half)
        else:
            self.optic = self.drive.copy()
        return self.optic.copy()

    @property
    def settled(self) -> bool:
        """Whether the drive is at the latest command."""
        return self._start == 0 and bool(np.array_equal(self.drive, self.target))

    def read_angles(self) -> np.ndarray:
        """What the encoders report (4,) [rad]: the drive's angles with noise, quantized."""
        c = self.config
        angles = self.drive.copy()
        if c.encoder_noise > 0:
            angles += c.encoder_noise * self._encoder_rng.standard_normal(4)
        return _quantize(angles, c.encoder_resolution)

    def read_detectors(self, round_trip: int, e: float, m: float,
                       peak: float) -> tuple[float, float, float]:
        """What the detectors report for round trip ``round_trip`` with true ``e``,
        ``m``, ``peak``: ``(E, M, peak)``, E and M with their noise, ceiling and resolution
        (M is read at round trips 1, 1 + k, 1 + 2k, ... and repeats its last reading in
        between), peak scaled by E's reading squared."""
        c = self.config
        e_read, m_read = e, m
        if c.detector_noise > 0:
            e_noise, m_noise = self._detector_rng.standard_normal(2)
            e_read = e * (1.0 + c.detector_noise * e_noise)
            m_read = m * (1.0 + c.detector_noise * m_noise)
        if c.detector_saturation > 0:
            e_read = min(e_read, c.detector_saturation)
        e_read = float(_quantize(np.array(e_read), c.detector_resolution))
        m_read = float(_quantize(np.array(m_read), c.detector_resolution))
        if c.spectrum_refresh > 1:
            if (round_trip - 1) % c.spectrum_refresh or not math.isfinite(m_read):
                m_read = self._last_m if math.isfinite(self._last_m) else m_read
            else:
                self._last_m = m_read
        peak_read = peak * (e_read / e) ** 2 if e > 0 else peak
        return e_read, m_read, peak_read


def _quantize(values: np.ndarray, step: float) -> np.ndarray:
    return values if step <= 0 else np.round(values / step) * step


#: Named benches: the servos of the stress suite and the lab bench of the bench issue
#: (a motorized mount's lag and slew, its encoder's noise, a detector's 1 % noise).
BENCH_PRESETS: dict[str, dict[str, float]] = {
    'ideal': {},
    'servo-3': {'servo_lag': 3, 'slew_rate': 0.1},
    'servo-6': {'servo_lag': 6, 'slew_rate': 0.04},
    'lab': {'servo_lag': 6, 'slew_rate': 0.04, 'encoder_noise': 0.001,
            'detector_noise': 0.01},
}


def parse_bench(items: list[str]) -> BenchConfig:
    """A bench from ``PRESET`` names (:data:`BENCH_PRESETS`) and ``KEY=VALUE`` settings,
    later items overriding earlier ones; ValueError naming a bad item."""
    values: dict[str, float] = {}
    for item in items:
        key, sep, text = item.partition('=')
        if not sep:
            if item not in BENCH_PRESETS:
                raise ValueError(f'unknown bench {item!r}: use one of '
                                 f'{", ".join(BENCH_PRESETS)} or KEY=VALUE with KEY one of '
                                 f'{", ".join(BENCH_FIELDS)}')
            values.update(BENCH_PRESETS[item])
            continue
        if key not in BENCH_FIELDS:
            raise ValueError(f'unknown bench setting {key!r}; known: {", ".join(BENCH_FIELDS)}')
        try:
            number = float(text)
        except ValueError:
            raise ValueError(f'bench setting {key} must be a number, got {text!r}') from None
        integer = isinstance(getattr(BenchConfig(), key), int)
        if integer and number != int(number):
            raise ValueError(f'bench setting {key} must be an integer, got {text!r}')
        values[key] = int(number) if integer else number
    return BenchConfig(**values)
