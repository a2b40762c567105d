"""Property-based fuzzing (hypothesis) of every node: parameters and messages.

Per node, one process is started with its defaults; its parameters and their descriptors
are read over ROS (what ``ros2 param describe`` shows), then hypothesis drives it with
parameter changes of any type and value (NaN, inf, 0, negative, huge, wrong types) and
with bursts of messages of any length and value on every topic it subscribes, each burst
ending in a valid message. Properties, checked after every example:

- the node stays alive and answers its parameter service;
- a refused value leaves the parameter as it was, an accepted one is what it reads back;
- nothing non-finite is published;
- and over the run: memory stays bounded, warnings and errors stay rate-limited, and
  SIGINT ends the node with exit code 0 and no traceback.

Then fresh processes are started with values drawn the same way: each either runs (and
stops cleanly) or exits with code 2 and one ``cannot start`` line, never a traceback.
Sizes follow the hypothesis profile of ``test/strategies.py`` (``make fuzz``: long).
"""

from __future__ import annotations

import math
import signal
import string
import subprocess
import time
from dataclasses import dataclass

import numpy as np
import psutil
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.ros.io import QOS
from test.nodes.rosutil import NodeProcess, Probe
from test.strategies import any_float, any_int

#: Examples per node: parameter changes and bursts at runtime, and fresh starts (a start
#: costs seconds: the ci profile tries 10 and 2 per node, the long one 250 and 50).
RUNTIME = settings(max_examples=max(10, settings.default.max_examples // 4))
STARTS = settings(max_examples=max(2, settings.default.max_examples // 20))
#: Largest memory growth of a node over its runtime fuzz [bytes].
MAX_GROWTH = 300 * 2 ** 20
#: Warning and error lines a node may log per second of fuzz (rate-limited logs: one per
#: topic or key per 2 s).
MAX_LINES_PER_SECOND = 5.0
SERVICE_TIMEOUT = 20.0
#: Numeric parameters without a range, and why: NaN means "not given" (passive's K).
UNRANGED = {'baseline_controller': ('initial_birefringence',)}
#: How long a fresh node whose services are up may take to refuse its parameters [s].
SETTLE = 2.0
STATE = [0.0, 3.2, 18.0, 3.2 / 18.0, 3.2, 1.0, -0.39, -0.25, 0.52, -0.14]
#: A valid message per subscribed topic (element 0, a round trip, is filled in).
VALID = {itf.TOPIC_STATE: STATE, itf.TOPIC_ESTIMATE: [0.0, 0.2, 0.5, 0.2, 0.1],
         itf.TOPIC_MEASUREMENT: [0.0, *STATE[1:3], *STATE[6:], 1.0, -1.0],
         itf.TOPIC_SIM_TRUTH: [0.0, 0.1], itf.TOPIC_ANGLES_CMD: STATE[6:],
         itf.TOPIC_BIREFRINGENCE: [0.05]}


@dataclass(frozen=True)
class NodeSpec:
    module: str
    name: str
    args: tuple[str, ...] = ()


NODES = {
    'laser_sim': NodeSpec('dlmpc_ros.nodes.laser_sim_node', 'laser_sim',
                          ('round_trips_per_second:=200.0',)),
    'drift_injector': NodeSpec('dlmpc_ros.nodes.drift_injector_node', 'drift_injector'),
    'vae_estimator': NodeSpec('dlmpc_ros.nodes.vae_estimator_node', 'vae_estimator'),
    'mpc_controller': NodeSpec('dlmpc_ros.nodes.mpc_controller_node', 'mpc_controller'),
    'baseline_controller': NodeSpec('dlmpc_ros.nodes.baseline_controller_node',
                                    'baseline_controller', ('controller:=esc',)),
    'recorder': NodeSpec('dlmpc_ros.nodes.recorder_node', 'recorder',
                         ('output:={tmp}/bag{n}',)),
}

_TEXT = st.text(alphabet=string.ascii_letters + string.digits + '_/.-', max_size=12)


def value_strategy(kind: int) -> st.SearchStrategy[ParameterValue]:
    """Values of a parameter's own type (extremes included), or of any other type."""
    own = {
        ParameterType.PARAMETER_DOUBLE: any_float().map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=x)),
        ParameterType.PARAMETER_INTEGER: any_int().map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=x)),
        ParameterType.PARAMETER_BOOL: st.booleans().map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=x)),
        ParameterType.PARAMETER_STRING: _TEXT.map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=x)),
        ParameterType.PARAMETER_DOUBLE_ARRAY: st.lists(any_float(), max_size=6).map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                     double_array_value=x)),
        ParameterType.PARAMETER_STRING_ARRAY: st.lists(_TEXT, max_size=4).map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_STRING_ARRAY,
                                     string_array_value=x)),
        ParameterType.PARAMETER_INTEGER_ARRAY: st.lists(any_int(), max_size=4).map(
            lambda x: ParameterValue(type=ParameterType.PARAMETER_INTEGER_ARRAY,
                                     integer_array_value=x)),
    }
    other = st.sampled_from(sorted(own)).flatmap(lambda k: own[k])
    return st.one_of(own[kind], other) if kind in own else other


def as_override(value: ParameterValue) -> str | None:
    """The ``-p name:=VALUE`` text of a value, or None where the command line cannot say it."""
    def number(x: float) -> str:
        return '.nan' if math.isnan(x) else ('.inf' if x > 0 else '-.inf') \
            if math.isinf(x) else repr(float(x))
    kind = value.type
    if kind == ParameterType.PARAMETER_DOUBLE:
        return number(value.double_value)
    if kind == ParameterType.PARAMETER_INTEGER:
        return str(value.integer_value)
    if kind == ParameterType.PARAMETER_BOOL:
        return 'true' if value.bool_value else 'false'
    if kind == ParameterType.PARAMETER_STRING:
        return f"'{value.string_value}'"
    if kind == ParameterType.PARAMETER_DOUBLE_ARRAY and len(value.double_array_value):
        return '[' + ','.join(number(x) for x in value.double_array_value) + ']'
    if kind == ParameterType.PARAMETER_INTEGER_ARRAY and len(value.integer_array_value):
        return '[' + ','.join(str(x) for x in value.integer_array_value) + ']'
    if kind == ParameterType.PARAMETER_STRING_ARRAY and len(value.string_array_value):
        return '[' + ','.join(f"'{x}'" for x in value.string_array_value) + ']'
    return None  # an empty list has no type on the command line


def same(a: ParameterValue, b: ParameterValue) -> bool:
    """Equal parameter values (NaN equal to NaN)."""
    if a.type != b.type:
        return False
    fields = {ParameterType.PARAMETER_DOUBLE: 'double_value',
              ParameterType.PARAMETER_INTEGER: 'integer_value',
              ParameterType.PARAMETER_BOOL: 'bool_value',
              ParameterType.PARAMETER_STRING: 'string_value',
              ParameterType.PARAMETER_DOUBLE_ARRAY: 'double_array_value',
              ParameterType.PARAMETER_INTEGER_ARRAY: 'integer_array_value',
              ParameterType.PARAMETER_STRING_ARRAY: 'string_array_value'}
    field = fields.get(a.type)
    if field is None:
        return True
    x, y = getattr(a, field), getattr(b, field)
    if field in ('double_value', 'double_array_value'):
        return np.array_equal(np.asarray(x, float), np.asarray(y, float), equal_nan=True)
    return list(x) == list(y) if 'array' in field else x == y


class ParameterClient:
    """The parameter services of one node, called from the probe."""

    def __init__(self, probe: Probe, node: str) -> None:
        self.probe = probe
        make = probe.node.create_client
        self.list = make(ListParameters, f'/{node}/list_parameters')
        self.describe = make(DescribeParameters, f'/{node}/describe_parameters')
        self.get = make(GetParameters, f'/{node}/get_parameters')
        self.set = make(SetParameters, f'/{node}/set_parameters')
        probe.spin_until(lambda: self.set.service_is_ready() and self.get.service_is_ready()
                         and self.list.service_is_ready()
                         and self.describe.service_is_ready(), 60, f'{node} services')

    def call(self, client, request):
        return self.probe.call(client, request, SERVICE_TIMEOUT)

    def descriptors(self) -> dict[str, object]:
        names = self.call(self.list, ListParameters.Request()).result.names
        names = [n for n in names if n != 'use_sim_time']
        return {d.name: d for d in self.call(
            self.describe, DescribeParameters.Request(names=names)).descriptors}

    def values(self, names: list[str]) -> list[ParameterValue]:
        return list(self.call(self.get, GetParameters.Request(names=names)).values)

    def set_one(self, name: str, value: ParameterValue):
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
        return self.call(self.set, request).results[0]


def _graph_of(probe: Probe, name: str) -> tuple[list[str], list[str]]:
    """Topics the node ``name`` subscribes and publishes, as the probe sees them so far."""
    try:
        return ([t for t, _ in probe.node.get_subscriber_names_and_types_by_node(name, '/')],
                [t for t, _ in probe.node.get_publisher_names_and_types_by_node(name, '/')])
    except Exception:  # rclpy raises NodeNameNonExistentError until discovery has it
        return [], []


def _publish_burst(probe: Probe, topic: str, burst: list[list[float]], round_trip: int,
                   publisher) -> None:
    for data in burst:
        publisher.publish(Float64MultiArray(data=data))
    valid = list(VALID[topic])
    if topic in (itf.TOPIC_STATE, itf.TOPIC_ESTIMATE, itf.TOPIC_SIM_TRUTH):
        valid[0] = float(round_trip)
    probe.publish(topic, valid, itf.FIELDS.get(topic))


def _check_outputs(boxes: dict[str, list]) -> None:
    for topic, box in boxes.items():
        for msg in box:
            assert np.isfinite(np.asarray(msg.data, float)).all(), \
                f'a non-finite value on {topic}: {list(msg.data)}'
        box.clear()


def _log_lines(text: str) -> int:
    return sum(1 for line in text.splitlines() if '[WARN]' in line or '[ERROR]' in line)


@pytest.mark.parametrize('which', sorted(NODES))
def test_a_node_survives_any_parameter_and_any_message(which, ros_env, tmp_path):
    spec = NODES[which]
    starts = iter(range(10 ** 6))

    def arguments() -> list[str]:
        n = next(starts)
        return [a for p in spec.args for a in ('-p', p.format(tmp=tmp_path, n=n))]
    args = arguments()
    probe = Probe(f'fuzz_{which}')
    node = NodeProcess(spec.module, ros_env, tmp_path / f'{which}.log', *args)
    try:
        client = ParameterClient(probe, spec.name)
        descriptors = client.descriptors()
        names = sorted(descriptors)
        undescribed = [n for n, d in descriptors.items() if not d.description]
        unranged = [n for n, d in descriptors.items()
                    if d.type in (ParameterType.PARAMETER_INTEGER, ParameterType.PARAMETER_DOUBLE)
                    and not (d.integer_range or d.floating_point_range)
                    and n not in UNRANGED.get(which, ())]
        assert not undescribed and not unranged, (undescribed, unranged)
        probe.spin_until(lambda: bool(_graph_of(probe, spec.name)[0]), 30,
                         f'the subscriptions of {which}')
        subscribed, published = _graph_of(probe, spec.name)
        topics = sorted(t for t in subscribed if t in VALID)
        raw = {t: probe.node.create_publisher(Float64MultiArray, t, QOS[t]) for t in topics}
        boxes = {t: probe.listen(t) for t in published if t in QOS and t not in topics}
        memory = psutil.Process(node.proc.pid).memory_info().rss
        started = time.monotonic()
        round_trip = [0]

        @RUNTIME
        @given(name=st.sampled_from(names), data=st.data(),
               bursts=st.lists(st.lists(st.one_of(any_float(), st.integers(-10, 10 ** 6).map(
                   float)), max_size=14), max_size=8))
        def fuzz(name, data, bursts):
            value = data.draw(value_strategy(descriptors[name].type))
            before = client.values([name])[0]
            result = client.set_one(name, value)
            after = client.values([name])[0]
            if result.successful:
                assert same(after, value), (name, value, after)
            else:
                assert same(after, before), (name, value, before, after)
                if not same(before, value):
                    assert result.reason, f'{name}: refused without a reason'
            for topic in topics:
                round_trip[0] += 10
                _publish_burst(probe, topic, bursts, round_trip[0], raw[topic])
            for _ in range(5):
                probe.executor.spin_once(timeout_sec=0.01)
            assert node.proc.poll() is None, node.output()[-3000:]
            _check_outputs(boxes)

        fuzz()
        client.values(names)  # still answering after everything
        growth = psutil.Process(node.proc.pid).memory_info().rss - memory
        assert growth < MAX_GROWTH, f'{which} grew by {growth / 2**20:.0f} MiB'
        seconds = time.monotonic() - started
    finally:
        code = node.stop()
        probe.close()
    log = node.output()
    assert code == 0, log[-3000:]
    assert 'Traceback' not in log
    lines = _log_lines(log)
    assert lines <= 20 + MAX_LINES_PER_SECOND * seconds, f'{lines} warnings in {seconds:.0f} s'

    # fresh starts with values drawn the same way, each under its own node name: it either
    # comes up (its parameter service answers) and stops cleanly, or refuses with rc 2
    fresh_probe = Probe(f'fuzz_{which}_starts')

    @STARTS
    @given(data=st.data())
    def start(data):
        chosen = data.draw(st.lists(st.sampled_from(names), min_size=1, max_size=3,
                                    unique=True))
        overrides = []
        for name in chosen:
            text = as_override(data.draw(value_strategy(descriptors[name].type)))
            if text is not None:
                overrides += ['-p', f'{name}:={text}']
        n = next(starts)
        log_file = tmp_path / f'{which}-start{n}.log'
        fresh = NodeProcess(spec.module, ros_env, log_file, *arguments(), *overrides,
                            '-r', f'__node:=fresh{n}')
        up = fresh_probe.node.create_client(GetParameters, f'/fresh{n}/get_parameters')
        try:
            fresh_probe.spin_until(lambda: fresh.proc.poll() is not None
                                   or up.service_is_ready(), 60, f'{which} to start or exit')
            try:  # its services come up before its parameters are checked
                fresh.proc.wait(SETTLE)
            except subprocess.TimeoutExpired:
                pass
        finally:
            running = fresh.proc.poll() is None
            code = fresh.stop()
            fresh_probe.node.destroy_client(up)
        text = fresh.output()
        assert 'Traceback' not in text, (overrides, text[-3000:])
        refused = 'cannot start' in text
        if running:  # SIGINT may still meet its start-up: then it dies of it, quietly
            assert code in ((2,) if refused else (0,)) + (-signal.SIGINT,), \
                (overrides, code, text[-3000:])
        else:
            assert code == 2 and refused, (overrides, code, text[-3000:])

    try:
        start()
    finally:
        fresh_probe.close()
