"""Start-up against a laser that already runs: seconds from launching ``bringup --nodes ''
--controller dlmpc`` to the first angle command the laser receives.

A laser (``laser_sim`` free-running at ``--rate`` round trips/s, standing in for a
hardware driver) runs first; then, ``--repeats`` times, the bringup starts the estimator
and the DL-MPC against it, and a probe on the same domain times the first
``/laser/angles_cmd``. The median and range go to ``--out``.

    .venv/bin/python bench/startup_driver.py --repeats 5 --out bench/results/startup_driver.json
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.ros.io import QOS


def first_command_after_launch(domain: int, logs: Path) -> float:
    """Launch the bringup against the running laser; seconds to its first command."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('startup_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    heard: list[float] = []
    node.create_subscription(Float64MultiArray, itf.TOPIC_ANGLES_CMD,
                             lambda _msg: heard.append(time.monotonic()),
                             QOS[itf.TOPIC_ANGLES_CMD])
    env = {**os.environ, 'ROS_DOMAIN_ID': str(domain)}
    started = time.monotonic()
    bringup = subprocess.Popen(
        [sys.executable, '-m', 'dlmpc_ros.bringup', '--nodes', '', '--controller', 'dlmpc',
         '--domain-id', str(domain), '--log-dir', str(logs)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        while not heard and time.monotonic() - started < 120 and bringup.poll() is None:
            executor.spin_once(timeout_sec=0.01)
    finally:
        bringup.send_signal(signal.SIGINT)
        bringup.wait(60)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    if not heard:
        raise RuntimeError(f'no command within 120 s; logs in {logs}')
    return heard[0] - started


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--repeats', type=int, default=5)
    p.add_argument('--rate', type=float, default=1000.0, help='laser round trips/s')
    p.add_argument('--domain-id', type=int, default=131)
    p.add_argument('--out', type=Path)
    args = p.parse_args()
    env = {**os.environ, 'ROS_DOMAIN_ID': str(args.domain_id),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    os.environ.update(env)
    with tempfile.TemporaryDirectory() as tmp:
        env['ROS_LOG_DIR'] = tmp
        laser = subprocess.Popen(
            [sys.executable, '-m', 'dlmpc_ros.nodes.laser_sim_node', '--ros-args', '-p',
             f'round_trips_per_second:={args.rate}'], env=env, stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT)
        try:
            time.sleep(3.0)  # the laser runs before the controller starts
            times = []
            for i in range(args.repeats):
                times.append(first_command_after_launch(args.domain_id, Path(tmp) / f'run{i}'))
                print(f'run {i + 1}: first command {times[-1]:.2f} s after the launch',
                      flush=True)
        finally:
            laser.send_signal(signal.SIGINT)
            laser.wait(30)
    result = {'seconds_to_first_command': times, 'median': statistics.median(times),
              'min': min(times), 'max': max(times), 'rate': args.rate, 'cores': os.cpu_count()}
    print(f'first command: median {result["median"]:.2f} s ({result["min"]:.2f}-'
          f'{result["max"]:.2f}) over {len(times)} launches')
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + '\n')


if __name__ == '__main__':
    main()
