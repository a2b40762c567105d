"""Checks shared by the frozen settings dataclasses (``__post_init__``).

Each helper raises ValueError naming the class, the field and the value, so that a bad
setting stops its user with one line that says what to change. A field made by
:func:`setting` carries its meaning and range with it: :func:`in_range` checks every such
field, and a node declares it as a parameter with that description and range.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any


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


def setting(default: Any, description: str, low: float | None = None,
            high: float | None = None) -> Any:
    """A dataclass field that is a user's setting: its ``default``, what it means (the
    node parameter's description) and, for a number, its range ``[low, high]``."""
    span = None if low is None or high is None else (low, high)
    return dataclasses.field(default=default,
                             metadata={'description': description, 'range': span})


def in_range(owner: object) -> None:
    """Every :func:`setting` field of ``owner`` with a range holds a number in it (an
    integer where the default is one)."""
    for f in dataclasses.fields(owner):
        span = f.metadata.get('range')
        if span is None:
            continue
        value = getattr(owner, f.name)
        whole = isinstance(f.default, int) and not isinstance(f.default, bool)
        number = isinstance(value, numbers.Integral if whole else numbers.Real)
        if not (number and not isinstance(value, bool) and math.isfinite(value)
                and span[0] <= value <= span[1]):
            _fail(owner, f.name, f"{'an integer' if whole else 'a number'} in "
                                 f'[{span[0]:g}, {span[1]:g}]')


def described(kind: type) -> dict[str, tuple[str, tuple[float, float] | None]]:
    """Setting name -> (description, range or None) of the :func:`setting` fields of the
    dataclass ``kind``."""
    return {f.name: (f.metadata['description'], f.metadata['range'])
            for f in dataclasses.fields(kind) if 'description' in f.metadata}
