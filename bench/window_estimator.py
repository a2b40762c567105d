"""Does a window of closed-loop measurements under the tracker's dither tell K, and can the
VAE learn that without K labels?

Runs the shipped DL-MPC in closed loop (fast mode) on the nominal cavity and on training
plants of the family (seeds 2001 and up: the response data's plants, never the held-out
101-108), on a sinusoid and a random walk (drift seed 11: no evaluation seed), and cuts
every window of ``--window`` control periods during which it tracked the curve. On those
windows it measures, against the true K (used for the scores only):

- the tracker's own estimate (the hand-made rule);
- supervised probes (small networks trained *with* K labels: a ceiling, not a method)
  from the last angles, the last measurement and the whole window;
- the package's conditional VAE (:class:`~dlmpc_ros.learning.vae.ConditionalVAE`) of
  that window length, trained on the windows without labels: its surrogate (the latent
  coordinate ``dlmpc-train vae``'s rule picks without labels,
  :func:`~dlmpc_ros.training.stages.vae.smoothest_used`) and, as a bound, the best linear
  read-out of its whole latent fit with K.

Three splits: across plants (every fifth run's plant held out), the nominal cavity alone
(its runs split in time), and each plant alone (a VAE per plant on the first 70 % of its
runs' windows, scored on the rest: what a lab gets from its own laser's data). Writes
JSON and prints a markdown table (the recorded one, with what it says, is
``bench/results/window_estimator.md``)::

    python bench/window_estimator.py --plants 9 --out bench/results/window_estimator.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.scaleout import default_workers, run_tasks

ROOT = Path(__file__).resolve().parents[1]
TRACKING_MODES = ('track', 'plan')


def closed_loop_run(job: tuple[int, str]) -> dict:
    """Per control period of one DL-MPC run: the measurement rows (C, 6), K, the tracker's
    estimate and the mode (plant seed 0: the nominal cavity)."""
    from dlmpc_ros.control.dlmpc_config import DLMPCConfig
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.control.step import AngleLimits
    from dlmpc_ros.control.step import MODES
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.training.envelope import PlantTask, draw_task
    plant_seed, scenario = job
    models = ROOT / 'models'
    plant = (draw_task(PlantTask(str(models / 'oracle.npz'), seed=plant_seed))['plant']
             if plant_seed else {})
    spec = RunSpec(scenario, 11, 'dlmpc', round_trips=20000, plant=plant)
    record = run_fast(spec, models, load_dlmpc(models, DLMPCConfig(
        limits=AngleLimits(max_step=spec.max_step))))
    i = np.searchsorted(record.round_trip, record.control_round_trip)
    tracking = np.isin(record.mode, [MODES.index(m) for m in TRACKING_MODES])
    rows = np.column_stack([record.E[i], record.M[i], record.angles[i]])
    return {'plant': plant_seed, 'rows': rows, 'K': record.K[i],
            'estimate': record.surrogate, 'tracking': tracking & np.isfinite(rows).all(1)
            & (rows[:, 0] > 0)}


def cut_windows(runs: list[dict], window: int) -> dict[str, np.ndarray]:
    """Every window of ``window`` tracked periods: rows (B, w, 6), K and estimate at its
    last period, run index and the control period it ends at."""
    out: dict[str, list] = {'rows': [], 'K': [], 'estimate': [], 'run': [], 'period': []}
    for r, run in enumerate(runs):
        ok = np.convolve(run['tracking'], np.ones(window), 'valid') == window  # all tracked
        for t in np.flatnonzero(ok) + window - 1:
            out['rows'].append(run['rows'][t - window + 1:t + 1])
            out['K'].append(run['K'][t])
            out['estimate'].append(run['estimate'][t])
            out['run'].append(r)
            out['period'].append(t)
    return {k: np.asarray(v) for k, v in out.items()}


def abs_r(a: np.ndarray, b: np.ndarray) -> float:
    return float(abs(np.corrcoef(a, b)[0, 1]))


def probe(x: np.ndarray, k: np.ndarray, train: np.ndarray, seed: int) -> float:
    """|r| on the test windows of a small network trained on the train windows with K."""
    import torch
    from torch import nn

    from dlmpc_ros.learning.fit import fit
    mean, std = x[train].mean(0), x[train].std(0) + 1e-9
    data = np.column_stack([(x - mean) / std, k]).astype(np.float32)
    torch.manual_seed(seed)
    net = nn.Sequential(nn.Linear(x.shape[1], 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(),
                        nn.Linear(64, 1))

    def loss(batch, _generator):
        return ((net(batch[:, :-1])[:, 0] - batch[:, -1]) ** 2).mean(), {}
    fit(net, loss, data[train], epochs=30, batch=256, seed=seed, show_progress=False)
    with torch.no_grad():
        predicted = net(torch.from_numpy(data[~train, :-1]))[:, 0].numpy()
    return abs_r(predicted, k[~train])


def window_vae(rows: np.ndarray, k: np.ndarray, run: np.ndarray, period: np.ndarray,
               train: np.ndarray, epochs: int, seed: int) -> dict:
    """The conditional VAE on the train windows (no labels); |r| of its surrogate and of
    the best linear read-out of its latent on the test windows."""
    import torch

    from dlmpc_ros.learning.features import Normalizer
    from dlmpc_ros.learning.fit import fit
    from dlmpc_ros.learning.vae import ConditionalVAE, VAEConfig
    from dlmpc_ros.training.stages.vae import label_free_choice
    norm = Normalizer.fit(rows[train][..., 0], rows[train][..., 1])
    model = ConditionalVAE(VAEConfig(window=rows.shape[1], latent=3, conditional=True,
                                     beta=0.05, normalizer=norm.to_dict()),
                           generator=torch.Generator().manual_seed(seed))
    history = fit(model, model.loss, rows[train], epochs, seed=seed, show_progress=False)
    with torch.no_grad():
        mu, logvar = (v.numpy() for v in model.encode(torch.as_tensor(rows, dtype=torch.float32)))
    # the label-free choice of dlmpc-train vae, over consecutive training windows
    rows_train = np.flatnonzero(train)
    following = ((np.diff(rows_train) == 1) & (np.diff(run[train]) == 0)
                 & (np.diff(period[train]) == 1))
    dim, _ = label_free_choice(mu[train], logvar[train], following)
    design = np.column_stack([mu, np.ones(len(mu))])
    coef = np.linalg.lstsq(design[train], k[train], rcond=None)[0]
    return {'surrogate_dim': dim, 'surrogate_abs_r': abs_r(mu[~train, dim], k[~train]),
            'per_latent_abs_r': [abs_r(mu[~train, d], k[~train]) for d in range(mu.shape[1])],
            'linear_readout_abs_r': abs_r(design[~train] @ coef, k[~train]),
            'final_loss': history[-1]}


def scores(w: dict[str, np.ndarray], train: np.ndarray, epochs: int, seed: int) -> dict:
    import torch

    from dlmpc_ros.learning.features import Normalizer, features
    rows, k = w['rows'], w['K']
    x = features(torch.as_tensor(rows, dtype=torch.float32), Normalizer()).numpy()  # (B, w, 10)
    return {
        'windows_train': int(train.sum()), 'windows_test': int((~train).sum()),
        'tracker_estimate_abs_r': abs_r(w['estimate'][~train], k[~train]),
        'probe_last_angles_abs_r': probe(x[:, -1, 2:], k, train, seed),
        'probe_last_measurement_abs_r': probe(x[:, -1], k, train, seed),
        'probe_window_abs_r': probe(x.reshape(len(x), -1), k, train, seed),
        'vae': window_vae(rows, k, w['run'], w['period'], train, epochs, seed),
    }


def per_plant(w: dict[str, np.ndarray], plant: np.ndarray, epochs: int, seed: int) -> dict:
    """|r| of the tracker's estimate and of a window VAE trained on each plant's own early
    windows, on that plant's later windows; per plant and their median."""
    rows = {}
    for p in np.unique(plant):
        own = {k: v[plant == p] for k, v in w.items()}
        train = _early(own['run'], np.arange(len(own['run'])), 0.7)
        vae = window_vae(own['rows'], own['K'], own['run'], own['period'], train, epochs, seed)
        rows[int(p)] = {'windows_train': int(train.sum()), 'windows_test': int((~train).sum()),
                        'tracker_estimate_abs_r': abs_r(own['estimate'][~train],
                                                        own['K'][~train]),
                        'vae_surrogate_abs_r': vae['surrogate_abs_r'],
                        'vae_linear_readout_abs_r': vae['linear_readout_abs_r']}
    median = {key: float(np.median([r[key] for r in rows.values()]))
              for key in ('tracker_estimate_abs_r', 'vae_surrogate_abs_r',
                          'vae_linear_readout_abs_r')}
    return {'plants': rows, 'median': median}


def table(results: dict) -> str:
    lines = ['| split | windows (train / test) | tracker estimate | probe: last angles | '
             'probe: last measurement | probe: window | window VAE surrogate | window VAE, '
             'best linear read-out |', '|---' * 8 + '|']
    for split, s in results.items():
        if 'plants' in s:
            continue
        v = s['vae']
        lines.append(f'| {split} | {s["windows_train"]} / {s["windows_test"]} | '
                     f'{s["tracker_estimate_abs_r"]:.2f} | {s["probe_last_angles_abs_r"]:.2f} | '
                     f'{s["probe_last_measurement_abs_r"]:.2f} | {s["probe_window_abs_r"]:.2f} | '
                     f'{v["surrogate_abs_r"]:.2f} | {v["linear_readout_abs_r"]:.2f} |')
    for split, s in results.items():
        if 'plants' not in s:
            continue
        lines += ['', f'{split}:', '', '| plant | windows (train / test) | tracker estimate | '
                  'window VAE surrogate | window VAE, best linear read-out |', '|---' * 5 + '|']
        for p, r in s['plants'].items():
            lines.append(f'| {p or "nominal"} | {r["windows_train"]} / {r["windows_test"]} | '
                         f'{r["tracker_estimate_abs_r"]:.2f} | {r["vae_surrogate_abs_r"]:.2f} | '
                         f'{r["vae_linear_readout_abs_r"]:.2f} |')
        m = s['median']
        lines.append(f'| median | | {m["tracker_estimate_abs_r"]:.2f} | '
                     f'{m["vae_surrogate_abs_r"]:.2f} | {m["vae_linear_readout_abs_r"]:.2f} |')
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--plants', type=int, default=9, help='family plants 2001, 2002, ...')
    p.add_argument('--window', type=int, default=12, help='control periods per window')
    p.add_argument('--epochs', type=int, default=60)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--workers', type=int, default=default_workers())
    p.add_argument('--out', type=Path, default=ROOT / 'bench/results/window_estimator.json')
    args = p.parse_args(argv)
    started = time.monotonic()
    plants = [0] + list(range(2001, 2001 + args.plants))
    jobs = [(plant, scenario) for plant in plants for scenario in ('sinusoidal', 'random_walk')]
    runs = run_tasks(closed_loop_run, jobs, args.workers, desc='closed-loop runs')
    w = cut_windows(runs, args.window)
    across = np.array([runs[r]['plant'] for r in w['run']])
    held_plants = plants[2::5]
    nominal = across == 0
    nominal_windows = {k: v[nominal] for k, v in w.items()}
    position = np.arange(nominal.sum())
    results = {
        f'across plants (plants {held_plants} held out)':
            scores(w, ~np.isin(across, held_plants), args.epochs, args.seed),
        'nominal cavity alone (last 30 % of each run held out)':
            scores(nominal_windows, _early(nominal_windows['run'], position, 0.7),
                   args.epochs, args.seed),
    }
    results['each plant alone (last 30 % of its runs held out)'] = per_plant(
        w, across, args.epochs, args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'window': args.window, 'plants': plants,
                                    'epochs': args.epochs, 'results': results,
                                    'wall_seconds': round(time.monotonic() - started)},
                                   indent=1))
    print(table(results))
    return 0


def _early(run: np.ndarray, position: np.ndarray, fraction: float) -> np.ndarray:
    """True for the first ``fraction`` of each run's windows."""
    keep = np.zeros(len(run), bool)
    for r in np.unique(run):
        idx = position[run == r]
        keep[idx[:int(fraction * len(idx))]] = True
    return keep


if __name__ == '__main__':
    raise SystemExit(main())
