"""Compiled kernels of the cavity solver (numba, with numpy.fft through rocket-fft).

One fiber pass is a symmetric (Strang) split step in the circular polarization basis
``p = (u + i v)/sqrt(2)``, ``m = (u - i v)/sqrt(2)``; both sub-flows are solved exactly:

- Kerr step (time domain): with ``A + B = 1`` the model's nonlinearity conserves
  ``|p|`` and ``|m|`` pointwise and only rotates phases,
  ``p *= exp(i h (A |p|^2 + (1 + B) |m|^2))`` and the same with p and m swapped.
- Linear step (Fourier domain): dispersion, loss and birefringence (``-i K sigma_x`` in
  this basis) are exact exponentials; the saturable gain multiplies mode ``k`` by
  ``exp((1 - tau k^2) G)`` with ``G(h) = integral of g dz``. Because ``g`` depends on
  the energy at the current z, G obeys the scalar ODE
  ``G' = 2 g0 / (1 + E(G, z) / E0)`` with
  ``E(G, z) = exp(-2 Gamma z) sum_k w_k exp(2 (1 - tau k^2) G)``,
  which is integrated with classical RK4 (the gain is not frozen over a step, so the
  whole scheme keeps second order).

``exp(-c k^2)`` over the grid is evaluated by the recurrence ``q^{(a+1)^2} = q^{a^2} q^{2a+1}``
on the integer mode index ``a``, and ``exp(i theta)`` by a vectorizable polynomial; both
save most of the time that libm calls would take.

The other schemes of :mod:`dlmpc_ros.core.schemes` (compositions of this step and its
Richardson extrapolation) run in :func:`run_scheme_serial` / :func:`run_scheme_parallel`,
built from faster pieces that round differently (in-place FFTs, a branch-free sin/cos, a
linear step without gathers); the default keeps its own kernel, so that its numbers stay
bit for bit those the shipped models were trained on.

Observables, per laser and round trip, are written in the order of :data:`OBSERVABLES`.
"""

from __future__ import annotations

import math

import numpy as np
import rocket_fft  # noqa: F401  (registers numpy.fft for numba)
from numba import njit, prange
from rocket_fft import lowlevel

#: Columns of the observable array written by the kernels.
OBSERVABLES = ('energy', 'E', 'M', 'O', 'peak', 'change', 'pulses')
N_OBSERVABLES = len(OBSERVABLES)

# numba fast-math flags that keep NaN and inf semantics (blow-ups must stay detectable).
# Not 'nsz': with 'nsz' and 'reassoc' together, the code a process compiles itself and
# the code it later loads from numba's cache round differently (measured with numba
# 0.68.1), so the first process on a machine computed other round trips than the rest.
_FAST = {'arcp', 'contract', 'reassoc', 'afn'}

_TWO_OVER_PI = 0.6366197723675814
_PIO2_HI = 1.57079632673412561417e+00
_PIO2_LO = 6.07710050650619224932e-11
# Minimax coefficients of sin and cos on [-pi/4, pi/4] (fdlibm's kernels).
_S1, _S2 = -1.66666666666666324348e-01, 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2 = 4.16666666666666019037e-02, -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4, _C5 = -2.75573143513906633035e-07, 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11


@njit(inline='always', fastmath=_FAST)
def cos_sin(theta: float) -> tuple[float, float]:
    """(cos(theta), sin(theta)) to about 1 ulp for |theta| < 1e5, branch-free."""
    quadrant = math.floor(theta * _TWO_OVER_PI + 0.5)
    r = (theta - quadrant * _PIO2_HI) - quadrant * _PIO2_LO
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    q = int(quadrant) & 3
    cos_out = c if q == 0 else (-s if q == 1 else (-c if q == 2 else s))
    sin_out = s if q == 0 else (c if q == 1 else (-s if q == 2 else -c))
    return cos_out, sin_out


@njit(inline='always', fastmath=_FAST)
def cos_sin_vectorizable(theta: float) -> tuple[float, float]:
    """:func:`cos_sin` without branches or integers (the quadrant turns the reduced pair
    by a multiple of pi/2 with factors 0 and +-1), so that loops over it vectorize: about
    3x faster in the Kerr step. Equal to 1 ulp, not bit for bit (the symmetric split
    step's kernel keeps :func:`cos_sin` so that its results stay what they were)."""
    quadrant = math.floor(theta * _TWO_OVER_PI + 0.5)
    r = (theta - quadrant * _PIO2_HI) - quadrant * _PIO2_LO
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    q = quadrant - 4.0 * math.floor(0.25 * quadrant)  # 0, 1, 2 or 3
    cos_q = 1.0 - min(q, 4.0 - q)  # cos(q pi / 2): 1, 0, -1, 0
    sin_q = 1.0 - abs(q - 1.0)  # sin(q pi / 2): 0, 1, 0, -1
    return c * cos_q - s * sin_q, s * cos_q + c * sin_q


@njit(inline='always', fastmath=_FAST)
def _square_exponent_table(q: float, out: np.ndarray) -> None:
    """out[a] = q ** (a * a) for a = 0 .. len(out) - 1 (q > 0; above 1 for a step
    backwards in z, in the compositions of :mod:`dlmpc_ros.core.schemes`)."""
    r = 1.0
    f = q
    q2 = q * q
    for a in range(out.shape[0]):
        out[a] = r
        r *= f
        f *= q2
        if r < 1e-290:  # avoid slow subnormals; the rest of the table is zero
            for b in range(a + 1, out.shape[0]):
                out[b] = 0.0
            break


@njit(inline='always', fastmath=_FAST)
def _gain_rate(g_int: float, z: float, weight: np.ndarray, table: np.ndarray,
               pump: float, sat_energy: float, tau_kappa2: float, loss: float) -> float:
    """g = dG/dz at integrated gain G = g_int, distance z into the linear step."""
    _square_exponent_table(math.exp(-2.0 * tau_kappa2 * g_int), table)
    acc = 0.0
    for a in range(weight.shape[0]):
        acc += weight[a] * table[a]
    energy = math.exp(2.0 * g_int - 2.0 * loss * z) * acc
    return 2.0 * pump / (1.0 + energy / sat_energy)


@njit(inline='always', fastmath=_FAST)
def _linear_step(big_p, big_m, h, phase, cos_k, sin_k, mode_index, weight, table,
                 norm, pump, sat_energy, tau_kappa2, loss) -> None:
    """Exact linear flow over length h in Fourier space, in place.

    phase: (n,) complex ``exp(-i D k^2 h / 2 - Gamma h)``; cos_k, sin_k: of ``K h``.
    """
    weight[:] = 0.0
    for j in range(big_p.shape[0]):
        pj, mj = big_p[j], big_m[j]
        weight[mode_index[j]] += norm * (pj.real * pj.real + pj.imag * pj.imag
                                         + mj.real * mj.real + mj.imag * mj.imag)
    k1 = _gain_rate(0.0, 0.0, weight, table, pump, sat_energy, tau_kappa2, loss)
    k2 = _gain_rate(0.5 * h * k1, 0.5 * h, weight, table, pump, sat_energy, tau_kappa2, loss)
    k3 = _gain_rate(0.5 * h * k2, 0.5 * h, weight, table, pump, sat_energy, tau_kappa2, loss)
    k4 = _gain_rate(h * k3, h, weight, table, pump, sat_energy, tau_kappa2, loss)
    g_int = h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    _square_exponent_table(math.exp(-tau_kappa2 * g_int), table)
    scale = math.exp(g_int)
    for j in range(big_p.shape[0]):
        f = phase[j] * (scale * table[mode_index[j]])
        pj, mj = big_p[j], big_m[j]
        big_p[j] = f * (cos_k * pj - 1j * sin_k * mj)
        big_m[j] = f * (cos_k * mj - 1j * sin_k * pj)


@njit(inline='always', fastmath=_FAST)
def _kerr_step(p, m, h, cross, four) -> None:
    """Exact Kerr flow over length h in the time domain, in place."""
    for j in range(p.shape[0]):
        pp = p[j].real * p[j].real + p[j].imag * p[j].imag
        mm = m[j].real * m[j].real + m[j].imag * m[j].imag
        c1, s1 = cos_sin(h * (cross * pp + (1.0 + four) * mm))
        c2, s2 = cos_sin(h * (cross * mm + (1.0 + four) * pp))
        p[j] = p[j] * complex(c1, s1)
        m[j] = m[j] * complex(c2, s2)


@njit(inline='always', fastmath=_FAST)
def _gain_rate_fast(g_int: float, z: float, weight: np.ndarray, pump: float,
                    sat_energy: float, tau_kappa2: float, loss: float) -> float:
    """:func:`_gain_rate` without a table: ``sum_a weight[a] q^(a^2)`` in one pass of four
    interleaved recurrences (a = 4b + i: ratio ``q^(8a + 16)``), so the multiplications
    do not wait on each other."""
    q = math.exp(-2.0 * tau_kappa2 * g_int)
    q2 = q * q
    q4 = q2 * q2
    q8 = q4 * q4
    q16 = q8 * q8
    q32 = q16 * q16
    r0, r1, r2, r3 = 1.0, q, q4, q8 * q
    f0, f1, f2, f3 = q16, q16 * q8, q32, q32 * q8
    acc0 = acc1 = acc2 = acc3 = 0.0
    size = weight.shape[0]
    full = size // 4
    for b in range(full):
        a = 4 * b
        acc0 += weight[a] * r0
        acc1 += weight[a + 1] * r1
        acc2 += weight[a + 2] * r2
        acc3 += weight[a + 3] * r3
        r0 *= f0
        r1 *= f1
        r2 *= f2
        r3 *= f3
        f0 *= q32
        f1 *= q32
        f2 *= q32
        f3 *= q32
    rest = size - 4 * full  # the last modes, r0 .. r2 hold their q^(a^2)
    if rest > 0:
        acc0 += weight[4 * full] * r0
    if rest > 1:
        acc1 += weight[4 * full + 1] * r1
    if rest > 2:
        acc2 += weight[4 * full + 2] * r2
    energy = math.exp(2.0 * g_int - 2.0 * loss * z) * ((acc0 + acc1) + (acc2 + acc3))
    return 2.0 * pump / (1.0 + energy / sat_energy)


@njit(inline='always', fastmath=_FAST)
def _linear_step_fast(big_p, big_m, h, phase, cos_k, sin_k, weight, table, norm, pump,
                      sat_energy, tau_kappa2, loss) -> None:
    """:func:`_linear_step` for modes in numpy ``fftfreq`` order (mode j and n - j share
    the index |a|, no gathers), with the first RK4 stage from the energy itself (at G = 0
    every mode's factor is 1) and the others from :func:`_gain_rate_fast`: the same
    result to rounding."""
    n = big_p.shape[0]
    half = n // 2
    for a in range(half + 1):
        pj, mj = big_p[a], big_m[a]
        weight[a] = norm * (pj.real * pj.real + pj.imag * pj.imag + mj.real * mj.real
                            + mj.imag * mj.imag)
    for a in range(1, n - half):
        pj, mj = big_p[n - a], big_m[n - a]
        weight[a] += norm * (pj.real * pj.real + pj.imag * pj.imag + mj.real * mj.real
                             + mj.imag * mj.imag)
    energy = 0.0
    for a in range(half + 1):
        energy += weight[a]
    k1 = 2.0 * pump / (1.0 + energy / sat_energy)
    k2 = _gain_rate_fast(0.5 * h * k1, 0.5 * h, weight, pump, sat_energy, tau_kappa2, loss)
    k3 = _gain_rate_fast(0.5 * h * k2, 0.5 * h, weight, pump, sat_energy, tau_kappa2, loss)
    k4 = _gain_rate_fast(h * k3, h, weight, pump, sat_energy, tau_kappa2, loss)
    g_int = h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    _square_exponent_table(math.exp(-tau_kappa2 * g_int), table)
    scale = math.exp(g_int)
    for a in range(half + 1):
        table[a] *= scale
    for j in range(half + 1):
        f = phase[j] * table[j]
        pj, mj = big_p[j], big_m[j]
        big_p[j] = f * (cos_k * pj - 1j * sin_k * mj)
        big_m[j] = f * (cos_k * mj - 1j * sin_k * pj)
    for j in range(half + 1, n):
        f = phase[j] * table[n - j]
        pj, mj = big_p[j], big_m[j]
        big_p[j] = f * (cos_k * pj - 1j * sin_k * mj)
        big_m[j] = f * (cos_k * mj - 1j * sin_k * pj)


@njit(inline='always', fastmath=_FAST)
def _kerr_step_fast(p, m, h, cross, four) -> None:
    """:func:`_kerr_step` with :func:`cos_sin_vectorizable`."""
    for j in range(p.shape[0]):
        pp = p[j].real * p[j].real + p[j].imag * p[j].imag
        mm = m[j].real * m[j].real + m[j].imag * m[j].imag
        c1, s1 = cos_sin_vectorizable(h * (cross * pp + (1.0 + four) * mm))
        c2, s2 = cos_sin_vectorizable(h * (cross * mm + (1.0 + four) * pp))
        p[j] = p[j] * complex(c1, s1)
        m[j] = m[j] * complex(c2, s2)


@njit(inline='always', fastmath=_FAST)
def _observe(p, m, phi_prev, dt, out) -> None:
    """Observables after the Jones elements; updates phi_prev to this round trip's phi."""
    n = p.shape[0]
    phi = np.empty(n)
    energy = 0.0
    peak = 0.0
    diff2 = 0.0
    for j in range(n):
        power = p[j].real * p[j].real + p[j].imag * p[j].imag \
            + m[j].real * m[j].real + m[j].imag * m[j].imag
        phi[j] = math.sqrt(power)
        energy += power
        peak = max(peak, power)
        d = phi[j] - phi_prev[j]
        diff2 += d * d
    energy *= dt
    spectrum = np.abs(np.fft.fft(phi.astype(np.complex128)))
    mean = spectrum.mean()
    m2 = 0.0
    m4 = 0.0
    for j in range(n):
        d = spectrum[j] - mean
        d2 = d * d
        m2 += d2
        m4 += d2 * d2
    m2 /= n
    m4 /= n
    if m2 * m2 > 0.0:
        kurtosis = m4 / (m2 * m2)
    else:  # a zero (or decayed, underflowing) field: the flat-spectrum limit, M's largest
        kurtosis = n - 2.0 + 1.0 / (n - 1.0)
    amplitude = math.sqrt(energy)
    norm2 = energy / dt
    # Pulses: runs of power above half the peak on the periodic grid; a field that is
    # above half its peak on most of the window is CW-like and counts as 0 pulses.
    runs = 0
    above = 0
    half = 0.5 * peak
    for j in range(n):
        now = phi[j] * phi[j] > half
        if now:
            above += 1
            if not (phi[j - 1] * phi[j - 1] > half):  # j - 1 = -1 wraps around
                runs += 1
    if above * 2 > n or peak == 0.0:
        runs = 0
    out[0] = energy
    out[1] = amplitude
    out[2] = kurtosis
    out[3] = amplitude / kurtosis
    out[4] = peak
    out[5] = math.sqrt(diff2 / norm2) if norm2 > 0.0 else 0.0
    out[6] = runs
    phi_prev[:] = phi


@njit(nogil=True, fastmath=_FAST, cache=True)
def _one_laser(p, m, phi_prev, birefringence, transfer, round_trips, steps, fiber_length,
               dispersion, cross, four, pump, sat_energy, gain_bandwidth, loss, k_grid,
               mode_index, dt, out) -> None:
    """Run ``round_trips`` round trips of one laser in place; out: (round_trips, 7)."""
    n = p.shape[0]
    h = fiber_length / steps
    kappa = k_grid[1] if n > 1 else 0.0
    tau_kappa2 = gain_bandwidth * kappa * kappa
    norm = dt / n
    phase_full = np.exp((-0.5j * dispersion * h) * k_grid * k_grid - loss * h)
    phase_half = np.exp((-0.25j * dispersion * h) * k_grid * k_grid - 0.5 * loss * h)
    cos_full, sin_full = math.cos(birefringence * h), math.sin(birefringence * h)
    cos_half, sin_half = math.cos(0.5 * birefringence * h), math.sin(0.5 * birefringence * h)
    weight = np.zeros(n // 2 + 1)
    table = np.empty(n // 2 + 1)
    t00, t01, t10, t11 = transfer[0, 0], transfer[0, 1], transfer[1, 0], transfer[1, 1]
    for r in range(round_trips):
        big_p = np.fft.fft(p)
        big_m = np.fft.fft(m)
        _linear_step(big_p, big_m, 0.5 * h, phase_half, cos_half, sin_half, mode_index,
                     weight, table, norm, pump, sat_energy, tau_kappa2, loss)
        for step in range(steps):
            p = np.fft.ifft(big_p)
            m = np.fft.ifft(big_m)
            _kerr_step(p, m, h, cross, four)
            big_p = np.fft.fft(p)
            big_m = np.fft.fft(m)
            if step < steps - 1:
                _linear_step(big_p, big_m, h, phase_full, cos_full, sin_full, mode_index,
                             weight, table, norm, pump, sat_energy, tau_kappa2, loss)
            else:
                _linear_step(big_p, big_m, 0.5 * h, phase_half, cos_half, sin_half,
                             mode_index, weight, table, norm, pump, sat_energy, tau_kappa2,
                             loss)
        p = np.fft.ifft(big_p)
        m = np.fft.ifft(big_m)
        for j in range(n):
            pj, mj = p[j], m[j]
            p[j] = t00 * pj + t01 * mj
            m[j] = t10 * pj + t11 * mj
        _observe(p, m, phi_prev, dt, out[r])
    return p, m


@njit(nogil=True, fastmath=_FAST, cache=True)
def _advance_laser(b, p, m, phi_prev, birefringence, transfer, round_trips, steps,
                   fiber_length, dispersion, cross, four, pump, sat_energy, gain_bandwidth,
                   loss, k_grid, mode_index, dt, out) -> None:
    """Advance laser b of a batch; p, m, phi_prev: (B, n); out: (round_trips, B, 7)."""
    obs = np.empty((round_trips, N_OBSERVABLES))
    pb, mb = _one_laser(p[b].copy(), m[b].copy(), phi_prev[b], birefringence[b], transfer[b],
                        round_trips, steps, fiber_length, dispersion, cross, four, pump,
                        sat_energy, gain_bandwidth, loss, k_grid, mode_index, dt, obs)
    p[b] = pb
    m[b] = mb
    out[:, b, :] = obs


# The two batch drivers are separate functions (not one function compiled twice) because
# numba's on-disk cache is keyed by the Python function: a shared one would hand the
# serial build to the parallel dispatcher.
@njit(nogil=True, cache=True)
def run_batch_serial(p, m, phi_prev, birefringence, transfer, round_trips, steps,
                     fiber_length, dispersion, cross, four, pump, sat_energy, gain_bandwidth,
                     loss, k_grid, mode_index, dt, out) -> None:
    """Advance every laser of a batch, one after the other (few lasers)."""
    for b in range(p.shape[0]):
        _advance_laser(b, p, m, phi_prev, birefringence, transfer, round_trips, steps,
                       fiber_length, dispersion, cross, four, pump, sat_energy, gain_bandwidth,
                       loss, k_grid, mode_index, dt, out)


@njit(nogil=True, cache=True, parallel=True)
def run_batch_parallel(p, m, phi_prev, birefringence, transfer, round_trips, steps,
                       fiber_length, dispersion, cross, four, pump, sat_energy,
                       gain_bandwidth, loss, k_grid, mode_index, dt, out) -> None:
    """Advance every laser of a batch, one laser per thread task."""
    for b in prange(p.shape[0]):
        _advance_laser(b, p, m, phi_prev, birefringence, transfer, round_trips, steps,
                       fiber_length, dispersion, cross, four, pump, sat_energy, gain_bandwidth,
                       loss, k_grid, mode_index, dt, out)


# The schemes other than the default symmetric split step (dlmpc_ros.core.schemes) run in
# one kernel built from the fast pieces above (in-place FFTs, the vectorizable Kerr step),
# which round differently; the default keeps its own kernel above, bit for bit.
@njit(nogil=True, fastmath=_FAST, cache=True)
def _one_laser_scheme(p, m, phi_prev, birefringence, transfer, round_trips, steps, weights,
                      multiples, coefficients, lengths, phases, fiber_length, cross, four,
                      pump, sat_energy, gain_bandwidth, loss, k_grid, mode_index, dt, out):
    """Run ``round_trips`` round trips of one laser; out: (round_trips, 7); returns the
    fields (p and m are overwritten).

    Fiber pass: for each level i, ``multiples[i] * steps`` steps from the same field, each
    step of length h the composition ``S(w_1 h) ... S(w_s h)`` of symmetric split steps
    (``weights``; adjacent linear half steps merged); the levels' fields are summed with
    ``coefficients`` (extrapolation). A composition has one level with coefficient 1, an
    extrapolation the weights (1,). ``lengths`` (levels, s + 2): the linear steps of a
    level (0 the first half step, 1 .. s-1 between sub-steps, s between two steps, s + 1
    the last half step); ``phases`` (levels, s + 2, n): their dispersion and loss factors
    ``exp(-i D k^2 l / 2 - Gamma l)`` (:func:`dlmpc_ros.core.cavity.scheme_tables`).
    """
    n = p.shape[0]
    s = weights.shape[0]
    levels = multiples.shape[0]
    kappa = k_grid[1] if n > 1 else 0.0
    tau_kappa2 = gain_bandwidth * kappa * kappa
    norm = dt / n
    inv_n = 1.0 / n
    cos_l = np.empty((levels, s + 2))
    sin_l = np.empty((levels, s + 2))
    for level in range(levels):
        for i in range(s + 2):
            cos_l[level, i] = math.cos(birefringence * lengths[level, i])
            sin_l[level, i] = math.sin(birefringence * lengths[level, i])
    weight = np.zeros(n // 2 + 1)
    table = np.empty(n // 2 + 1)
    axes = np.zeros(1, np.int64)
    start_p = np.empty(n, np.complex128)
    start_m = np.empty(n, np.complex128)
    big_p = np.empty(n, np.complex128)
    big_m = np.empty(n, np.complex128)
    sum_p = np.empty(n, np.complex128)
    sum_m = np.empty(n, np.complex128)
    t00, t01, t10, t11 = transfer[0, 0], transfer[0, 1], transfer[1, 0], transfer[1, 1]
    for r in range(round_trips):
        lowlevel.c2c(p, start_p, axes, True, 1.0, 1)
        lowlevel.c2c(m, start_m, axes, True, 1.0, 1)
        for level in range(levels):
            big_p[:] = start_p
            big_m[:] = start_m
            count = multiples[level] * steps
            h = fiber_length / count
            _linear_step_fast(big_p, big_m, lengths[level, 0], phases[level, 0],
                              cos_l[level, 0], sin_l[level, 0], weight, table, norm, pump,
                              sat_energy, tau_kappa2, loss)
            for step in range(count):
                for sub in range(s):
                    lowlevel.c2c(big_p, p, axes, False, inv_n, 1)
                    lowlevel.c2c(big_m, m, axes, False, inv_n, 1)
                    _kerr_step_fast(p, m, weights[sub] * h, cross, four)
                    lowlevel.c2c(p, big_p, axes, True, 1.0, 1)
                    lowlevel.c2c(m, big_m, axes, True, 1.0, 1)
                    i = sub + 1 if sub < s - 1 else (s if step < count - 1 else s + 1)
                    _linear_step_fast(big_p, big_m, lengths[level, i], phases[level, i],
                                      cos_l[level, i], sin_l[level, i], weight, table, norm,
                                      pump, sat_energy, tau_kappa2, loss)
            c = coefficients[level]
            if level == 0:
                for j in range(n):
                    sum_p[j] = c * big_p[j]
                    sum_m[j] = c * big_m[j]
            else:
                for j in range(n):
                    sum_p[j] += c * big_p[j]
                    sum_m[j] += c * big_m[j]
        lowlevel.c2c(sum_p, p, axes, False, inv_n, 1)
        lowlevel.c2c(sum_m, m, axes, False, inv_n, 1)
        for j in range(n):
            pj, mj = p[j], m[j]
            p[j] = t00 * pj + t01 * mj
            m[j] = t10 * pj + t11 * mj
        _observe(p, m, phi_prev, dt, out[r])
    return p, m


@njit(nogil=True, fastmath=_FAST, cache=True)
def _advance_laser_scheme(b, p, m, phi_prev, birefringence, transfer, round_trips, steps,
                          weights, multiples, coefficients, lengths, phases, fiber_length,
                          cross, four, pump, sat_energy, gain_bandwidth, loss, k_grid,
                          mode_index, dt, out) -> None:
    """:func:`_advance_laser` with :func:`_one_laser_scheme`."""
    obs = np.empty((round_trips, N_OBSERVABLES))
    pb, mb = _one_laser_scheme(p[b].copy(), m[b].copy(), phi_prev[b], birefringence[b],
                               transfer[b], round_trips, steps, weights, multiples,
                               coefficients, lengths, phases, fiber_length, cross, four,
                               pump, sat_energy, gain_bandwidth, loss, k_grid, mode_index,
                               dt, obs)
    p[b] = pb
    m[b] = mb
    out[:, b, :] = obs


@njit(nogil=True, cache=True)
def run_scheme_serial(p, m, phi_prev, birefringence, transfer, round_trips, steps, weights,
                      multiples, coefficients, lengths, phases, fiber_length, cross, four,
                      pump, sat_energy, gain_bandwidth, loss, k_grid, mode_index, dt,
                      out) -> None:
    """:func:`run_batch_serial` for any scheme (:func:`_one_laser_scheme`)."""
    for b in range(p.shape[0]):
        _advance_laser_scheme(b, p, m, phi_prev, birefringence, transfer, round_trips, steps,
                              weights, multiples, coefficients, lengths, phases,
                              fiber_length, cross, four, pump, sat_energy, gain_bandwidth,
                              loss, k_grid, mode_index, dt, out)


@njit(nogil=True, cache=True, parallel=True)
def run_scheme_parallel(p, m, phi_prev, birefringence, transfer, round_trips, steps, weights,
                        multiples, coefficients, lengths, phases, fiber_length, cross, four,
                        pump, sat_energy, gain_bandwidth, loss, k_grid, mode_index, dt,
                        out) -> None:
    """:func:`run_batch_parallel` for any scheme (:func:`_one_laser_scheme`)."""
    for b in prange(p.shape[0]):
        _advance_laser_scheme(b, p, m, phi_prev, birefringence, transfer, round_trips, steps,
                              weights, multiples, coefficients, lengths, phases,
                              fiber_length, cross, four, pump, sat_energy, gain_bandwidth,
                              loss, k_grid, mode_index, dt, out)
