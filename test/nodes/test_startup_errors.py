"""Nodes that cannot start say why once, and exit 2, without a traceback.

Every case runs the node as its own process with settings it cannot run with: bad
parameters (wrong values, wrong types, a bad scenario), a missing model directory, a
corrupt model file (garbage bytes), a truncated checkpoint or a model of the wrong kind
(temp copies of models/). The cases run a few at a time, all started by one fixture.
"""

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test.domains import next_domain

ROOT = Path(__file__).resolve().parents[2]
LASER = 'dlmpc_ros.nodes.laser_sim_node'
DRIFT = 'dlmpc_ros.nodes.drift_injector_node'
ESTIMATOR = 'dlmpc_ros.nodes.vae_estimator_node'
MPC = 'dlmpc_ros.nodes.mpc_controller_node'
BASELINE = 'dlmpc_ros.nodes.baseline_controller_node'
RECORDER = 'dlmpc_ros.nodes.recorder_node'
AT_ONCE = 3

#: id -> (node module, ROS arguments, texts the one message must hold). ``{models}`` is a
#: copy of models/ with the damage the id names.
CASES = {
    # laser_sim (points and initial: test_laser_sim_node.py)
    'laser-negative-lockstep-period': (LASER, ['-p', 'lockstep_period:=-10'],
                                       ['lockstep_period = -10 is outside its range [0, ']),
    # values the simulator once accepted and then died on (pump 1e308 blew the field up
    # every round trip; a tiny rate or a huge timeout overflowed the waits)
    'laser-huge-pump': (LASER, ['-p', 'pump:=1e308'],
                        ['pump = 1e+308 is outside its range [0, 100]']),
    'laser-tiny-rate': (LASER, ['-p', 'round_trips_per_second:=1e-10'],
                        ['round_trips_per_second must be 0 (free-run) or >= 0.001']),
    'laser-huge-timeout': (LASER, ['-p', 'lockstep_timeout:=1e300'],
                           ['lockstep_timeout = 1e+300 is outside its range']),
    'laser-initial-angles': (LASER, ['-p', 'initial_angles:=[0.1,0.2]'],
                             ['initial_angles must be 4 finite numbers']),
    'laser-wrong-type': (LASER, ['-p', 'pump:=2'], ["parameter 'pump'", "expecting type "
                                                    "'DOUBLE'"]),
    'laser-unknown-argument': (LASER, ['--bogus'], ['unknown ROS arguments', '--params-file']),
    'laser-bad-params-file': (LASER, ['--params-file', '{tmp}/bad.yaml'],
                              ['fix the command-line parameters or the parameter file',
                               'bad.yaml']),
    # drift_injector
    'drift-unknown-scenario': (DRIFT, ['-p', 'scenario:=teleport'],
                               ["unknown drift scenario 'teleport'; choose one of"]),
    'drift-out-of-range': (DRIFT, ['-p', 'scenario:=steps', '-p', 'values:=[0.9]'],
                           ['outside the model range']),
    'drift-negative-period': (DRIFT, ['-p', 'period:=-100.0'],
                              ['sinusoidal: period must be >= 1 round trip']),
    'drift-publish-every': (DRIFT, ['-p', 'publish_every:=0'],
                            ['publish_every = 0 is outside its range']),
    'drift-huge-sigma': (DRIFT, ['-p', 'scenario:=random_walk', '-p', 'sigma:=1e300'],
                         ['random_walk: sigma must be in [0, 0.6]']),
    # vae_estimator
    'estimator-models-dir-type': (ESTIMATOR, ['-p', 'models_dir:=2.5'],
                                  ["parameter 'models_dir'", "expecting type 'STRING'"]),
    'estimator-no-models': (ESTIMATOR, ['-p', 'models_dir:={tmp}/nowhere'],
                            ['vae_encoder.npz is missing', 'dlmpc-train vae']),
    'estimator-corrupt': (ESTIMATOR, ['-p', 'models_dir:={models}'],
                          ['vae_encoder.npz cannot be read', 'dlmpc-train vae']),
    'estimator-truncated': (ESTIMATOR, ['-p', 'models_dir:={models}'],
                            ['vae_encoder.npz cannot be read', 'dlmpc-train vae']),
    'estimator-wrong-kind': (ESTIMATOR, ['-p', 'models_dir:={models}'],
                             ['vae_encoder.npz is malformed', 'dlmpc-train vae']),
    # mpc_controller
    'mpc-negative-period': (MPC, ['-p', 'period:=-1'],
                            ['period = -1 is outside its range [1, 1e+06]', '[round trips]']),
    'mpc-angle-limits': (MPC, ['-p', 'angle_low:=1.0', '-p', 'angle_high:=0.5'],
                         ['angle limits must be finite with low < high']),
    'mpc-max-step': (MPC, ['-p', 'max_step:=-1.0'],
                     ['max_step = -1.0 is outside its range', '[rad]']),
    'mpc-iterations': (MPC, ['-p', 'min_iterations:=5', '-p', 'max_iterations:=2'],
                       ['min_iterations <= start_iterations <= max_iterations']),
    'mpc-lock-fraction': (MPC, ['-p', 'lock_fraction:=1.5'],
                          ['lock_fraction = 1.5 is outside its range [1e-06, 0.999999]']),
    'mpc-strategy': (MPC, ['-p', 'strategy:=fastest'],
                     ["strategy = 'fastest' is not one of ('dlmpc', 'paper')"]),
    'mpc-track-guard': (MPC, ['-p', 'track_guard:=0.0'],
                        ['track_guard = 0.0 is outside its range [1e-06, 1]']),
    'mpc-no-curve': (MPC, ['-p', 'models_dir:={models}'], ['track_curve.npz is missing',
                                                           'dlmpc-train curve']),
    'mpc-no-models': (MPC, ['-p', 'models_dir:=/nonexistent'], ['is missing', 'dlmpc-train']),
    'mpc-corrupt': (MPC, ['-p', 'models_dir:={models}'], ['kmap.pt is corrupt',
                                                          'dlmpc-train kmap']),
    # the paper's loops read the MP-RNN (the default strategy does not load it)
    'mpc-truncated': (MPC, ['-p', 'models_dir:={models}', '-p', 'strategy:=paper'],
                      ['mprnn.pt is corrupt', 'dlmpc-train mprnn']),
    # a loadable kmap.pt whose metrics are a list: an AttributeError traceback once
    'mpc-kmap-metrics': (MPC, ['-p', 'models_dir:={models}'], ['kmap.pt has malformed metrics',
                                                               'dlmpc-train kmap']),
    # recorder: a timer of 1e300 s overflowed (and left a 43-byte .mcap behind)
    'recorder-huge-period': (RECORDER, ['-p', 'output:={tmp}/bag-huge', '-p',
                                        'discovery_period:=1e300'],
                             ['discovery_period = 1e+300 is outside its range']),
    # baseline_controller (esc needs no model file)
    'baseline-unknown-controller': (BASELINE, ['-p', 'controller:=teleport'],
                                    ["unknown controller 'teleport'", 'registered are']),
    # plug-in controllers (docs/controllers.md); a factory that raises: baseline-no-models
    'baseline-plugin-import': (BASELINE, ['-p', 'controller:=test.control.nowhere:make'],
                               ["controller 'test.control.nowhere:make': cannot import"]),
    'baseline-plugin-not-a-controller': (
        BASELINE, ['-p', 'controller:=test.control.plugin_examples:not_a_controller'],
        ["its factory returned 'str', not a controller"]),
    'baseline-zero-period': (BASELINE, ['-p', 'controller:=esc', '-p', 'period:=0'],
                             ['period = 0 is outside its range [1, 1e+06]']),
    'baseline-angle-limits': (BASELINE, ['-p', 'controller:=esc', '-p', 'angle_low:=2.0',
                                         '-p', 'angle_high:=-2.0'],
                              ['angle limits must be finite with low < high']),
    'baseline-no-models': (BASELINE, ['-p', 'controller:=fixed_best', '-p',
                                      'models_dir:={tmp}/nowhere'],
                           ['oracle.npz are missing', 'dlmpc-train baselines']),
    'baseline-corrupt': (BASELINE, ['-p', 'controller:=oracle', '-p', 'models_dir:={models}'],
                         ['oracle.npz cannot be read', 'dlmpc-train baselines']),
}


def _damaged_models(case: str, tmp: Path) -> Path:
    """A copy of models/ with one file spoiled as the case's name says."""
    models = tmp / f'models-{case}'
    shutil.copytree(ROOT / 'models', models, ignore=shutil.ignore_patterns('figures'))
    if case == 'estimator-corrupt':
        (models / 'vae_encoder.npz').write_bytes(os.urandom(4096))
    elif case == 'estimator-truncated':
        data = (models / 'vae_encoder.npz').read_bytes()
        (models / 'vae_encoder.npz').write_bytes(data[:len(data) // 2])
    elif case == 'estimator-wrong-kind':
        shutil.copy(models / 'track_curve.npz', models / 'vae_encoder.npz')
    elif case == 'mpc-corrupt':
        (models / 'kmap.pt').write_bytes(b'\x00garbage' * 512)
    elif case == 'mpc-no-curve':
        (models / 'track_curve.npz').unlink()
    elif case == 'baseline-corrupt':
        (models / 'oracle.npz').write_bytes(os.urandom(2048))
    elif case == 'mpc-truncated':
        data = (models / 'mprnn.pt').read_bytes()
        (models / 'mprnn.pt').write_bytes(data[:1000])
    elif case == 'mpc-kmap-metrics':
        import torch
        payload = torch.load(models / 'kmap.pt', weights_only=True)
        payload['metrics'] = [1.0, 2.0]
        torch.save(payload, models / 'kmap.pt')
    return models


@pytest.fixture(scope='module')
def outcomes(tmp_path_factory) -> dict[str, tuple[int, str]]:
    """Run every case, AT_ONCE at a time: id -> (exit code, output)."""
    tmp = tmp_path_factory.mktemp('startup')
    (tmp / 'bad.yaml').write_text('laser_sim: {ros__parameters: {pump: [\n')
    env = {**os.environ, 'ROS_DOMAIN_ID': str(next_domain()),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(tmp / 'ros-log')}
    pending = list(CASES)
    running: dict[str, tuple[subprocess.Popen, float]] = {}
    results = {}
    while pending or running:
        while pending and len(running) < AT_ONCE:
            case = pending.pop(0)
            module, args, _ = CASES[case]
            models = _damaged_models(case, tmp) if '{models}' in ' '.join(args) else None
            args = [a.format(tmp=tmp, models=models) for a in args]
            log = open(tmp / f'{case}.log', 'wb')
            proc = subprocess.Popen([sys.executable, '-m', module, '--ros-args', *args],
                                    env=env, stdout=log, stderr=subprocess.STDOUT)
            log.close()
            running[case] = (proc, time.monotonic())
        for case, (proc, started) in list(running.items()):
            if proc.poll() is None and time.monotonic() - started > 90:
                proc.kill()  # it started after all: the case fails below
                proc.wait()
            if proc.poll() is not None:
                results[case] = (proc.returncode, (tmp / f'{case}.log').read_text())
                del running[case]
        time.sleep(0.05)
    return results


@pytest.mark.parametrize('case', list(CASES))
def test_node_refuses_to_start_with_one_clear_message(outcomes, case):
    code, output = outcomes[case]
    assert code == 2, output
    assert 'Traceback' not in output, output
    lines = [line for line in output.splitlines() if 'cannot start' in line]
    assert len(lines) == 1, output
    for text in CASES[case][2]:
        assert text in lines[0], output
