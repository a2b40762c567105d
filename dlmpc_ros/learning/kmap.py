"""The K-to-angles map (paper section 3C): a small fully connected network from the K
surrogate to good angles.

Training pairs follow the paper's subset rule: the surrogate range is cut into equal
intervals, and within +-delta of each interval's centre the steady state with the
highest objective gives the target angles. Where neighbouring intervals' best angles lie
on different branches, a network fit through them would average incompatible settings;
so among each interval's top candidates the chosen sequence maximizes the summed O minus
a penalty on the angle jump between neighbours (a small dynamic program). The network
predicts ``(sin 2 alpha, cos 2 alpha)`` (pi-periodic angles without a wrap-around), fit
with Adam on the L2 loss.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from dlmpc_ros.learning.features import angle_features, angles_from_features


@dataclass
class KMapConfig:
    hidden: int = 64
    layers: int = 3

    def to_dict(self) -> dict:
        return asdict(self)


class KMap(nn.Module):
    """Surrogate (..., 1) -> angles (..., 4) in radians, in [-pi/2, pi/2)."""

    def __init__(self, config: KMapConfig) -> None:
        super().__init__()
        self.config = config
        sizes = [1] + [config.hidden] * (config.layers - 1)
        blocks: list[nn.Module] = []
        for a, b in zip(sizes[:-1], sizes[1:]):
            blocks += [nn.Linear(a, b), nn.ReLU()]
        self.net = nn.Sequential(*blocks, nn.Linear(sizes[-1], 8))

    def features(self, s: torch.Tensor) -> torch.Tensor:
        """(..., 8) predicted sin/cos features."""
        return self.net(s)

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return angles_from_features(self.features(s))


@dataclass(frozen=True)
class SubsetRule:
    """The interval subset rule; ``delta`` as a multiple of the interval width."""

    intervals: int = 61
    delta: float = 0.75
    top: int = 5
    jump_penalty: float = 0.02
    low_quantile: float = 0.005


def training_subset(surrogate: np.ndarray, objective: np.ndarray, angles: np.ndarray,
                    rule: SubsetRule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pick (surrogate centre, angles, O) per interval; returns (n,), (n, 4), (n,)."""
    lo, hi = np.quantile(surrogate, [rule.low_quantile, 1 - rule.low_quantile])
    centres = np.linspace(lo, hi, rule.intervals)
    half = rule.delta * (hi - lo) / (rule.intervals - 1)
    cand_o, cand_a, keep = [], [], []
    for i, c in enumerate(centres):
        rows = np.flatnonzero(np.abs(surrogate - c) <= half)
        if rows.size == 0:
            continue
        best = rows[np.argsort(objective[rows])[::-1][:rule.top]]
        cand_o.append(objective[best])
        cand_a.append(angles[best])
        keep.append(i)
    # Dynamic program over intervals: maximize sum O - penalty * |feature jump|.
    feats = [np.concatenate([np.sin(2 * a), np.cos(2 * a)], axis=-1) for a in cand_a]
    score = [cand_o[0].copy()]
    back: list[np.ndarray] = []
    for j in range(1, len(cand_o)):
        jump = np.linalg.norm(feats[j][:, None, :] - feats[j - 1][None, :, :], axis=-1)
        total = score[-1][None, :] - rule.jump_penalty * jump  # (now, previous)
        back.append(total.argmax(axis=1))
        score.append(cand_o[j] + total.max(axis=1))
    pick = [int(np.argmax(score[-1]))]
    for j in range(len(cand_o) - 1, 0, -1):
        pick.append(int(back[j - 1][pick[-1]]))
    pick.reverse()
    chosen_a = np.stack([cand_a[j][p] for j, p in enumerate(pick)])
    chosen_o = np.array([cand_o[j][p] for j, p in enumerate(pick)])
    return centres[keep], chosen_a, chosen_o


def train_kmap(centres: np.ndarray, targets: np.ndarray, config: KMapConfig, seed: int = 0,
               steps: int = 3000, lr: float = 3e-3) -> tuple[KMap, list[float]]:
    """Fit the map to (surrogate, angles) pairs with Adam on the L2 loss of the features."""
    torch.manual_seed(seed)
    model = KMap(config)
    s = torch.as_tensor(centres, dtype=torch.float32)[:, None]
    y = angle_features(torch.as_tensor(targets, dtype=torch.float32))
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    for _ in range(steps):
        optimizer.zero_grad()
        loss = 0.5 * ((model.features(s) - y) ** 2).sum(dim=-1).mean()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    return model, losses
