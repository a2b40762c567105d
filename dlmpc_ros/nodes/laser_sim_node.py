"""laser_sim: the simulated NPR mode-locked fiber laser as a ROS 2 node.

Publishes every round trip ``/laser/state``, ``/laser/objective`` and, for evaluation
only, ``/laser/sim_truth`` ``[round_trip, K]`` (the K that round trip ran with); subscribes
``/laser/angles_cmd`` ``[alpha1, alpha2, alpha3, alpha_p]`` (rad) and
``/laser/birefringence`` ``[K]``; publishes ``/laser/status`` once a second. Round trips
run in a worker thread, free-running or paced by ``round_trips_per_second``; commands take
effect from the next round trip.

The bench (off by default: ``core/bench.py``): servos that start ``servo_lag`` round
trips after a command and turn at most ``slew_rate`` rad per round trip, with
``backlash``; encoders that report the drive's angles with ``encoder_noise`` and
``encoder_resolution``; detectors whose E and M carry ``detector_noise``,
``detector_resolution`` and ``detector_saturation``, M refreshed every
``spectrum_refresh`` round trips. /laser/state then carries what they report (O = E / M,
energy and peak scaled as E's reading), /laser/sim_truth still the true K.

Lockstep (for reproducible runs, simulator only, with servos that reach a command on the
next round trip): with ``lockstep_period`` P > 0 the
laser waits after every round trip r with r % P == 0 until a new angle command arrives,
and with ``lockstep_birefringence`` after every round trip until a new K arrives; after
``lockstep_timeout`` seconds it warns and goes on, so a dead controller never freezes it.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import asdict, fields

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.core.bench import BENCH_FIELDS, Bench, BenchConfig
from dlmpc_ros.core.bench import RANGES as BENCH_RANGES
from dlmpc_ros.core.cavity import INITIAL_CONDITIONS, Cavity
from dlmpc_ros.core.config import RANGES as CAVITY_RANGES
from dlmpc_ros.core.config import CavityConfig, config_problems
from dlmpc_ros.health import CounterWindow, Findings, Health, laser_health
from dlmpc_ros.ros import params
from dlmpc_ros.ros.diagnostics import DiagnosticsPublisher
from dlmpc_ros.ros.io import QOS, vector_message

CAVITY_NAMES = tuple(f.name for f in fields(CavityConfig))
DEFAULTS: dict[str, object] = {
    **asdict(CavityConfig()), **BenchConfig().to_dict(),
    'initial_angles': [-0.39, -0.25, 0.52, -0.14], 'initial_birefringence': 0.1,
    'initial': 'sech', 'seed': 0, 'round_trips_per_second': 0.0, 'max_round_trips': 0,
    'angle_limit': 2 * math.pi, 'birefringence_limit': 1.0, 'wait_for_subscribers': 0,
    'lockstep_period': 0, 'lockstep_birefringence': False, 'lockstep_timeout': 10.0,
}
DESCRIPTIONS = {
    'dispersion': 'D, averaged group-velocity dispersion (normal < 0; normalized units)',
    'cross_phase': 'A, cross-phase modulation coefficient (A + B = 1)',
    'four_wave': 'B, four-wave-mixing coefficient (A + B = 1)',
    'pump': 'g0, pump strength of the saturable gain 2 g0 / (1 + energy / E0)',
    'saturation_energy': 'E0, gain saturation energy (normalized units)',
    'gain_bandwidth': 'tau, parabolic gain bandwidth: gain g (1 - tau k^2)',
    'loss': 'Gamma, distributed fiber loss per unit length',
    'fiber_length': 'Z, fiber length of one round trip (normalized units)',
    'window': 'T, width of the periodic time window (normalized units)',
    'points': 'n, time (and wavenumber) grid points',
    'steps_per_round_trip': 'steps of the fiber pass (each one step of the scheme); 0: the '
                            "scheme's own (richardson4 6, strang 32, suzuki4 4, yoshida4 14)",
    'scheme': "integration scheme of the fiber pass: 'richardson4' (default), 'suzuki4' or "
              "'yoshida4' (fourth order), 'strang' (second order; docs/solver.md)",
    'steady_tolerance': 'relative change of the amplitude per round trip below which the '
                        'laser is at steady state',
    'initial_angles': 'alpha1, alpha2, alpha3, alpha_p at start [rad]',
    'initial_birefringence': 'K at start, until /laser/birefringence says otherwise',
    'initial': f'initial field, one of {INITIAL_CONDITIONS}',
    'seed': 'seed of the noise initial condition',
    'round_trips_per_second': 'pace of the simulation [round trips/s]; 0 runs as fast as '
                              'possible',
    'max_round_trips': 'stop after this many round trips; 0 runs until shut down',
    'angle_limit': 'angle commands with any |alpha| above this [rad] are rejected',
    'birefringence_limit': 'K messages with |K| above this are rejected',
    'wait_for_subscribers': 'hold the first round trip until /laser/state has this many '
                            'subscribers (so that recorders miss nothing), and in lockstep '
                            'until the command and K topics have publishers',
    'lockstep_period': 'wait for an angle command after every round trip r with r % '
                       'lockstep_period == 0 (0: free-run)',
    'lockstep_birefringence': 'wait for a K message after every round trip',
    'lockstep_timeout': 'time to wait in lockstep before warning and going on [s]',
    'servo_lag': 'bench: round trips between a command and the servos starting to move',
    'slew_rate': 'bench: largest angle change of a servo per round trip [rad]; 0: no limit',
    'backlash': 'bench: play of each mount [rad]; the optic rests up to half of it short '
                'of the drive after a reversal (the encoder reads the drive)',
    'encoder_noise': 'bench: standard deviation of the noise on each reported angle [rad]',
    'encoder_resolution': 'bench: step of the reported angles [rad]; 0: continuous',
    'detector_noise': 'bench: relative standard deviation of the noise on each E and M '
                      'reading (energy and peak carry E\'s factor)',
    'detector_resolution': 'bench: step of the reported E and M [model units]; 0: '
                           'continuous',
    'detector_saturation': 'bench: largest E the detector reports; 0: no ceiling',
    'spectrum_refresh': 'bench: M is read every this many round trips (an optical spectrum '
                        'analyser\'s sweep) and repeated in between',
}
READ_ONLY = frozenset({'points', 'window', 'initial', 'seed', 'initial_angles',
                       'initial_birefringence', 'wait_for_subscribers', 'lockstep_period',
                       'lockstep_birefringence', *BENCH_FIELDS})
#: The values each numeric parameter may take: the cavity's (core.config.RANGES) and the
#: node's own, all of which the node can run (no overflowing waits, no endless loops).
RANGES: dict[str, tuple[float, float]] = {
    **CAVITY_RANGES, **BENCH_RANGES,
    'initial_birefringence': (-1.0, 1.0), 'seed': (0, 2 ** 31 - 1),
    'round_trips_per_second': (0.0, 1e6), 'max_round_trips': (0, 2 ** 53),
    'angle_limit': (0.0, 100.0), 'birefringence_limit': (0.0, 10.0),
    'wait_for_subscribers': (0, 1000), 'lockstep_period': (0, 10 ** 6),
    'lockstep_timeout': (0.001, 3600.0),
}
#: Slowest pace that is not free-running [round trips per second].
MIN_RATE = 1e-3


class LaserSimNode(Node):
    def __init__(self) -> None:
        super().__init__('laser_sim')
        self.values = params.declare(self, DEFAULTS, DESCRIPTIONS, READ_ONLY, RANGES)
        problems = self._problems(self.values)
        if problems:
            raise params.StartupError('; '.join(problems))
        self.cavity = Cavity(self._cavity_config(self.values), batch=1,
                             angles=np.array(self.values['initial_angles']),
                             birefringence=self.values['initial_birefringence'],
                             initial=self.values['initial'], seed=self.values['seed'])
        self.bench = Bench(BenchConfig(**{name: self.values[name] for name in BENCH_FIELDS}),
                           np.array(self.values['initial_angles']), seed=self.values['seed'])
        self.finished = False
        self.exit_code = 0
        self._lock = threading.Condition()
        self._pending: dict[str, object] = {}
        # Counters (under _lock): valid commands and K received, rejected messages, ...
        self.counts = dict.fromkeys(itf.LASER_STATUS_FIELDS[2:], 0)
        self._warn = itf.RateLimitedLog(self.get_logger().warning)
        self._error = itf.RateLimitedLog(self.get_logger().error)
        self._state_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_STATE,
                                                QOS[itf.TOPIC_STATE])
        self._objective_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_OBJECTIVE,
                                                    QOS[itf.TOPIC_OBJECTIVE])
        self._truth_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_SIM_TRUTH,
                                                QOS[itf.TOPIC_SIM_TRUTH])
        self._status_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_LASER_STATUS,
                                                 QOS[itf.TOPIC_LASER_STATUS])
        self._rate_mark = (time.monotonic(), 0)
        self.create_timer(1.0, self._publish_status)
        self._rate = 0.0  # round trips per second over the last status period
        self._health_windows = (CounterWindow(), CounterWindow())
        DiagnosticsPublisher(self, self._health, hardware_id='simulated cavity')
        for topic, handler in ((itf.TOPIC_ANGLES_CMD, self._on_angles),
                               (itf.TOPIC_BIREFRINGENCE, self._on_birefringence)):
            self.create_subscription(Float64MultiArray, topic, handler, QOS[topic])
        self.add_on_set_parameters_callback(lambda ps: params.result(
            self._problems({**self.values, **{p.name: p.value for p in ps}})))
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._run, name='round_trips', daemon=True)
        self._worker.start()

    @staticmethod
    def _cavity_config(values: dict) -> CavityConfig:
        return CavityConfig(**{name: values[name] for name in CAVITY_NAMES})

    @staticmethod
    def _problems(values: dict) -> list[str]:
        problems = config_problems({name: values[name] for name in CAVITY_NAMES})
        angles = values['initial_angles']
        if len(angles) != 4 or not all(math.isfinite(a) for a in angles):
            problems.append(f'initial_angles must be 4 finite numbers, got {list(angles)}')
        if values['initial'] not in INITIAL_CONDITIONS:
            problems.append(f'initial must be one of {INITIAL_CONDITIONS}, '
                            f"got {values['initial']!r}")
        for name in ('round_trips_per_second', 'max_round_trips', 'angle_limit',
                     'birefringence_limit', 'initial_birefringence', 'wait_for_subscribers',
                     'lockstep_period', 'lockstep_timeout'):
            value, (low, high) = values[name], RANGES[name]
            if not (math.isfinite(value) and low <= value <= high):
                problems.append(f'{name} must be in [{low:g}, {high:g}], got {value}')
        try:
            bench = BenchConfig(**{name: values[name] for name in BENCH_FIELDS})
        except ValueError as err:
            problems.append(str(err))
        else:
            if values['lockstep_period'] > 0 and not bench.instant_servos:
                problems.append('lockstep_period needs servos that reach a command at once '
                                '(servo_lag, slew_rate and backlash 0): with slower ones the '
                                'controller decides when its command is reached, which the '
                                'laser cannot wait for; run free or paced '
                                '(round_trips_per_second)')
        rate = values['round_trips_per_second']
        if 0 < rate < MIN_RATE:
            problems.append(f'round_trips_per_second must be 0 (free-run) or >= {MIN_RATE:g}, '
                            f'got {rate}')
        return problems

    def _apply_parameters(self, changed) -> None:
        with self._lock:
            self.values.update({p.name: p.value for p in changed})
            self._pending['config'] = self._cavity_config(self.values)

    def _on_vector(self, topic: str, msg: Float64MultiArray, limit: float):
        fault = itf.vector_fault(msg.data, itf.FIELDS[topic], limit)
        if fault is not None:
            self._warn.dropped(topic, fault)
            with self._lock:
                self.counts['messages_rejected'] += 1
            return None
        return np.array(msg.data, dtype=float)

    def _on_angles(self, msg: Float64MultiArray) -> None:
        angles = self._on_vector(itf.TOPIC_ANGLES_CMD, msg, self.values['angle_limit'])
        if angles is not None:
            with self._lock:
                self._pending['angles'] = angles
                self.counts['commands_received'] += 1
                self._lock.notify_all()

    def _on_birefringence(self, msg: Float64MultiArray) -> None:
        k = self._on_vector(itf.TOPIC_BIREFRINGENCE, msg, self.values['birefringence_limit'])
        if k is not None:
            with self._lock:
                self._pending['birefringence'] = k[0]
                self.counts['birefringence_received'] += 1
                self._lock.notify_all()

    def _publish_status(self) -> None:
        now, round_trip = time.monotonic(), self.cavity.round_trip
        then, before = self._rate_mark
        self._rate_mark = (now, round_trip)
        self._rate = (round_trip - before) / (now - then)
        with self._lock:
            counts = list(self.counts.values())
        self._status_pub.publish(vector_message(
            itf.LASER_STATUS_FIELDS, [round_trip, self._rate, *counts]))

    def _health(self, findings: Findings, now: float) -> Health:
        with self._lock:
            counts = dict(self.counts)
        rate = self.values['round_trips_per_second']
        findings.values['pace'] = ('lockstep' if self.values['lockstep_period'] > 0
                                   else f'{rate:g} round trips/s' if rate > 0 else 'free-run')
        drops, counters = self._health_windows
        findings.new_drops(drops, self._warn)
        return laser_health(findings, counters, self.cavity.round_trip, self._rate, counts,
                            running=self.exit_code == 0)

    def _wait_for(self, counter: str, seen: int) -> None:
        """Lockstep: wait until ``counts[counter]`` passes ``seen`` (or time out)."""
        timeout = self.values['lockstep_timeout']
        with self._lock:
            arrived = self._lock.wait_for(
                lambda: self.counts[counter] > seen or self._stop.is_set(), timeout)
            if not arrived:
                self.counts['lockstep_timeouts'] += 1
        if not arrived:
            self._warn(f'lockstep:{counter}', f'lockstep: no new {counter.split("_")[0]} '
                       f'message within {timeout:g} s at round trip {self.cavity.round_trip}; '
                       'going on')

    def _wait_for_graph(self) -> None:
        """Before round trip 1: wait for subscribers (and, in lockstep, publishers)."""
        wanted = self.values['wait_for_subscribers']
        needs = [lambda: self._state_pub.get_subscription_count() >= wanted]
        if self.values['lockstep_period'] > 0:
            needs.append(lambda: self.count_publishers(itf.TOPIC_ANGLES_CMD) > 0)
        if self.values['lockstep_birefringence']:
            needs.append(lambda: self.count_publishers(itf.TOPIC_BIREFRINGENCE) > 0)
        waited = time.monotonic()
        while not all(need() for need in needs) and not self._stop.wait(0.01):
            pass
        if not self._stop.is_set() and (wanted > 0 or len(needs) > 1):
            self.get_logger().info(
                f'graph complete after {time.monotonic() - waited:.2f} s: '
                f'{self._state_pub.get_subscription_count()} /laser/state subscribers; '
                'starting round trip 1')

    def _apply_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, {}
        if 'config' in pending:
            self.cavity.config = pending['config']
        if 'angles' in pending:
            self.bench.command(pending['angles'])
        if 'angles' in pending or not self.bench.config.instant_servos:
            self.cavity.set_angles(self.bench.advance())
        if 'birefringence' in pending:
            self.cavity.set_birefringence(pending['birefringence'])

    def _run(self) -> None:
        """Worker thread: round trips until stopped or max_round_trips is reached."""
        try:
            self._round_trips()
        except Exception as err:  # never die silently while the node keeps spinning
            if not (self._stop.is_set() or not self.context.ok()):
                self.get_logger().fatal(f'simulation stopped: {type(err).__name__}: {err}')
                self.exit_code = 1
        finally:
            self.finished = True

    def _round_trips(self) -> None:
        # Load the compiled kernel (about 0.3 s from numba's cache) on a throwaway laser
        # while discovery runs, so that round trip 1 comes on time and the pace does not
        # start by catching up.
        Cavity(self.cavity.config).run(1)
        self._wait_for_graph()
        next_time = time.monotonic()
        limit = self.values['max_round_trips']
        while not self._stop.is_set() and (limit == 0 or self.cavity.round_trip < limit):
            self._apply_pending()
            k = float(self.cavity.birefringence[0])
            with self._lock:
                seen_angles = self.counts['commands_received']
                seen_k = self.counts['birefringence_received']
            result = self.cavity.step()
            if not result.finite[0]:
                self._error('blow-up', f'field blew up at round trip {self.cavity.round_trip};'
                            ' reset to the initial pulse')
                self.cavity.reset()
                with self._lock:
                    self.counts['resets'] += 1
                continue
            state = self._reading(result.laser(0))
            self._truth_pub.publish(vector_message(itf.SIM_TRUTH_FIELDS, [state[0], k]))
            self._state_pub.publish(vector_message(itf.STATE_FIELDS, state))
            self._objective_pub.publish(vector_message(itf.OBJECTIVE_FIELDS, [state[3]]))
            period = self.values['lockstep_period']
            if period > 0 and state[0] % period == 0:
                self._wait_for('commands_received', seen_angles)
            if self.values['lockstep_birefringence']:
                self._wait_for('birefringence_received', seen_k)
            rate = self.values['round_trips_per_second']
            if rate > 0:
                next_time = max(next_time + 1.0 / rate, time.monotonic() - 1.0)
                self._stop.wait(max(0.0, next_time - time.monotonic()))

    def _reading(self, row: dict) -> list[float]:
        """The /laser/state of a round trip's true values, as the bench reports them."""
        if self.bench.config.ideal:
            return [row['round_trip'], row['E'], row['M'], row['O'], row['energy'],
                    row['peak'], *self.cavity.angles[0]]
        e, m, peak = self.bench.read_detectors(row['round_trip'], row['E'], row['M'],
                                               row['peak'])
        scale = (e / row['E']) ** 2 if row['E'] > 0 else 1.0
        return [row['round_trip'], e, m, e / m if m > 0 else 0.0, row['energy'] * scale,
                peak, *self.bench.read_angles()]

    def drain(self, executor) -> None:
        """Take the commands and K still queued once the round trips have ended, so
        that the counters logged at stop hold everything that arrived."""
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        self._worker.join()

        def handled() -> int:
            with self._lock:
                return sum(self.counts.values())
        params.drain_until_quiet(executor, handled, longest=5.0)

    def stop(self) -> None:
        """Stop the worker thread and wait for it (run_node then lets the readers
        acknowledge the last round trips) and log the counters."""
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        self._worker.join()
        with self._lock:
            counts = ', '.join(f'{k} {v}' for k, v in self.counts.items())
        self.get_logger().info(f'stopped after round trip {self.cavity.round_trip}: {counts}')


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(LaserSimNode, args))


if __name__ == '__main__':
    main()
