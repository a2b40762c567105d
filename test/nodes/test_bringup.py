"""The whole graph through the bringup, as separate processes."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from dlmpc_ros.control.step import MODES
from dlmpc_ros.core.drift import make_scenario


def test_bringup_runs_the_graph_and_records_every_round_trip(ros_env, tmp_path):
    """... with a plugged-in controller (the example of docs/controllers.md) in the
    baseline_controller node."""
    out = tmp_path / 'run.csv'
    domain = ros_env['ROS_DOMAIN_ID']
    # 250 round trips a second: the K message's lag (tens of ms on a machine busy with
    # another test) stays within the median of 20 round trips checked below
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller',
         'dlmpc_ros.examples.hill_climber:make', '--round-trips', '400', '--rate', '250',
         '--scenario', 'sinusoidal', '--scenario-param', 'period=200',
         '--scenario-param', 'amplitude=0.25',
         '--domain-id', domain, '--csv', str(out), '--plot', str(tmp_path / 'run.png'),
         '--log-dir', str(tmp_path / 'logs')],
        env=ros_env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert 'graph connected' in proc.stdout
    with open(out) as handle:
        rows = list(csv.DictReader(handle))
    assert [int(float(r['round_trip'])) for r in rows] == list(range(1, 401))
    k = np.array([float(r['K']) for r in rows])
    rt = np.array([float(r['round_trip']) for r in rows])
    known = np.isfinite(k)
    assert known.all()
    # Every recorded K is the K the laser ran that round trip with: the scenario's K of that
    # round trip, or of a recent one (the K message travels while the laser goes on).
    scenario = make_scenario('sinusoidal', period=200.0, amplitude=0.25)
    lags = np.arange(0, 200)
    lag = [lags[np.abs(scenario(np.maximum(r - lags, 0)) - kk) < 1e-12]
           for r, kk in zip(rt[known], k[known])]
    assert all(len(d) for d in lag), 'a recorded K is not a value of the scenario'
    assert np.median([d[0] for d in lag]) <= 20
    o = np.array([float(r['O']) for r in rows])
    assert np.isfinite(o).all() and o.std() > 0.01  # the drift moves the laser
    assert (tmp_path / 'run.png').stat().st_size > 10_000
    with open(tmp_path / 'run.controller.csv') as handle:
        modes = {int(float(r['mode'])) for r in csv.DictReader(handle)}
    assert modes == {MODES.index('custom')}  # the plug-in decided, through the node


def test_bringup_stops_at_start_on_a_controller_it_cannot_build(ros_env, tmp_path):
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller',
         'test.control.plugin_examples:not_a_controller', '--log-dir', str(tmp_path / 'logs')],
        env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count('\n') == 1, proc.stderr
    assert proc.stderr.startswith("bringup: controller 'test.control.plugin_examples:"
                                  "not_a_controller': its factory returned 'str', not a "
                                  'controller'), proc.stderr
    assert not (tmp_path / 'logs').exists()


def test_bringup_rejects_bad_scenario_before_starting_nodes(ros_env, tmp_path):
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--scenario', 'steps', '--scenario-param',
         'values=0.9', '--log-dir', str(tmp_path / 'logs')],
        env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'outside the model range' in proc.stderr
    assert not (tmp_path / 'logs').exists()


@pytest.mark.parametrize('bad', ['--domain-id=300', '--nodes=laser_sim,teleporter',
                                 '--measurement-round-trips=0'])
def test_bringup_rejects_bad_options(ros_env, bad):
    proc = subprocess.run([sys.executable, '-m', 'dlmpc_ros.bringup', bad], env=ros_env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'error' in proc.stderr


def test_bringup_reports_a_node_that_dies(ros_env, tmp_path):
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller', 'none', '--round-trips', '100',
         '--laser-param',
         'points=8', '--domain-id', ros_env['ROS_DOMAIN_ID'], '--connect-timeout', '60',
         '--log-dir', str(tmp_path / 'logs')],
        env=ros_env, capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert 'laser_sim exited with code 2' in proc.stderr
    assert 'points = 8 is outside its range [16, 4096]' in proc.stderr


def test_ctrl_c_stops_the_graph_cleanly(ros_env, tmp_path):
    import signal
    import time

    proc = subprocess.Popen(
        [sys.executable, '-u', '-m', 'dlmpc_ros.bringup', '--controller', 'none', '--rate', '500',
         '--domain-id',
         ros_env['ROS_DOMAIN_ID'], '--log-dir', str(tmp_path / 'logs')],
        env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        lines = []
        while time.monotonic() < deadline:
            lines.append(proc.stdout.readline())
            if 'graph connected' in lines[-1] or proc.poll() is not None:
                break
        assert 'graph connected' in lines[-1], ''.join(lines)
        proc.send_signal(signal.SIGINT)
        out = proc.communicate(timeout=60)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, ''.join(lines) + out
    assert 'interrupted, stopping the graph' in out
    for name in ('laser_sim', 'drift_injector'):
        assert 'Traceback' not in (tmp_path / 'logs' / f'{name}.log').read_text()


def test_an_exploring_run_records_every_state_message_and_calibrates_the_models(
        ros_env, tmp_path):
    """The calibration workflow of a lab: record the exploring DL-MPC on a laser that is
    not the nominal cavity, then `dlmpc-train adapt` makes a models folder from the bag
    that the controller loads."""
    from dlmpc_ros.control.factory import load_dlmpc, load_estimator
    from dlmpc_ros.recording import check_round_trips, read_bag
    bag = tmp_path / 'bag'
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller', 'explore', '--lockstep',
         '--plant', 'pump=1.62', '--plant', 'loss=0.12', '--round-trips', '3000',
         '--record', str(bag),
         '--domain-id', ros_env['ROS_DOMAIN_ID'], '--log-dir', str(tmp_path / 'logs')],
        env=ros_env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    topics = read_bag(bag)
    check = check_round_trips(topics['/laser/state'].column('round_trip'))
    assert check.first == 1 and check.last >= 3000 and check.contiguous
    # the recorder stops last, so it holds everything the simulator published
    assert len(topics['/laser/sim_truth'].data) == check.count
    assert len(topics['/controller/status'].data) >= 10

    adapted = tmp_path / 'adapted'
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.cli.train', 'adapt', '--bag', str(bag), '--out',
         str(adapted), '--quick', '--laser-estimator', '--no-progress'],
        env=ros_env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = json.loads((adapted / 'adapt.json').read_text())
    assert report['pairs'] > 0 and report['held_out_pairs'] > 0
    assert report['round_trips_used'] >= 3000
    # 300 periods: the laser's own estimator learns from their windows with a pulse
    estimator = report['estimator']
    assert estimator['kept'] and estimator['periods'] >= 300, estimator
    assert load_estimator(adapted).encoder.window == estimator['window']
    controller = load_dlmpc(adapted)
    assert controller.rotation_prior is not None and controller.planner is not None
    if any(report['correction']):       # kept: the planner starts from it
        np.testing.assert_allclose(controller.turn_correction, report['correction'])
    else:                               # none kept: no file, the planner as shipped
        assert controller.turn_correction is None


@pytest.mark.parametrize('delay', [0.3, 1.5, 4.0])
def test_ctrl_c_at_any_moment_of_start_up_stops_everything_cleanly(ros_env, tmp_path, delay):
    """A Ctrl-C 0.3 s in once gave a 20-line bringup traceback and rc 1, one at 1.5 s a
    KeyboardInterrupt traceback in every node's log."""
    import os
    import signal
    import time

    logs = tmp_path / 'logs'
    proc = subprocess.Popen(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller', 'dlmpc', '--round-trips',
         '0', '--domain-id', ros_env['ROS_DOMAIN_ID'], '--log-dir', str(logs)],
        env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)
    time.sleep(delay)
    nodes = [int(p.read_text()) for p in logs.glob('*.pid')] if logs.exists() else []
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
    for log in logs.glob('*.log') if logs.exists() else ():
        text = log.read_text(errors='replace')
        assert 'Traceback' not in text and 'KeyboardInterrupt' not in text, (log.name, text)
    assert not (logs.exists() and list(logs.glob('*.pid')))
    for pid in nodes:  # every node the bringup had started is gone
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def _wait_for(proc: subprocess.Popen, text: str, timeout: float = 120.0) -> str:
    """stdout of ``proc`` up to the first line holding ``text`` (AssertionError if it ends
    or ``timeout`` passes first)."""
    import time
    lines = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lines.append(proc.stdout.readline())
        if text in lines[-1] or proc.poll() is not None:
            break
    out = ''.join(lines)
    assert text in out, out
    return out


def test_a_bringup_keeps_its_graph_to_itself(ros_env, tmp_path):
    """Two bringups on one domain once ran as one graph (both controllers commanding both
    lasers); an exported ROS_DOMAIN_ID was replaced by 87 without a word; the nodes inherited
    the caller's ROS_STATIC_PEERS and FASTDDS_* settings, and laser_sim's sockets bound every
    interface although discovery was localhost-only."""
    import ipaddress
    import signal

    import psutil

    domain = ros_env['ROS_DOMAIN_ID']
    env = {**ros_env, 'ROS_STATIC_PEERS': '10.11.12.13',
           'FASTDDS_BUILTIN_TRANSPORTS': 'LARGE_DATA', 'RMW_FASTRTPS_USE_QOS_FROM_XML': '1'}
    command = [sys.executable, '-u', '-m', 'dlmpc_ros.bringup', '--controller', 'none',
               '--rate', '200', '--nodes', 'laser_sim,drift_injector']
    proc = subprocess.Popen(command + ['--log-dir', str(tmp_path / 'a')], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out = _wait_for(proc, 'graph connected')
        assert f'domain {domain} (from ROS_DOMAIN_ID)' in out
        assert ('not passing on the middleware settings FASTDDS_BUILTIN_TRANSPORTS, '
                'RMW_FASTRTPS_USE_QOS_FROM_XML, ROS_STATIC_PEERS') in out
        second = subprocess.run(command + ['--log-dir', str(tmp_path / 'b')], env=env,
                                capture_output=True, text=True, timeout=60)
        assert second.returncode == 2, second.stdout + second.stderr
        assert f'already runs on ROS domain {domain}' in second.stderr
        assert not (tmp_path / 'b').exists()
        nodes = psutil.Process(proc.pid).children(recursive=True)
        assert len(nodes) >= 2
        for node in nodes:
            environ = node.environ()
            assert environ['ROS_DOMAIN_ID'] == domain
            assert not {'ROS_STATIC_PEERS', 'FASTDDS_BUILTIN_TRANSPORTS',
                        'RMW_FASTRTPS_USE_QOS_FROM_XML'} & set(environ)
            sockets = [c.laddr.ip for c in node.net_connections('inet4')]
            assert sockets
            for ip in sockets:  # loopback, or the discovery multicast group
                address = ipaddress.ip_address(ip)
                assert address.is_loopback or address.is_multicast, (node.cmdline(), ip)
        proc.send_signal(signal.SIGINT)
        out += proc.communicate(timeout=60)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    logs = ''.join(f'\n--- {log.name}\n{log.read_text()[-2000:]}'
                   for log in sorted((tmp_path / 'a').glob('*.log')))
    assert proc.returncode == 0, out + logs
    # the domain is free again once the first graph has stopped
    third = subprocess.Popen(command + ['--log-dir', str(tmp_path / 'c')], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_for(third, 'graph connected')
        third.send_signal(signal.SIGINT)
        third.communicate(timeout=60)
    finally:
        if third.poll() is None:
            third.kill()
    assert third.returncode == 0


@pytest.mark.parametrize('controller, nodes, strategy', [
    ('dlmpc', ['vae_estimator', 'mpc_controller'], None),
    ('dlmpc_paper', ['vae_estimator', 'mpc_controller'], 'paper'),
    ('esc', ['baseline_controller'], None)])
def test_a_controller_name_starts_its_nodes_with_its_settings(tmp_path, controller, nodes,
                                                              strategy):
    """dlmpc_paper in the bringup is the mpc_controller's strategy:=paper with its
    estimator, as the registered controller of that name is in dlmpc-evaluate."""
    from dlmpc_ros.bringup import build_graph, parse_args
    graph = build_graph(parse_args(['--controller', controller]), {}, tmp_path)
    started = {node.name: node.overrides for node in graph.nodes}
    assert [n for n in started if n in ('vae_estimator', 'mpc_controller',
                                        'baseline_controller')] == nodes
    if 'mpc_controller' in started:
        assert started['mpc_controller'].get('strategy') == strategy


@pytest.mark.parametrize('discovery', ['localhost', 'subnet'])
def test_the_graph_environment_holds_only_the_bringups_middleware_settings(discovery):
    from dlmpc_ros.bringup import graph_environment, parse_args
    args = parse_args(['--domain-id', '42', '--discovery', discovery])
    base = {'PATH': '/bin', 'ROS_DOMAIN_ID': '7', 'FASTRTPS_DEFAULT_PROFILES_FILE': '/x.xml',
            'CYCLONEDDS_URI': 'file:///y', 'ROS_LOCALHOST_ONLY': '1'}
    env, dropped = graph_environment(args, base)
    assert dropped == ['CYCLONEDDS_URI', 'FASTRTPS_DEFAULT_PROFILES_FILE', 'ROS_LOCALHOST_ONLY']
    assert env['PATH'] == '/bin' and env['ROS_DOMAIN_ID'] == '42'
    profile = env.get('FASTRTPS_DEFAULT_PROFILES_FILE')
    if discovery == 'localhost':  # the loopback-only transport of the package
        assert profile and '127.0.0.1' in open(profile).read()
    else:  # the middleware's own transports on every interface
        assert profile is None and 'CYCLONEDDS_URI' not in env


def test_no_message_is_lost_at_full_speed(ros_env, tmp_path):
    """Free-running, laser_sim once counted 14,742 of 24,892 K messages and 2,305 of 2,488
    commands (keep-last-10 readers behind a busy simulator), and the bag missed some."""
    import re

    from dlmpc_ros import interfaces as itf
    from dlmpc_ros.recording import check_round_trips, read_bag
    bag, logs = tmp_path / 'bag', tmp_path / 'logs'
    proc = subprocess.run(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller', 'esc', '--round-trips',
         '4000', '--record', str(bag), '--domain-id', ros_env['ROS_DOMAIN_ID'],
         '--log-dir', str(logs)],
        env=ros_env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr

    topics = read_bag(bag)
    check = check_round_trips(topics[itf.TOPIC_STATE].column('round_trip'))
    assert check.first == 1 and check.last >= 4000 and check.contiguous, check
    # one K per state (drift_injector sends K for the next round trip)
    assert len(topics[itf.TOPIC_BIREFRINGENCE]) >= check.count - 100

    def logged(node: str, pattern: str) -> int:
        found = re.findall(pattern, (logs / f'{node}.log').read_text())
        assert found, f'{node} logged no {pattern!r}'
        return int(found[-1])

    k_sent = logged('drift_injector', r'published (\d+) K messages')
    commands_sent = logged('baseline_controller', r'published (\d+) commands')
    k_received = logged('laser_sim', r'birefringence_received (\d+)')
    commands_received = logged('laser_sim', r'commands_received (\d+)')
    # a decision waits until the laser reports its last command (at full speed a command
    # lands some round trips after its decision): fewer than one per 10 round trips
    assert k_sent >= check.count - 100 and commands_sent >= 100
    assert len(topics[itf.TOPIC_OBJECTIVE]) == len(topics[itf.TOPIC_SIM_TRUTH]) == check.count
    # A writer matches a reader a moment after the reader sees the writer: the first few
    # messages of a node that starts publishing at once may miss a reader (one run: 3 of
    # 458 controller status messages missed the bag). Nothing is lost after that.
    for got, sent in ((k_received, k_sent), (len(topics[itf.TOPIC_BIREFRINGENCE]), k_sent),
                      (commands_received, commands_sent),
                      (len(topics[itf.TOPIC_ANGLES_CMD]), commands_sent),
                      (len(topics[itf.TOPIC_CONTROLLER_STATUS]), commands_sent)):
        assert sent - 5 <= got <= sent, (got, sent)


def test_the_dlmpc_controls_a_driver_written_from_the_contract_alone(ros_env, tmp_path):
    """test/nodes/minimal_driver.py imports no dlmpc_ros: a free-running laser of 200 round
    trips/s with servos that start 3 round trips late and turn 0.1 rad per round trip, a
    quantized encoder and noisy detectors. ``bringup --nodes ''`` runs the estimator and
    the DL-MPC against it (its laser starts locked: the DL-MPC moves onto its curve, then
    scans); each decision waits until the reported angles reach the last command."""
    import re
    import signal
    import time
    from pathlib import Path

    from dlmpc_ros.recording.run_csv import decisions_path
    driver_script = Path(__file__).with_name('minimal_driver.py')
    driver = subprocess.Popen([sys.executable, '-u', str(driver_script), '200'], env=ros_env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    run_csv = tmp_path / 'run.csv'
    try:
        started = time.time()
        bringup = subprocess.Popen(
            [sys.executable, '-u', '-m', 'dlmpc_ros.bringup', '--nodes', '', '--controller',
             'dlmpc', '--csv', str(run_csv), '--domain-id', ros_env['ROS_DOMAIN_ID'],
             '--log-dir', str(tmp_path / 'logs')],
            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            lines = [_wait_for(driver, 'command ')]
            while len(lines) < 40 and bringup.poll() is None:
                lines.append(driver.stdout.readline())
            bringup.send_signal(signal.SIGINT)
            out = bringup.communicate(timeout=60)[0]
        finally:
            if bringup.poll() is None:
                bringup.kill()
    finally:
        driver.send_signal(signal.SIGINT)
        rest = driver.communicate(timeout=30)[0]
    assert bringup.returncode == 0, out
    commands = [line for line in ''.join(lines).splitlines() if line.startswith('command ')]
    assert len(commands) >= 30, ''.join(lines) + rest
    first_at = float(commands[0].split()[2])
    print(f'first command {first_at - started:.1f} s after the bringup started')
    with open(decisions_path(run_csv)) as handle:
        decided = [int(float(row['round_trip'])) for row in csv.DictReader(handle)]
    gaps = np.diff(decided)
    # at least a period apart, and longer where a measured command moved the lagging
    # servos (a scan command on its way asks for none: those come a period apart)
    assert gaps.min() >= 10 and gaps.max() > 10, gaps
    assert re.search(r'commands \d+', rest)
    assert 'Traceback' not in (tmp_path / 'logs' / 'mpc_controller.log').read_text()
