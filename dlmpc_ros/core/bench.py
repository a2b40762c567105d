"""The lab bench around the cavity: servos that take time to reach a command, encoders
that report their angles inexactly, and detectors with noise, a resolution, a ceiling and
an optical spectrum analyser that refreshes M only every few round trips.

Everything is off by default (:class:`BenchConfig` ``()`` is the ideal bench: a command
is reached on the next round trip and every reading is exact), so the simulator and the
fast closed loop behave as before unless a setting asks otherwise. Units: angles in rad,
times in round trips, E and M in the model's units (``E = sqrt(energy)``).

Per round trip, :class:`Bench` gives the angles the cavity runs with
(:meth:`Bench.advance`, through its :class:`Servos`, which also move the mounts of B
lasers at once) and turns the laser's true E, M and peak into what the detectors report
(:meth:`Bench.read_detectors`), and the drive's angles into what the encoders report
(:meth:`Bench.read_angles`).
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

    def changes(self) -> dict[str, float]:
        """The settings that differ from an ideal bench."""
        ideal = asdict(BenchConfig())
        return {k: v for k, v in asdict(self).items() if v != ideal[k]}

    def full_step_round_trips(self, step: float) -> int:
        """Round trips from a command to reaching a move of ``step`` rad (lag and slew)."""
        moving = 1 if self.slew_rate == 0 else math.ceil(step / self.slew_rate - 1e-12)
        return self.servo_lag + max(moving, 1)


#: Fields of :class:`BenchConfig`, in order (the laser_sim node's parameter names).
BENCH_FIELDS = tuple(f.name for f in fields(BenchConfig))


class Servos:
    """The mounts of one laser (angles (4,)) or of B lasers (angles (B, 4)) [rad]: where
    each drive and optic is, the latest command, and the round trips until each drive
    moves (``servo_lag``, ``slew_rate`` and ``backlash`` of ``config``)."""

    def __init__(self, config: BenchConfig, angles: np.ndarray) -> None:
        self.config = config
        self.drive = np.array(angles, float)       # (..., 4) the drive's (motor's) angles
        self.optic = self.drive.copy()              # (..., 4) what the light sees
        self.target = self.drive.copy()             # (..., 4) the latest command
        self.wait = np.zeros(self.drive.shape[:-1], np.int64)  # round trips to the start

    def command(self, angles: np.ndarray) -> None:
        """New commands (..., 4) [rad]; a drive whose command changed starts after
        ``servo_lag`` round trips (a resent command does not restart the lag)."""
        angles = np.array(angles, float)
        changed = (angles != self.target).any(axis=-1)
        self.wait = np.where(changed, self.config.servo_lag, self.wait)
        self.target = angles

    def place(self, angles: np.ndarray, index: int | np.ndarray) -> None:
        """Put the mounts in ``index`` at ``angles`` at once, at rest (a new episode)."""
        self.drive[index] = self.optic[index] = self.target[index] = angles
        self.wait[index] = 0

    def advance(self) -> np.ndarray:
        """Move the servos by one round trip; the optic's angles (..., 4) [rad] this round
        trip runs with."""
        c = self.config
        waiting = self.wait > 0
        self.wait = np.where(waiting, self.wait - 1, self.wait)
        gap = self.target - self.drive
        if c.slew_rate > 0:  # the last stretch lands on the target exactly
            moved = np.where(np.abs(gap) <= c.slew_rate, self.target,
                             self.drive + np.clip(gap, -c.slew_rate, c.slew_rate))
        else:
            moved = self.target
        self.drive = np.where(waiting[..., None], self.drive, moved)
        if c.backlash > 0:  # the optic follows once the drive has taken up the play
            half = c.backlash / 2
            self.optic = np.clip(self.optic, self.drive - half, self.drive + half)
        else:
            self.optic = self.drive.copy()
        return self.optic.copy()

    @property
    def settled(self) -> np.ndarray:
        """Whether each drive is at its latest command (a bool of the batch's shape)."""
        return (self.wait == 0) & (self.drive == self.target).all(axis=-1)


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
        self.servos = Servos(config, angles)
        self._detector_rng = np.random.default_rng(seed)
        self._encoder_rng = np.random.default_rng([seed, 1])
        self._last_m = math.nan

    def command(self, angles: np.ndarray) -> None:
        """A new command (4,) [rad] (:meth:`Servos.command`)."""
        self.servos.command(angles)

    def advance(self) -> np.ndarray:
        """Move the servos by one round trip; the optic's angles (4,) [rad]."""
        return self.servos.advance()

    @property
    def settled(self) -> bool:
        """Whether the drive is at the latest command."""
        return bool(self.servos.settled)

    def read_angles(self) -> np.ndarray:
        """What the encoders report (4,) [rad]: the drive's angles with noise, quantized."""
        c = self.config
        angles = self.servos.drive.copy()
        if c.encoder_noise > 0:
            angles += c.encoder_noise * self._encoder_rng.standard_normal(4)
        return quantize(angles, c.encoder_resolution)

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
        e_read = float(quantize(np.array(e_read), c.detector_resolution))
        m_read = float(quantize(np.array(m_read), c.detector_resolution))
        if c.spectrum_refresh > 1:
            if (round_trip - 1) % c.spectrum_refresh or not math.isfinite(m_read):
                m_read = self._last_m if math.isfinite(self._last_m) else m_read
            else:
                self._last_m = m_read
        peak_read = peak * (e_read / e) ** 2 if e > 0 else peak
        return e_read, m_read, peak_read


def quantize(values: np.ndarray, step: float) -> np.ndarray:
    """``values`` rounded to whole multiples of ``step`` (unchanged for step 0)."""
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
