"""mpc_controller: the DL-MPC controller (a lock acquisition scan while the laser is off its
pulse, curve tracking once locked, turns of the curve planned with the steady-response
predictor, the angles held otherwise; ``strategy:=paper``: the VAE surrogate + map inner loop
and MP-RNN planning).

Subscribes ``/laser/state`` (and, with ``strategy:=paper`` or ``track:=false``, whose inner
loop reads the VAE's surrogate, ``/estimator/birefringence``); once per decision (at least
a period apart, once the laser reports its last command reached:
``ros/controller_base.py``) publishes ``/controller/measurement``, ``/laser/angles_cmd`` and
``/controller/status``. It never reads the true K:
it has no subscription to ``/laser/birefringence`` or ``/laser/sim_truth``, and none of
the files it loads (``kmap.pt``, ``mprnn.pt``, ``track_curve.npz``, ``response.pt``,
``rotation_prior.npz``, ``turn_correction.npz``) holds the K of a run.
"""

from __future__ import annotations

import sys
from dataclasses import fields
from typing import TYPE_CHECKING

from rclpy.experimental import EventsExecutor

from dlmpc_ros.control.dlmpc_config import (AcquisitionConfig, DLMPCConfig, PlannerConfig,
                                           TrackingConfig)
from dlmpc_ros.control.factory import load_dlmpc
from dlmpc_ros.core import checks
from dlmpc_ros.learning.model_files import ModelFileError
from dlmpc_ros.paths import models_dir
from dlmpc_ros.ros import params
from dlmpc_ros.ros.controller_base import ControllerNodeBase

if TYPE_CHECKING:  # torch: imported once the node exists (see MPCControllerNode)
    from dlmpc_ros.control.dlmpc import DLMPCController
    from dlmpc_ros.control.paper_loops import PaperDLMPC

#: The :class:`DLMPCConfig` fields that hold the other configs (not settings).
NESTED = frozenset({'limits', 'acquisition', 'tracking', 'planner'})


def _params(kind: type, prefix: str = '', renamed: dict[str, str] | None = None
            ) -> dict[str, str]:
    """Node parameter -> setting, for every setting of the config class ``kind``: the
    parameter is ``prefix + setting`` unless ``renamed`` names it."""
    renamed = renamed or {}
    return {renamed.get(f.name, prefix + f.name): f.name for f in fields(kind)
            if f.name not in NESTED}


def _defaults(kind: type, names: dict[str, str]) -> dict[str, object]:
    """Node parameter -> the default of its setting."""
    default = kind()
    return {param: getattr(default, name) for param, name in names.items()}


def _described(parts: tuple[tuple[type, dict[str, str]], ...]
               ) -> tuple[dict[str, str], dict[str, tuple[float, float]]]:
    """Node parameter -> its setting's description, and -> its range (numbers), for the
    config classes and their parameter names in ``parts``."""
    descriptions, ranges = {}, {}
    for kind, names in parts:
        settings = checks.described(kind)
        for param, name in names.items():
            descriptions[param], span = settings[name]
            if span is not None:
                ranges[param] = span
    return descriptions, ranges


def _config(kind: type, names: dict[str, str], values: dict, **nested: object) -> object:
    """``kind`` built from the node's parameter ``values``."""
    return kind(**{name: values[param] for param, name in names.items()}, **nested)


DLMPC_PARAMS = _params(DLMPCConfig)
ACQUISITION_PARAMS = _params(AcquisitionConfig, renamed={
    'patience': 'acquire_patience', 'relock_patience': 'acquire_relock_patience',
    'dwell_periods': 'acquire_dwell'})
TRACKING_PARAMS = _params(TrackingConfig, 'track_')
PLANNER_PARAMS = _params(PlannerConfig, 'plan_')
DEFAULTS = _defaults(DLMPCConfig, DLMPC_PARAMS)
#: ``dlmpc``: the shipped controller; ``paper``: the paper's loops alone.
STRATEGIES = ('dlmpc', 'paper')
#: Each part's switch, then its settings.
ACQUISITION_DEFAULTS = {'acquire': True, **_defaults(AcquisitionConfig, ACQUISITION_PARAMS)}
TRACKING_DEFAULTS = {'track': True, **_defaults(TrackingConfig, TRACKING_PARAMS)}
PLANNER_DEFAULTS = {'plan': True, **_defaults(PlannerConfig, PLANNER_PARAMS)}
#: Descriptions and ranges: every setting's beside it in its config class
#: (:func:`~dlmpc_ros.core.checks.setting`), then the node's own switches.
SETTING_DESCRIPTIONS, RANGES = _described((
    (DLMPCConfig, DLMPC_PARAMS), (AcquisitionConfig, ACQUISITION_PARAMS),
    (TrackingConfig, TRACKING_PARAMS), (PlannerConfig, PLANNER_PARAMS)))
DESCRIPTIONS = {
    **SETTING_DESCRIPTIONS,
    'strategy': f'one of {STRATEGIES}: dlmpc, the shipped controller (lock acquisition, '
                'curve tracking, planned turns, the angles held otherwise); paper, '
                'the paper\'s DL-MPC alone (VAE + map inner loop, MP-RNN outer loop; the '
                'acquire, track and plan parameters are then ignored)',
    'acquire': 'scan for mode-locking while the measured O says the laser is off its pulse',
    'track': 'once locked, move onto the tracking curve (track_curve.npz) and follow K along '
             'it by extremum seeking on the measured O',
    'plan': 'while tracking, turn the curve where the steady-response predictor '
            '(response.pt) says O gains (the model-predictive step on this laser)',
}


class MPCControllerNode(ControllerNodeBase):
    def __init__(self) -> None:
        super().__init__('mpc_controller',
                         {'strategy': 'dlmpc', **DEFAULTS, **ACQUISITION_DEFAULTS,
                          **TRACKING_DEFAULTS, **PLANNER_DEFAULTS}, DESCRIPTIONS, RANGES)
        v = self.values
        if v['strategy'] not in STRATEGIES:
            raise params.StartupError(f"strategy = {v['strategy']!r} is not one of "
                                      f'{STRATEGIES}')
        paper = v['strategy'] == 'paper'
        try:
            acquisition = (_config(AcquisitionConfig, ACQUISITION_PARAMS, v)
                           if v['acquire'] and not paper else None)
            tracking = (_config(TrackingConfig, TRACKING_PARAMS, v)
                        if v['track'] and not paper else None)
            planner = (_config(PlannerConfig, PLANNER_PARAMS, v)
                       if v['plan'] and not paper else None)
            config = _config(DLMPCConfig, DLMPC_PARAMS, v, limits=self.limits,
                             acquisition=acquisition, tracking=tracking, planner=planner)
        except (ValueError, TypeError) as err:
            raise params.StartupError(str(err)) from None
        # torch (about 1 s of CPU) loads after the node's DDS participant exists, so that
        # the other nodes discover it meanwhile; /laser/state is subscribed in start(),
        # once the controller can act, so the simulator still waits for it.
        import torch
        torch.set_num_threads(1)  # small models: threads only contend with the other nodes
        try:
            controller = load_dlmpc(models_dir(self.values['models_dir']), config)
        except (ModelFileError, FileNotFoundError) as err:
            raise params.StartupError(str(err)) from None
        if hasattr(controller, 'warm_up'):  # the paper's MP-RNN plans
            controller.warm_up()
        self.start(controller)

    def fresh_controller(self, controller: DLMPCController | PaperDLMPC
                         ) -> DLMPCController | PaperDLMPC:
        return controller.fresh()


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(MPCControllerNode, args, executor_factory=EventsExecutor))


if __name__ == '__main__':
    main()
