"""The simulator against the spec's DOP853 reference values and a fine-step solution."""

import numpy as np
import pytest

from dlmpc_ros.core.cavity import Cavity

# Spec reference rows: angles, K, (E, M) after round trip 3.
REFERENCE = [
    ((-0.39, -0.25, 0.52, -0.14), 0.10, (4.305911768, 28.354038744)),
    ((0.30, -1.10, 0.70, 0.25), -0.20, (3.143169159, 52.304968115)),
    ((1.24, -0.24, 0.28, -1.49), 0.00, (3.499729567, 33.238936485)),
]
# The spec's first-round-trip values of row 1, and those of rounds 1-2 of every row from
# the project's own DOP853 reference (dlmpc_ros.core.reference, rtol 1e-10), which
# reproduces all of the spec's published values to 1e-9.
FIRST_TWO = [
    ((5.709011437, 29.785585435), (5.294643555, 30.656822044)),
    ((3.854731601, 34.694910960), (3.104252614, 44.457121048)),
    ((1.852207676, 30.919471144), (3.030474768, 32.123409844)),
]


@pytest.mark.parametrize('row', range(3))
def test_first_three_round_trips_match_reference(row):
    angles, k, third = REFERENCE[row]
    cavity = Cavity(angles=np.array(angles), birefringence=k)
    result = cavity.run(3)
    expected = np.array([*FIRST_TWO[row], third])  # (3, 2): E, M per round trip
    got = np.stack([result.E[:, 0], result.M[:, 0]], axis=1)
    np.testing.assert_allclose(got, expected, rtol=1e-3)
    np.testing.assert_allclose(result.O[:, 0], got[:, 0] / got[:, 1], rtol=1e-12)


def test_reference_integrator_reproduces_spec_values():
    from dlmpc_ros.core.reference import reference_round_trips
    rows = reference_round_trips(np.array(REFERENCE[0][0]), REFERENCE[0][1], 1)
    assert rows[0]['E'] == pytest.approx(5.709011437, rel=1e-8)
    assert rows[0]['M'] == pytest.approx(29.785585435, rel=1e-8)
