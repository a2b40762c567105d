"""Throughput of the recorder node: paced raw publishers in, the bag's counts out.

For each rate, a fresh recorder process records three Float64MultiArray topics (the
shape of laser_sim's /laser/state, /laser/objective and /laser/sim_truth) that this
process publishes at the given total rate for a few seconds. Reports messages lost, the
rate the bag received and the recorder's CPU time per message.

    .venv/bin/python bench/bench_recorder.py --rates 3000 9000 15000 --seconds 3
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording import check_round_trips, read_bag
from dlmpc_ros.recording.repair import McapScan, find_mcaps
from dlmpc_ros.ros.io import QOS, vector_message

TOPICS = (itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE)


def cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def flushed_count(bag: Path) -> int:
    try:
        return sum(1 for mcap in find_mcaps(bag) for _ in McapScan(mcap))
    except (OSError, ValueError):
        return 0


def run(index: int, rate: float, seconds: float, work: Path, env: dict[str, str]) -> dict:
    bag = work / f'bag_{index}'
    log = open(work / f'recorder_{index}.log', 'wb')
    recorder = subprocess.Popen([sys.executable, '-m', 'dlmpc_ros.nodes.recorder_node',
                                 '--ros-args', '-p', f'output:={bag}', '-p',
                                 "topics_prefixes:=['/laser/state', '/laser/objective', "
                                 "'/laser/sim_truth']"],
                                env=env, stdout=log, stderr=subprocess.STDOUT)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench_publisher', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        pubs = [node.create_publisher(Float64MultiArray, t, QOS[t]) for t in TOPICS]
        deadline = time.monotonic() + 60
        while any(p.get_subscription_count() == 0 for p in pubs):
            if time.monotonic() > deadline:
                raise TimeoutError('the recorder did not subscribe')
            executor.spin_once(timeout_sec=0.05)
        rows = int(rate * seconds / len(TOPICS))
        payloads = [[serialize_message(vector_message(itf.SIM_TRUTH_FIELDS, [i, 0.1]))
                     for i in range(1, rows + 1)],
                    [serialize_message(vector_message(itf.STATE_FIELDS, [i] + [0.5] * 9))
                     for i in range(1, rows + 1)],
                    [serialize_message(vector_message(itf.OBJECTIVE_FIELDS, [0.5]))] * rows]
        cpu0 = cpu_seconds(recorder.pid)
        start = time.monotonic()
        for i in range(rows):
            for pub, payload in zip(pubs, payloads):
                pub.publish(payload[i])
            lag = start + (i + 1) * len(TOPICS) / rate - time.monotonic()
            if lag > 0:
                time.sleep(lag)
        sent_in = time.monotonic() - start
        total = rows * len(TOPICS)
        settle = time.monotonic() + 10
        last, last_change = -1, time.monotonic()
        while time.monotonic() < settle:  # until the bag stops growing
            count = flushed_count(bag)
            if count >= total or time.monotonic() - last_change > 2.0:
                break
            if count != last:
                last, last_change = count, time.monotonic()
            time.sleep(0.2)
        cpu = cpu_seconds(recorder.pid) - cpu0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        recorder.send_signal(signal.SIGINT)
        recorder.wait(30)
        log.close()
    topics = read_bag(bag)
    received = sum(len(t) for t in topics.values())
    stamps = [t.timestamps_ns for t in topics.values() if len(t)]
    span = (max(s[-1] for s in stamps) - min(s[0] for s in stamps)) / 1e9 if stamps else 0
    state = check_round_trips(topics[itf.TOPIC_STATE].column('round_trip'))
    return {'state_gaps': state.gaps, 'rate': rate, 'sent': total,
            'sent_rate': total / sent_in, 'received': received, 'lost': total - received,
            'received_rate': received / span if span else 0.0,
            'cpu_us_per_message': 1e6 * cpu / max(received, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--rates', type=float, nargs='+', default=[3000, 9000, 15000])
    p.add_argument('--seconds', type=float, default=3.0)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        env = {**os.environ, 'ROS_DOMAIN_ID': os.environ.get('ROS_DOMAIN_ID', '140'),
               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
               'ROS_LOG_DIR': str(work / 'ros-log')}
        os.environ.update(env)
        print(f'{"rate":>8} {"sent":>7} {"sent/s":>8} {"received":>9} {"lost":>6} '
              f'{"recv/s":>8} {"CPU us/msg":>10}')
        for index, rate in enumerate(args.rates):
            r = run(index, rate, args.seconds, work, env)
            print(f'{r["rate"]:8.0f} {r["sent"]:7d} {r["sent_rate"]:8.0f} {r["received"]:9d} '
                  f'{r["lost"]:6d} {r["received_rate"]:8.0f} {r["cpu_us_per_message"]:10.1f}',
                  flush=True)
            if r['state_gaps']:
                print(f'         /laser/state gaps: {r["state_gaps"]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
