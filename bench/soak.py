"""Soak test: the closed loop through the bringup for many round trips; memory and backlog.

Runs ``bringup --controller dlmpc`` (free-running unless ``--rate``, sinusoidal drift,
every round trip to CSV) for ``--round-trips`` laser round trips, and every
``--sample-every`` seconds records:

- the resident memory (``VmRSS`` of ``/proc/PID/status``) of every node process (found
  through the bringup's ``<log dir>/<node>.pid`` files) and of the bringup itself (which
  runs the monitor);
- the backlog: the laser's own round trip (``/laser/status``, once a second) minus the
  last round trip the monitor wrote to the CSV, and minus the round trip of the
  controller's latest decision (``/controller/status``); decisions the controller skipped
  (a controller that cannot keep up drops states once its queue of 1000 is full).

Writes ``--out`` (JSON: settings, samples, summary) after every sample and at the end;
the summary gives each process's RSS growth after the warm-up (first ``--warmup`` of the
round trips) in percent and in MiB per million round trips (least squares), and the
largest backlogs. Exit code: the bringup's.

Usage: ``python bench/soak.py [--round-trips 1000000] [--rate 0] [--out FILE]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.recording.run_csv import decisions_path

NODES = ('laser_sim', 'drift_injector', 'vae_estimator', 'mpc_controller')
HERE = Path(__file__).resolve().parent


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--round-trips', type=int, default=1_000_000)
    p.add_argument('--rate', type=float, default=0.0,
                   help='laser round trips per second (0: free-running, the default)')
    p.add_argument('--period', type=int, default=10, help='control period [round trips]')
    p.add_argument('--sample-every', type=float, default=10.0, help='seconds between samples')
    p.add_argument('--warmup', type=float, default=0.1,
                   help='fraction of the round trips before RSS growth is counted')
    p.add_argument('--domain-id', type=int, default=88)
    p.add_argument('--out', type=Path, default=HERE / 'results' / 'soak.json')
    p.add_argument('--work-dir', type=Path,
                   help='logs and CSV go here (default: a temporary directory, removed)')
    return p.parse_args(argv)


def rss_kib(pid: int) -> int | None:
    """Resident set size [KiB] of a process, None if it is gone."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError, ValueError):
        pass
    return None


def last_csv_round_trip(path: Path) -> int | None:
    """Round trip of the last complete row of a growing CSV (reads only its tail)."""
    try:
        with open(path, 'rb') as handle:
            handle.seek(0, os.SEEK_END)
            size = handle.tell()
            handle.seek(max(0, size - 4096))
            lines = handle.read().split(b'\n')[:-1]  # the part after the last \n may be cut
    except FileNotFoundError:
        return None
    for line in reversed(lines):
        try:
            return int(float(line.split(b',', 1)[0]))
        except ValueError:
            continue
    return None


class Listener:
    """The laser's round trip and the controller's latest decision, over ROS; at each
    laser status (once a second) the backlogs of the controller and of the monitor's CSV."""

    def __init__(self, csv_path: Path) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import Float64MultiArray

        from dlmpc_ros import interfaces as itf
        from dlmpc_ros.ros.io import QOS

        self._rclpy = rclpy
        self.csv_path = csv_path
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('soak_listener')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.laser_round_trip = 0
        self.laser_rate = 0.0
        self.decision_round_trip = 0
        self.decisions = 0
        self.controller_backlog: list[int] = []  # at each laser status, since the last sample
        self.monitor_backlog: list[int] = []
        self.monitor_round_trip: int | None = None
        self.node.create_subscription(Float64MultiArray, itf.TOPIC_LASER_STATUS,
                                      self._on_laser, QOS[itf.TOPIC_LASER_STATUS])
        self.node.create_subscription(Float64MultiArray, itf.TOPIC_CONTROLLER_STATUS,
                                      self._on_decision, QOS[itf.TOPIC_CONTROLLER_STATUS])

    def _on_laser(self, msg) -> None:
        self.laser_round_trip, self.laser_rate = int(msg.data[0]), float(msg.data[1])
        if self.decisions:
            self.controller_backlog.append(self.laser_round_trip - self.decision_round_trip)
        self.monitor_round_trip = last_csv_round_trip(self.csv_path)
        if self.monitor_round_trip is not None:
            self.monitor_backlog.append(self.laser_round_trip - self.monitor_round_trip)

    def _on_decision(self, msg) -> None:
        self.decision_round_trip = max(self.decision_round_trip, int(msg.data[0]))
        self.decisions += 1

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.1, max(0.0, deadline - time.monotonic())))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown()


def summarize(samples: list[dict], round_trips: int, warmup: float, period: int) -> dict:
    """RSS growth after the warm-up and the largest backlogs."""
    after = [s for s in samples if s['laser_round_trip'] >= warmup * round_trips]
    rss = {}
    names = sorted({name for s in samples for name in s['rss_kib']})
    for name in names:
        points = [(s['laser_round_trip'], s['rss_kib'][name]) for s in after
                  if s['rss_kib'].get(name) is not None]
        if len(points) < 2:
            rss[name] = {'samples_after_warmup': len(points)}
            continue
        x, y = np.array(points, float).T
        slope = np.polyfit(x, y, 1)[0] if np.ptp(x) > 0 else 0.0
        rss[name] = {'at_warmup_mib': round(y[0] / 1024, 1), 'last_mib': round(y[-1] / 1024, 1),
                     'max_mib': round(y.max() / 1024, 1),
                     'growth_after_warmup_pct': round(100 * (y[-1] - y[0]) / y[0], 2),
                     'slope_mib_per_million_round_trips': round(slope * 1e6 / 1024, 2),
                     'samples_after_warmup': len(points)}

    def largest(key: str) -> int | None:
        values = [s[key] for s in samples if s.get(key) is not None]
        return max(values) if values else None

    last = samples[-1] if samples else {}
    rates = [s['laser_rate'] for s in samples if s['laser_rate'] > 0]
    return {'rss': rss,
            'max_monitor_backlog_round_trips': largest('monitor_backlog_max'),
            'max_controller_backlog_round_trips': largest('controller_backlog_max'),
            'decisions': last.get('decisions'),
            'decisions_expected': (last.get('laser_round_trip', 0) // period) or None,
            'mean_laser_rate_rt_per_s': round(float(np.mean(rates)), 1) if rates else None}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    os.environ['ROS_DOMAIN_ID'] = str(args.domain_id)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    requested = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: requested.append(True))
    temp = None
    if args.work_dir is None:
        temp = tempfile.TemporaryDirectory(prefix='dlmpc-soak-')
        args.work_dir = Path(temp.name)
    args.work_dir.mkdir(parents=True, exist_ok=True)
    log_dir, csv_path = args.work_dir / 'logs', args.work_dir / 'run.csv'
    decisions_csv = decisions_path(csv_path)
    cmd = [sys.executable, '-u', '-m', 'dlmpc_ros.bringup', '--controller', 'dlmpc',
           '--scenario', 'sinusoidal', '--round-trips', str(args.round_trips),
           '--rate', str(args.rate), '--period', str(args.period),
           '--domain-id', str(args.domain_id), '--csv', str(csv_path),
           '--log-dir', str(log_dir)]
    report = {'command': cmd, 'settings': {k: str(v) if isinstance(v, Path) else v
                                           for k, v in vars(args).items()},
              'machine': {'cpus': os.cpu_count(), 'python': platform.python_version(),
                          'processor': platform.machine()},
              'samples': [], 'summary': {}}
    print(f'soak: {args.round_trips} round trips, work dir {args.work_dir}', flush=True)
    bringup_out = open(args.work_dir / 'bringup.out', 'w')
    bringup = subprocess.Popen(cmd, stdout=bringup_out, stderr=subprocess.STDOUT,
                               start_new_session=True)
    listener = Listener(csv_path)
    started = time.monotonic()
    code = None
    try:
        while code is None:
            listener.spin_for(args.sample_every)
            code = bringup.poll()
            pids = {'bringup': bringup.pid}
            for name in NODES:
                try:
                    pids[name] = int((log_dir / f'{name}.pid').read_text())
                except (FileNotFoundError, ValueError):
                    pass
            laser = listener.laser_round_trip
            backlog, listener.controller_backlog = listener.controller_backlog, []
            monitor, listener.monitor_backlog = listener.monitor_backlog, []
            sample = {'t_s': round(time.monotonic() - started, 1), 'laser_round_trip': laser,
                      'laser_rate': round(listener.laser_rate, 1),
                      'monitor_round_trip': listener.monitor_round_trip,
                      'monitor_backlog': monitor[-1] if monitor else None,
                      'monitor_backlog_max': max(monitor) if monitor else None,
                      'decision_round_trip': listener.decision_round_trip,
                      'decisions': listener.decisions,
                      'decisions_recorded': last_csv_round_trip(decisions_csv),
                      'controller_backlog': backlog[-1] if backlog else None,
                      'controller_backlog_max': max(backlog) if backlog else None,
                      'rss_kib': {name: rss_kib(pid) for name, pid in pids.items()}}
            if laser and code is None:
                report['samples'].append(sample)
                rss = '  '.join(f'{name} {kib / 1024:.0f}' for name, kib in
                                sample['rss_kib'].items() if kib is not None)
                print(f'soak: {sample["t_s"]:7.0f} s  round trip {laser:>8d} '
                      f'({sample["laser_rate"]:5.0f}/s)  backlog (max): monitor '
                      f'{sample["monitor_backlog"]} ({sample["monitor_backlog_max"]})  '
                      f'controller {sample["controller_backlog"]} '
                      f'({sample["controller_backlog_max"]})  RSS MiB: {rss}', flush=True)
                report['summary'] = summarize(report['samples'], args.round_trips,
                                              args.warmup, args.period)
                _write(args.out, report)
            if requested and code is None:
                print('soak: interrupted; stopping the bringup', flush=True)
                bringup.send_signal(signal.SIGINT)
                code = bringup.wait(60)
    finally:
        listener.close()
        if bringup.poll() is None:
            bringup.send_signal(signal.SIGINT)
            try:
                bringup.wait(60)
            except subprocess.TimeoutExpired:
                bringup.kill()
        bringup_out.close()
        code = bringup.returncode
        report['bringup_exit_code'] = code
        report['wall_s'] = round(time.monotonic() - started, 1)
        report['bringup_tail'] = (args.work_dir / 'bringup.out').read_text().splitlines()[-6:]
        report['summary'] = summarize(report['samples'], args.round_trips, args.warmup,
                                      args.period)
        _write(args.out, report)
        if temp is not None:
            temp.cleanup()
    print(json.dumps(report['summary'], indent=2))
    print(f'soak: bringup exit code {code}; results in {args.out}')
    return code


def _write(path: Path, report: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix('.json.tmp')
    tmp.write_text(json.dumps(report, indent=2) + '\n')
    tmp.replace(path)


if __name__ == '__main__':
    sys.exit(main())
