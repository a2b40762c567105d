"""``dlmpc-train adapt``: calibrate the DL-MPC to a lab's laser from a bag of its own run.

A lab cannot run the simulator's sweep on its laser, but it can record the DL-MPC in its
exploring mode (``bringup --controller explore --record DIR``: the tracker as usual, and
every plan a random turn of the curve within the trust radius, taken back if O falls).
From ``/laser/state`` alone (E, M and the angles of every round trip; no K, no plant
parameter: a hardware laser has neither) this module

1. places every control period's angles on the rotated curve and its twin
   (:func:`~dlmpc_ros.control.rotation.locate`: curve point ``u``, rotation ``theta``);
2. pairs settled periods at the same point within ``window`` periods of each other
   (``u`` within ``same_point``; a period is settled when its angles are those of the
   period before), giving the inputs ``(u, theta_a, log E_a, log M_a, theta_b -
   theta_a)`` and the target ``log(O_b / O_a)`` of the steady-response predictor, as its
   own training pairs are (:mod:`dlmpc_ros.training.stages.response`);
3. fine-tunes every member of the shipped predictor on those pairs, with an L2 pull of
   ``prior_weight`` toward its shipped weights (the pretrained model is the prior, the
   laser corrects it);
4. takes, at each knot of the learned rotation, the rotation of the best settled state
   recorded near it (``prior_samples`` at least), as the rotation the controller starts
   from (``rotation_prior.npz``);

and writes a models folder that ``bringup --models-dir`` and ``dlmpc-evaluate
--models-dir`` run with: the shipped files, the adapted ``response.pt`` and the prior.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.rotation import locate
from dlmpc_ros.control.tracking import TrackingConfig
from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import save_checkpoint
from dlmpc_ros.learning.curve import FILE_NAME, load_curve
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.response import LOST, load_response
from dlmpc_ros.learning.rotation_prior import save_rotation_prior
from dlmpc_ros.recording.reader import read_bag


@dataclass(frozen=True)
class AdaptConfig:
    """Settings of the calibration (times in control periods)."""

    period: int = 10
    """Control period of the recorded run [round trips]."""
    round_trips: int = 0
    """Use the bag's first this many round trips (0: all)."""
    window: int = 12
    """Periods between the two states of a pair at most."""
    same_point: float = 0.01
    """Largest distance of the two states' curve points (K units)."""
    misfit: float = 0.05
    """Largest RMS distance [rad] of a state from the rotated curve family."""
    pulse_fraction: float = 0.3
    """A state holds a pulse when its O is at least this fraction of the bag's best."""
    epochs: int = 40
    lr: float = 5e-4
    prior_weight: float = 1e-2
    """Weight of the L2 pull toward the shipped weights (sum over parameters)."""
    prior_samples: int = 5
    """Settled states near a knot needed before the prior sets its rotation."""
    seed: int = 0

    def __post_init__(self) -> None:
        checks.counts(self, 'period', 'window', 'epochs', 'prior_samples')
        checks.counts(self, 'round_trips', 'seed', minimum=0)
        checks.positive(self, 'same_point')
        checks.positive(self, 'misfit')
        checks.positive(self, 'lr')
        checks.non_negative(self, 'prior_weight')
        checks.fraction(self, 'pulse_fraction')


def laser_periods(bag: Path, cfg: AdaptConfig) -> dict[str, np.ndarray]:
    """The bag's ``/laser/state`` at the end of every control period: ``round_trip``,
    ``E``, ``M`` (n,) and ``angles`` (n, 4)."""
    topic = read_bag(bag, [itf.TOPIC_STATE]).get(itf.TOPIC_STATE)
    if topic is None or not len(topic):
        raise FileNotFoundError(f'{bag} has no {itf.TOPIC_STATE} messages to calibrate from')
    data = topic.data
    round_trip = data[:, 0]
    keep = np.isfinite(data[:, :12]).all(axis=1) & (round_trip % cfg.period == 0)
    if cfg.round_trips:
        keep &= round_trip <= cfg.round_trips
    data = data[keep][np.argsort(round_trip[keep], kind='stable')]
    return {'round_trip': data[:, 0], 'E': data[:, 1], 'M': data[:, 2],
            'angles': data[:, 6:10]}


def laser_pairs(periods: dict[str, np.ndarray], grid: np.ndarray, curve: np.ndarray,
                cfg: AdaptConfig) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Training pairs (inputs (m, 5), targets (m,)) of the recorded run, and its settled
    states on the curve family (``u``, ``theta``, ``O``)."""
    branch, u, theta, misfit = locate(periods['angles'], grid, curve)
    objective = periods['E'] / periods['M']
    settled = np.r_[False, np.all(np.abs(np.diff(periods['angles'], axis=0)) < 1e-9, axis=1)]
    pulse = objective >= cfg.pulse_fraction * np.max(objective)
    good = settled & pulse & (misfit <= cfg.misfit)
    index = np.flatnonzero(good)
    x, y = [], []
    for a in index:
        later = index[(index > a) & (index <= a + cfg.window)]
        later = later[(branch[later] == branch[a])
                      & (np.abs(u[later] - u[a]) <= cfg.same_point)]
        for b in later:
            x.append((u[a], theta[a], np.log(periods['E'][a]), np.log(periods['M'][a]),
                      theta[b] - theta[a]))
            y.append(max(float(np.log(objective[b] / objective[a])), LOST))
    states = {'u': u[good], 'theta': theta[good], 'O': objective[good]}
    return np.asarray(x, float).reshape(-1, 5), np.asarray(y, float), states


def rotation_prior(states: dict[str, np.ndarray], knots: np.ndarray, cfg: AdaptConfig
                   ) -> np.ndarray:
    """The rotation (knots,) [rad] of the best settled state near each knot (0 where
    fewer than ``prior_samples`` were recorded)."""
    half = 0.5 * float(knots[1] - knots[0])
    values = np.zeros(knots.size)
    for i, knot in enumerate(knots):
        near = np.abs(states['u'] - knot) <= half
        if near.sum() >= cfg.prior_samples:
            values[i] = states['theta'][near][np.argmax(states['O'][near])]
    return values


def adapt_models(bag: Path, models_dir: Path, out: Path, cfg: AdaptConfig | None = None,
                 show_progress: bool = True) -> dict:
    """Calibrate the models of ``models_dir`` to the laser of ``bag``; writes ``out``."""
    cfg = cfg or AdaptConfig()
    started = time.monotonic()
    bag, models_dir, out = Path(bag), Path(models_dir), Path(out)
    grid, curve, _ = load_curve(models_dir / FILE_NAME)
    model, payload = load_response(models_dir / 'response.pt')
    periods = laser_periods(bag, cfg)
    x, y, states = laser_pairs(periods, grid, curve, cfg)
    if y.size == 0:
        raise ValueError(f'{bag} holds no pairs of settled states on the tracking curve to '
                         'calibrate from; record a run of `bringup --controller explore`')
    prior = [p.detach().clone() for p in model.parameters()]
    samples = torch.as_tensor(np.c_[x, y], dtype=torch.float32)
    generator = torch.Generator().manual_seed(cfg.seed)
    before = _rmse(model, x, y)
    for m, member in enumerate(model.members):
        own = list(member.parameters())
        start = [prior[i] for i, p in enumerate(model.parameters())
                 if any(p is q for q in own)]

        def loss_fn(batch: torch.Tensor, _g, member=member, own=own, start=start):
            z = (batch[:, :-1] - model.mean) / model.std
            fit_loss = torch.mean((member(z)[:, 0] - batch[:, -1]) ** 2)
            pull = sum(torch.sum((p - p0) ** 2) for p, p0 in zip(own, start))
            return fit_loss + cfg.prior_weight * pull, {}
        pick = torch.randint(samples.shape[0], (samples.shape[0],), generator=generator)
        fit(member, loss_fn, samples[pick], cfg.epochs, batch=256, lr=cfg.lr,
            seed=cfg.seed + m, desc=f'adapt member {m + 1}', show_progress=show_progress)
    model.eval()
    after = _rmse(model, x, y)
    knots = np.linspace(grid[0], grid[-1], TrackingConfig().rotation_knots)
    values = rotation_prior(states, knots, cfg)
    if out.resolve() != models_dir.resolve():
        shutil.copytree(models_dir, out, dirs_exist_ok=True)
    report = {'bag': str(bag.resolve()), 'models_dir': str(models_dir.resolve()),
              'round_trips_used': int(periods['round_trip'][-1]) if periods['round_trip'].size
              else 0, 'control_periods': int(periods['round_trip'].size),
              'settled_states': int(states['u'].size), 'pairs': int(y.size),
              'rmse_before': before, 'rmse_after': after,
              'prior_knots_set': int(np.count_nonzero(values)), 'settings': asdict(cfg),
              'wall_seconds': round(time.monotonic() - started, 1)}
    metrics = {**payload.get('metrics', {}), 'adapted': report}
    save_checkpoint(out / 'response.pt', 'response', model.state_dict(), payload['config'],
                    metrics, payload.get('data_fingerprint', ''))
    save_rotation_prior(out, knots, values, report)
    (out / 'adapt.json').write_text(json.dumps(report, indent=2))
    return report


def _rmse(model, x: np.ndarray, y: np.ndarray) -> float:
    with torch.no_grad():
        predicted = model(torch.as_tensor(x, dtype=torch.float32)).mean(-1).numpy()
    return float(np.sqrt(np.mean((predicted - y) ** 2)))
