"""Angle arithmetic of the pi-periodic elements, and the settings checks (with a setting's
description and range)."""

import math

import numpy as np
import pytest

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import angle_distance, unwrap_table, wrap_angles


def test_wrap_angles_maps_into_the_half_open_range_and_keeps_the_element():
    alpha = np.array([-4.0, -math.pi / 2, 0.3, math.pi / 2, 7.0])
    wrapped = wrap_angles(alpha)
    assert (wrapped >= -math.pi / 2).all() and (wrapped < math.pi / 2).all()
    np.testing.assert_allclose(np.sin(2 * wrapped), np.sin(2 * alpha), atol=1e-12)
    assert wrapped[3] == pytest.approx(-math.pi / 2)


def test_angle_distance_is_modulo_pi_per_element():
    a = np.array([1.5, 0.0, 0.0, 0.0])
    assert angle_distance(a, -a) == pytest.approx(np.pi - 3.0)
    assert angle_distance(a, a + np.array([np.pi, -np.pi, 2 * np.pi, 0.0])) < 1e-12


def test_unwrap_table_makes_rows_continuous():
    smooth = np.linspace(-1.4, 1.4, 30)[:, None] * np.array([1.0, -1.0, 0.5, 2.0])
    shifted = smooth + np.pi * np.random.default_rng(0).integers(-2, 3, smooth.shape)
    table = unwrap_table(shifted)
    assert np.abs(np.diff(table, axis=0)).max() < 0.2
    np.testing.assert_allclose(wrap_angles(table - smooth), 0.0, atol=1e-12)


def test_checks_name_the_class_the_field_and_the_value():
    class Settings:
        count, rate, share = 0, -1.0, 1.5
    with pytest.raises(ValueError, match=r'Settings\.count must be an integer >= 1, got 0'):
        checks.counts(Settings(), 'count')
    with pytest.raises(ValueError, match=r'Settings\.rate must be a finite number > 0'):
        checks.positive(Settings(), 'rate')
    with pytest.raises(ValueError, match=r'Settings\.share must be in \(0, 1\]'):
        checks.fraction(Settings(), 'share')
    checks.non_negative(Settings(), 'count')
    Settings.rate = float('nan')
    with pytest.raises(ValueError, match='finite'):
        checks.finite(Settings(), 'rate')


def test_a_setting_carries_its_description_and_range_and_is_checked_against_it():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Settings:
        count: int = checks.setting(3, 'periods', 1, 10)
        rate: float = checks.setting(0.5, 'a rate [rad]', 0.0, 1.0)
        on: bool = checks.setting(True, 'a switch')

        def __post_init__(self) -> None:
            checks.in_range(self)

    assert checks.described(Settings) == {'count': ('periods', (1, 10)),
                                          'rate': ('a rate [rad]', (0.0, 1.0)),
                                          'on': ('a switch', None)}
    Settings(count=np.int64(10), rate=np.float32(0.0))     # numpy numbers, at the ends
    for bad, why in ((dict(count=11), r'count must be an integer in \[1, 10\]'),
                     (dict(count=2.0), 'count must be an integer'),
                     (dict(count=True), 'count must be an integer'),
                     (dict(rate=float('nan')), r'rate must be a number in \[0, 1\]')):
        with pytest.raises(ValueError, match=rf'Settings\.{why}'):
            Settings(**bad)
