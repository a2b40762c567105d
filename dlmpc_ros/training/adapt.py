"""``dlmpc-train adapt``: calibrate the DL-MPC to a lab's laser from a bag of its own run.

A lab cannot run the simulator's sweep on its laser, but it can record the DL-MPC in its
exploring mode (``bringup --controller explore --record DIR``: the tracker as usual, and
every plan a random turn of the curve within the trust radius, taken back if O falls).
From ``/laser/state`` alone (E, M and the angles of every round trip; no K, no plant
parameter: a hardware laser has neither) this module

1. places every control period's angles on the rotated curve and its twin
   (:func:`~dlmpc_ros.learning.curve.locate`: curve point ``u``, rotation ``theta``);
2. pairs settled periods at the same point within ``window`` periods of each other
   (``u`` within ``same_point``; a period is settled when its angles are those of the
   period before), giving the inputs ``(u, theta_a, log E_a, log M_a, theta_b -
   theta_a)`` and the target ``log(O_b / O_a)`` of the steady-response predictor, as its
   own training pairs are (:mod:`dlmpc_ros.training.stages.response`);
3. fits what the shipped predictor gets wrong on this laser, the correction ``a + b * d +
   c * |d|`` of its predicted change of log O in the turn ``d`` that the planner also
   learns online (:class:`~dlmpc_ros.control.rotation_planner.OnlineCorrection`), to the
   pairs of the run's first ``1 - validation`` share of periods, and keeps it
   (``turn_correction.npz``: the planner starts from it) only where it predicts the pairs
   of the last ``validation`` share (held out, later in the run) better than no
   correction (else no such file: the planner starts as shipped);
   with ``fine_tune``, it also fine-tunes every member of the predictor on those pairs,
   with an L2 pull of ``prior_weight`` toward its shipped weights, keeping each member at
   the epoch that predicts the held-out pairs best (off by default: the fine-tuned
   predictor predicted the held-out pairs better and planned worse,
   ``bench/results/calibration/``);
4. at each knot of the learned rotation, bins the settled states recorded near it by
   rotation (``prior_bin`` wide) and takes the bin of the highest mean O as the rotation
   the controller starts from (``rotation_prior.npz``), only where it beats the bin of
   the shipped rotation (0) by ``prior_margin`` and both hold ``prior_samples`` states
   (else 0: no evidence that a turn pays there);
5. with ``estimator`` (off by default), learns this laser's own estimator and
   K-to-angles map from its windows of measurements, without labels
   (:mod:`~dlmpc_ros.training.adapt_estimator`);

and writes a models folder that ``bringup --models-dir`` and ``dlmpc-evaluate
--models-dir`` run with: the shipped files, ``response.pt`` (adapted with ``fine_tune``),
the correction, the prior (and with ``estimator`` the laser's ``vae.pt``, ``vae_encoder.*``
and ``kmap.pt``).
"""

from __future__ import annotations

import copy
import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import MEASUREMENT_ROUND_TRIPS
from dlmpc_ros.control.rotation_planner import OnlineCorrection
from dlmpc_ros.control.tracking import ROTATION_KNOTS
from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import save_checkpoint
from dlmpc_ros.learning.curve import FILE_NAME, load_curve, locate
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.response import ResponseEnsemble
from dlmpc_ros.learning.response_file import load_response
from dlmpc_ros.learning.rotation_prior import save_rotation_prior
from dlmpc_ros.learning.turn_correction import FILE_NAME as CORRECTION_FILE
from dlmpc_ros.learning.turn_correction import save_turn_correction
from dlmpc_ros.recording.reader import read_bag
from dlmpc_ros.training.adapt_estimator import EstimatorAdaptConfig, calibrate_estimator
from dlmpc_ros.training.response import LOST


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
    fine_tune: bool = False
    """Also fine-tune the predictor's members on the laser's pairs (measured to plan worse
    on held-out plants; the correction alone is the default)."""
    ridge: float = 1.0
    """Ridge weight (toward 0) of the correction's least-squares fit."""
    epochs: int = 40
    lr: float = 5e-4
    prior_weight: float = 1e-2
    """Weight of the L2 pull toward the shipped weights (sum over parameters)."""
    validation: float = 0.25
    """Share of the run's periods (its last ones) whose pairs are held out of the
    fine-tune and choose each member's epoch."""
    prior_samples: int = 5
    """Settled states a rotation bin near a knot needs before the prior compares it."""
    prior_bin: float = 0.05
    """Width of the rotation bins of the prior [rad]."""
    prior_margin: float = 0.02
    """Least relative gain of mean O of a bin over the shipped rotation's bin."""
    estimator: EstimatorAdaptConfig | None = None
    """Learn this laser's own estimator and map (:mod:`~dlmpc_ros.training.adapt_estimator`;
    None, the default: the shipped ones, which measured better in closed loop,
    ``bench/results/laser_estimator.md``)."""
    measurement_round_trips: int = MEASUREMENT_ROUND_TRIPS
    """Round trips a period's measurement averages, as the controller's parameter."""
    seed: int = 0

    def __post_init__(self) -> None:
        checks.counts(self, 'period', 'window', 'epochs', 'prior_samples',
                      'measurement_round_trips')
        checks.counts(self, 'round_trips', 'seed', minimum=0)
        checks.positive(self, 'same_point')
        checks.positive(self, 'misfit')
        checks.positive(self, 'lr')
        checks.positive(self, 'ridge')
        checks.non_negative(self, 'prior_weight')
        checks.fraction(self, 'pulse_fraction')
        if not 0 < self.validation < 1:
            raise ValueError(f'validation must be in (0, 1), got {self.validation}')
        checks.positive(self, 'prior_bin')
        checks.non_negative(self, 'prior_margin')


def laser_states(bag: Path, cfg: AdaptConfig) -> np.ndarray:
    """The bag's ``/laser/state`` messages (n, 10) up to round trip ``cfg.round_trips``."""
    topic = read_bag(bag, [itf.TOPIC_STATE]).get(itf.TOPIC_STATE)
    if topic is None or not len(topic):
        raise FileNotFoundError(f'{bag} has no {itf.TOPIC_STATE} messages to calibrate from')
    data = topic.data
    return data[data[:, 0] <= cfg.round_trips] if cfg.round_trips else data


def laser_periods(states: np.ndarray, cfg: AdaptConfig) -> dict[str, np.ndarray]:
    """The ``/laser/state`` messages ``states`` (n, 10) at the end of every control
    period: ``round_trip``, ``E``, ``M`` (n,) and ``angles`` (n, 4)."""
    round_trip = states[:, 0]
    keep = np.isfinite(states[:, :12]).all(axis=1) & (round_trip % cfg.period == 0)
    data = states[keep][np.argsort(round_trip[keep], kind='stable')]
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
    """The rotation (knots,) [rad] of the best-averaging rotation bin near each knot, where
    it beats the bin of rotation 0 by ``prior_margin`` (else 0)."""
    half = 0.5 * float(knots[1] - knots[0])
    values = np.zeros(knots.size)
    for i, knot in enumerate(knots):
        near = np.abs(states['u'] - knot) <= half
        bins = np.round(states['theta'][near] / cfg.prior_bin).astype(int)
        objective = states['O'][near]
        means = {b: objective[bins == b].mean() for b in np.unique(bins)
                 if np.count_nonzero(bins == b) >= cfg.prior_samples}
        if 0 not in means or len(means) < 2:
            continue
        best = max(means, key=means.get)
        if means[best] > (1 + cfg.prior_margin) * means[0]:
            values[i] = float(np.mean(states['theta'][near][bins == best]))
    return values


def split_periods(periods: dict[str, np.ndarray], validation: float
                  ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The run's periods before and after its last ``validation`` share (in time)."""
    cut = int(round((1 - validation) * periods['round_trip'].size))
    return ({k: v[:cut] for k, v in periods.items()},
            {k: v[cut:] for k, v in periods.items()})


def adapt_models(bag: Path, models_dir: Path, out: Path, cfg: AdaptConfig | None = None,
                 show_progress: bool = True) -> dict:
    """Calibrate the models of ``models_dir`` to the laser of ``bag``; writes ``out``."""
    cfg = cfg or AdaptConfig()
    started = time.monotonic()
    bag, models_dir, out = Path(bag), Path(models_dir), Path(out)
    grid, curve, _ = load_curve(models_dir / FILE_NAME)
    model, payload = load_response(models_dir / 'response.pt')
    states_bag = laser_states(bag, cfg)
    periods = laser_periods(states_bag, cfg)
    _, _, states = laser_pairs(periods, grid, curve, cfg)
    train, held_out = split_periods(periods, cfg.validation)
    x, y, _ = laser_pairs(train, grid, curve, cfg)
    x_val, y_val, _ = laser_pairs(held_out, grid, curve, cfg)
    if y.size == 0 or y_val.size == 0:
        raise ValueError(f'{bag} holds too few pairs of settled states on the tracking curve '
                         f'to calibrate from ({y.size} to fit, {y_val.size} held out); record '
                         'a longer run of `bringup --controller explore`')
    before, before_val = prediction_rmse(model, x, y), prediction_rmse(model, x_val, y_val)
    coefficients, corrected_val = turn_correction(model, x, y, x_val, y_val, cfg)
    if cfg.fine_tune:
        epochs_kept = fine_tune(model, x, y, x_val, y_val, cfg, show_progress)
        after, after_val = prediction_rmse(model, x, y), prediction_rmse(model, x_val, y_val)
    else:  # the shipped predictor, unchanged
        epochs_kept, after, after_val = [0] * len(model.members), before, before_val
    knots = np.linspace(grid[0], grid[-1], ROTATION_KNOTS)
    values = rotation_prior(states, knots, cfg)
    if out.resolve() != models_dir.resolve():
        shutil.copytree(models_dir, out, dirs_exist_ok=True)
    estimator = ({'kept': False, 'why': 'not asked for'} if cfg.estimator is None
                 else calibrate_estimator(
                     states_bag, out, cfg.estimator, period=cfg.period,
                     round_trips=cfg.measurement_round_trips,
                     pulse_fraction=cfg.pulse_fraction, validation=cfg.validation,
                     seed=cfg.seed, show_progress=show_progress))
    report = {'bag': str(bag.resolve()), 'models_dir': str(models_dir.resolve()),
              'round_trips_used': int(periods['round_trip'][-1]) if periods['round_trip'].size
              else 0, 'control_periods': int(periods['round_trip'].size),
              'settled_states': int(states['u'].size), 'pairs': int(y.size),
              'held_out_pairs': int(y_val.size), 'rmse_before': before, 'rmse_after': after,
              'held_out_rmse_before': before_val, 'held_out_rmse_after': after_val,
              'epochs_kept': epochs_kept, 'correction': coefficients.tolist(),
              'held_out_rmse_corrected': corrected_val,
              'prior_knots_set': int(np.count_nonzero(values)), 'estimator': estimator,
              'settings': asdict(cfg), 'wall_seconds': round(time.monotonic() - started, 1)}
    metrics = {**payload.get('metrics', {}), 'adapted': report}
    save_checkpoint(out / 'response.pt', 'response', model.state_dict(), payload['config'],
                    metrics, payload.get('data_fingerprint', ''))
    save_rotation_prior(out, knots, values, report)
    (out / CORRECTION_FILE).unlink(missing_ok=True)  # none kept: the planner's own start
    if np.any(coefficients):
        save_turn_correction(out, coefficients, report)
    (out / 'adapt.json').write_text(json.dumps(report, indent=2))
    return report


def turn_correction(model: ResponseEnsemble, x: np.ndarray, y: np.ndarray,
                    x_val: np.ndarray, y_val: np.ndarray, cfg: AdaptConfig
                    ) -> tuple[np.ndarray, float]:
    """The correction (3,) of ``model``'s predicted change of log O in the turn, fit to
    pairs ``x`` (m, 5), ``y`` (m,) as the planner fits it online (all of them, ridge
    ``cfg.ridge``), and the RMSE of the corrected prediction on the held-out pairs; zeros
    (and the uncorrected RMSE) when it does not predict them better than no correction."""
    errors = y - _predict(model, x)
    correction = OnlineCorrection(max(len(y), 1), ridge=cfg.ridge)
    correction.extend(x[:, 4], errors)
    held_out = y_val - _predict(model, x_val)
    uncorrected = float(np.sqrt(np.mean(held_out ** 2)))
    corrected = float(np.sqrt(np.mean((held_out - correction(x_val[:, 4])) ** 2)))
    if not corrected < uncorrected:
        return np.zeros_like(correction.coefficients), uncorrected
    return correction.coefficients, corrected


def fine_tune(model: ResponseEnsemble, x: np.ndarray, y: np.ndarray, x_val: np.ndarray,
              y_val: np.ndarray, cfg: AdaptConfig, show_progress: bool = True) -> list[int]:
    """Fine-tune each member of ``model`` in place on pairs ``x`` (m, 5), ``y`` (m,) with an
    L2 pull toward its current weights; keep it at the epoch with the least error on the
    held-out pairs (epoch 0: its weights before). Returns the epoch kept per member."""
    prior = [p.detach().clone() for p in model.parameters()]
    samples = torch.as_tensor(np.c_[x, y], dtype=torch.float32)
    held = (torch.as_tensor((x_val - model.mean.numpy()) / model.std.numpy(),
                            dtype=torch.float32), torch.as_tensor(y_val, dtype=torch.float32))
    generator = torch.Generator().manual_seed(cfg.seed)
    epochs_kept = []
    for m, member in enumerate(model.members):
        own = list(member.parameters())
        start = [prior[i] for i, p in enumerate(model.parameters())
                 if any(p is q for q in own)]
        best = {'error': _member_error(member, held), 'epoch': 0,
                'state': copy.deepcopy(member.state_dict())}

        def keep_best(epoch: int, _loss: float, member=member, best=best) -> None:
            error = _member_error(member, held)
            if error < best['error']:
                best.update(error=error, epoch=epoch + 1,
                            state=copy.deepcopy(member.state_dict()))

        def loss_fn(batch: torch.Tensor, _g, member=member, own=own, start=start):
            z = (batch[:, :-1] - model.mean) / model.std
            fit_loss = torch.mean((member(z)[:, 0] - batch[:, -1]) ** 2)
            pull = sum(torch.sum((p - p0) ** 2) for p, p0 in zip(own, start))
            return fit_loss + cfg.prior_weight * pull, {}
        pick = torch.randint(samples.shape[0], (samples.shape[0],), generator=generator)
        fit(member, loss_fn, samples[pick], cfg.epochs, batch=256, lr=cfg.lr,
            seed=cfg.seed + m, on_epoch=keep_best, desc=f'adapt member {m + 1}',
            show_progress=show_progress)
        member.load_state_dict(best['state'])
        epochs_kept.append(best['epoch'])
    model.eval()
    return epochs_kept


def _member_error(member: torch.nn.Module, held: tuple[torch.Tensor, torch.Tensor]
                  ) -> float:
    """Mean squared error of one member on the held-out pairs (normalized inputs)."""
    was_training = member.training
    member.eval()
    with torch.no_grad():
        error = float(torch.mean((member(held[0])[:, 0] - held[1]) ** 2))
    member.train(was_training)
    return error


def _predict(model, x: np.ndarray) -> np.ndarray:
    """The ensemble's mean predicted change of log O (m,) for pairs ``x`` (m, 5)."""
    with torch.no_grad():
        return model(torch.as_tensor(x, dtype=torch.float32)).mean(-1).numpy().astype(float)


def prediction_rmse(model, x: np.ndarray, y: np.ndarray) -> float:
    """RMSE of the ensemble's mean predicted change of log O on pairs ``x`` (m, 5), ``y``
    (m,)."""
    return float(np.sqrt(np.mean((_predict(model, x) - y) ** 2)))
