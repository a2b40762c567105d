"""Where ``dlmpc-data`` writes the datasets and ``dlmpc-train`` reads them and writes the
models (a data directory and a models directory)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Workspace:
    """The data and models directories of one training run."""

    data_dir: Path = Path('data')
    """Datasets of ``dlmpc-data`` (not shipped)."""
    models_dir: Path = Path('models')
    """Model files, tables, metrics and figures of ``dlmpc-train`` (shipped)."""

    @property
    def sweep(self) -> Path:
        return self.data_dir / 'sweep'

    @property
    def oracle(self) -> Path:
        """The oracle envelope of the data (``dlmpc-data oracle``)."""
        return self.data_dir / 'oracle.npz'

    @property
    def trajectories(self) -> Path:
        return self.data_dir / 'trajectories'

    @property
    def extra_trajectories(self) -> Path:
        """More training lanes for the predictor only (see ``dlmpc-data trajectories``)."""
        return self.data_dir / 'trajectories_extra'

    @property
    def response(self) -> Path:
        """The rotation data of the plant family (``dlmpc-train response``)."""
        return self.data_dir / 'response'

    @property
    def response_closed_loop(self) -> Path:
        """The exploring DL-MPC's runs on training plants (``dlmpc-train response``)."""
        return self.data_dir / 'response_closed_loop'

    def model(self, kind: str) -> Path:
        return self.models_dir / f'{kind}.pt'

    @property
    def baselines(self) -> Path:
        """The baseline tables (``dlmpc-train baselines``)."""
        return self.models_dir / 'oracle.npz'

    @property
    def figures(self) -> Path:
        return self.models_dir / 'figures'

    @property
    def metrics(self) -> Path:
        return self.models_dir / 'metrics.json'

    def write_metrics(self, stage: str, metrics: dict) -> Path:
        """Put one stage's metrics into ``models/metrics.json`` (the others are kept)."""
        existing = json.loads(self.metrics.read_text()) if self.metrics.exists() else {}
        existing[stage] = metrics
        self.metrics.parent.mkdir(parents=True, exist_ok=True)
        self.metrics.write_text(json.dumps(existing, indent=2, default=float))
        return self.metrics
