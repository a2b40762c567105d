"""Messages lost per topic in a free-running graph: three witnesses compared.

Runs ``bringup --controller dlmpc --record BAG`` at full speed (no ``--rate``) for
``--round-trips`` round trips while this process holds an independent subscriber on
every topic of the graph (reliable, keep all, raw: nothing but counting in its
callbacks, on its own events-executor thread: as fast a reader as rclpy has). laser_sim
waits for this subscriber too (``wait_for_subscribers`` one above the bringup's), so it
misses nothing to discovery.
Per topic it reports what the publishing node says it sent (its log at stop), what the
receiving node counted (laser_sim's counters for commands and K), what the independent
subscriber heard and what the bag holds; a repeat count runs it several times.

    .venv/bin/python bench/topic_loss.py --round-trips 20000 --repeats 3 \
        --out bench/results/topic_loss.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dlmpc_ros import interfaces as itf  # noqa: E402

TOPICS = (itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE, itf.TOPIC_SIM_TRUTH, itf.TOPIC_BIREFRINGENCE,
          itf.TOPIC_ANGLES_CMD, itf.TOPIC_ESTIMATE, itf.TOPIC_CONTROLLER_STATUS,
          itf.TOPIC_LASER_STATUS)
#: laser_sim's state readers in a bringup of the dlmpc graph with a recorder (drift
#: injector, estimator, controller, recorder, the bringup's monitor) plus this one.
READERS = 6


class Witness:
    """The independent subscriber: counts every message of every topic."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64MultiArray

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('loss_witness', context=self.context)
        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_ALL, durability=DurabilityPolicy.VOLATILE)
        self.counts = dict.fromkeys(TOPICS, 0)
        self.states: list[bytes] = []
        self.statuses: list[bytes] = []
        for topic in TOPICS:
            self.node.create_subscription(Float64MultiArray, topic, self._counter(topic), qos,
                                          raw=True)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.1)

    def _counter(self, topic: str):
        counts = self.counts
        keep = (self.states.append if topic == itf.TOPIC_STATE
                else self.statuses.append if topic == itf.TOPIC_CONTROLLER_STATUS else None)

        def count(raw: bytes) -> None:
            counts[topic] += 1
            if keep is not None:
                keep(raw)
        return count

    def state_round_trips(self, raws=None):
        """(n,) round trips of the /laser/state (or ``raws``) messages heard, in order."""
        from dlmpc_ros.recording.reader import decode_float64_arrays
        fields, data, _ = decode_float64_arrays(self.states if raws is None else raws)
        return data[:, 0] if len(data) else data

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def node_counts(log_dir: Path) -> dict[str, float]:
    """Counters the nodes logged at stop."""
    out: dict[str, float] = {}
    laser = (log_dir / 'laser_sim.log').read_text(errors='replace')
    match = re.findall(r'stopped after round trip (\d+): (.*)', laser)
    if match:
        out['laser_round_trips'] = int(match[-1][0])
        for key, value in re.findall(r'(\w+) (\d+)', match[-1][1]):
            out[f'laser_{key}'] = int(value)
    drift = (log_dir / 'drift_injector.log').read_text(errors='replace')
    match = re.findall(r'published (\d+) K messages', drift)
    if match:
        out['drift_published'] = int(match[-1])
    mpc = (log_dir / 'mpc_controller.log').read_text(errors='replace')
    match = re.findall(r'published (\d+) commands', mpc)
    if match:
        out['controller_published'] = int(match[-1])
    estimator = (log_dir / 'vae_estimator.log').read_text(errors='replace')
    match = re.findall(r'published (\d+) estimates', estimator)
    if match:
        out['estimator_published'] = int(match[-1])
    return out


def run_once(round_trips: int, domain: int, work: Path) -> dict:
    from dlmpc_ros.recording import check_round_trips, read_bag

    env = {**os.environ, 'ROS_DOMAIN_ID': str(domain),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_LOG_DIR': str(work / 'ros')}
    os.environ.update(env)
    witness = Witness(domain)
    bag, log_dir = work / 'bag', work / 'logs'
    started = time.monotonic()
    try:
        proc = subprocess.run(
            [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller', 'dlmpc', '--record',
             str(bag), '--round-trips', str(round_trips), '--domain-id', str(domain),
             '--laser-param', f'wait_for_subscribers={READERS}', '--log-dir', str(log_dir)],
            env=env, cwd=ROOT, capture_output=True, text=True, timeout=3600)
        time.sleep(3.0)  # the witness takes its backlog
    finally:
        witness.close()
    if proc.returncode != 0:
        raise SystemExit(f'bringup failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}')
    seconds = time.monotonic() - started
    topics = read_bag(bag)
    counts = node_counts(log_dir)
    state = check_round_trips(topics[itf.TOPIC_STATE].column('round_trip'))
    rows = {}
    for topic in TOPICS:
        sent = {itf.TOPIC_BIREFRINGENCE: counts.get('drift_published'),
                itf.TOPIC_ANGLES_CMD: counts.get('controller_published'),
                itf.TOPIC_ESTIMATE: counts.get('estimator_published'),
                itf.TOPIC_CONTROLLER_STATUS: counts.get('controller_published')}.get(
                    topic, counts.get('laser_round_trips') if topic in (
                        itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE, itf.TOPIC_SIM_TRUTH) else None)
        received = {itf.TOPIC_BIREFRINGENCE: counts.get('laser_birefringence_received'),
                    itf.TOPIC_ANGLES_CMD: counts.get('laser_commands_received')}.get(topic)
        rows[topic] = {'sent': sent, 'laser_sim_received': received,
                       'witness': witness.counts[topic],
                       'bag': len(topics[topic]) if topic in topics else 0}
    heard = check_round_trips(witness.state_round_trips())
    # Controller statuses (one per command) the witness missed: all before its first one
    # means its own subscription matched the controller late (discovery), not a loss.
    witness_status = set(witness.state_round_trips(witness.statuses).tolist())
    bag_status = topics[itf.TOPIC_CONTROLLER_STATUS].column('round_trip').tolist() \
        if itf.TOPIC_CONTROLLER_STATUS in topics else []
    missed = [rt for rt in bag_status if rt not in witness_status]
    first_heard = min(witness_status) if witness_status else None
    return {'round_trips': round_trips, 'seconds': round(seconds, 1),
            'rate': round(counts.get('laser_round_trips', 0) / seconds),
            'state_gaps': [list(g) for g in state.gaps],
            'witness_state': [heard.first, heard.last, [list(g) for g in heard.gaps]],
            'witness_status_missed': len(missed),
            'witness_status_missed_after_its_first': sum(
                1 for rt in missed if first_heard is not None and rt > first_heard),
            'topics': rows,
            'rejected': counts.get('laser_messages_rejected')}


def table(runs: list[dict]) -> str:
    lines = ['| run | topic | sent (publisher) | laser_sim received | witness | bag |',
             '|---|---|---:|---:|---:|---:|']
    for i, run in enumerate(runs, 1):
        for topic, row in run['topics'].items():
            cells = ['-' if row[k] is None else str(row[k])
                     for k in ('sent', 'laser_sim_received', 'witness', 'bag')]
            lines.append(f'| {i} | `{topic}` | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--repeats', type=int, default=1)
    p.add_argument('--domain-id', type=int, default=77)
    p.add_argument('--out', type=Path, help='write the runs as JSON (and a .md table)')
    args = p.parse_args()
    runs = []
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            run = run_once(args.round_trips, args.domain_id, Path(tmp))
        runs.append(run)
        print(f'run {i + 1}: {run["rate"]} round trips/s over {run["seconds"]} s, bag state '
              f'gaps {run["state_gaps"]}, witness state first, last, gaps '
              f'{run["witness_state"]}, controller statuses the witness missed '
              f'{run["witness_status_missed"]} (after its first: '
              f'{run["witness_status_missed_after_its_first"]})', flush=True)
    print(table(runs))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(runs, indent=1) + '\n')
        args.out.with_suffix('.md').write_text(table(runs) + '\n')


if __name__ == '__main__':
    main()
