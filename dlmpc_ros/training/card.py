"""models/MODEL_CARD.md: how the shipped models were made and what they measured."""

from __future__ import annotations

import json
from pathlib import Path

from dlmpc_ros.training.workspace import Workspace

TARGETS = {
    'vae': ('abs_pearson_r_heldout', '>= 0.95',
            'absolute Pearson r of surrogate vs true K, held-out'),
    'kmap': ('oracle_ratio_test_k', '>= 0.90',
             'steady O at the map\'s angles / O*(K), mean over the 30 test K, surrogate '
             'read at the oracle\'s state (whose angles carry K)'),
}
#: Figures shown beside the targets (stage, key, what).
EXTRA_ROWS = (('kmap', 'oracle_ratio_from_median_state',
               'same over all 61 K, surrogate read at the sweep\'s median state for each K'),)


def _data_meta(ws: Workspace) -> dict:
    out = {}
    for name, directory in (('sweep', ws.sweep), ('trajectories', ws.trajectories),
                            ('trajectories_extra', ws.extra_trajectories),
                            ('response', ws.response)):
        meta = directory / 'metadata.json'
        if meta.exists():
            out[name] = json.loads(meta.read_text())
    oracle_meta = ws.oracle.with_suffix('.json')
    if oracle_meta.exists():
        out['oracle'] = json.loads(oracle_meta.read_text())
    return out


#: How each dataset's line of the card begins (a dataset absent from the data directory
#: keeps its line from the card as it was: a stage trained alone keeps the others' notes).
DATA_LINES = {'sweep': '- steady-state sweep:', 'oracle': '- oracle envelope:',
              'trajectories': '- trajectories:',
              'trajectories_extra': '- trajectories_extra', 'response': '- response data:'}


def _previous_data_lines(path: Path) -> dict[str, str]:
    """The dataset lines of an existing card, by dataset."""
    if not path.exists():
        return {}
    lines = path.read_text().splitlines()
    return {name: line for name, start in DATA_LINES.items() for line in lines
            if line.startswith(start)}


def write_model_card(ws: Workspace) -> Path:
    """Write ``models/MODEL_CARD.md`` from ``models/metrics.json`` and the datasets' notes."""
    metrics = json.loads(ws.metrics.read_text()) if ws.metrics.exists() else {}
    data = _data_meta(ws)
    path = ws.models_dir / 'MODEL_CARD.md'
    previous = _previous_data_lines(path)
    lines = ['# dlmpc_ros model card', '',
             'Made by `dlmpc-data all` then `dlmpc-train all` (seed 0) on a 2-core CPU '
             'machine; `make models` runs both. Files load with `torch.load(weights_only=True)` '
             '(no code is executed); each holds its state_dict, config, metrics, data '
             'fingerprint and schema version.', '']
    lines += ['## Data', '']
    if 'sweep' in data:
        s = data['sweep']
        lines.append(f"- steady-state sweep: {s.get('samples')} samples, converged fraction "
                     f"{s.get('converged_fraction', float('nan')):.3f}, "
                     f"{s.get('round_trips_total')} round trips, fingerprint "
                     f"{s.get('fingerprint')}; settings {json.dumps(s['settings']['sweep'])}")
        cavity = s['settings'].get('cavity', {})
        if 'scheme' in cavity:
            lines.append(f"- solver of all the data: {cavity['scheme']}, "
                         f"{cavity['steps_per_round_trip']} steps per round trip "
                         '(`docs/solver.md`)')
    if 'oracle' in data:
        o = data['oracle']
        lines.append(f"- oracle envelope: {o['k_points']} K values, mean O* "
                     f"{o['mean_O_star']:.4f}, mean gain over the sweep's best "
                     f"{100 * o['mean_gain_over_sweep_best']:.1f} %, largest gain of random "
                     f"probes at 2x the final step "
                     f"{100 * o['max_gain_of_random_probes_at_2x_min_step']:.2f} %")
    if 'trajectories' in data:
        t = data['trajectories']
        lines.append(f"- trajectories: settings {json.dumps(t['settings']['trajectories'])}")
    if 'trajectories_extra' in data:
        t = data['trajectories_extra']
        lines.append('- trajectories_extra (training lanes for the MP-RNN only): settings '
                     f"{json.dumps(t['settings']['trajectories'])}")
    if 'response' in data:
        r = data['response']
        cfg = r['settings']['response']
        lines.append(f"- response data: {r.get('samples')} steady states of "
                     f"{cfg['plants']} plants of the family (seeds {cfg['first_seed']} to "
                     f"{cfg['first_seed'] + cfg['plants'] - 1}), the curve turned both ways at "
                     f"K {cfg['k_values']}, fingerprint {r.get('fingerprint')}; settings "
                     f"{json.dumps(cfg)}")
    made = {name for name, start in DATA_LINES.items()
            if any(line.startswith(start) for line in lines)}
    lines += [line for name, line in previous.items() if name not in made]
    lines += ['', '## Models and measurements', '', '| model | figure | measured | target |',
              '|---|---|---|---|']
    for stage, (key, target, what) in TARGETS.items():
        if stage in metrics:
            lines.append(f'| {stage} | {what} | {metrics[stage][key]:.3f} | {target} |')
    for stage, key, what in EXTRA_ROWS:
        if key in metrics.get(stage, {}):
            lines.append(f'| {stage} | {what} | {metrics[stage][key]:.3f} | |')
    if 'response' in metrics:
        r = metrics['response']
        lines.append(f"| response | RMSE of the predicted change of log O, plants held out "
                     f"of its data (pulse kept) | {r['heldout_rmse_where_kept']:.3f} | |")
        lines.append(f"| response | one-step plans on those plants: share of the best "
                     f"turn's gain within {r['fit']['plan_radius']} rad "
                     f"({r['heldout_plans']['plans_that_lose_the_pulse']} of "
                     f"{r['heldout_plans']['plans']} lose the pulse) | "
                     f"{r['heldout_plans']['share_of_best_gain']:.3f} | |")
        if r.get('closed_loop', {}).get('rmse', {}).get('held_out_plants') is not None:
            c = r['closed_loop']
            seeds = c['held_out_plants']
            lines.append(f"| response | RMSE of the predicted change of log O on the exploring "
                         f"DL-MPC's own pairs, family plants {seeds[0]}-{seeds[-1]} held out "
                         f"of its {c['pairs']} closed-loop pairs (rotation data alone: "
                         f"{c['rmse_pretrained']['held_out_plants']:.3f}) | "
                         f"{c['rmse']['held_out_plants']:.3f} | |")
    if 'mprnn' in metrics:
        m = metrics['mprnn']
        ratio = m['rmse_O_model'][-1] / m['rmse_O_persistence'][-1]
        lines.append(f'| mprnn | O prediction RMSE at horizon {len(m["rmse_O_model"])} / '
                     f'persistence, held-out | {ratio:.3f} | <= 0.5 |')
        lines += ['', 'How low the predictor target can go on this data: a plain GRU '
                  'encoder-decoder trained on the same windows, from the measurements and '
                  'also given the true K, `bench/predictor_reference.py` (recorded in '
                  '`bench/results/predictor_reference_64.md` and `_192.md`, for 64 and 192 '
                  'training lanes); training variants of the MP-RNN: '
                  '`bench/results/mprnn_variants.md`.']
    lines += ['', 'Where the VAE surrogate gets its information from (the angles, or E and M), '
              'and how much of K one measurement holds (supervised probes, for comparison): '
              '`dlmpc-train check-estimator --out DIR`; for the shipped models it is recorded '
              'in `docs/results/estimator-check/`.']
    if 'curve' in metrics:
        c = metrics['curve']
        lines += ['', f"The DL-MPC's tracking curve `track_curve.npz` ({c['points']} points, mean "
                  f"steady O {c['mean_objective']:.4f}) is the refined tracking path of "
                  '`oracle.npz` as a curve of angles over an estimate axis; `dlmpc-train '
                  'curve` remakes it from the shipped `oracle.npz`.']
    if 'drl' in metrics:
        lines += drl_lines(metrics['drl'])
    lines += ['', '## Full metrics', '', '```json', json.dumps(
        {k: {kk: vv for kk, vv in v.items() if not kk.startswith('per_k') and kk != 'curve'}
         for k, v in metrics.items()}, indent=1, default=float)[:20000], '```', '']
    path.write_text('\n'.join(lines))
    return path


def drl_lines(m: dict) -> list[str]:
    """The deep-RL baseline's section of the card (``dlmpc-train drl``)."""
    c, machine = m['config'], m['machine']
    settings = c.get(m['algorithm'], {})
    conditions = ', '.join(f"{x['scenario']} from {x['initial']} x {x['lanes']}"
                           for x in c['conditions'])
    load = (f"; load average {machine['load_average_1min_before']:.1f} before and "
            f"{machine['load_average_1min']:.1f} after, this job adding about 1: more is "
            'other jobs sharing the cores' if 'load_average_1min_before' in machine else '')
    note = f" {m['note']}" if m.get('note') else ''
    made = (f"Made by `dlmpc-train drl --seed {m['seed']}` (`make models` runs it after "
            f"`all`): Stable-Baselines3 {machine.get('stable-baselines3')} "
            f"{m['algorithm'].upper()} on `ModeLockedLaser-v0`'s vector env, {m['steps']:,} env "
            'steps (control periods of 10 round trips, all lanes together) in '
            f"{m['wall_seconds'] / 60:.1f} minutes ({m['steps_per_second']:.0f} steps/s) on one "
            f"core of this machine ({machine['cpu_count']} cores, {machine['processor']}, torch "
            f"{machine.get('torch')} with 1 thread, {machine['platform']}{load}); seed "
            f"{m['seed']}.{note}")
    lines = ['', '## Deep-RL baseline (`drl_policy.npz` + `.json`)', '',
             f"{made} Lanes: {conditions}; a family plant drawn per reset (domain "
             'randomization; held-out plants 101-108 never drawn), episodes of '
             f"{c['episode_periods']} periods, solver {json.dumps(c['solver'])} (the default "
             f"grid, fewer split steps), reward the measured O x {c['reward_scale']:g}, "
             f"observation the env's window of {c['features']['window']} periods of (E, M, "
             'angles) through fixed features (`learning/policy.py`), action the change of the '
             f"angles in [-1, 1] x 0.25 rad. Network {c['net']}; settings "
             f"{json.dumps(settings)}. The SB3 archive (pickles) is not kept: the policy "
             "network's weights are plain arrays, read back without pickles and run in numpy "
             "(largest difference from SB3's deterministic action on random observations "
             f"{m['export_max_difference']:.1e}).", '',
             f"![reward curve]({m['figure']})", '',
             'Development episodes on the default cavity after training '
             f"({m['development_seconds']:.0f} s; one episode of {c['episode_periods']} periods "
             'per lane, beside holding the start angles):', '',
             '| episodes | lanes | policy mean O | policy O / O* | hold mean O | hold O / O* |',
             '|---|---|---|---|---|---|']
    for name, d in m['development'].items():
        lines.append(f"| {name.replace('_', ' ')} | {d['lanes']} | {d['policy_mean_O']:.4f} | "
                     f"{d['policy_O_over_O_star']:.3f} | {d['hold_mean_O']:.4f} | "
                     f"{d['hold_O_over_O_star']:.3f} |")
    return lines
