"""Integration schemes of the fiber pass, all built on the symmetric split step S(h).

- ``strang``: N symmetric split steps of length h = Z / N; second order.
- Compositions (``yoshida4``, ``suzuki4``): each of the N steps is ``S(c_1 h) ... S(c_s h)``
  with weights summing to 1 (Yoshida 1990, Suzuki 1990); the linear half steps between
  sub-steps merge into one. A symmetric composition with these weights cancels the h^3
  local error of S and is fourth order. Some weights are negative (a step backwards in z,
  unavoidable beyond second order), which limits the step: below 4 (Suzuki) or 14
  (Yoshida) steps per round trip the error jumps on some states (docs/solver.md).
- Extrapolation (``richardson4``): each round trip's fiber pass is run with
  ``m_i N`` symmetric steps from the same field, and the fields are combined with
  coefficients that cancel the h^2 term of the symmetric step's even error expansion
  (Richardson): ``(4 S_{2N} - S_N) / 3``, fourth order, and every step goes forward.

In every scheme the sub-flows are exact except the saturable gain, integrated by RK4
(fourth order) within each linear step, so no scheme loses its order to the gain.
"""

from __future__ import annotations

_CBRT2 = 2.0 ** (1.0 / 3.0)
_SUZUKI = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))

#: Composition weights ``c_1 .. c_s`` of each composition scheme.
COMPOSITIONS: dict[str, tuple[float, ...]] = {
    'strang': (1.0,),
    'yoshida4': (1.0 / (2.0 - _CBRT2), -_CBRT2 / (2.0 - _CBRT2), 1.0 / (2.0 - _CBRT2)),
    'suzuki4': (_SUZUKI, _SUZUKI, 1.0 - 4.0 * _SUZUKI, _SUZUKI, _SUZUKI),
}
#: Extrapolation schemes: step multiples ``m_i`` and the coefficients of their fields.
EXTRAPOLATIONS: dict[str, tuple[tuple[int, ...], tuple[float, ...]]] = {
    'richardson4': ((1, 2), (-1.0 / 3.0, 4.0 / 3.0)),
}
#: Every scheme's name.
SCHEMES: tuple[str, ...] = (*COMPOSITIONS, *EXTRAPOLATIONS)
#: Order of convergence of each scheme in the step size.
ORDER: dict[str, int] = {'strang': 2, 'yoshida4': 4, 'suzuki4': 4, 'richardson4': 4}
#: Each scheme's steps per round trip when none are given: for the fourth-order schemes
#: the fewest that keep E and M within 1e-3 of DOP853 (``bench/bench_cavity.py``); for
#: ``strang`` the 32 of the models' data before 2026-12-05 (2.4e-4 on the spec rows).
DEFAULT_STEPS: dict[str, int] = {'strang': 32, 'yoshida4': 14, 'suzuki4': 4, 'richardson4': 6}
#: The scheme a cavity runs when none is given (docs/solver.md).
DEFAULT_SCHEME = 'richardson4'


def symmetric_steps(scheme: str, steps: int) -> int:
    """Symmetric split steps (Kerr steps, 4 FFTs of n points each) of one round trip."""
    if scheme in COMPOSITIONS:
        return steps * len(COMPOSITIONS[scheme])
    return steps * sum(EXTRAPOLATIONS[scheme][0])
