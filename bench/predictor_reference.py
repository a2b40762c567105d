"""Reference predictors for the MP-RNN target: how far below persistence can anything get?

Trains a plain GRU encoder-decoder on exactly the MP-RNN's windows (same trajectories,
same training lanes, same validation/test split of the held-out lanes, same loss on the
states plus 400 x the objective's squared error, predictions fed back over the horizon,
cosine learning rate). Two variants:

- ``measured``: the history's features only, as the MP-RNN sees them;
- ``true K``: the same plus the true K of every history row, a privileged input no
  deployed predictor has. If this one does no better, the remaining error is not for
  lack of knowing K.

The decoder adds its output to the last state (it starts from persistence). Writes the
O RMSE relative to persistence at horizons 1..N as JSON and a markdown table.

Usage::

    python bench/predictor_reference.py --data-dir data --models-dir models \\
        --out bench/results/predictor_reference.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[1]


class GRUPredictor(nn.Module):
    """GRU over the history rows (B, H, 10 [+1]); GRU cell over the horizon with the
    future controls (B, N, 4); returns normalized states (B, N, 2)."""

    def __init__(self, n_in: int, hidden: int) -> None:
        super().__init__()
        self.encoder = nn.GRU(n_in, hidden, batch_first=True)
        self.decoder = nn.GRUCell(2 + 8, hidden)
        self.out = nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 2))

    def forward(self, history: torch.Tensor, states_now: torch.Tensor,
                future_u: torch.Tensor) -> torch.Tensor:
        from dlmpc_ros.learning.features import angle_features

        _, h = self.encoder(history)
        h, v = h[0], states_now
        controls = angle_features(future_u)                            # (B, N, 8)
        out = []
        for j in range(future_u.shape[1]):
            h = self.decoder(torch.cat([v, controls[:, j]], dim=-1), h)
            v = v + self.out(h)
            out.append(v)
        return torch.stack(out, dim=1)


def inputs(data, idx: torch.Tensor, true_k: torch.Tensor | None):
    """History features (with the true K appended when given), batch and states now."""
    batch = data.batch(idx)
    history = batch.history
    if true_k is not None:
        lane, t = data.index[idx, 0:1], data.index[idx, 1:2]
        rows = t + torch.arange(-data.history_len + 1, 1)
        history = torch.cat([history, true_k[lane, rows][..., None]], dim=-1)
    return history, batch


@torch.no_grad()
def o_ratio(model: GRUPredictor, data, norm, true_k) -> np.ndarray:
    """O RMSE of the model over persistence's, per horizon (N,)."""
    n = data.config.horizon
    model_sq, persist_sq = torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.float64)
    for start in range(0, len(data), 1024):
        history, batch = inputs(data, torch.arange(start, min(start + 1024, len(data))), true_k)
        states_now = batch.history[:, -1, :2]
        pred = model(history, states_now, batch.future_u)
        o_true = norm.objective(batch.future_x[..., :2])
        model_sq += ((norm.objective(pred) - o_true) ** 2).sum(0).double()
        persist_sq += ((norm.objective(states_now[:, None]) - o_true) ** 2).sum(0).double()
    return (model_sq / persist_sq).sqrt().numpy()


def train_reference(sets: dict, true_k: dict | None, norm, hidden: int, epochs: int,
                    seed: int, batch_size: int = 256, lr: float = 1e-3) -> dict:
    """Train on ``sets['train']``; O ratios on 'val' and 'test'. ``true_k``: per set, the
    true K (lanes, T) of its lanes, or None for the measured-only variant."""
    from tqdm import tqdm

    torch.manual_seed(seed)
    train = sets['train']
    k_of = (lambda name: true_k[name]) if true_k is not None else (lambda name: None)
    n_in = train.feats.shape[-1] + (1 if true_k is not None else 0)
    model = GRUPredictor(n_in, hidden)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    per_epoch = len(train) // batch_size
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * per_epoch)
    gen = torch.Generator().manual_seed(seed)
    history = []
    for _ in tqdm(range(epochs), desc='GRU' + (' + true K' if true_k is not None else ''),
                  unit='epoch'):
        order = torch.randperm(len(train), generator=gen)
        model.train()
        for step in range(per_epoch):
            hist, batch = inputs(train, order[step * batch_size:(step + 1) * batch_size],
                                 k_of('train'))
            pred = model(hist, batch.history[:, -1, :2], batch.future_u)
            v_true = batch.future_x[..., :2]
            loss = (((pred - v_true) ** 2).sum((1, 2))
                    + 400.0 * ((norm.objective(pred) - norm.objective(v_true)) ** 2).sum(1))
            opt.zero_grad()
            loss.mean().backward()
            nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            schedule.step()
        model.eval()
        history.append(float(o_ratio(model, sets['val'], norm, k_of('val'))[-1]))
    return {'validation_h10_per_epoch': history,
            'validation_ratio': o_ratio(model, sets['val'], norm, k_of('val')).tolist(),
            'test_ratio': o_ratio(model, sets['test'], norm, k_of('test')).tolist()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--data-dir', type=Path, default=ROOT / 'data')
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--hidden', type=int, default=128)
    p.add_argument('--epochs', type=int, default=8)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--extra-trajectories', type=Path, nargs='*', default=[],
                   help='more training lanes, as the MP-RNN stage takes them '
                        '(e.g. data/trajectories_extra)')
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)

    from dlmpc_ros.learning.features import measurements
    from dlmpc_ros.learning.mprnn import MPRNNConfig
    from dlmpc_ros.learning.vae import load_vae
    from dlmpc_ros.training.stages.mprnn import split_held_out, surrogate_series
    from dlmpc_ros.training.trajectories import load_trajectories
    from dlmpc_ros.training.windows import WindowDataset
    from dlmpc_ros.training.workspace import Workspace

    ws = Workspace(args.data_dir, args.models_dir)
    traj = load_trajectories(ws.trajectories)
    vae, _ = load_vae(ws.model('vae'))
    measured = measurements(traj)
    val_lanes, test_lanes = split_held_out(traj['held_out'])  # as in the MP-RNN stage
    config = MPRNNConfig(norm=vae.config.normalizer)
    train_lanes = np.flatnonzero(~traj['held_out'])
    parts = {'train': [(measured[train_lanes], traj['K'][train_lanes])],
             'val': [(measured[val_lanes], traj['K'][val_lanes])],
             'test': [(measured[test_lanes], traj['K'][test_lanes])]}
    for directory in args.extra_trajectories:
        extra = load_trajectories(directory)
        lanes = ~extra['held_out']
        parts['train'].append((measurements(extra)[lanes], extra['K'][lanes]))
    sets, k_of = {}, {}
    for name, pieces in parts.items():
        lane_measured = np.concatenate([m for m, _ in pieces])
        sets[name] = WindowDataset(lane_measured, surrogate_series(vae, lane_measured), config,
                                   stride=5 if name == 'val' else 1)
        k_of[name] = torch.as_tensor(np.concatenate([k for _, k in pieces]),
                                     dtype=torch.float32) * 10.0  # O(1) like the features
    results = {'settings': {**{k: str(v) if isinstance(v, Path) else v
                               for k, v in vars(args).items()},
                            'extra_trajectories': [str(d) for d in args.extra_trajectories],
                            'train_trajectories': int(sets['train'].feats.shape[0])}}
    for name, privileged in (('measured', False), ('true K', True)):
        started = time.monotonic()
        r = train_reference(sets, k_of if privileged else None, config.normalizer,
                            args.hidden, args.epochs, args.seed)
        results[name] = {**r, 'wall_seconds': round(time.monotonic() - started, 1)}
        print(f"{name}: test O error / persistence at horizon 10 = {r['test_ratio'][-1]:.3f}",
              flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    lines = ['# Reference predictors for the MP-RNN target', '',
             '`python bench/predictor_reference.py` (GRU encoder-decoder, hidden '
             f'{args.hidden}, {args.epochs} epochs, seed {args.seed}; the MP-RNN\'s windows, '
             f"split and loss; {results['settings']['train_trajectories']} training lanes). "
             'O RMSE relative to persistence on the test lanes.', '',
             '| inputs | h1 | h5 | h10 | validation h10 | wall s |', '|---|---|---|---|---|---|']
    for name in ('measured', 'true K'):
        r = results[name]
        t = r['test_ratio']
        lines.append(f"| {name} | {t[0]:.3f} | {t[4]:.3f} | {t[-1]:.3f} | "
                     f"{r['validation_ratio'][-1]:.3f} | {r['wall_seconds']:.0f} |")
    args.out.with_suffix('.md').write_text('\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
