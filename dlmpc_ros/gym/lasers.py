"""B lasers stepped one control period at a time: the engine of the single and the
vector environment (numpy and the batched cavity kernel; no gymnasium).

Every laser (lane) has its own episode: drift scenario, plant, initial field, bench
state and random streams, all drawn at :meth:`LaserBatch.begin` from that lane's
generator in a fixed order, so a lane's episode depends only on its generator, whichever
other lanes share the batch. Lanes of one fixed plant share one :class:`Cavity` (one
kernel call per round trip for all of them); with ``plant='family'`` each lane has its own
cavity (its plant's parameters are the kernel's constants).

A period: the lanes' new commands go to the servos; P round trips run, each with K of the
lane's scenario at that round trip and the angles its servos have reached (with ideal
servos: the command from the period's first round trip on); the detectors and encoders
read every round trip (``core/bench.py``'s noise, resolution, ceiling and spectrum
refresh, drawn per lane); the measurement is the mean E and M and the median reported
angles of the period's last min(n, P) round trips whose angles are within the settle
tolerance of the command (``control/step.py``, ``PeriodMeasurement``), or the last reading when
none is (``settled`` False). A round trip whose field blows up resets that laser's field,
as the simulator node does; a period with no finite round trip measures E = 0, M = 1.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dlmpc_ros.control.observation import (E_BOUNDS, M_BOUNDS, MEASUREMENT, MeasurementWindow,
                                           delta_commands)
from dlmpc_ros.control.observation import observation_bounds as window_bounds
from dlmpc_ros.core.bench import Servos, quantize
from dlmpc_ros.core.cavity import Cavity, initial_field
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.grid import Grid
from dlmpc_ros.core.plants import plant_parameters
from dlmpc_ros.gym.config import SOLVER_FIELDS, LaserEnvConfig, checked_envelope

# The measurement's columns, the observation's bounds and window and the delta action's
# commands are control/observation.py's, which the DRL controller runs too.
__all__ = ['E_BOUNDS', 'INFO_KEYS', 'M_BOUNDS', 'MEASUREMENT', 'LaserBatch', 'PeriodResult',
           'action_bounds', 'observation_bounds']


@dataclass(frozen=True)
class PeriodResult:
    """What one period gives per lane (arrays with a leading (B,))."""

    measurement: np.ndarray
    """(B, 6) the measured E, M and reported angles [rad]."""
    reward: np.ndarray
    """(B,) measured O = E / M (0 when nothing was finite)."""
    info: dict[str, np.ndarray]
    """Per-lane logging values (see :data:`INFO_KEYS`), never part of the observation."""


#: Keys of ``info``: the true K at the period's last round trip, the envelope O*(K) there
#: (NaN: no envelope), the true (noise-free) O of the measured round trips (their mean E
#: over their mean M: the reward without the bench's noise), the
#: episode's round trip, whether the measurement was of settled readings, whether a round
#: trip blew up, the lane's family seed (-1 for a fixed plant) and its plant's physical
#: parameters (8,) (``core/plants.py`` PHYSICS_FIELDS order).
INFO_KEYS = ('K', 'O_star', 'O_true', 'round_trip', 'settled', 'blown_up', 'family_seed',
             'plant')


class LaserBatch:
    """B lasers with their own episodes, stepped one period per call."""

    def __init__(self, config: LaserEnvConfig, batch: int) -> None:
        if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
            raise ValueError(f'the number of lasers must be an integer >= 1, got {batch!r}')
        self.config = config
        self.batch = B = int(batch)
        self.limits = config.limits
        self.bench = config.bench_config
        self.n = min(config.measurement_round_trips, config.period)
        self.base = config.base_cavity
        self.grid = Grid.from_config(self.base)
        self.family = config.plant == 'family'
        fixed = None if self.family else Cavity(self.base, batch=B)
        self._groups: list[tuple[Cavity | None, np.ndarray]] = (
            [(None, np.array([i])) for i in range(B)] if self.family
            else [(fixed, np.arange(B))])
        self.servos = Servos(self.bench, np.zeros((B, 4)))  # every lane's mounts
        self.round_trip = np.zeros(B, np.int64)
        self.last_m = np.full(B, np.nan)
        self.window = MeasurementWindow(B, config.window, config.low, config.high)
        self._fresh = np.ones(B, bool)
        self._scenarios: list = [None] * B
        self._envelopes: list[dict[str, np.ndarray] | None] = [None] * B
        self._field_rngs: list[np.random.Generator | None] = [None] * B
        self._noise_rngs: list[np.random.Generator | None] = [None] * B
        self._plants = np.zeros((B, 8))
        self._family_seed = np.full(B, -1, np.int64)
        self._fixed_envelope = config.fixed_envelope

    # -- episodes ---------------------------------------------------------------------
    def begin(self, lane: int, rng: np.random.Generator) -> None:
        """Start lane ``lane``'s episode from ``rng``: its angles, K, plant, field and
        noise streams, drawn always in the same order (whether used or not)."""
        cfg = self.config
        angles = rng.uniform(-np.pi / 2, np.pi / 2, 4)
        k0 = float(rng.uniform(-0.3, 0.3))
        drift_seed, plant_seed, field_seed, noise_seed = (int(s) for s in
                                                          rng.integers(2 ** 31, size=4))
        if not isinstance(cfg.initial_angles, str):
            angles = np.asarray(cfg.initial_angles, float)
        self._scenarios[lane] = cfg.scenario_for(rng, k0, drift_seed)
        if self.family:
            if cfg.plant_source is not None:
                cavity_cfg, envelope = cfg.plant_source(plant_seed)
                if not isinstance(cavity_cfg, CavityConfig):
                    raise ValueError('ModeLockedLaser plant_source must return '
                                     f'(CavityConfig, envelope), got {cavity_cfg!r}')
                # the plant's physics on the env's grid and solver
                cavity_cfg = replace(cavity_cfg, **{name: getattr(self.base, name)
                                                    for name in SOLVER_FIELDS})
                self._envelopes[lane] = None if envelope is None else checked_envelope(envelope)
            else:
                cavity_cfg = cfg.family.draw(plant_seed, 0, base=self.base)
                self._envelopes[lane] = None
            self._groups[lane] = (Cavity(cavity_cfg, batch=1), np.array([lane]))
            self._family_seed[lane] = plant_seed
            self._plants[lane] = list(plant_parameters(cavity_cfg).values())
        else:
            self._envelopes[lane] = self._fixed_envelope
            self._plants[lane] = list(plant_parameters(self.base).values())
        self._field_rngs[lane] = np.random.default_rng(field_seed)
        self._noise_rngs[lane] = np.random.default_rng(noise_seed)
        cavity, index = self._lane_cavity(lane)
        cavity.set_angles(angles, index)
        u, v = initial_field(self.grid, cfg.initial, 1, self._field_rngs[lane])
        cavity.set_fields(u, v, index)
        self.servos.place(angles, lane)
        self.round_trip[lane] = 0
        self.last_m[lane] = np.nan
        self._fresh[lane] = True

    def _lane_cavity(self, lane: int) -> tuple[Cavity, np.ndarray]:
        if self.family:
            cavity = self._groups[lane][0]
            assert cavity is not None
            return cavity, np.array([0])
        cavity = self._groups[0][0]
        assert cavity is not None
        return cavity, np.array([lane])

    # -- one period --------------------------------------------------------------------
    def commands(self, actions: np.ndarray) -> np.ndarray:
        """The commands (B, 4) [rad] the actions (B, 4) give from the current ones."""
        actions = np.asarray(actions, float)
        if self.config.action == 'delta':
            return delta_commands(self.servos.target, actions, self.limits)
        return self.limits.apply(self.servos.target, actions)

    def period(self, actions: np.ndarray | None = None,
               move: np.ndarray | None = None) -> PeriodResult:
        """Command the lanes in ``move`` (default all; None actions: none) by their
        actions (B, 4), run P round trips on every lane and measure each."""
        cfg, bench, B, P = self.config, self.bench, self.batch, self.config.period
        if actions is not None:
            wanted = self.commands(actions)
            move = np.ones(B, bool) if move is None else np.asarray(move, bool)
            self.servos.command(np.where(move[:, None], wanted, self.servos.target))
        first = self.round_trip + 1
        ks = np.stack([np.asarray(self._scenarios[i](np.arange(first[i], first[i] + P)),
                                  float) for i in range(B)], axis=1)       # (P, B)
        e_true, m_true = np.full((P, B), np.nan), np.full((P, B), np.nan)
        drives = np.empty((P, B, 4))
        instant = bench.instant_servos
        for j in range(P):
            if j == 0 or not instant:  # instant servos move once, on the first round trip
                optic = self.servos.advance()
                for cavity, lanes in self._groups:
                    cavity.set_angles(optic[lanes])
            drives[j] = self.servos.drive
            for cavity, lanes in self._groups:
                cavity.set_birefringence(ks[j, lanes])
                result = cavity.step()
                e_true[j, lanes], m_true[j, lanes] = result.E, result.M
                for k in np.flatnonzero(~result.finite):
                    u, v = initial_field(self.grid, cfg.initial, 1, self._field_rngs[lanes[k]])
                    cavity.set_fields(u, v, np.array([k]))
        self.round_trip += P
        return self._measure(e_true, m_true, drives, ks[-1], first)

    def _measure(self, e_true: np.ndarray, m_true: np.ndarray, drives: np.ndarray,
                 k_last: np.ndarray, first: np.ndarray) -> PeriodResult:
        c, B, P, n = self.bench, self.batch, self.config.period, self.n
        finite = np.isfinite(e_true) & np.isfinite(m_true)                 # (P, B)
        e_read, m_read = e_true.copy(), m_true.copy()
        angles = drives.copy()
        if c.detector_noise > 0 or c.encoder_noise > 0:
            for i in range(B):
                draws = self._noise_rngs[i].standard_normal((P, 6))
                e_read[:, i] *= 1.0 + c.detector_noise * draws[:, 0]
                m_read[:, i] *= 1.0 + c.detector_noise * draws[:, 1]
                angles[:, i] += c.encoder_noise * draws[:, 2:]
        if c.detector_saturation > 0:
            e_read = np.minimum(e_read, c.detector_saturation)
        e_read = quantize(e_read, c.detector_resolution)
        m_read = quantize(m_read, c.detector_resolution)
        angles = quantize(angles, c.encoder_resolution)
        if c.spectrum_refresh > 1:
            for j in range(P):
                fresh = ((first + j - 1) % c.spectrum_refresh == 0) & finite[j]
                self.last_m = np.where(fresh, m_read[j], self.last_m)
                m_read[j] = np.where(np.isfinite(self.last_m), self.last_m, m_read[j])
        tail = slice(P - n, P)
        at_command = np.abs(angles - self.servos.target[None]).max(axis=2) \
            <= self.config.settle_tolerance
        use = (finite & at_command)[tail]                                   # (n, B)
        settled = use.any(axis=0)
        measurement = np.empty((B, 6))
        o_true = np.full(B, np.nan)
        for i in range(B):
            rows = np.flatnonzero(use[:, i]) + P - n
            if not rows.size:
                last = np.flatnonzero(finite[:, i])
                rows = last[-1:]
            if rows.size:
                measurement[i, 0] = e_read[rows, i].mean()
                measurement[i, 1] = m_read[rows, i].mean()
                measurement[i, 2:] = np.median(angles[rows, i], axis=0)
                o_true[i] = e_true[rows, i].mean() / m_true[rows, i].mean()
            else:
                measurement[i] = [0.0, 1.0, *self.servos.target[i]]
        with np.errstate(divide='ignore', invalid='ignore'):
            reward = np.where(measurement[:, 1] > 0, measurement[:, 0] / measurement[:, 1],
                              0.0)
        o_star = np.full(B, np.nan)
        for i in range(B):
            envelope = self._envelopes[i]
            if envelope is not None:
                o_star[i] = np.interp(k_last[i], envelope['K'], envelope['O_star'])
        self.window.push(measurement, self._fresh)
        self._fresh[:] = False
        info = {'K': k_last.copy(), 'O_star': o_star, 'O_true': o_true,
                'round_trip': self.round_trip.copy(), 'settled': settled,
                'blown_up': ~finite.all(axis=0), 'family_seed': self._family_seed.copy(),
                'plant': self._plants.copy()}
        return PeriodResult(measurement, reward, info)

    def observation(self) -> np.ndarray:
        """(B, window * 6) float32: the window's measurements, oldest first, clipped into
        the observation's bounds (:class:`~dlmpc_ros.control.observation.MeasurementWindow`)."""
        return self.window.observation()


def observation_bounds(config: LaserEnvConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (window * 6,) of an observation."""
    return window_bounds(config.window, config.low, config.high)


def action_bounds(config: LaserEnvConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (4,) of an action."""
    if config.action == 'delta':
        return np.full(4, -config.max_step), np.full(4, config.max_step)
    return np.full(4, config.low), np.full(4, config.high)

