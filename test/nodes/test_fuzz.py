"""Every node against a flood of malformed messages on every topic it subscribes.

Per node at least FUZZ_COUNT malformed messages (wrong lengths, empty, NaN, +/-inf, 1e308,
out-of-range angles and K, negative, fractional and huge round trips) from a generator
with a fixed seed, interleaved with valid messages and with odd-but-well-formed ones (angles
far outside the servo range, E < 0, M <= 0, values of 1e200). The valid messages double as
checkpoints: the test waits for the node's answer to each, so the node has dealt with
everything sent before it. The node must stay up, publish only finite values (commands
inside the angle limits), still work afterwards, log a bounded number of warnings and exit
0 on SIGINT.
"""

import math

import numpy as np
import pytest

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.core.drift import make_scenario
from test.nodes.rosutil import NodeProcess, Probe

FUZZ_COUNT = 10_000
SEED = 20261123
#: Warning lines a node may log over its whole fuzz run (dropped messages: one line per
#: topic per 2 s, with the count of those not logged).
MAX_WARNINGS = 50
ANGLES = [-0.39, -0.25, 0.52, -0.14]


# -- the generator ----------------------------------------------------------------------

def malformed(rng: np.random.Generator, valid: list[float], out_of_range: list[float],
              round_trip: bool) -> list[float]:
    """A message a node must drop: ``valid`` spoiled in one of several ways.

    ``out_of_range`` are finite values beyond the topic's limit for its vector elements;
    ``round_trip``: element 0 is a round trip (negative, fractional and huge ones spoil it).
    """
    kinds = ['length', 'empty', 'nan', 'inf', 'huge', 'range'] + ['round_trip'] * round_trip
    kind = kinds[rng.integers(len(kinds))]
    data = list(valid)
    n = len(data)
    index = int(rng.integers(n))
    if kind == 'length':
        length = int(rng.choice([m for m in range(0, 2 * n + 3) if m != n]))
        return [float(x) for x in rng.normal(0.0, 1.0, length)]
    if kind == 'empty':
        return []
    if kind == 'nan':
        data[index] = math.nan
    elif kind == 'inf':
        data[index] = math.inf if rng.random() < 0.5 else -math.inf
    elif kind == 'huge':
        data[index] = 1e308 if rng.random() < 0.5 else -1e308
    elif kind == 'range' and out_of_range:
        data[index if not round_trip else int(rng.integers(1, n))] = float(
            rng.choice(out_of_range))
    else:  # a round trip that is not a count
        data[0] = float(rng.choice([-1.0 - rng.integers(10 ** 6), data[0] + 0.5,
                                    -0.25, 1e17 + 64, 2.0 ** 60, 1e300, -1e300]))
    return data


def odd_state(rng: np.random.Generator, round_trip: int) -> list[float]:
    """A well-formed state no laser would send: nodes take it and must survive it."""
    e, m = 3.2, 18.0
    angles = list(ANGLES)
    kind = rng.integers(5)
    if kind == 0:
        angles[int(rng.integers(4))] = float(rng.choice([1e6, -7.5, 40.0, 1e200]))
    elif kind == 1:
        e = float(rng.choice([-5.0, -1e200, 1e200]))
    elif kind == 2:
        m = float(rng.choice([0.0, -3.0, 1e-300, 1e200]))
    elif kind == 3:
        round_trip = itf.MAX_ROUND_TRIP - itf.MAX_ROUND_TRIP % 10
    else:
        angles = [float(a) for a in rng.uniform(-1e5, 1e5, 4)]
    return [round_trip, e, m, e / m if m else 0.0, e, 1.0, *angles]


def state(round_trip: int, angles=ANGLES) -> list[float]:
    return [round_trip, 3.2, 18.0, 3.2 / 18.0, 3.2, 1.0, *angles]


def measurement(round_trip: int) -> list[float]:
    """A /controller/measurement: settled, its settle time not measured."""
    return [round_trip, 3.2, 18.0, *ANGLES, 1.0, -1.0]


# -- the harness ------------------------------------------------------------------------

@pytest.fixture
def probe(ros_env):
    p = Probe('fuzzer')
    yield p
    p.close()


class Fuzz:
    """Counts what is sent; checks what the node published and logged."""

    def __init__(self, probe: Probe, outputs: list[str]) -> None:
        self.probe = probe
        self.rng = np.random.default_rng(SEED)
        self.sent = 0
        self.boxes = {topic: probe.listen(topic) for topic in outputs}

    def send_malformed(self, topic: str, count: int, valid: list[float],
                       out_of_range: list[float], round_trip: bool = False) -> None:
        for _ in range(count):
            self.probe.publish(topic, malformed(self.rng, valid, out_of_range, round_trip))
        self.sent += count

    def check_published(self, low: float = -math.inf, high: float = math.inf) -> None:
        for topic, box in self.boxes.items():
            values = np.array([x for m in box for x in m.data])
            assert np.isfinite(values).all(), f'a non-finite value on {topic}'
            if topic == itf.TOPIC_ANGLES_CMD:
                assert ((values >= low) & (values <= high)).all(), \
                    f'a command outside [{low}, {high}]'

    def check_log(self, node: NodeProcess, code: int, topics: list[str]) -> None:
        log = node.output()
        assert code == 0, log[-3000:]
        assert 'Traceback' not in log
        warnings = [line for line in log.splitlines() if '[WARN]' in line]
        assert len(warnings) < MAX_WARNINGS, '\n'.join(warnings)
        for topic in topics:
            assert f'dropped a message on {topic}' in log


def _start(module, ros_env, tmp_path, *params) -> NodeProcess:
    args = [a for p in params for a in ('-p', p)]
    return NodeProcess(module, ros_env, tmp_path / f'{module.rsplit(".", 1)[1]}.log', *args)


# -- the nodes --------------------------------------------------------------------------

def test_laser_sim(ros_env, tmp_path, probe):
    fuzz = Fuzz(probe, [itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE, itf.TOPIC_SIM_TRUTH,
                        itf.TOPIC_LASER_STATUS])
    states, truths = fuzz.boxes[itf.TOPIC_STATE], fuzz.boxes[itf.TOPIC_SIM_TRUTH]
    status = fuzz.boxes[itf.TOPIC_LASER_STATUS]
    node = _start('dlmpc_ros.nodes.laser_sim_node', ros_env, tmp_path,
                  'round_trips_per_second:=200.0', 'wait_for_subscribers:=1')
    try:
        probe.wait_matched(itf.TOPIC_ANGLES_CMD)
        probe.wait_matched(itf.TOPIC_BIREFRINGENCE)
        batch = 9  # the command topics keep the last 10 messages
        good = 0
        while fuzz.sent < FUZZ_COUNT:
            good += 1
            angles = [a + d for a, d in zip(ANGLES, fuzz.rng.uniform(-0.05, 0.05, 4))]
            k = float(fuzz.rng.uniform(-0.2, 0.2))
            fuzz.send_malformed(itf.TOPIC_ANGLES_CMD, batch, angles, [7.0, -100.0, 1e30])
            probe.publish(itf.TOPIC_ANGLES_CMD, angles, itf.ANGLE_FIELDS)
            fuzz.send_malformed(itf.TOPIC_BIREFRINGENCE, batch, [k], [1.5, -3.0, 1e30])
            probe.publish(itf.TOPIC_BIREFRINGENCE, [k], itf.BIREFRINGENCE_FIELDS)
            probe.spin_until(lambda: states and truths and truths[-1].data[1] == k  # noqa: B023
                             and list(states[-1].data[6:]) == angles,  # noqa: B023
                             30, 'the laser to apply the valid messages')
        probe.spin_until(lambda: status and status[-1].data[4] >= fuzz.sent, 10,
                         f'the laser status to count {fuzz.sent} rejected messages')
        # every message reached the laser: counted as a command, a K or a rejection
        assert list(status[-1].data[2:5]) == [good, good, fuzz.sent]
        assert node.proc.poll() is None
        rts = [int(m.data[0]) for m in states]
        assert rts == list(range(1, len(rts) + 1))
        fuzz.check_published()
    finally:
        code = node.stop()
    fuzz.check_log(node, code, [itf.TOPIC_ANGLES_CMD, itf.TOPIC_BIREFRINGENCE])


def test_drift_injector(ros_env, tmp_path, probe):
    fuzz = Fuzz(probe, [itf.TOPIC_BIREFRINGENCE])
    ks = fuzz.boxes[itf.TOPIC_BIREFRINGENCE]
    scenario = make_scenario('sinusoidal')
    node = _start('dlmpc_ros.nodes.drift_injector_node', ros_env, tmp_path)
    try:
        probe.wait_matched(itf.TOPIC_STATE)
        round_trip = 0
        probe.spin_until(lambda: probe.node.count_publishers(itf.TOPIC_BIREFRINGENCE), 30,
                         'the K publisher')
        for _ in range(600):  # until the K publisher is matched: a K per state from then
            probe.publish(itf.TOPIC_STATE, state(0), itf.STATE_FIELDS)
            probe.executor.spin_once(timeout_sec=0.05)
            if ks:
                break
        while fuzz.sent < FUZZ_COUNT:
            round_trip += 1
            fuzz.send_malformed(itf.TOPIC_STATE, 250, state(round_trip), [], round_trip=True)
            for _ in range(3):
                probe.publish(itf.TOPIC_STATE, odd_state(fuzz.rng, round_trip))
            probe.publish(itf.TOPIC_STATE, state(round_trip), itf.STATE_FIELDS)
            want = scenario(round_trip + 1)
            probe.spin_until(lambda: ks[-1].data[0] == want, 30,  # noqa: B023
                             f'K of round trip {round_trip + 1}')
        fuzz.check_published()
        assert all(abs(m.data[0]) <= 0.2 for m in ks)
    finally:
        code = node.stop()
    fuzz.check_log(node, code, [itf.TOPIC_STATE])


def test_vae_estimator(ros_env, tmp_path, probe):
    fuzz = Fuzz(probe, [itf.TOPIC_ESTIMATE])
    estimates = fuzz.boxes[itf.TOPIC_ESTIMATE]
    node = _start('dlmpc_ros.nodes.vae_estimator_node', ros_env, tmp_path)
    try:
        probe.wait_matched(itf.TOPIC_MEASUREMENT)
        round_trip = 0
        while fuzz.sent < FUZZ_COUNT:
            round_trip += 20  # checkpoints; odd measurements between them
            good = measurement(round_trip)
            fuzz.send_malformed(itf.TOPIC_MEASUREMENT, 250, good, [], round_trip=True)
            for _ in range(3):
                odd = odd_state(fuzz.rng, round_trip - 10)
                probe.publish(itf.TOPIC_MEASUREMENT, [*odd[:3], *odd[6:], 1.0, -1.0])
            probe.publish(itf.TOPIC_MEASUREMENT, good, itf.MEASUREMENT_FIELDS)
            probe.spin_until(lambda: estimates and estimates[-1].data[0] == round_trip,  # noqa: B023
                             30, f'the estimate of round trip {round_trip}')
        fuzz.check_published()
    finally:
        code = node.stop()
    fuzz.check_log(node, code, [itf.TOPIC_MEASUREMENT])


def test_mpc_controller(ros_env, tmp_path, probe):
    fuzz = Fuzz(probe, [itf.TOPIC_ANGLES_CMD, itf.TOPIC_CONTROLLER_STATUS])
    status = fuzz.boxes[itf.TOPIC_CONTROLLER_STATUS]
    probe.listen(itf.TOPIC_MEASUREMENT)  # as the estimator does: the controller reads
    # strategy:=paper reads both inputs (the default reads no estimate; its /laser/state is
    # the same base class's, and test_fuzz_properties fuzzes the default node)
    node = _start('dlmpc_ros.nodes.mpc_controller_node', ros_env, tmp_path, 'period:=10',
                  'estimator_timeout:=5.0', 'settle_tolerance:=1.0',  # fixed angles
                  'strategy:=paper')
    try:
        probe.wait_matched(itf.TOPIC_STATE)
        probe.wait_matched(itf.TOPIC_ESTIMATE)
        round_trip = 0
        estimate = [0.0, 0.2, 0.5, 0.2, 0.1]
        while fuzz.sent < FUZZ_COUNT:
            round_trip += 20  # checkpoints; odd states at the period between them
            estimate[0] = round_trip
            fuzz.send_malformed(itf.TOPIC_STATE, 150, state(round_trip), [], round_trip=True)
            fuzz.send_malformed(itf.TOPIC_ESTIMATE, 100, estimate, [], round_trip=True)
            if fuzz.rng.random() < 0.5:  # an odd state, with an odd or no estimate
                probe.publish(itf.TOPIC_STATE, odd_state(fuzz.rng, round_trip - 10))
                probe.publish(itf.TOPIC_ESTIMATE, [round_trip - 10, float(fuzz.rng.choice(
                    [1e200, -1e200, 40.0, 0.2])), 0.5, 0.0, 0.0])
            probe.publish(itf.TOPIC_STATE, state(round_trip), itf.STATE_FIELDS)
            probe.publish(itf.TOPIC_ESTIMATE, estimate)
            probe.spin_until(lambda: status and status[-1].data[0] == round_trip,  # noqa: B023
                             30, f'the decision of round trip {round_trip}')
        _still_controls(probe, fuzz, status, round_trip, estimate)
        fuzz.check_published(AngleLimits().low, AngleLimits().high)
    finally:
        code = node.stop()
    fuzz.check_log(node, code, [itf.TOPIC_STATE, itf.TOPIC_ESTIMATE])


def _still_controls(probe, fuzz, status, round_trip, estimate=None) -> None:
    """After the flood: valid input gets decisions that use it (no 'hold')."""
    from dlmpc_ros.control.step import MODES
    for _ in range(25):
        round_trip += 10
        probe.publish(itf.TOPIC_STATE, state(round_trip), itf.STATE_FIELDS)
        if estimate is not None:
            probe.publish(itf.TOPIC_ESTIMATE, [round_trip, *estimate[1:]])
        probe.spin_until(lambda: status[-1].data[0] == round_trip, 30,  # noqa: B023
                         f'the decision of round trip {round_trip}')
    assert MODES[int(status[-1].data[1])] != 'hold'


def _baseline_models(tmp_path) -> str:
    """The installed models/ if it has the baseline tables, else stand-in tables (the fuzz
    is about input handling, not about the angles in the tables)."""
    from dlmpc_ros.learning.tables import REQUIRED_KEYS, load_baselines
    from dlmpc_ros.paths import models_dir
    try:
        load_baselines(models_dir() / 'oracle.npz')
        return ''
    except (FileNotFoundError, ValueError):
        k = np.linspace(-0.3, 0.3, 61)
        tables = {key: np.zeros(k.size) for key in REQUIRED_KEYS}
        tables.update(K=k, angles=np.tile(ANGLES, (k.size, 1)),
                      tracking_angles=np.tile(ANGLES, (k.size, 1)),
                      fixed_best_angles=np.array(ANGLES))
        np.savez(tmp_path / 'oracle.npz', **tables)
        return str(tmp_path)


@pytest.mark.parametrize('name', ['fixed_best', 'oracle'])
def test_baseline_controller(ros_env, tmp_path, probe, name):
    fuzz = Fuzz(probe, [itf.TOPIC_ANGLES_CMD, itf.TOPIC_CONTROLLER_STATUS])
    status = fuzz.boxes[itf.TOPIC_CONTROLLER_STATUS]
    # settle_timeout = period: a decision every period, settled or not (an odd state's
    # angles make a command that the next states' angles never reach)
    node = _start('dlmpc_ros.nodes.baseline_controller_node', ros_env, tmp_path, 'period:=10',
                  'settle_timeout:=10', f'controller:={name}',
                  f"models_dir:='{_baseline_models(tmp_path)}'")
    topics = [itf.TOPIC_STATE] + [itf.TOPIC_SIM_TRUTH] * (name == 'oracle')
    try:
        for topic in topics:
            probe.wait_matched(topic)
        round_trip = 0
        while fuzz.sent < FUZZ_COUNT:
            round_trip += 20  # checkpoints; odd states at the period between them
            per_topic = 250 // len(topics)
            fuzz.send_malformed(itf.TOPIC_STATE, per_topic, state(round_trip), [],
                                round_trip=True)
            for _ in range(3):
                probe.publish(itf.TOPIC_STATE, odd_state(fuzz.rng, round_trip - 10))
            if name == 'oracle':
                fuzz.send_malformed(itf.TOPIC_SIM_TRUTH, per_topic, [round_trip, 0.1], [],
                                    round_trip=True)
                probe.publish(itf.TOPIC_SIM_TRUTH, [round_trip - 10, 1e200])
                probe.publish(itf.TOPIC_SIM_TRUTH, [round_trip, 0.1], itf.SIM_TRUTH_FIELDS)
            probe.publish(itf.TOPIC_STATE, state(round_trip), itf.STATE_FIELDS)
            probe.spin_until(lambda: status and status[-1].data[0] == round_trip,  # noqa: B023
                             30, f'the decision of round trip {round_trip}')
        _still_controls(probe, fuzz, status, round_trip)
        fuzz.check_published(AngleLimits().low, AngleLimits().high)
    finally:
        code = node.stop()
    fuzz.check_log(node, code, topics)
