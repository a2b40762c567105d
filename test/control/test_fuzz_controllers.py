"""Property-based fuzzing of every controller without ROS.

A node hands a controller only states that pass ``interfaces.state_fault``: finite values
up to 1e300 in magnitude, odd ones included (E < 0, M <= 0, angles far outside the servo
range). Property: whatever such measurements and surrogates come, in any order, every
step returns finite angles inside the angle limits, and no step raises.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dlmpc_ros.control.factory import CONTROLLERS, make_baseline, make_controller
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.paths import models_dir
from test.strategies import finite_float

LIMITS = AngleLimits()
ANGLES = [-0.39, -0.25, 0.52, -0.14]
#: The steps of one example: laser-like measurements mixed with odd ones.
measurement = st.one_of(
    st.tuples(st.floats(0.5, 6.0), st.floats(5.0, 40.0),
              *(st.floats(-1.0, 1.0) for _ in range(4))).map(list),
    st.lists(finite_float(), min_size=6, max_size=6),
)
surrogate = st.one_of(st.none(), finite_float(), st.floats(-1.0, 1.0))
steps = st.lists(st.tuples(measurement, surrogate), min_size=1, max_size=25)

_built: dict[str, object] = {}


def _controller(name: str):
    """One controller per name for the whole module (its state carries over from one
    example to the next: more adversarial than a fresh one)."""
    if name not in _built:
        if name == 'passive':
            _built[name] = make_baseline('passive', models_dir(), LIMITS, angles=np.array(ANGLES))
        elif name == 'oracle':
            _built[name] = make_baseline('oracle', models_dir(), LIMITS)
        else:
            _built[name] = make_controller(name, models_dir(), LIMITS, initial_k=0.0)
    return _built[name]


@pytest.mark.parametrize('name', [*CONTROLLERS, 'dlmpc_ros.examples.hill_climber:make'])
@given(sequence=steps)
def test_every_step_commands_finite_angles_inside_the_limits(name, sequence):
    controller = _controller(name)
    for values, k_surrogate in sequence:
        step = controller.step(np.array(values, dtype=float), k_surrogate)
        angles = np.asarray(step.angles, dtype=float)
        assert angles.shape == (4,) and np.isfinite(angles).all(), (values, step)
        assert ((angles >= LIMITS.low - 1e-12) & (angles <= LIMITS.high + 1e-12)).all()
        assert np.isfinite(step.latency_ms) and step.iterations >= 0
