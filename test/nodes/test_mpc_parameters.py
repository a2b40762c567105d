"""Every setting of the shipped DL-MPC is an ``mpc_controller`` node parameter, with a
description, a range where it is a number, and the config's own default (issue 32)."""

from __future__ import annotations

from dataclasses import fields

import pytest

from dlmpc_ros.control.dlmpc_config import (AcquisitionConfig, DLMPCConfig, PlannerConfig,
                                           TrackingConfig)
from dlmpc_ros.nodes import mpc_controller_node as node
from dlmpc_ros.ros import controller_params as base

#: Settings whose node parameter is not ``prefix + name``.
RENAMED = {(AcquisitionConfig, 'patience'): 'acquire_patience',
           (AcquisitionConfig, 'relock_patience'): 'acquire_relock_patience',
           (AcquisitionConfig, 'dwell_periods'): 'acquire_dwell'}
PREFIX = {DLMPCConfig: '', TrackingConfig: 'track_', AcquisitionConfig: '',
          PlannerConfig: 'plan_'}
NESTED = {'limits', 'acquisition', 'tracking', 'planner'}
SETTINGS = [(kind, f.name) for kind in PREFIX for f in fields(kind) if f.name not in NESTED]
DEFAULTS = {'strategy': 'dlmpc', **node.DEFAULTS, **node.ACQUISITION_DEFAULTS,
            **node.TRACKING_DEFAULTS, **node.PLANNER_DEFAULTS}


@pytest.mark.parametrize('kind,name', SETTINGS, ids=[f'{k.__name__}.{n}' for k, n in SETTINGS])
def test_each_setting_is_a_described_node_parameter_with_its_default(kind, name):
    param = RENAMED.get((kind, name), PREFIX[kind] + name)
    assert param in DEFAULTS, f'{kind.__name__}.{name} has no node parameter {param}'
    assert DEFAULTS[param] == getattr(kind(), name)
    assert node.DESCRIPTIONS.get(param), f'{param} has no description'
    if not isinstance(DEFAULTS[param], bool):
        assert param in node.RANGES, f'{param} has no range'


def test_servo_limits_are_the_base_class_parameters():
    for param in ('angle_low', 'angle_high', 'max_step'):
        assert param in base.COMMON_DEFAULTS and base.COMMON_DESCRIPTIONS.get(param)
        assert param in base.COMMON_RANGES
