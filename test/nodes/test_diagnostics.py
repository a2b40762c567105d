"""/diagnostics: every node reports its health once a second, with levels that mean
something (a dead laser is an ERROR for its controller)."""

import signal

from diagnostic_msgs.msg import DiagnosticArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.health import ERROR, OK
from dlmpc_ros.ros.io import DIAGNOSTICS_QOS
from test.nodes.rosutil import NodeProcess, Probe


def _latest(box: list, name: str):
    for msg in reversed(box):
        for status in msg.status:
            if status.name == name:
                return status
    return None


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_laser_and_controller_report_their_health_and_a_dead_laser_is_an_error(
        ros_env, tmp_path):
    probe = Probe('diagnostics_probe')
    box: list = []
    probe.node.create_subscription(DiagnosticArray, itf.TOPIC_DIAGNOSTICS, box.append,
                                   DIAGNOSTICS_QOS)
    laser = NodeProcess('dlmpc_ros.nodes.laser_sim_node', ros_env, tmp_path / 'laser.log',
                        '-p', 'round_trips_per_second:=200.0')
    controller = NodeProcess('dlmpc_ros.nodes.baseline_controller_node', ros_env,
                             tmp_path / 'controller.log', '-p', 'controller:=esc')
    try:
        probe.spin_until(lambda: _latest(box, 'laser_sim') is not None
                         and _latest(box, 'baseline_controller') is not None
                         and _values(_latest(box, 'baseline_controller'))['mode'] != 'none yet',
                         60, 'both nodes on /diagnostics')
        laser_status = _latest(box, 'laser_sim')
        assert laser_status.level == bytes([OK]), laser_status.message
        values = _values(laser_status)
        assert int(values['round_trip']) > 0 and values['pace'] == '200 round trips/s'
        assert {'rate_hz', 'commands_received', 'messages_rejected', 'resets'} <= set(values)
        assert laser_status.hardware_id == 'simulated cavity'
        ctrl = _latest(box, 'baseline_controller')
        assert ctrl.level == bytes([OK]), ctrl.message
        assert _values(ctrl)['mode'] == 'esc' and int(_values(ctrl)['commands_published']) > 0
        recent = [v for k, v in _values(ctrl).items() if k.startswith('modes_last_')]
        assert recent == ['esc 100 %']    # what the controller has been doing lately

        # malformed commands: a warning that names the topic and the reason
        for _ in range(3):
            probe.publish(itf.TOPIC_ANGLES_CMD, [1.0, 2.0])
        probe.spin_until(lambda: 'malformed' in _latest(box, 'laser_sim').message, 10,
                         'the dropped commands on /diagnostics')
        assert _latest(box, 'laser_sim').level == bytes([1])
        assert itf.TOPIC_ANGLES_CMD in _latest(box, 'laser_sim').message

        laser.proc.send_signal(signal.SIGKILL)  # the laser dies without a word
        probe.spin_until(lambda: _latest(box, 'baseline_controller').level == bytes([ERROR]),
                         15, 'the controller to report the silent laser')
        assert f'no {itf.TOPIC_STATE} for' in _latest(box, 'baseline_controller').message
    finally:
        laser.stop()
        code = controller.stop()
        probe.close()
    assert code == 0, controller.output()[-2000:]
