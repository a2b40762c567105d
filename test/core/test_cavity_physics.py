"""Physics and API properties of the batched simulator."""

import numpy as np
import pytest

from dlmpc_ros.core.cavity import Cavity, RoundTripResult
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.grid import Grid
from dlmpc_ros.core.observables import objective_terms
from dlmpc_ros.core.reference import reference_round_trips

GOOD = np.array([-0.39, -0.25, 0.52, -0.14])


def _transparent(cavity: Cavity) -> None:
    """Make the Jones elements the identity (no waveplates, no polarizer)."""
    cavity._transfer[:] = np.eye(2)


@pytest.mark.parametrize('scheme, rtol', [('strang', 1e-12), ('richardson4', 1e-6)])
def test_energy_conserved_without_gain_loss_and_jones(scheme, rtol):
    """Each symmetric step is unitary; the extrapolation's sum of two is not, and keeps
    the energy only to its order (5e-8 here)."""
    cfg = CavityConfig(pump=0.0, loss=0.0, gain_bandwidth=0.0, steps_per_round_trip=16,
                       scheme=scheme)
    cavity = Cavity(cfg, birefringence=0.2)
    _transparent(cavity)
    start = Grid.from_config(cfg).dt * np.sum(np.abs(np.stack(cavity.fields())) ** 2)
    energies = cavity.run(5).energy[:, 0]
    np.testing.assert_allclose(energies, start, rtol=rtol)


def test_lossless_split_step_matches_dop853_field_energy_and_shape():
    cfg = CavityConfig(pump=0.0, loss=0.0, gain_bandwidth=0.0)
    angles = np.array([0.1, 0.2, 0.3, 0.4])
    cavity = Cavity(cfg, angles=angles, birefringence=0.15)
    got = cavity.run(2)
    ref = reference_round_trips(angles, 0.15, 2, cfg)
    np.testing.assert_allclose(got.E[:, 0], [r['E'] for r in ref], rtol=1e-4)
    np.testing.assert_allclose(got.M[:, 0], [r['M'] for r in ref], rtol=1e-3)


def test_pi_periodicity_of_the_simulated_laser():
    base = Cavity(angles=GOOD, birefringence=0.05).run(4)
    for i in range(4):
        shifted = GOOD.copy()
        shifted[i] -= np.pi
        other = Cavity(angles=shifted, birefringence=0.05).run(4)
        np.testing.assert_allclose(other.E, base.E, rtol=1e-10)
        np.testing.assert_allclose(other.M, base.M, rtol=1e-10)


def test_batch_equals_loop_of_single_lasers():
    rng = np.random.default_rng(7)
    angles = rng.uniform(-1.5, 1.5, (6, 4))
    ks = rng.uniform(-0.3, 0.3, 6)
    batch = Cavity(batch=6, angles=angles, birefringence=ks).run(5)  # parallel kernel
    for b in range(6):
        single = Cavity(angles=angles[b], birefringence=ks[b]).run(5)
        np.testing.assert_allclose(batch.E[:, b], single.E[:, 0], rtol=1e-12)
        np.testing.assert_allclose(batch.M[:, b], single.M[:, 0], rtol=1e-12)


def test_warm_start_and_changes_between_round_trips():
    cavity = Cavity(angles=GOOD, birefringence=0.1)
    cavity.run(3)
    cavity.set_angles([0.3, -1.1, 0.7, 0.25])
    cavity.set_birefringence(-0.2)
    split = cavity.run(2)
    # The same history in one go, by a fresh cavity: warm start carries the field over.
    again = Cavity(angles=GOOD, birefringence=0.1)
    again.run(3)
    again.set_angles([0.3, -1.1, 0.7, 0.25])
    again.set_birefringence(-0.2)
    for _ in range(2):
        last = again.step()
    assert split.round_trip[-1, 0] == last.round_trip[0] == 5
    assert split.E[-1, 0] == pytest.approx(last.E[0], rel=1e-13)
    # ...and differs from a cold start at the new settings.
    cold = Cavity(angles=np.array([0.3, -1.1, 0.7, 0.25]), birefringence=-0.2).run(2)
    assert abs(cold.E[-1, 0] - split.E[-1, 0]) > 1e-3


def test_kernel_observables_match_the_numpy_definitions():
    cavity = Cavity(angles=GOOD, birefringence=0.1)
    result = cavity.step()
    u, v = cavity.fields()
    terms = objective_terms(u, v, cavity.grid.dt)
    for key in ('energy', 'E', 'M', 'O'):
        np.testing.assert_allclose(getattr(result, key), terms[key], rtol=1e-12)
    assert result.peak[0] == pytest.approx(np.max(np.abs(u) ** 2 + np.abs(v) ** 2), rel=1e-12)


def test_steady_state_detected_and_single_pulse_counted():
    cavity = Cavity(angles=GOOD, birefringence=0.1)
    result = cavity.run(60)
    assert result.converged[-1, 0]
    assert not result.converged[0, 0]
    assert result.pulses[-1, 0] == 1
    assert result.change[-1, 0] < 1e-6


def test_cw_like_state_counts_no_pulse_and_large_kurtosis():
    cavity = Cavity(birefringence=0.0)
    n = cavity.grid.points
    cavity.set_fields(np.full(n, 0.5 + 0j), np.zeros(n))
    _transparent(cavity)
    result = cavity.step()
    assert result.pulses[0] == 0
    assert result.M[0] > 200


def test_noise_initial_condition_is_seeded():
    a = Cavity(initial='noise', seed=3).run(2).E
    b = Cavity(initial='noise', seed=3).run(2).E
    c = Cavity(initial='noise', seed=4).run(2).E
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_blow_up_is_reported_not_returned_as_numbers():
    cavity = Cavity(batch=2, angles=GOOD, birefringence=0.1)
    u, v = cavity.fields()
    u[1, 3] = np.nan
    cavity.set_fields(u, v)
    result = cavity.step()
    assert result.finite.tolist() == [True, False]
    assert np.isfinite(result.E[0]) and np.isnan(result.E[1]) and np.isnan(result.O[1])
    assert result.pulses[1] == -1
    cavity.reset([1])
    assert cavity.step().finite.all()


def test_zero_field_has_zero_objective():
    cavity = Cavity()
    n = cavity.grid.points
    cavity.set_fields(np.zeros(n), np.zeros(n))
    result = cavity.step()
    assert result.O[0] == 0.0 and np.isfinite(result.M[0])


@pytest.mark.parametrize('settings, decays', [({'pump': 0.0}, True), ({'loss': 5.0}, True),
                                              ({'pump': 0.1}, False)])
def test_a_weak_laser_runs_on_and_below_threshold_decays_to_a_zero_objective(settings, decays):
    """Below threshold the field decays through underflow to zero: a real state, with the
    zero field's observables (O = 0), never an error (it was a ZeroDivisionError in the
    kernel's kurtosis once the spectrum's variance underflowed)."""
    # 8 steps: the decay to zero (loss, polarizer) needs no accurate pass; 4x cheaper
    cavity = Cavity(CavityConfig(**settings, steps_per_round_trip=8), batch=2,
                    birefringence=np.array([0.1, -0.2]))
    result = cavity.run(2500)
    assert result.finite.all() and np.isfinite(result.M).all() and (result.O[:10] > 0).all()
    assert ((result.O[-1] == 0.0) & (result.E[-1] == 0.0)).all() == decays


@pytest.mark.parametrize('kwargs, message', [
    ({'points': 8}, 'points must be >= 16'),
    ({'cross_phase': 0.5}, 'cross_phase \\+ four_wave must equal 1'),
    ({'saturation_energy': 0.0}, 'saturation_energy must be > 0'),
    ({'pump': float('nan')}, 'pump must be a finite number'),
])
def test_invalid_config_is_rejected_with_a_reason(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CavityConfig(**kwargs)


def test_bad_commands_are_rejected():
    cavity = Cavity(batch=2)
    with pytest.raises(ValueError, match='finite'):
        cavity.set_angles([0.0, np.inf, 0.0, 0.0])
    with pytest.raises(ValueError, match='do not fit'):
        cavity.set_angles(np.zeros((3, 4)))
    with pytest.raises(ValueError, match='finite'):
        cavity.set_birefringence(np.nan)


def test_result_rows_are_numbered_from_one():
    result = Cavity().run(3)
    assert isinstance(result, RoundTripResult)
    assert result.round_trip[:, 0].tolist() == [1, 2, 3]
