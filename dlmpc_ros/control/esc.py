"""Extremum-seeking control (ESC) of the four angles, after Brunton, Fu and Kutz,
"Extremum-seeking control of a mode-locked laser", IEEE JQE 49 (2013).

Every control period the controller gets one measurement ``(E, M, alpha[4])`` and
climbs the objective ``J = O = E / M`` without a model:

1. each angle is dithered around its mean ``theta_i`` by ``a_i sin(2 pi f_i k)`` (k
   counts control periods; the frequencies are distinct and no second-order product of
   them, ``f_i + f_j``, ``|f_i - f_j|``, ``2 f_i``, aliased into [0, 0.5], lands on a
   dither frequency, so the demodulated channels do not leak into each other);
2. the measured objective (optionally its logarithm, or divided by its running mean) is
   high-pass filtered (a washout ``y = J - eta``, ``eta += h (J - eta)``);
3. ``y`` times each channel's own dither (the one whose effect the measurement shows:
   the one commanded a period earlier) gives a gradient sample ``2 y s_i / a_i``; a
   first-order low-pass filter (``g += l (sample - g)``) averages it into the gradient
   estimate ``g`` [objective units per rad];
4. gradient ascent on the means: ``theta += gain g`` (at most ``max_mean_step`` per
   angle and period), and the next command ``theta + a sin(2 pi f (k + 1))`` goes
   through :meth:`AngleLimits.apply` (range, pi-periodicity, servo speed).

The laser settles to a new angle set within a few round trips, shorter than the control
period (10 round trips), so the plant is quasi-static at the dither frequencies and no
demodulation phase is needed. Angles are in radians, frequencies in cycles per control
period. The scheme finds and tracks a *local* maximum; where the laser starts out of
mode-locking the objective is flat and the climb is slow.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from dlmpc_ros.control.step import AngleLimits, ControlStep, implausible
from dlmpc_ros.core.angles import wrap_angles

#: Objective transforms understood by :class:`ESCConfig`.
NORMALIZATIONS = ('none', 'log', 'mean')
#: Least distance [cycles per period] between a dither frequency and any other dither
#: frequency or second-order product of two of them (aliased into [0, 0.5]).
MIN_SEPARATION = 0.02
#: Smallest objective magnitude the ``log`` and ``mean`` normalizations divide by.
TINY_OBJECTIVE = 1e-9


def _fold(f: float) -> float:
    """Alias a frequency [cycles per sample] into [0, 0.5]."""
    f = f % 1.0
    return min(f, 1.0 - f)


@dataclass(frozen=True)
class ESCConfig:
    """Settings of the extremum-seeking controller (angles in radians, one sample per
    control period).

    The defaults were tuned on the drift scenarios from random starts
    (``bench/tune_esc.py``, results in ``bench/results/esc_tuning.json``). The
    amplitudes follow the objective's curvature per angle near an optimum (alpha3 is
    about ten times flatter than alpha1); the small gain is what keeps a locked laser
    from being walked off the edge of its mode-locking region.
    """

    amplitude: float | tuple[float, ...] = (0.015, 0.015, 0.04, 0.02)
    """Dither amplitude [rad]: one for all four angles or one per angle (4 values)."""
    frequencies: tuple[float, ...] = (0.06, 0.19, 0.31, 0.44)
    """Dither frequency of each angle [cycles per control period], in (0, 0.5): distinct
    and not harmonically related (see :data:`MIN_SEPARATION`)."""
    high_pass: float = 0.2
    """Washout constant h in (0, 1]: the objective's mean follows with time constant
    about 1/h periods; h = 1 uses the difference to the previous sample."""
    low_pass: float = 0.1
    """Gradient filter constant l in (0, 1]: the estimate averages over about 1/l
    periods (l = 1: no averaging)."""
    gain: float = 0.001
    """Gradient-ascent gain [rad^2 per objective unit per period]."""
    normalize: str = 'log'
    """Objective transform before the high-pass: ``'none'`` (O itself), ``'log'``
    (log O: scale-free, climbs as well at O = 0.02 as at 0.2) or ``'mean'`` (the
    high-passed O divided by its running mean)."""
    max_mean_step: float = 0.02
    """Largest change of any angle's mean per period [rad] (keeps the step after a drop
    out of mode-locking from throwing the means far away)."""

    def __post_init__(self) -> None:
        amplitudes = np.atleast_1d(np.asarray(self.amplitude, float))
        if amplitudes.shape not in ((1,), (4,)) or not np.isfinite(amplitudes).all() \
                or (amplitudes <= 0).any() or (amplitudes > 0.5).any():
            raise ValueError(f'amplitude must be one or four values in (0, 0.5] rad, '
                             f'got {self.amplitude}')
        freqs = np.asarray(self.frequencies, float)
        if freqs.shape != (4,) or not np.isfinite(freqs).all() \
                or (freqs <= 0).any() or (freqs >= 0.5).any():
            raise ValueError(f'frequencies must be four values in (0, 0.5) cycles per '
                             f'period, got {self.frequencies}')
        products = [_fold(fi + fj) for fi in freqs for fj in freqs]
        products += [_fold(fi - fj) for i, fi in enumerate(freqs) for j, fj in enumerate(freqs)
                     if i != j]
        for i, f in enumerate(freqs):
            others = np.array(products + [g for j, g in enumerate(freqs) if j != i])
            if np.abs(others - f).min() < MIN_SEPARATION:
                raise ValueError(f'frequencies {self.frequencies}: {f} lies within '
                                 f'{MIN_SEPARATION} of another frequency or of a sum, '
                                 'difference or harmonic of two (aliased into [0, 0.5]); '
                                 'use distinct, not harmonically related frequencies')
        for name in ('high_pass', 'low_pass'):
            value = getattr(self, name)
            if not 0 < value <= 1:
                raise ValueError(f'{name} must be in (0, 1], got {value}')
        if not (math.isfinite(self.gain) and self.gain > 0):
            raise ValueError(f'gain must be finite and > 0, got {self.gain}')
        if self.normalize not in NORMALIZATIONS:
            raise ValueError(f'normalize must be one of {NORMALIZATIONS}, '
                             f'got {self.normalize!r}')
        if not (math.isfinite(self.max_mean_step) and self.max_mean_step > 0):
            raise ValueError(f'max_mean_step must be finite and > 0 rad, '
                             f'got {self.max_mean_step}')

    @property
    def amplitudes(self) -> np.ndarray:
        """(4,) dither amplitudes [rad]."""
        return np.broadcast_to(np.asarray(self.amplitude, float), (4,)).copy()


class ESCController:
    """Multi-parameter extremum-seeking controller of the four angles.

    Parameters
    ----------
    initial_angles
        (4,) starting means [rad]; None takes the angles of the first measurement.
    config
        Dither, filter and gain settings.
    limits
        Angle range and servo speed; every command goes through ``limits.apply``.
    """

    name = 'esc'

    def __init__(self, initial_angles: np.ndarray | None = None,
                 config: ESCConfig | None = None, limits: AngleLimits | None = None) -> None:
        self.config = config or ESCConfig()
        self.limits = limits or AngleLimits()
        if initial_angles is not None:
            initial_angles = np.asarray(initial_angles, float)
            if initial_angles.shape != (4,) or not np.isfinite(initial_angles).all():
                raise ValueError(f'esc: initial_angles must be 4 finite numbers [rad], '
                                 f'got {initial_angles}')
        self.initial_angles = initial_angles
        self._amplitudes = self.config.amplitudes                     # (4,) [rad]
        self._omega = 2 * np.pi * np.asarray(self.config.frequencies)  # (4,) [rad / period]
        self.reset()

    def reset(self) -> None:
        """Forget the filters, the gradient estimate and the means (a fresh start)."""
        self.means: np.ndarray | None = (None if self.initial_angles is None
                                         else self.initial_angles.copy())
        self.gradient = np.zeros(4)           # objective units per rad
        self.periods = 0                      # dither clock, control periods
        self._washout: float | None = None    # high-pass state eta
        self._scale: float | None = None      # running |O| for normalize='mean'
        self._dither_sent = np.zeros(4)       # unit dither of the last command
        self._last_command: np.ndarray | None = None

    def _objective(self, e: float, m: float) -> float | None:
        """The transformed objective, or None where it is unusable."""
        o = e / m if m != 0 else math.nan
        if not math.isfinite(o):
            return None
        if self.config.normalize == 'log':
            return math.log(max(o, TINY_OBJECTIVE))
        return o

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        """One control period: measurement ``(E, M, alpha[4])`` in, next angles out."""
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        if measurement.shape != (6,):
            raise ValueError(f'esc: measurement must be (E, M, alpha1, alpha2, alpha3, '
                             f'alpha_p), got shape {measurement.shape}')
        current = measurement[2:6]
        j = None if implausible(measurement) else self._objective(measurement[0],
                                                                   measurement[1])
        if j is None:
            angles = self._hold(current)
        else:
            angles = self._climb(j, current)
        self._last_command = angles
        return ControlStep(angles=angles, mode='esc',
                           latency_ms=1e3 * (time.perf_counter() - started))

    def _hold(self, current: np.ndarray) -> np.ndarray:
        """No usable measurement: keep the angles, leave the filters alone."""
        self._dither_sent = np.zeros(4)
        if np.isfinite(current).all():
            return self.limits.apply(current, current)
        if self._last_command is not None:
            return self._last_command.copy()
        fallback = self.means if self.means is not None else np.zeros(4)
        return self.limits.apply(fallback, fallback)

    def _climb(self, j: float, current: np.ndarray) -> np.ndarray:
        cfg = self.config
        if self.means is None:
            self.means = current.copy()
        if self._washout is None:
            self._washout = j
            self._scale = abs(j)
        # High-pass (washout) of the objective, then demodulation with the dither whose
        # effect this measurement shows.
        y = j - self._washout
        self._washout += cfg.high_pass * (j - self._washout)
        if cfg.normalize == 'mean':
            y /= max(self._scale, TINY_OBJECTIVE)
            self._scale += cfg.high_pass * (abs(j) - self._scale)
        sample = 2.0 * y * self._dither_sent / self._amplitudes       # (4,)
        self.gradient += cfg.low_pass * (sample - self.gradient)
        move = np.clip(cfg.gain * self.gradient, -cfg.max_mean_step, cfg.max_mean_step)
        # Means: the pi-equivalent nearest to the current angles, kept inside the range.
        means = self.means + move
        means = current + wrap_angles(means - current)
        self.means = np.clip(means, self.limits.low, self.limits.high)
        self.periods += 1
        self._dither_sent = np.sin(self._omega * self.periods)
        wanted = self.means + self._amplitudes * self._dither_sent
        return self.limits.apply(current, wanted)
