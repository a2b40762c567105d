import json

import pytest

from dlmpc_ros.cli.sim import main


def test_dlmpc_sim_prints_json_rows_and_summary(capsys):
    assert main(['--round-trips', '6', '--every', '2', '-K', '0.1']) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [row['round_trip'] for row in lines[:-1]] == [2, 4, 6]
    assert {'round_trip', 'E', 'M', 'O', 'energy', 'peak'} <= set(lines[0])
    assert lines[-1] == {'converged': False, 'round_trips': 6, 'finite': True}


def test_dlmpc_sim_until_steady(capsys):
    assert main(['--round-trips', '500', '--every', '1000', '--until-steady']) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert lines[-1]['converged'] is True and lines[-1]['round_trips'] < 500
    assert lines[-2]['round_trip'] == lines[-1]['round_trips']


def test_dlmpc_sim_runs_every_requested_round_trip_past_steady_state(capsys):
    # this laser is steady after a few hundred round trips; without --until-steady the
    # command still prints all of them (it used to stop at the first steady one)
    assert main(['--round-trips', '1000']) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [row['round_trip'] for row in lines[:-1]] == list(range(1, 1001))
    assert lines[-1] == {'converged': True, 'round_trips': 1000, 'finite': True}


def test_dlmpc_sim_rejects_bad_parameters(capsys):
    with pytest.raises(SystemExit) as err:
        main(['--points', '4'])
    assert err.value.code == 2
    assert 'points must be >= 16' in capsys.readouterr().err


def test_each_scheme_brings_its_own_steps_unless_given():
    from dlmpc_ros.cli.sim import parse_args
    assert parse_args([]).config.steps == 6                          # richardson4
    assert parse_args(['--scheme', 'strang']).config.steps == 32
    assert parse_args(['--scheme', 'strang', '--steps-per-round-trip', '8']).config.steps == 8
