"""dlmpc-evaluate --resume: runs saved as they finish are kept, changed ones are rerun."""

import json

from dlmpc_ros.cli.evaluate import main as evaluate_main

ARGS = ['--fast', '--controller', 'passive', '--controller', 'fixed_best', '--seed', '1',
        '--workers', '1']


def test_resume_keeps_finished_runs_and_reruns_missing_or_changed_ones(tmp_path, capsys):
    out = tmp_path / 'eval'
    assert evaluate_main([*ARGS, '--round-trips', '300', '--out', str(out)]) == 0
    first = json.loads((out / 'metrics.json').read_text())
    (out / 'sinusoidal-s1-passive' / 'record.npz').write_bytes(b'PK\x03\x04cut')  # a kill
    capsys.readouterr()
    assert evaluate_main([*ARGS, '--round-trips', '300', '--resume', '--out', str(out)]) == 0
    assert '1 of 2 runs already in' in capsys.readouterr().out
    again = json.loads((out / 'metrics.json').read_text())
    assert [_measured(r) for r in again['runs']] == [_measured(r) for r in first['runs']]
    assert evaluate_main([*ARGS, '--round-trips', '400', '--resume', '--out', str(out)]) == 0
    assert '0 of 2 runs already in' in capsys.readouterr().out
    rerun = json.loads((out / 'sinusoidal-s1-fixed_best' / 'metrics.json').read_text())
    assert rerun['round_trips'] == 400


def _measured(run: dict) -> dict:
    """A run's metrics but its wall-clock latencies (the rerun one is timed anew)."""
    return {k: v for k, v in run['metrics'].items() if 'latency' not in k}
