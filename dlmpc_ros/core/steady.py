"""Run a batch of lasers until each meets the steady-state rule (or a round-trip cap)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dlmpc_ros.core.cavity import Cavity


@dataclass(frozen=True)
class SteadyResult:
    """Per laser (B,): observables at convergence (or at the cap), and how it ended.

    ``E, M, O, energy, peak`` are NaN where the field blew up.
    """

    E: np.ndarray
    M: np.ndarray
    O: np.ndarray  # noqa: E741
    energy: np.ndarray
    peak: np.ndarray
    pulses: np.ndarray
    converged: np.ndarray
    finite: np.ndarray
    round_trips: np.ndarray


def run_to_steady(cavity: Cavity, max_round_trips: int = 300, chunk: int = 10) -> SteadyResult:
    """Advance ``cavity`` until every laser converged (checked every ``chunk`` round trips
    on the last round trip of the chunk), blew up, or ran ``max_round_trips``.

    Lasers that finished early keep being simulated with the others (one kernel call per
    chunk), but their recorded values are those at the round trip where they finished.
    """
    batch = cavity.batch
    out = {name: np.full(batch, np.nan) for name in ('E', 'M', 'O', 'energy', 'peak')}
    pulses = np.full(batch, -1, np.int64)
    converged = np.zeros(batch, bool)
    finite = np.ones(batch, bool)
    used = np.zeros(batch, np.int64)
    done = np.zeros(batch, bool)
    ran = 0
    while not done.all() and ran < max_round_trips:
        step = min(chunk, max_round_trips - ran)
        last = cavity.run(step).last()
        ran += step
        finish = ~done & (last.converged | ~last.finite | (ran >= max_round_trips))
        for name in out:
            out[name][finish] = getattr(last, name)[finish]
        pulses[finish] = last.pulses[finish]
        converged[finish] = last.converged[finish]
        finite[finish] = last.finite[finish]
        used[finish] = ran
        done |= finish
    return SteadyResult(pulses=pulses, converged=converged, finite=finite, round_trips=used,
                        **out)
