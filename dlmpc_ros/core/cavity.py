"""The batched cavity simulator: many lasers, each with its own angles and birefringence.

The field state carries over between round trips (warm start); angles and K may change
between any two round trips. Fields are kept in the circular basis internally; use
:meth:`Cavity.fields` for the linear-basis envelopes ``u``, ``v``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from dlmpc_ros.core import kernels
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.grid import Grid
from dlmpc_ros.core.jones import FROM_CIRCULAR, TO_CIRCULAR, circular_transfer
from dlmpc_ros.core.schemes import COMPOSITIONS, EXTRAPOLATIONS

#: Initial conditions understood by :func:`initial_field`.
INITIAL_CONDITIONS = ('sech', 'noise')
#: Batches at least this large use the thread-parallel kernel.
PARALLEL_MIN_BATCH = 4


def initial_field(grid: Grid, kind: str = 'sech', batch: int = 1,
                  rng: np.random.Generator | None = None,
                  noise_amplitude: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Linear-basis initial envelopes ``(u, v)``, each (batch, n) complex.

    ``sech``: the spec's ``u = v = sech(t/2)``. ``noise``: independent complex white
    noise of RMS ``noise_amplitude`` per point and polarization (needs ``rng``).
    """
    n = grid.points
    if kind == 'sech':
        u = np.broadcast_to(1.0 / np.cosh(grid.t_grid / 2), (batch, n)).astype(np.complex128)
        return u, u.copy()
    if kind == 'noise':
        if rng is None:
            raise ValueError("initial condition 'noise' needs a random generator")
        scale = noise_amplitude / np.sqrt(2.0)
        u, v = (scale * (rng.standard_normal((batch, n)) + 1j * rng.standard_normal((batch, n)))
                for _ in range(2))
        return u, v
    raise ValueError(f'unknown initial condition {kind!r}; choose one of {INITIAL_CONDITIONS}')


@lru_cache(maxsize=16)
def scheme_tables(config: CavityConfig) -> tuple[np.ndarray, ...]:
    """What :func:`kernels.run_scheme_serial` takes for ``config.scheme``, computed once per
    configuration ('strang' runs its own kernel; here it is a composition of one step).

    Returns ``weights`` (s,) of the composition, ``multiples`` (L,) int and
    ``coefficients`` (L,) of the extrapolation levels, ``lengths`` (L, s + 2) of each
    level's linear steps and ``phases`` (L, s + 2, n) complex, their dispersion and loss
    factors (see :func:`kernels._one_laser_scheme`).
    """
    name = config.scheme
    if name in COMPOSITIONS:
        weights, multiples, coefficients = np.array(COMPOSITIONS[name]), (1,), (1.0,)
    else:
        weights = np.ones(1)
        multiples, coefficients = EXTRAPOLATIONS[name]
    multiples, coefficients = np.array(multiples, np.int64), np.array(coefficients)
    s = weights.shape[0]
    h = config.fiber_length / (multiples[:, None] * config.steps)  # (L, 1)
    between = 0.5 * (weights[:-1] + weights[1:])
    shares = np.concatenate([[0.5 * weights[0]], between,
                             [0.5 * (weights[-1] + weights[0]), 0.5 * weights[-1]]])
    lengths = h * shares  # (L, s + 2)
    k2 = Grid.from_config(config).k_grid ** 2
    phases = np.exp((-0.5j * config.dispersion * lengths[..., None]) * k2
                    - config.loss * lengths[..., None])
    assert lengths.shape == (multiples.shape[0], s + 2)
    return weights, multiples, coefficients, lengths, phases


@dataclass(frozen=True)
class RoundTripResult:
    """Observables of every laser after the Jones elements of one or more round trips.

    Arrays are (B,) for one round trip, or (R, B) from :meth:`Cavity.run`. Entries of
    lasers whose field is not finite are NaN; check ``finite`` before using a value.

    Attributes
    ----------
    round_trip
        Round-trip count of each row (1 after the first round trip).
    energy
        Integral of ``|u|^2 + |v|^2`` over the window.
    E
        ``sqrt(energy)``, the L2 norm of the field.
    M
        Pearson kurtosis of the magnitude spectrum ``|fft(phi)|``.
    O
        Objective ``E / M``.
    peak
        Peak power ``max |u|^2 + |v|^2``.
    change
        Relative L2 change of ``phi`` against the previous round trip.
    pulses
        Count of pulses: runs above half the peak power; 0 for CW-like fields.
    converged
        ``change < steady_tolerance``.
    finite
        False where the field has blown up (non-finite values).
    """

    round_trip: np.ndarray
    energy: np.ndarray
    E: np.ndarray
    M: np.ndarray
    O: np.ndarray  # noqa: E741  (the paper's name)
    peak: np.ndarray
    change: np.ndarray
    pulses: np.ndarray
    converged: np.ndarray
    finite: np.ndarray

    @classmethod
    def from_kernel(cls, first_round_trip: int, obs: np.ndarray,
                    tolerance: float) -> RoundTripResult:
        """Build from the kernel's (R, B, 7) array; rows are numbered from first_round_trip."""
        finite = np.isfinite(obs).all(axis=-1)
        if not finite.all():
            obs = np.where(finite[..., None], obs, np.nan)
        cols = {name: obs[..., i] for i, name in enumerate(kernels.OBSERVABLES)}
        rounds, batch = obs.shape[:2]
        rows = np.repeat(np.arange(first_round_trip, first_round_trip + rounds), batch)
        return cls(
            round_trip=rows.reshape(rounds, batch),
            energy=cols['energy'], E=cols['E'], M=cols['M'], O=cols['O'], peak=cols['peak'],
            change=cols['change'],
            pulses=np.where(finite, cols['pulses'], -1).astype(np.int64),
            converged=finite & (cols['change'] < tolerance),
            finite=finite,
        )

    def last(self) -> RoundTripResult:
        """The last round trip of a multi-round-trip result, as (B,) arrays."""
        if self.E.ndim == 1:
            return self
        return RoundTripResult(*(v[-1] for v in self.__dict__.values()))

    def laser(self, index: int) -> dict[str, float | int | bool]:
        """Plain-Python values of one laser (last round trip)."""
        last = self.last()
        return {k: v[index].item() for k, v in last.__dict__.items()}


class Cavity:
    """B independent NPR mode-locked fiber lasers simulated round trip by round trip.

    Parameters
    ----------
    config
        Physical and solver settings.
    batch
        Number of lasers B.
    angles
        (4,) or (B, 4) initial ``(alpha1, alpha2, alpha3, alpha_p)`` in radians.
    birefringence
        Scalar or (B,) initial K.
    initial
        ``'sech'`` or ``'noise'`` (see :func:`initial_field`).
    seed
        Seed of the noise initial condition.
    """

    def __init__(self, config: CavityConfig | None = None, batch: int = 1,
                 angles: np.ndarray | None = None, birefringence: np.ndarray | float = 0.0,
                 initial: str = 'sech', seed: int | None = None) -> None:
        if batch < 1:
            raise ValueError(f'batch must be >= 1, got {batch}')
        self.config = config or CavityConfig()
        self.grid = Grid.from_config(self.config)
        self.batch = batch
        self.initial = initial
        self._rng = np.random.default_rng(seed)
        self._angles = np.zeros((batch, 4))
        self._transfer = np.empty((batch, 2, 2), np.complex128)
        self._birefringence = np.zeros(batch)
        self._p = np.empty((batch, self.grid.points), np.complex128)
        self._m = np.empty_like(self._p)
        self._phi_prev = np.empty((batch, self.grid.points))
        self.round_trip = 0
        self.set_angles(np.zeros(4) if angles is None else angles)
        self.set_birefringence(birefringence)
        self.reset()

    # -- commands -------------------------------------------------------------------
    @property
    def angles(self) -> np.ndarray:
        """(B, 4) current angles in radians (a copy)."""
        return self._angles.copy()

    @property
    def birefringence(self) -> np.ndarray:
        """(B,) current K (a copy)."""
        return self._birefringence.copy()

    def set_angles(self, angles: np.ndarray, index: np.ndarray | slice | None = None) -> None:
        """Set (4,) or (B, 4) angles [rad] for all lasers or the lasers in ``index``."""
        sel = slice(None) if index is None else index
        angles = np.asarray(angles, dtype=float)
        target_shape = self._angles[sel].shape
        try:
            angles = np.broadcast_to(angles, target_shape)
        except ValueError:
            raise ValueError(f'angles of shape {angles.shape} do not fit {target_shape}') from None
        if not np.isfinite(angles).all():
            raise ValueError('angles must be finite')
        self._angles[sel] = angles
        self._transfer[sel] = circular_transfer(self._angles[sel])

    def set_birefringence(self, birefringence: np.ndarray | float,
                          index: np.ndarray | slice | None = None) -> None:
        """Set scalar or (B,) K for all lasers or the lasers in ``index``."""
        sel = slice(None) if index is None else index
        value = np.asarray(birefringence, dtype=float)
        if not np.isfinite(value).all():
            raise ValueError('birefringence must be finite')
        try:
            self._birefringence[sel] = value
        except ValueError:
            raise ValueError(f'birefringence of shape {value.shape} does not fit '
                             f'{self._birefringence[sel].shape}') from None

    def reset(self, index: np.ndarray | slice | None = None) -> None:
        """Put the lasers (all, or those in ``index``) back to the initial field."""
        sel = slice(None) if index is None else index
        count = self._p[sel].shape[0]
        u, v = initial_field(self.grid, self.initial, count, self._rng)
        self._set_linear_fields(u, v, sel)

    def set_fields(self, u: np.ndarray, v: np.ndarray,
                   index: np.ndarray | slice | None = None) -> None:
        """Set the linear-basis envelopes, (B, n) or (n,) complex each."""
        sel = slice(None) if index is None else index
        shape = self._p[sel].shape
        u = np.broadcast_to(np.asarray(u, np.complex128), shape)
        v = np.broadcast_to(np.asarray(v, np.complex128), shape)
        self._set_linear_fields(u, v, sel)

    def _set_linear_fields(self, u: np.ndarray, v: np.ndarray, sel) -> None:
        self._p[sel] = TO_CIRCULAR[0, 0] * u + TO_CIRCULAR[0, 1] * v
        self._m[sel] = TO_CIRCULAR[1, 0] * u + TO_CIRCULAR[1, 1] * v
        self._phi_prev[sel] = np.sqrt(np.abs(u) ** 2 + np.abs(v) ** 2)

    # -- simulation -------------------------------------------------------------------
    def fields(self) -> tuple[np.ndarray, np.ndarray]:
        """Linear-basis envelopes ``(u, v)`` after the Jones elements, (B, n) each."""
        u = FROM_CIRCULAR[0, 0] * self._p + FROM_CIRCULAR[0, 1] * self._m
        v = FROM_CIRCULAR[1, 0] * self._p + FROM_CIRCULAR[1, 1] * self._m
        return u, v

    def run(self, round_trips: int = 1) -> RoundTripResult:
        """Advance every laser by ``round_trips``; returns (round_trips, B) observables."""
        if round_trips < 1:
            raise ValueError(f'round_trips must be >= 1, got {round_trips}')
        cfg, grid = self.config, self.grid
        obs = np.empty((round_trips, self.batch, kernels.N_OBSERVABLES))
        parallel = self.batch >= PARALLEL_MIN_BATCH
        # floats always (a setting given as an int would compile the kernels once more)
        common = (*map(float, (cfg.cross_phase, cfg.four_wave, cfg.pump, cfg.saturation_energy,
                               cfg.gain_bandwidth, cfg.loss)),
                  grid.k_grid, grid.mode_index, grid.dt, obs)
        state = (self._p, self._m, self._phi_prev, self._birefringence, self._transfer,
                 round_trips, cfg.steps)
        if cfg.scheme == 'strang':  # its own kernel: the default's numbers stay bit for bit
            kernel = kernels.run_batch_parallel if parallel else kernels.run_batch_serial
            kernel(*state, float(cfg.fiber_length), float(cfg.dispersion), *common)
        else:
            kernel = kernels.run_scheme_parallel if parallel else kernels.run_scheme_serial
            kernel(*state, *scheme_tables(cfg), float(cfg.fiber_length), *common)
        result = RoundTripResult.from_kernel(self.round_trip + 1, obs, cfg.steady_tolerance)
        self.round_trip += round_trips
        return result

    def step(self) -> RoundTripResult:
        """Advance every laser by one round trip; returns (B,) observables."""
        return self.run(1).last()


def compile_kernels() -> None:
    """Compile the serial and the thread-parallel kernels (the symmetric split step's and
    the compositions') into numba's on-disk cache (one short run of each), so that no
    later process pays the compile time (about 20 s each)."""
    for scheme in ('strang', 'richardson4'):
        for batch in (1, PARALLEL_MIN_BATCH):
            Cavity(CavityConfig(scheme=scheme), batch=batch).run(1)
