"""dlmpc-bag: inspect, repair and export the bags that the recorder node writes.

``dlmpc-bag info DIR`` lists topics, counts and duration, and checks the round-trip index
of ``/laser/state`` (first, last, gaps, duplicates). ``dlmpc-bag repair DIR`` makes a bag
whose recorder was killed readable again. ``dlmpc-bag csv DIR OUT.csv`` writes the
``/laser/state`` rows joined by round trip with the K of ``/laser/sim_truth``, and the
``/controller/status`` decisions, in the bringup's CSV files (K is NaN without a
simulator); ``dlmpc-evaluate --bag DIR`` turns a bag into metrics and plots.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording.export import bag_to_csv
from dlmpc_ros.recording.reader import check_round_trips, read_bag, read_metadata
from dlmpc_ros.recording.repair import repair
from dlmpc_ros.recording.writer import BagError

#: Gaps listed one by one by ``info`` (the rest are counted).
SHOWN_GAPS = 10


def _time(ns: int) -> str:
    seconds, rest = divmod(ns, 1_000_000_000)
    text = time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime(seconds))
    return f'{text}.{rest // 1_000_000:03d} UTC ({ns / 1e9:.3f})'


def info(bag: Path) -> int:
    meta = read_metadata(bag)
    count = meta['message_count']
    print(f'bag:        {bag}, storage {meta["storage_identifier"]}, metadata version '
          f'{meta["version"]}, ros_distro {meta.get("ros_distro", "?")}')
    for entry in meta.get('files') or [{'path': p} for p in meta['relative_file_paths']]:
        path = bag / entry['path']
        size = f'{path.stat().st_size / 2**20:.2f} MiB' if path.is_file() else 'MISSING'
        counted = f', {entry["message_count"]} messages' if 'message_count' in entry else ''
        print(f'file:       {entry["path"]} ({size}{counted})')
    if count:
        start = meta['starting_time']['nanoseconds_since_epoch']
        duration = meta['duration']['nanoseconds']
        print(f'duration:   {duration / 1e9:.3f} s')
        print(f'start:      {_time(start)}')
        print(f'end:        {_time(start + duration)}')
    print(f'messages:   {count}')
    topics = [(t['topic_metadata']['name'], t['topic_metadata']['type'], t['message_count'])
              for t in meta['topics_with_message_count']]
    width = max((len(name) for name, _, _ in topics), default=0)
    print('topics:' + ('' if topics else '     none'))
    for name, msgtype, n in topics:
        print(f'  {name:<{width}}  {n:>9d}  {msgtype}')
    if itf.TOPIC_STATE in {name for name, _, _ in topics}:
        state = read_bag(bag, [itf.TOPIC_STATE])[itf.TOPIC_STATE]
        check = check_round_trips(state.data[:, 0])
        print(f'{itf.TOPIC_STATE} round trips: {_round_trip_summary(check)}')
        for start, end in check.gaps[:SHOWN_GAPS]:
            span = f'{start}' if start == end else f'{start}..{end}'
            print(f'  missing {span} ({end - start + 1})')
        if len(check.gaps) > SHOWN_GAPS:
            print(f'  ... and {len(check.gaps) - SHOWN_GAPS} more gaps')
    return 0


def _round_trip_summary(check) -> str:
    if not check.count:
        return 'none'
    text = f'{check.first} .. {check.last} in {check.count} messages'
    if check.contiguous:
        return text + ', contiguous'
    problems = []
    if check.gaps:
        problems.append(f'{check.missing} missing in {len(check.gaps)} gaps')
    if check.duplicates:
        problems.append(f'{check.duplicates} duplicates')
    if check.out_of_order:
        problems.append(f'{check.out_of_order} out of order')
    return f'{text}: ' + ', '.join(problems)


def repair_command(bag: Path) -> int:
    report = repair(bag)
    for file in report.files:
        count = sum(file.counts.values())
        if file.rewritten:
            print(f'{file.mcap}: unfinished; rewrote {count} messages from {file.chunks} '
                  f'complete chunks ({file.dropped_bytes} bytes at the end could not be read)')
        else:
            print(f'{file.mcap}: finished, {count} messages; nothing lost')
    for topic, n in report.counts.items():
        print(f'  {topic}  {n}')
    print(f'wrote {bag / "metadata.yaml"} ({len(report.files)} file'
          f'{"s" if len(report.files) > 1 else ""}, {report.message_count} messages)')
    return 0


def csv_command(bag: Path, out: Path) -> int:
    report = bag_to_csv(bag, out)
    print(f'wrote {report.rows} rows to {report.run_csv} (K known for {report.rows_with_k})')
    print(f'wrote {report.decisions} controller decisions to {report.decisions_csv} '
          f'(estimator latency known for {report.decisions_with_estimate})'
          f'{report.skipped_text()}')
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='dlmpc-bag', description=__doc__.split('\n\n')[0])
    sub = p.add_subparsers(dest='command', required=True)
    sub.add_parser('info', help='topics, counts, duration and round-trip gaps of a bag') \
        .add_argument('bag', type=Path, help='bag directory')
    sub.add_parser('repair', help='make a bag whose recorder was killed readable') \
        .add_argument('bag', type=Path, help='bag directory')
    export = sub.add_parser('csv',
                            help='the run (with the true K) and the decisions as CSV')
    export.add_argument('bag', type=Path, help='bag directory')
    export.add_argument('out', type=Path, help='CSV file to write')
    args = p.parse_args(argv)
    try:
        if args.command == 'info':
            return info(args.bag)
        if args.command == 'repair':
            return repair_command(args.bag)
        return csv_command(args.bag, args.out)
    except (BagError, OSError) as err:
        print(f'dlmpc-bag: {err}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
