"""Checks shared by the frozen settings dataclasses (``__post_init__``).

Each helper raises ValueError naming the class, the field and the value, so that a bad
setting stops its user with one line that says what to change.
"""

from __future__ import annotations

import math


def _fail(owner: object, name: str, wanted: str) -> None:
    raise ValueError(f'{type(owner).__name__}.{name} must be {wanted}, '
                     f'got {getattr(owner, name)!r}')


def _real(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


def finite(owner: object, *names: str) -> None:
    """Every field in ``names`` is a finite number."""
    for name in names:
        if not _real(getattr(owner, name)):
            _fail(owner, name, 'a finite number')


def counts(owner: object, *names: str, minimum: int = 1) -> None:
    """Every field in ``names`` is an integer >= ``minimum``."""
    for name in names:
        value = getattr(owner, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            _fail(owner, name, f'an integer >= {minimum}')


def positive(owner: object, *names: str) -> None:
    """Every field in ``names`` is a finite number > 0."""
    for name in names:
        value = getattr(owner, name)
        if not (_real(value) and value > 0):
            _fail(owner, name, 'a finite number > 0')


def non_negative(owner: object, *names: str) -> None:
    """Every field in ``names`` is a finite number >= 0."""
    for name in names:
        value = getattr(owner, name)
        if not (_real(value) and value >= 0):
            _fail(owner, name, 'a finite number >= 0')


def fraction(owner: object, *names: str, closed: bool = True) -> None:
    """Every field in ``names`` lies in (0, 1] (``closed``) or in (0, 1)."""
    for name in names:
        value = getattr(owner, name)
        if not (_real(value) and 0 < value and (value <= 1 if closed else value < 1)):
            _fail(owner, name, 'in (0, 1]' if closed else 'in (0, 1)')
