"""mpc_controller: the DL-MPC controller (MP-RNN planning, VAE surrogate + map inner loop,
a lock acquisition scan while the laser is off its pulse, curve tracking once locked, and
turns of the curve planned with the steady-response predictor).

Subscribes ``/laser/state`` and ``/estimator/birefringence``; once per decision (at least a
period apart, once the laser reports its last command reached: ``ros/controller_base.py``)
publishes ``/controller/measurement``, ``/laser/angles_cmd`` and ``/controller/status``.
It never reads the true K:
it has no subscription to ``/laser/birefringence`` or ``/laser/sim_truth``, and none of
the files it loads (``kmap.pt``, ``mprnn.pt``, ``track_curve.npz``, ``response.pt``,
``rotation_prior.npz``, ``turn_correction.npz``) holds the K of a run.
"""

from __future__ import annotations

import sys
from dataclasses import fields
from typing import TYPE_CHECKING

from rclpy.experimental import EventsExecutor

from dlmpc_ros.control.acquisition import AcquisitionConfig
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.factory import load_dlmpc
from dlmpc_ros.control.rotation_planner import PlannerConfig
from dlmpc_ros.control.tracking import MAX_STEP, MIN_STEP, TrackingConfig
from dlmpc_ros.learning.model_files import ModelFileError
from dlmpc_ros.paths import models_dir
from dlmpc_ros.ros import params
from dlmpc_ros.ros.controller_base import ControllerNodeBase

if TYPE_CHECKING:  # torch: imported once the node exists (see MPCControllerNode)
    from dlmpc_ros.control.dlmpc import DLMPCController

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
DESCRIPTIONS = {
    'strategy': f'one of {STRATEGIES}: dlmpc, the shipped controller (lock acquisition, '
                'curve tracking, planned turns, the VAE + map before the first lock); paper, '
                'the paper\'s DL-MPC alone (VAE + map inner loop, MP-RNN outer loop; the '
                'acquire, track and plan parameters are then ignored)',
    'min_iterations': 'MP-RNN outer loop (strategy paper, or track false): fewest '
                      'gradient-ascent iterations per plan',
    'max_iterations': 'MP-RNN outer loop: most gradient-ascent iterations per plan',
    'start_iterations': 'MP-RNN outer loop: iterations of the first plan',
    'learning_rate': 'MP-RNN outer loop: Adam step of the plan optimization [rad]',
    'error_threshold': 'MP-RNN outer loop: recent one-step prediction error (normalized) '
                       'above which the VAE + map inner loop takes over',
    'accurate_error': 'MP-RNN outer loop: prediction errors below this count as accurate '
                      '(more iterations)',
    'acquire': 'scan the map for mode-locking while the measured O says the laser is off '
               'its pulse',
    'lock_fraction': 'locked when O >= this x the mean O of the map training targets',
    'acquire_patience': 'unlocked control periods before the scan starts',
    'acquire_relock_patience': 'unlocked control periods before the scan starts once '
                               'the laser has been locked in this run',
    'acquire_dwell': 'control periods the scan waits at each point',
    'track': 'once locked, move onto the tracking curve (track_curve.npz) and follow K along '
             'it by extremum seeking on the measured O',
    'track_start': 'curve parameter where tracking starts after the inner loop (K units)',
    'track_dither': 'half-amplitude of the dither on the curve parameter (K units)',
    'track_block': 'control periods per dither half',
    'track_step': 'first change of the curve estimate per compared dither block (K units; '
                  'it adapts between 0.005 and 0.03)',
    'track_guard': 'right after an entry, hand back to the inner loop when O falls below '
                   'this x the O before tracking took over',
    'track_noise_deadband': 'the curve estimate moves only when the dither\'s O difference '
                            'passes this many standard deviations of the measurement noise '
                            'read off the run; 0: off',
    'track_entry_patience': 'locked control periods under the inner loop before tracking '
                            'takes over',
    'track_settle': 'control periods after entry before the guard judges O',
    'track_guard_periods': 'consecutive control periods under track_guard that hand back',
    'track_mirror_margin': 'how far past K = 0 the estimate must go before the tracker '
                           'turns to the mirror branch (K units)',
    'track_turn_guard': 'during a change of branch, O under this x the O before it turns '
                        'back',
    'track_trial_drop': 'relative fall of O under its best on this branch that makes the '
                        'tracker try the other branch (0: only the estimate decides)',
    'track_entry_trial_after': 'control periods after an entry before the other branch is '
                               'tried once',
    'track_entry_trial_below': 'the entry trial is made only if O is under this x the '
                               'curve\'s own O at the estimate (0: never)',
    'plan': 'while tracking, turn the curve where the steady-response predictor '
            '(response.pt) says O gains (the model-predictive step on this laser)',
    'plan_radius': 'trust radius: largest turn of the curve per plan [rad]',
    'plan_spread_penalty': 'weight of the predictor ensemble\'s spread against its mean gain',
    'plan_noise_gate': 'a turn must be predicted to gain this many standard deviations of '
                       'the measured noise of its own gain (0: off)',
    'plan_online': 'correct the predictor online from the run\'s own turns',
    'plan_explore': 'calibration runs: random turns within the trust radius instead of the '
                    'planned ones (record a bag for `dlmpc-train adapt`)',
}
RANGES: dict[str, tuple[float, float]] = {
    'min_iterations': (1, 10_000), 'max_iterations': (1, 10_000),
    'start_iterations': (1, 10_000), 'learning_rate': (1e-9, 10.0),
    'error_threshold': (1e-12, 1e6), 'accurate_error': (1e-12, 1e6),
    'lock_fraction': (1e-6, 0.999999),
    'acquire_patience': (1, 1_000_000), 'acquire_relock_patience': (1, 1_000_000),
    'acquire_dwell': (1, 1_000_000),
    'track_dither': (1e-9, 1.0), 'track_step': (MIN_STEP, MAX_STEP),
    'track_guard': (1e-6, 1.0), 'track_noise_deadband': (0.0, 10.0),
    'track_start': (-1.0, 1.0), 'track_block': (1, 10_000),
    'track_entry_patience': (1, 1_000_000), 'track_settle': (0, 1_000_000),
    'track_guard_periods': (1, 1_000_000), 'track_mirror_margin': (0.0, 1.0),
    'track_turn_guard': (1e-6, 1.0), 'track_trial_drop': (0.0, 0.999999),
    'track_entry_trial_after': (0, 1_000_000), 'track_entry_trial_below': (0.0, 100.0),
    'plan_radius': (1e-3, 1.0), 'plan_spread_penalty': (0.0, 100.0),
    'plan_noise_gate': (0.0, 100.0),
}


class MPCControllerNode(ControllerNodeBase):
    uses_estimator = True

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
            self.controller = load_dlmpc(models_dir(self.values['models_dir']), config)
        except (ModelFileError, FileNotFoundError) as err:
            raise params.StartupError(str(err)) from None
        self.controller.warm_up()
        self.start()

    def fresh_controller(self) -> DLMPCController:
        return self.controller.fresh()


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(MPCControllerNode, args, executor_factory=EventsExecutor))


if __name__ == '__main__':
    main()
