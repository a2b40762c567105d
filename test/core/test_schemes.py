"""The integration schemes of the fiber pass: order of convergence against DOP853, the
fastest settings' accuracy, batches, and the setting's validation."""

from dataclasses import replace

import numpy as np
import pytest

from dlmpc_ros.core import kernels
from dlmpc_ros.core.cavity import Cavity, scheme_tables
from dlmpc_ros.core.config import CavityConfig, config_problems
from dlmpc_ros.core.reference import reference_round_trips
from dlmpc_ros.core.schemes import ORDER, SCHEMES
from test.core.test_cavity_accuracy import FIRST_TWO, REFERENCE

ROW = np.array(REFERENCE[0][0]), REFERENCE[0][1]
#: Step counts in each scheme's asymptotic range (coarser steps of the fourth-order
#: schemes converge faster than h^4 there, see docs/solver.md).
ORDER_STEPS = {'strang': (8, 16), 'yoshida4': (12, 24), 'suzuki4': (8, 16),
               'richardson4': (8, 16)}
#: The fewest steps of each fourth-order scheme that keep E and M within 1e-3 of DOP853
#: (docs/solver.md); the default scheme needs 30.
FEWEST = {'suzuki4': 4, 'richardson4': 6}


@pytest.fixture(scope='module')
def reference_fields():
    """DOP853 (rtol 1e-10) fields after round trip 1 of the spec's first row."""
    row = reference_round_trips(*ROW, 1, fields=True)[0]
    return row['u'], row['v']


def _field_error(scheme: str, steps: int, reference) -> float:
    cavity = Cavity(CavityConfig(scheme=scheme, steps_per_round_trip=steps), angles=ROW[0],
                    birefringence=ROW[1])
    cavity.run(1)
    u, v = (f[0] for f in cavity.fields())
    ru, rv = reference
    return float(np.sqrt(np.sum(np.abs(u - ru) ** 2 + np.abs(v - rv) ** 2)
                         / np.sum(np.abs(ru) ** 2 + np.abs(rv) ** 2)))


@pytest.mark.parametrize('scheme', SCHEMES)
def test_each_scheme_converges_at_its_order(scheme, reference_fields):
    coarse, fine = ORDER_STEPS[scheme]
    errors = [_field_error(scheme, steps, reference_fields) for steps in (coarse, fine)]
    slope = np.log(errors[0] / errors[1]) / np.log(fine / coarse)
    assert abs(slope - ORDER[scheme]) < 0.3, (errors, slope)


@pytest.mark.parametrize('scheme', sorted(FEWEST))
def test_the_fewest_steps_keep_the_spec_rows_within_1e_3(scheme):
    config = CavityConfig(scheme=scheme, steps_per_round_trip=FEWEST[scheme])
    angles = np.array([row[0] for row in REFERENCE])
    result = Cavity(config, batch=3, angles=angles,
                    birefringence=np.array([row[1] for row in REFERENCE])).run(3)
    expected = np.array([[*FIRST_TWO[i], REFERENCE[i][2]] for i in range(3)])  # (3, 3, 2)
    got = np.stack([result.E.T, result.M.T], axis=-1)
    np.testing.assert_allclose(got, expected, rtol=1e-3)


def test_a_locked_laser_s_steady_state_matches_fine_steps():
    def objective(scheme: str, steps: int) -> float:
        cavity = Cavity(CavityConfig(scheme=scheme, steps_per_round_trip=steps),
                        angles=ROW[0], birefringence=ROW[1])
        result = cavity.run(200)
        assert result.converged[-1, 0] and result.pulses[-1, 0] == 1
        return result.O[-1, 0]

    fine = objective('suzuki4', 16)  # within 1e-7 of 512 symmetric steps
    for scheme, steps in FEWEST.items():
        assert objective(scheme, steps) == pytest.approx(fine, rel=1e-3)


@pytest.mark.parametrize('scheme', ['suzuki4', 'richardson4'])
def test_batch_equals_loop_of_single_lasers(scheme):
    rng = np.random.default_rng(3)
    angles = rng.uniform(-1.5, 1.5, (4, 4))
    ks = rng.uniform(-0.3, 0.3, 4)
    config = CavityConfig(scheme=scheme, steps_per_round_trip=FEWEST[scheme])
    batch = Cavity(config, batch=4, angles=angles, birefringence=ks).run(4)  # parallel
    for b in range(4):
        single = Cavity(config, angles=angles[b], birefringence=ks[b]).run(4)
        np.testing.assert_allclose(batch.E[:, b], single.E[:, 0], rtol=1e-12)
        np.testing.assert_allclose(batch.M[:, b], single.M[:, 0], rtol=1e-12)


def test_the_scheme_is_validated_and_each_brings_its_own_steps():
    assert CavityConfig().scheme == 'richardson4' and CavityConfig().steps == 6
    assert replace(CavityConfig(), scheme='strang').steps == 32  # the data of old
    assert CavityConfig(scheme='strang', steps_per_round_trip=36).steps == 36
    assert CavityConfig().to_dict()['steps_per_round_trip'] == 6  # records say what ran
    with pytest.raises(ValueError, match='steps_per_round_trip'):
        CavityConfig(steps_per_round_trip=-1)
    for bad in ('rk45', '', 4, None, True):
        with pytest.raises(ValueError, match='scheme'):
            CavityConfig(scheme=bad)
        assert config_problems({'scheme': bad})
    assert not config_problems({'scheme': 'suzuki4'})
    assert CavityConfig(scheme='richardson4').order == 4


@pytest.mark.parametrize('points', [64, 33])
def test_the_schemes_kernel_with_one_symmetric_step_equals_the_default_kernel(points):
    """The fourth-order schemes' kernel (its own FFT calls, sin/cos and gain stages) run
    with the weights of the symmetric step computes what the default's kernel does."""
    config = CavityConfig(points=points, steps_per_round_trip=8)
    rng = np.random.default_rng(5)
    angles, ks = rng.uniform(-1.5, 1.5, (2, 4)), rng.uniform(-0.3, 0.3, 2)
    default = Cavity(config, batch=2, angles=angles, birefringence=ks)
    general = Cavity(config, batch=2, angles=angles, birefringence=ks)
    tables = scheme_tables(config)  # 'strang' as a composition of one step
    obs = np.empty((5, 2, kernels.N_OBSERVABLES))
    grid = general.grid
    kernels.run_scheme_serial(
        general._p, general._m, general._phi_prev, general._birefringence, general._transfer,
        5, config.steps_per_round_trip, *tables, config.fiber_length, config.cross_phase,
        config.four_wave, config.pump, config.saturation_energy, config.gain_bandwidth,
        config.loss, grid.k_grid, grid.mode_index, grid.dt, obs)
    expected = default.run(5)
    np.testing.assert_allclose(obs[..., 1], expected.E, rtol=1e-11)
    np.testing.assert_allclose(obs[..., 2], expected.M, rtol=1e-10)
