"""Controllers by spec: a registered name or ``package.module:factory``.

A factory is any callable ``factory(models_dir: Path, limits: AngleLimits, **settings)``
that returns a controller (:class:`~dlmpc_ros.control.step.Controller`: a ``name`` and
``step(measurement, surrogate) -> ControlStep``). Names are entry points of the group
:data:`GROUP` (the built-in controllers register there in setup.py, as any installed
package can). A harness offers a few settings (:data:`OFFERED`); a factory gets those
its signature names, and no others. Every failure (a spec that does not import, a
factory that raises, an object that is not a controller) is a one-line
:class:`ControllerSpecError`.
"""

from __future__ import annotations

import importlib
import inspect
import re
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

from dlmpc_ros.control.step import AngleLimits, Controller

#: The entry-point group under which packages register controller factories by name.
GROUP = 'dlmpc_ros.controllers'
#: Settings a harness may offer, each passed only to a factory that names it:
#: ``initial_k`` (the true K of round trip 1: what the ``passive`` baseline was tuned
#: for; evaluation only, a fair controller never names it), ``angles`` (the angles the
#: ``passive`` baseline holds), ``dlmpc_config`` and ``ga_config`` (the DL-MPC's and the
#: genetic algorithm's settings).
OFFERED = ('initial_k', 'angles', 'dlmpc_config', 'ga_config')


class ControllerSpecError(ValueError):
    """A controller spec that cannot be resolved or built (one line: which and why)."""


def _line(err: BaseException) -> str:
    text = ' '.join(str(err).split())
    return f'{type(err).__name__}: {text}' if text else type(err).__name__


def registered() -> dict[str, str]:
    """Registered controller names -> ``module:factory`` (every installed package's)."""
    found: dict[str, str] = {}
    for point in metadata.entry_points(group=GROUP):
        if found.get(point.name, point.value) != point.value:
            raise ControllerSpecError(
                f'controller {point.name!r} is registered twice ({found[point.name]} and '
                f'{point.value}) in entry-point group {GROUP}; uninstall one')
        found[point.name] = point.value
    return dict(sorted(found.items()))


def resolve(spec: str) -> Callable[..., Controller]:
    """The factory of ``spec`` (a registered name or ``package.module:factory``),
    imported here; :class:`ControllerSpecError` if it cannot be."""
    if not isinstance(spec, str) or not spec.strip():
        raise ControllerSpecError(f'controller spec must be a name or package.module:factory, '
                                  f'got {spec!r}')
    target = spec.strip()
    if ':' not in target:
        names = registered()
        if target not in names:
            raise ControllerSpecError(
                f'unknown controller {target!r}: registered are {", ".join(names) or "none"} '
                f'(entry-point group {GROUP}); or give package.module:factory')
        target = names[target]
    module_name, _, attribute = target.partition(':')
    try:
        obj = importlib.import_module(module_name.strip())
    except Exception as err:  # noqa: BLE001 (any import error is the user's module's)
        raise ControllerSpecError(f'controller {spec!r}: cannot import {module_name!r} '
                                  f'({_line(err)})') from None
    for part in attribute.strip().split('.'):
        if not part or not hasattr(obj, part):
            raise ControllerSpecError(f'controller {spec!r}: {module_name!r} has no '
                                      f'{attribute!r}')
        obj = getattr(obj, part)
    if not callable(obj):
        raise ControllerSpecError(f'controller {spec!r}: {target} is a '
                                  f'{type(obj).__name__}, not a factory')
    return obj


def build(spec: str, models_dir: Path, limits: AngleLimits | None = None,
          **offered: object) -> Controller:
    """The controller of ``spec``: its factory called with ``models_dir``, ``limits``
    and those ``offered`` settings (not None) that the factory names."""
    if not set(offered) <= set(OFFERED):
        unknown = sorted(set(offered) - set(OFFERED))
        raise TypeError(f'a harness offers only {OFFERED}, not {unknown}')
    factory = resolve(spec)
    limits = limits or AngleLimits()
    settings = {k: v for k, v in offered.items() if v is not None and k in _named(factory)}
    try:
        controller = factory(Path(models_dir), limits, **settings)
    except Exception as err:  # noqa: BLE001 (whatever the factory raises, said in one line)
        raise ControllerSpecError(f'controller {spec!r}: its factory raised '
                                  f'{_line(err)}') from None
    if not isinstance(getattr(controller, 'name', None), str) or not callable(
            getattr(controller, 'step', None)):
        raise ControllerSpecError(
            f'controller {spec!r}: its factory returned {type(controller).__name__!r}, not a '
            'controller (one needs a str name and a step(measurement, surrogate) method '
            'returning a ControlStep)')
    return controller


def _named(factory: Callable) -> set[str]:
    """The keyword settings a factory's signature names (beyond the two positional)."""
    try:
        parameters = list(inspect.signature(factory).parameters.values())
    except (TypeError, ValueError):
        return set()
    return {p.name for p in parameters[2:]
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def label(spec: str) -> str:
    """``spec`` as a file name: a registered name as it is, ``package.module:factory``
    with every character but letters, digits, ``.``, ``_`` and ``-`` as ``-``."""
    return re.sub(r'[^A-Za-z0-9._-]', '-', spec.strip())
