"""Hypothesis strategies and profiles shared by the property-based fuzz tests.

Profiles: ``ci`` (default; sized for ``make test``) and ``long`` (``make fuzz``, or
``DLMPC_FUZZ_PROFILE=long``): the same properties over many more examples.
"""

from __future__ import annotations

import math
import os

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

settings.register_profile('ci', max_examples=40, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile('long', max_examples=1000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get('DLMPC_FUZZ_PROFILE', 'ci'))

#: Values every numeric input is tried with, beside random ones.
EDGES = (0.0, -0.0, 1.0, -1.0, 5e-324, -5e-324, 1e-300, 1e300, -1e300, 1e308, -1e308,
         2.0 ** 53, -(2.0 ** 53), 1e9, -1e9)


def any_float() -> st.SearchStrategy[float]:
    """Any double: NaN, +/-inf, zero, subnormal, huge and ordinary values."""
    return st.one_of(st.sampled_from(EDGES + (math.nan, math.inf, -math.inf)),
                     st.floats(allow_nan=True, allow_infinity=True))


def finite_float(limit: float = 1e300) -> st.SearchStrategy[float]:
    """Finite doubles in [-limit, limit], edges included."""
    return st.one_of(st.sampled_from([e for e in EDGES if abs(e) <= limit]),
                     st.floats(-limit, limit, allow_nan=False, allow_infinity=False))


def any_int() -> st.SearchStrategy[int]:
    """Integers from the int64 extremes to small and negative ones."""
    return st.one_of(st.sampled_from([0, 1, -1, 2, 2 ** 31, -(2 ** 31), 2 ** 53, 2 ** 63 - 1,
                                      -(2 ** 63)]),
                     st.integers(-(2 ** 63), 2 ** 63 - 1), st.integers(-100, 10_000))
