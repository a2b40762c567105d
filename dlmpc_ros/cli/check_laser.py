"""dlmpc-check-laser: check that the laser on this ROS domain keeps the interface of
docs/interfaces.md (the simulator, or a hardware driver that replaces it).

Runs against whatever node publishes /laser/state on the current ROS_DOMAIN_ID:
(a) the state stream (layout, finite values, increasing round trips, rate and jitter),
(b) O = E/M and /laser/objective, (c) angle commands take effect within a bound,
(d) malformed commands are dropped without effect, (e) /laser/status. Checks (c) and (d)
move the waveplates by --step rad and put them back at the end; stop any controller
first. Exit code 0 when every check passes, 1 when one fails, 2 for bad arguments or no
laser within --timeout, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from diagnostic_msgs.msg import DiagnosticArray
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import conformance as cf
from dlmpc_ros import interfaces as itf
from dlmpc_ros.ros.io import DIAGNOSTICS_QOS, QOS, layout_for, vector_message
from dlmpc_ros.ros.stop_signals import stop_on_signals

NAMES = {'a': 'state stream', 'b': 'objective', 'c': 'angle commands',
         'd': 'malformed commands', 'e': 'status', 'f': 'diagnostics'}


class NoLaser(RuntimeError):
    """No /laser/state arrived within --timeout."""


class Interrupted(RuntimeError):
    """SIGINT or SIGTERM."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    d = cf.Settings()
    p = argparse.ArgumentParser(prog='dlmpc-check-laser', description=__doc__.split('\n\n')[0])
    p.add_argument('--duration', type=float, default=d.duration,
                   help='seconds of /laser/state to measure rate and jitter (default: '
                        '%(default)s)')
    p.add_argument('--timeout', type=float, default=30.0,
                   help='seconds to wait for the laser (first /laser/state, a reader of '
                        '/laser/angles_cmd) before exit code 2 (default: %(default)s)')
    p.add_argument('--period', type=int, default=d.period,
                   help='control period P [round trips] the controllers will use (default: '
                        '%(default)s)')
    p.add_argument('--min-rate', type=float, default=d.min_rate,
                   help='fewest /laser/state messages per second (default: %(default)s)')
    p.add_argument('--max-gap', type=float, default=d.max_gap,
                   help='longest time without /laser/state [s] (default: %(default)s)')
    p.add_argument('--steadiness', type=float, default=d.steadiness,
                   help='in every fifth of the window the rate must reach this fraction of '
                        'the mean (default: %(default)s)')
    p.add_argument('--tolerance', type=float, default=d.tolerance,
                   help="a state angle has reached its command within this [rad]: the "
                        "controllers' settle_tolerance (default: %(default)s)")
    p.add_argument('--max-round-trips', type=int, default=d.max_round_trips,
                   help='a command must show in the state within this many round trips: '
                        "the controllers' settle_timeout (default: %(default)s)")
    p.add_argument('--step', type=float, default=d.step,
                   help="angle change of the first test command [rad]: the controllers' "
                        'max_step (default: %(default)s); the others move half of it')
    p.add_argument('--commands', type=int, default=3,
                   help='number of test commands before the malformed ones (default: '
                        '%(default)s)')
    p.add_argument('--command-timeout', type=float, default=5.0,
                   help='seconds to wait for one command to show (default: %(default)s)')
    p.add_argument('--angle-limit', type=float, default=d.angle_limit,
                   help='interface range of a command, |alpha| above it is malformed [rad] '
                        '(default: 2 pi)')
    p.add_argument('--status-timeout', type=float, default=d.status_timeout,
                   help='/laser/status at least once per this many seconds (default: '
                        '%(default)s)')
    p.add_argument('--status-optional', action='store_true',
                   help='a missing /laser/status is a WARN, not a FAIL')
    p.add_argument('--no-commands', action='store_true',
                   help='only listen: skip checks (c) and (d), send nothing')
    p.add_argument('--domain-id', type=int,
                   help='ROS domain to check (default: ROS_DOMAIN_ID, else 0)')
    p.add_argument('--json', type=Path, metavar='FILE', help='also write the report here')
    args = p.parse_args(argv)
    positive = ('duration', 'timeout', 'min_rate', 'max_gap', 'steadiness', 'tolerance', 'step',
                'command_timeout', 'angle_limit', 'status_timeout')
    for name in positive:
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            p.error(f'--{name.replace("_", "-")} must be a finite number > 0, got {value}')
    for name in ('period', 'max_round_trips', 'commands'):
        if getattr(args, name) < 1:
            p.error(f'--{name.replace("_", "-")} must be >= 1')
    if args.steadiness > 1:
        p.error('--steadiness is a fraction of the mean rate: at most 1')
    if args.step <= 2 * args.tolerance:
        p.error('--step must be larger than twice --tolerance')
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        p.error('--domain-id must be in 0..232')
    args.settings = cf.Settings(
        duration=args.duration, period=args.period, min_rate=args.min_rate,
        max_gap=args.max_gap, steadiness=args.steadiness, tolerance=args.tolerance,
        max_round_trips=args.max_round_trips, step=args.step, angle_limit=args.angle_limit,
        status_timeout=args.status_timeout, status_required=not args.status_optional)
    return args


class CheckLaserNode(Node):
    """Records /laser/state, /laser/objective and /laser/status; publishes angle commands."""

    def __init__(self, context: Context) -> None:
        super().__init__('check_laser', context=context)
        self.states: list[cf.Sample] = []
        self.objectives: list[cf.Sample] = []
        self.statuses: list[cf.Sample] = []
        for topic, box in ((itf.TOPIC_STATE, self.states),
                           (itf.TOPIC_OBJECTIVE, self.objectives),
                           (itf.TOPIC_LASER_STATUS, self.statuses)):
            self.create_subscription(Float64MultiArray, topic, self._recorder(box), QOS[topic])
        self.commands = self.create_publisher(Float64MultiArray, itf.TOPIC_ANGLES_CMD,
                                              QOS[itf.TOPIC_ANGLES_CMD])
        self.diagnostics: list[tuple[float, str, int, str]] = []
        self.create_subscription(DiagnosticArray, itf.TOPIC_DIAGNOSTICS, self._on_diagnostics,
                                 DIAGNOSTICS_QOS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        now = time.monotonic()
        for status in msg.status:
            level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
            self.diagnostics.append((now, status.name, level, status.message))

    @staticmethod
    def _recorder(box: list[cf.Sample]) -> Callable[[Float64MultiArray, dict], None]:
        def record(msg: Float64MultiArray, info: dict) -> None:
            received = time.monotonic()
            source = info.get('source_timestamp') or 0
            box.append(cf.Sample(
                received=received, sent=source * 1e-9 if source else received,
                data=tuple(msg.data), label=msg.layout.dim[0].label if msg.layout.dim else '',
                sequence=info.get('publication_sequence_number') or 0))
        return record

    def endpoints(self, topic: str, publishers: bool) -> tuple[list[str], bool | None]:
        """Names of the other nodes publishing (or subscribing) ``topic``, and whether all
        of them are reliable (None: there are none)."""
        infos = (self.get_publishers_info_by_topic if publishers
                 else self.get_subscriptions_info_by_topic)(topic)
        infos = [i for i in infos if i.node_name != self.get_name()]
        names = sorted({f'{i.node_namespace.rstrip("/")}/{i.node_name}' for i in infos})
        reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                       for i in infos) if infos else None
        return names, reliable

    def latest_state(self) -> cf.Sample | None:
        return next((x for x in reversed(self.states) if x.valid_state), None)


class Session:
    """The checker node, its executor and the run's progress (sent commands)."""

    def __init__(self, node: CheckLaserNode, executor: SingleThreadedExecutor,
                 requested: threading.Event, args: argparse.Namespace) -> None:
        self.node = node
        self.executor = executor
        self.requested = requested
        self.args = args
        self.s: cf.Settings = args.settings
        self.original: tuple[float, ...] | None = None
        self.last_target: tuple[float, ...] | None = None

    def spin_until(self, condition: Callable[[], object], timeout: float) -> bool:
        """Spin until ``condition()`` holds (True) or ``timeout`` seconds pass (False)."""
        deadline = time.monotonic() + timeout
        while not condition():
            if self.requested.is_set():
                raise Interrupted('interrupted')
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(0.05, remaining))
        return True

    def drain(self) -> None:
        """Take every message already waiting, without waiting for more."""
        node = self.node

        def received() -> int:
            return len(node.states) + len(node.objectives) + len(node.statuses)

        idle = 0
        deadline = time.monotonic() + 1.0
        while idle < 5 and time.monotonic() < deadline:  # a spin may serve something else
            before = received()
            self.executor.spin_once(timeout_sec=0.0)
            idle = idle + 1 if received() == before else 0

    def command(self, target: tuple[float, ...], purpose: str) -> cf.CommandTrial:
        """Publish one valid command; wait until the state shows it and holds it for a
        control period, or until it is clearly late."""
        node, s = self.node, self.s
        self.drain()  # else the newest state here is older than the laser's round trip
        last = node.latest_state()
        trial = cf.CommandTrial(tuple(target), int(last.data[0]) if last else -1,
                                time.monotonic(), purpose=purpose)
        first = len(node.states)
        node.commands.publish(vector_message(itf.ANGLE_FIELDS, target))
        self.last_target = trial.target
        late = 3 * s.max_round_trips + 10
        hold = max(s.period, 10)
        scan = {'next': first, 'settled': None}

        def finished() -> bool:
            for i in range(scan['next'], len(node.states)):
                if scan['settled'] is None and cf.reached(node.states[i], target, s.tolerance):
                    scan['settled'] = i
            scan['next'] = len(node.states)
            if scan['settled'] is not None:
                return len(node.states) - scan['settled'] > hold
            # Clearly late: give up, but not before a second has passed, so that a command
            # held up by a stall is measured rather than left to land in the next trial.
            newest = node.latest_state()
            return (newest is not None and newest.data[0] - trial.sent_round_trip > late
                    and time.monotonic() - trial.sent_at > 1.0)

        self.spin_until(finished, self.args.command_timeout)
        trial.states = node.states[first:]
        return trial

    def restore(self) -> None:
        """Put the angles back where the laser had them, if a command moved them."""
        if self.original is None or self.last_target == self.original:
            return
        self.requested.clear()
        try:
            trial = self.command(self.original, 'restore')
        except Interrupted:
            trial = None
        done = trial is not None and cf.settle(trial, self.s.tolerance) is not None
        print(f'dlmpc-check-laser: {"put" if done else "could not put"} the angles back to '
              f'{cf.fmt_angles(self.original)}', file=sys.stderr, flush=True)


def _command_checks(session: Session, rt_rate: float) -> dict[str, object]:
    """(c) and (d): send test commands, malformed ones, then restore the angles."""
    node, s = session.node, session.s
    out: dict[str, object] = {'trials': [], 'reason': '', 'malformed': [],
                              'reliable': None}
    others, _ = node.endpoints(itf.TOPIC_ANGLES_CMD, publishers=True)
    if others:
        out['reason'] = (f'{", ".join(others)} also publish{"es" if len(others) == 1 else ""}'
                         ' /laser/angles_cmd: stop the controller, or pass --no-commands')
        return out
    if not session.spin_until(lambda: node.commands.get_subscription_count() > 0,
                              session.args.timeout):
        out['reason'] = f'nothing subscribes /laser/angles_cmd within {session.args.timeout:g} s'
        return out
    _, out['reliable'] = node.endpoints(itf.TOPIC_ANGLES_CMD, publishers=False)
    last = node.latest_state()
    if last is None:
        out['reason'] = 'no valid /laser/state to take the current angles from'
        return out
    session.original = tuple(float(a) for a in last.angles)
    out['original'] = session.original
    trials: list[cf.CommandTrial] = out['trials']
    out['first_command_at'] = time.monotonic()
    targets = cf.command_targets(session.original, s.step, session.args.commands)
    for k, target in enumerate(targets):  # the first moves by max_step, the others by half
        trials.append(session.command(target, 'full step' if k == 0 else 'half step'))
    newest = node.latest_state()
    before = tuple(newest.angles) if newest is not None else trials[-1].target
    malformed = cf.malformed_commands(before, s.step, s.angle_limit)
    start, first = time.monotonic(), len(node.states)
    for _, data in malformed:
        node.commands.publish(Float64MultiArray(layout=layout_for(itf.ANGLE_FIELDS),
                                                data=[float(x) for x in data]))
    rate = rt_rate if math.isfinite(rt_rate) and rt_rate > 0 else 1.0
    observe = min(max((3 * s.max_round_trips + 10) / rate, 0.5), 5.0)
    session.spin_until(lambda: False, observe)
    out.update(malformed=malformed, before=before, malformed_start=start,
               malformed_end=time.monotonic(), after=node.states[first:])
    # A valid command away from where the laser is shows that commands still work.
    recovery = max(cf.command_targets(session.original, s.step, 2),
                   key=lambda target: max(abs(a - b) for a, b in zip(target, before)))
    out['recovery'] = session.command(recovery, 'after the malformed')
    trials.append(out['recovery'])
    restore = session.command(session.original, 'restore')
    trials.append(restore)
    at = cf.settle(restore, s.tolerance)
    out['confirmed_sent'] = restore.states[at].sent if at is not None else (
        node.states[-1].sent if node.states else None)
    return out


def run_checks(session: Session, domain: str) -> tuple[list[cf.CheckResult], dict]:
    """All six checks; raises NoLaser when no /laser/state arrives within --timeout."""
    node, s, args = session.node, session.s, session.args
    began = time.monotonic()
    print(f'dlmpc-check-laser: ROS domain {domain}: waiting up to {args.timeout:g} s for '
          f'{itf.TOPIC_STATE}', flush=True)
    if not session.spin_until(lambda: node.states, args.timeout):
        names, reliable = node.endpoints(itf.TOPIC_STATE, publishers=True)
        if names:
            qos = 'best effort, the interface is reliable' if reliable is False else 'reliable'
            raise NoLaser(f'{", ".join(names)} publish {itf.TOPIC_STATE} ({qos}), but no '
                          f'message arrived within {args.timeout:g} s')
        raise NoLaser(f'no node publishes {itf.TOPIC_STATE} on ROS domain {domain} within '
                      f'{args.timeout:g} s (check ROS_DOMAIN_ID and '
                      'ROS_AUTOMATIC_DISCOVERY_RANGE)')
    found = node.states[0].received
    print(f'dlmpc-check-laser: {itf.TOPIC_STATE} after {found - began:.1f} s; measuring for '
          f'{s.duration:g} s', flush=True)
    session.spin_until(lambda: time.monotonic() >= found + s.duration, s.duration + 1.0)
    end = time.monotonic()
    lasers, reliable = node.endpoints(itf.TOPIC_STATE, publishers=True)  # names known by now
    print(f'dlmpc-check-laser: laser {", ".join(lasers)}', flush=True)
    window = [x for x in node.states if x.received <= end]
    a = cf.check_state_stream(window, found, end, s, max(len(lasers), 1), reliable)
    b = cf.check_objective(window, [x for x in node.objectives if x.received <= end], s)
    rt_rate = float(a.figures.get('round_trips_per_s', math.nan))
    info: dict[str, object] = {'domain': domain, 'lasers': lasers}
    if args.no_commands:
        c = cf.skipped('c', NAMES['c'], '--no-commands')
        d = cf.skipped('d', NAMES['d'], '--no-commands')
        e = cf.check_status(node.statuses, found, time.monotonic(), s, rt_rate)
        f = cf.check_diagnostics(node.diagnostics, lasers, found, time.monotonic())
        return [a, b, c, d, e, f], info
    print('dlmpc-check-laser: sending test commands', flush=True)
    try:
        out = _command_checks(session, rt_rate)
    finally:
        session.restore()
    info['original_angles'] = out.get('original')
    c = cf.check_commands(out['trials'], s, out['reason'], out['reliable'])
    if 'after' in out:
        d = cf.check_malformed(out['malformed'], out['before'], out['after'],
                               out['malformed_start'], out['malformed_end'], out['recovery'],
                               s)
    else:
        d = cf.CheckResult('d', NAMES['d'], cf.FAIL, 'no command sent', [out['reason']])
    confirmed = out.get('confirmed_sent')
    if node.statuses and confirmed is not None:
        session.spin_until(lambda: node.statuses[-1].sent >= confirmed, s.status_timeout)
    expected = None
    if out['trials']:
        expected = {'commands_received': len(out['trials']),
                    'messages_rejected': len(out['malformed'])}
    e = cf.check_status(node.statuses, found, time.monotonic(), s, rt_rate,
                        out.get('first_command_at'), confirmed, expected)
    f = cf.check_diagnostics(node.diagnostics, lasers, found, time.monotonic())
    return [a, b, c, d, e, f], info


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if threading.current_thread() is threading.main_thread():
        requested = stop_on_signals()
    else:
        requested = threading.Event()
    domain = str(args.domain_id if args.domain_id is not None
                 else os.environ.get('ROS_DOMAIN_ID', '0'))
    context = Context()
    rclpy.init(context=context, domain_id=args.domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    try:
        node = CheckLaserNode(context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        session = Session(node, executor, requested, args)
        try:
            results, info = run_checks(session, domain)
        except NoLaser as err:
            print(f'dlmpc-check-laser: no laser: {err}', file=sys.stderr)
            return 2
        except Interrupted:
            print('dlmpc-check-laser: interrupted', file=sys.stderr)
            return 128 + signal.SIGINT
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    print(cf.format_report(results), flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(cf.report_dict(results, args.settings, info), indent=2,
                                        default=float) + '\n')
    return cf.exit_code(results)


if __name__ == '__main__':
    sys.exit(main())
