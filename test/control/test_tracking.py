"""Curve tracking: entry, extremum seeking along the curve, the guard."""

from dataclasses import replace

import numpy as np
import pytest

from dlmpc_ros.control.dlmpc import DLMPCController
from dlmpc_ros.control.dlmpc_config import DLMPCConfig, TrackingConfig
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.control import tracking
from dlmpc_ros.control.tracking import (COOLDOWN, TRACKER_TRANSITIONS, TURN_PERIODS, CurveTracker,
                                       TrackerState, TurnEvent)
from dlmpc_ros.core.symmetry import QUARTER_TURN

from test.control.toy_curve import ANGLES, GRID

#: ``entry_trial_after`` that never comes: tests of other turns leave the entry trial out
NEVER = 1_000_000  # the largest the setting takes



def _objective(angles: np.ndarray, k: float) -> float:
    """A toy laser on the curve: O peaks at s = k and falls off quadratically."""
    return 0.2 - 0.3 * (angles[0] / 2 - k) ** 2


def _drive(tracker: CurveTracker, k_of_period, periods: int, start_o: float = 0.2):
    """Feed the tracker the toy O of its own commands; (estimates, commands or None)."""
    o, estimates, commands = start_o, [], []
    for t in range(periods):
        cmd = tracker.step(o)
        commands.append(cmd)
        estimates.append(tracker.estimate if tracker.active else np.nan)
        o = _objective(cmd, k_of_period(t)) if cmd is not None else start_o
    return np.array(estimates), commands


def test_tracker_enters_after_the_lock_patience_at_its_start_point():
    cfg = TrackingConfig(entry_patience=5, start=-0.1)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    assert all(tracker.step(0.2) is None for _ in range(4))
    first = tracker.step(0.2)
    assert first is not None and tracker.active
    np.testing.assert_allclose(first, tracker.curve(-0.1 + cfg.dither))
    # an unlocked period restarts the count
    other = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    for o in (0.2, 0.2, 0.05, 0.2, 0.2, 0.2, 0.2):
        assert other.step(o) is None


def test_estimate_climbs_to_the_peak_and_follows_a_drifting_one():
    cfg = TrackingConfig(entry_patience=1, settle=0, step=0.01)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    est, _ = _drive(tracker, lambda t: 0.15, 400)
    assert abs(np.nanmean(est[-60:]) - 0.15) < 0.03          # from -0.1 up to 0.15
    drift = lambda t: 0.15 * np.sin(2 * np.pi * t / 2000)     # noqa: E731
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    est, _ = _drive(tracker, drift, 3000)
    truth = np.array([drift(t) for t in range(3000)])
    late = slice(500, None)
    assert np.nanmax(np.abs(est[late] - truth[late])) < 0.1
    assert np.nanmean(np.abs(est[late] - truth[late])) < 0.03
    assert np.corrcoef(est[late], truth[late])[0, 1] > 0.95


def test_a_block_is_judged_by_the_o_of_its_last_period():
    pattern = (0.2, 0.2, 0.3)                       # period by period, one block long
    cfg = TrackingConfig(entry_patience=1, settle=0, block=3)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    for t in range(60):
        tracker.step(pattern[t % 3])
    assert any(tracker._branch_best == pytest.approx(v) for v in (0.2, 0.3))
    assert not tracker._branch_best == pytest.approx(0.7 / 3)  # not the block's mean


def test_flat_objective_inside_the_deadband_leaves_the_estimate_alone():
    cfg = TrackingConfig(entry_patience=1, settle=0)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    o = 0.2
    for _ in range(100):
        tracker.step(o)
        o = 0.2 + 1e-6  # changes far below the deadband
    assert tracker.estimate == pytest.approx(cfg.start)


def test_the_noise_deadband_reads_the_noise_off_the_run_and_holds_the_estimate_at_the_peak():
    """A noisy toy laser (1.4 % on O per period) at its peak: judging the dither against
    the noise it measured keeps the estimate nearer the peak than the fixed deadband;
    without noise it tracks as before."""
    def run(noise_deadband: float, noise: float, seed: int, k: float = -0.1):
        rng = np.random.default_rng(seed)
        cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1,
                             noise_deadband=noise_deadband)
        planned: list[float] = []
        planner = _NoisePlanner(planned)
        tracker = CurveTracker(GRID, ANGLES, threshold=0.05, config=cfg, planner=planner)
        planner.tracker = tracker
        o, estimates = 0.2 - (0.1 + k) ** 2, []
        for _ in range(2000):
            command = tracker.step(o)
            o = (0.2 - (command[0] / 2 - k) ** 2) * (1 + noise * rng.standard_normal())
            estimates.append(tracker.estimate)
        assert planned and not any(planned)  # the planner is told the noise it reads
        return np.array(estimates[500:]), tracker

    fixed = np.mean([np.mean(np.abs(run(0.0, 0.014, s)[0] + 0.1)) for s in range(3)])
    aware = np.mean([np.mean(np.abs(run(1.0, 0.014, s)[0] + 0.1)) for s in range(3)])
    assert aware < 0.8 * fixed, (aware, fixed)
    _, tracker = run(1.0, 0.014, 0)
    assert 0.011 < tracker.dither.noise() < 0.017  # one period's 1.4 %
    assert 0.01 < tracker.dither.deadband() < 0.03  # about 1.4 % x sqrt(1.5)
    quiet, tracker = run(1.0, 0.0, 0, k=0.0)  # no noise: climbs from -0.1 to the peak
    assert abs(np.mean(quiet[-300:])) < 0.02
    assert tracker.dither.deadband() < 1e-3 and tracker.dither.noise() < 1e-3


def test_a_failed_entry_hands_back_and_waits_a_growing_cooldown_later_the_guard_is_off():
    cfg = TrackingConfig(entry_patience=2, settle=4, guard=0.9, guard_periods=2,
                         block=2, start=0.0)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    _drive(tracker, lambda t: 0.0, 40)
    assert tracker.active
    tracker.estimate = 0.25                       # as if K had jumped away from it
    assert all(tracker.step(0.15) is not None for _ in range(10))  # 0.15 < 0.9 x 0.2
    assert tracker.active and tracker.estimate != pytest.approx(0.0)  # past the entry: on
    tracker.interrupt()                           # the scan takes over; a new entry
    for _ in range(COOLDOWN * 2 + cfg.entry_patience):
        if tracker.active:
            break
        tracker.step(0.2)
    assert tracker.active
    for _ in range(cfg.settle + 2):
        last = tracker.step(0.15)                 # poor right after this entry
    assert last is None and not tracker.active    # handed back
    assert sum(tracker.step(0.2) is not None for _ in range(COOLDOWN)) == 0
    # The failed entry doubled the cooldown for the next failure.
    assert tracker._cooldown == 2 * COOLDOWN


def test_after_a_failed_entry_the_tracker_enters_again_where_it_left_the_angles():
    """The hold after a failed entry keeps the curve point the tracker left at; the next
    entry at those held angles starts there, not at the start point (only the run's first
    entry does)."""
    cfg = TrackingConfig(entry_patience=2, settle=4, guard=0.9, guard_periods=2,
                         block=2, start=0.0)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    for _ in range(cfg.entry_patience):
        tracker.step(0.2)
    assert tracker.active and tracker.estimate == pytest.approx(0.0)  # the first: at start
    tracker.estimate = 0.25                       # as if the dither had taken it there
    for _ in range(cfg.settle + 2 * cfg.block):
        held = tracker.step(0.15)                 # 0.15 < 0.9 x 0.2: the entry fails
        if not tracker.active:
            break
    left = tracker.estimate
    assert not tracker.active and held is None and left == pytest.approx(0.25, abs=0.05)
    for _ in range(4 * COOLDOWN):                 # the angles held; the laser stays locked
        if tracker.step(0.2) is not None:
            break
    assert tracker.active and tracker.estimate == pytest.approx(left)


class _NoisePlanner:
    """A planner that never turns and records the noise it is told less the tracker's."""

    def __init__(self, told: list[float]) -> None:
        self.told, self.tracker, self.undone = told, None, 0

    def plan(self, u: float, theta: float, noise: float = 0.0, at_least: float = 0.0) -> float:
        self.told.append(noise - self.tracker.dither.noise())
        return 0.0

    def retract(self) -> float:
        return 0.0


def test_interrupt_stops_tracking():
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1,
                           config=TrackingConfig(entry_patience=1))
    assert tracker.step(0.2) is not None
    tracker.interrupt()
    assert not tracker.active
    assert [tracker.step(0.2) is None for _ in range(COOLDOWN + 1)] == [True] * COOLDOWN + [False]


def _mirrored_objective(cmd: np.ndarray, k: float, angles: np.ndarray = ANGLES,
                        curvature: float = 0.6) -> float:
    """A toy laser with the cavity's mirror symmetry: the curve c is best for K < 0, its
    twin c(-s) + pi/2 (all four angles a quarter turn on) for K > 0. Half-way round
    costs O (nothing at K = 0, where turning is a symmetry): a little on one side of the
    circle, and on the other, which side depending on K's sign, the pulse once |K| is past
    0.1 (as on the simulator)."""
    theta = cmd[1] - angles[0, 1]                 # how far all four are turned
    u = (cmd[0] - theta) / 2                      # the curve point that was turned

    def on_curve(s: float, kk: float) -> float:
        return 0.2 - curvature * (s - kk) ** 2 - 0.1 * max(kk, 0.0)
    w = np.sin(theta) ** 2                        # 0 on the curve, 1 on the twin
    mixed = (1 - w) * on_curve(u, k) + w * on_curve(u, -k)
    wrong_way = k * (np.mod(theta, np.pi) - np.pi / 2) < 0
    cost = 30.0 * max(abs(k) - 0.1, 0.0) if wrong_way else k ** 2  # free near K = 0
    return mixed * max(1 - cost * np.sin(2 * theta) ** 2, 0.0)


def _drive_mirrored(tracker: CurveTracker, k_of_period, periods: int,
                    angles: np.ndarray = ANGLES, curvature: float = 0.6,
                    states: list | None = None):
    """Feed the tracker the mirrored toy's O and the angles it ran with; (O, commands,
    branch) per period (and its state after each period into ``states``)."""
    o, current, objectives, commands, branch = 0.2, None, [], [], []
    for t in range(periods):
        cmd = tracker.step(o, current)
        if states is not None:
            states.append(tracker.state)
        if cmd is not None:  # through the servo limits, as the supervisor sends it
            current = tracker.limits.apply(cmd if current is None else current, cmd)
            cmd = current
            o = _mirrored_objective(cmd, k_of_period(t), angles, curvature)
        objectives.append(o)
        commands.append(current)
        branch.append(tracker.branch)
    return np.array(objectives), commands, np.array(branch)


def test_tracker_turns_to_the_mirror_twin_when_k_drifts_through_zero():
    # entered without the scan; the entry's own trial of the twin is another test's
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1, entry_trial_after=NEVER)
    drift = lambda t: -0.15 + 0.3 * min(t / 2500, 1.0)          # noqa: E731
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    states: list[TrackerState] = []
    o, _, branch = _drive_mirrored(tracker, drift, 3000, states=states)
    assert tracker.branch == -1 and tracker.turner.abandoned == 0
    # every change of state is one of the documented transitions
    changes = {(a, b) for a, b in zip(states, states[1:]) if a is not b}
    assert (TrackerState.DITHER, TrackerState.TURN) in changes
    assert changes <= TRACKER_TRANSITIONS, changes - TRACKER_TRANSITIONS
    assert tracker.turner.made >= 1       # turns that found no better branch were taken back
    changed = np.flatnonzero(np.diff(branch)) + 1
    assert changed.size == tracker.turner.made + 2 * tracker.turner.rejected
    assert abs(tracker.estimate - 0.15) < 0.06
    # on the twin at K = 0.15 the toy gives 0.2 (less the dither's cost), the curve 0.185
    assert np.mean(o[-100:]) > 0.19
    # the turns kept the pulse (the toy's O falls to 0.1 halfway round at |K| = 0.1)
    assert o[200:].min() > 0.16
    # a tracker that never changes branch stays on the curve and pays for it
    plain = CurveTracker(GRID, ANGLES, threshold=0.1,
                         config=replace(cfg, mirror_margin=1.0, trial_drop=0.0))
    o_plain, _, _ = _drive_mirrored(plain, drift, 3000)
    assert plain.branch == 1 and np.mean(o_plain[-100:]) < 0.186


def _dip_and_drift(dip_end: int, drift_start: int) -> tuple[CurveTracker, list, list, list]:
    """A tracker at K = -0.05 on the toy; O dips by 15 % from period 150 to ``dip_end`` (a
    branch trial), then K runs up to 0.15 from period ``drift_start``. Returns the tracker,
    the turns begun (period, estimate, wait then), their ends (period, branch) and the branch
    of every period."""
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.05, entry_trial_after=NEVER)
    drift = lambda t: -0.05 + 0.002 * min(max(t - drift_start, 0), 100)  # noqa: E731
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    o, current, begun, ended, branch = 0.2, None, [], [], []
    for t in range(600):
        before = tracker.state
        cmd = tracker.step(o, current)
        if before is not TrackerState.TURN and tracker.state is TrackerState.TURN:
            begun.append((t, tracker.estimate, tracker.turner.wait))
        if before is TrackerState.TURN and tracker.state is not TrackerState.TURN:
            ended.append((t, tracker.branch))
        branch.append(tracker.branch)
        current = tracker.limits.apply(cmd if current is None else current, cmd)
        dip = 0.85 if 150 <= t < dip_end else 1.0
        o = _mirrored_objective(current, drift(t)) * dip
    return tracker, begun, ended, branch


def test_a_crossing_of_k_0_asks_for_a_turn_even_while_an_earlier_turn_cools_down():
    """A trial at K < 0 judged while O still dips finds the twin no better and goes back,
    which starts the wait between turns; K then goes through 0, and the estimate's crossing
    asks for the turn at once instead of leaving the laser on the branch for K < 0 until the
    wait is over."""
    tracker, begun, ended, branch = _dip_and_drift(dip_end=180, drift_start=170)
    assert begun[0][1] < 0 and ended[0][1] == 1          # the trial, turned back
    assert begun[1][1] > 0.03 and begun[1][2] > 0        # past 0 while its wait ran
    assert branch[-1] == -1 and branch[260] == -1        # on the twin soon after K passed 0
    assert abs(tracker.estimate - 0.15) < 0.06


def test_a_kept_turn_leaves_no_wait_the_next_evidence_turns_again_at_once():
    """A trial at K < 0 judged after the dip keeps the twin (the O before was the dipped
    one); the twin's estimate then says K < 0, and the turn back comes at once: a kept turn
    starts no wait between turns (``bench/results/kept_turn_no_wait.md``)."""
    tracker, begun, ended, branch = _dip_and_drift(dip_end=165, drift_start=250)
    assert begun[0][1] < 0 and ended[0][1] == -1 and tracker.turner.made >= 1  # kept
    assert begun[1][2] == 0 and begun[1][0] - ended[0][0] < 40  # the next, without a wait
    assert ended[1][1] == 1                                     # back on the curve for K < 0
    assert branch[-1] == -1 and abs(tracker.estimate - 0.15) < 0.06


def test_the_guard_judges_entries_only_not_the_end_of_a_branch_turn():
    """A branch turn ending late in a run is judged by its own rule: a fall of O after it
    leaves the tracker on (the scan takes over if the pulse goes), not stopped."""
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1, entry_trial_after=NEVER)
    drift = lambda t: -0.15 + 0.3 * min(t / 2500, 1.0)          # noqa: E731
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    o, current, before = 0.2, None, tracker.state
    for t in range(3000):
        cmd = tracker.step(o, current)
        current = tracker.limits.apply(cmd if current is None else current, cmd)
        o = _mirrored_objective(current, drift(t))
        if before is TrackerState.TURN and tracker.state is TrackerState.DITHER:
            break                                   # a turn just ended
        before = tracker.state
    assert t > 100 and tracker.active
    for _ in range(3 * cfg.block + cfg.guard_periods):  # O well under 0.85 x the entry's
        assert tracker.step(0.12, current) is not None
    assert tracker.active


def test_where_the_estimate_says_nothing_a_fall_of_o_makes_the_tracker_try_the_twin():
    """A laser whose O does not change along the curve (on other cavities the best point
    often sits at the curve's end whatever K is): the estimate never leaves its start, K
    drifts through 0, O falls on the curve, and the tracker tries the twin and keeps it."""
    # entered without the scan; the entry's own trial of the twin is another test's
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1, entry_trial_after=NEVER)
    drift = lambda t: -0.15 + 0.35 * min(t / 2500, 1.0)          # noqa: E731
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    o, _, branch = _drive_mirrored(tracker, drift, 3000, curvature=0.0)
    assert tracker.branch == -1 and tracker.turner.made >= 1
    assert np.mean(o[-100:]) > 0.195                    # the twin's 0.2, not the curve's 0.18
    silent = CurveTracker(GRID, ANGLES, threshold=0.1, config=replace(cfg, trial_drop=0.0))
    o_silent, _, _ = _drive_mirrored(silent, drift, 3000, curvature=0.0)
    assert silent.branch == 1 and np.mean(o_silent[-100:]) < 0.185


def test_a_fall_of_o_while_an_entry_settles_still_makes_the_tracker_try_the_twin():
    """The branch's best counts from the entry: K steps across 0 while the entry settles
    (before the dither compares), O falls on the curve, and the tracker tries the twin."""
    cfg = TrackingConfig(entry_patience=1, start=-0.1, entry_trial_after=NEVER)
    step = lambda t: -0.15 if t < cfg.settle - 4 else 0.25          # noqa: E731
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    o, _, branch = _drive_mirrored(tracker, step, 400, curvature=0.0)
    assert o[cfg.settle] < 0.18                         # fallen on the curve
    assert branch[-1] == -1 and tracker.turner.made >= 1 and np.mean(o[-50:]) > 0.195


def test_noise_alone_makes_the_tracker_try_the_twin_less_where_the_trial_averages_blocks(
        monkeypatch):
    """K held on the curve's side, 2 % noise on O: the best of many single noisy blocks
    sits some standard deviations over the laser's O, so single blocks fall
    ``trial_drop`` under it by chance and the tracker tries the twin (and turns back);
    the mean of two blocks against the best such mean does so far less often. (The O
    a turn is judged by and the guard at its landing are the single period's and off:
    they end turns in other ways, and this is about what starts them.)"""
    monkeypatch.setattr(tracking, 'TURN_REFERENCE', 1)

    def trials(blocks: int) -> int:
        monkeypatch.setattr(tracking, 'TRIAL_BLOCKS', blocks)
        cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.15)
        tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
        rng, o, current = np.random.default_rng(5), 0.2, None
        for _ in range(6000):
            cmd = tracker.step(o, current)
            current = tracker.limits.apply(cmd if current is None else current, cmd)
            o = _mirrored_objective(current, -0.15) * (1 + 0.02 * rng.standard_normal())
        turner = tracker.turner
        return turner.made + turner.rejected + turner.abandoned

    single, averaged = trials(1), trials(2)
    assert single >= 4 and averaged <= single / 2


def test_after_an_acquisition_lock_the_tracker_tries_the_other_branch_once():
    """The scan stops at the first point that passes the lock level, here on the weaker
    branch (K = 0.15 held, O flat along the curve, nothing else would make it turn): the
    entry trial finds the twin and keeps it; without it the tracker stays."""
    cfg = TrackingConfig(settle=5, start=-0.1, trial_drop=0.0, mirror_margin=0.5)
    for entry_trial, branch, low, high in ((True, -1, 0.195, 1.0), (False, 1, 0.0, 0.186)):
        after = cfg.entry_trial_after if entry_trial else NEVER
        tracker = CurveTracker(GRID, ANGLES, threshold=0.1,
                               config=replace(cfg, entry_trial_after=after))
        tracker.enter_at(-0.1, 1, 0.185)
        o, _, _ = _drive_mirrored(tracker, lambda t: 0.15, 300, curvature=0.0)
        assert tracker.branch == branch, entry_trial
        assert low < np.mean(o[-50:]) < high, entry_trial
        assert tracker.turner.made + tracker.turner.rejected == int(entry_trial)
    # a lock whose O is already near what the curve gave on the simulator is not tried
    content = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg,
                           expected=np.full(GRID.size, 0.2))
    content.enter_at(-0.1, 1, 0.185)
    _drive_mirrored(content, lambda t: 0.15, 300, curvature=0.0)
    assert content.branch == 1 and content.turner.made + content.turner.rejected == 0
    doubtful = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg,
                            expected=np.full(GRID.size, 0.3))     # 0.185 < 0.8 x 0.3
    doubtful.enter_at(-0.1, 1, 0.185)
    _drive_mirrored(doubtful, lambda t: 0.15, 300, curvature=0.0)
    assert doubtful.branch == -1


def test_an_entry_without_the_scan_tries_the_other_branch_too():
    """The laser locked at held angles (no scan) and tracking began at ``start`` on the curve,
    the weaker branch at K = 0.15: the entry trial finds the twin; without it the tracker
    stays."""
    cfg = TrackingConfig(settle=5, start=-0.1, trial_drop=0.0, mirror_margin=0.5,
                         entry_patience=1)
    for trial, branch in ((True, -1), (False, 1)):
        after = cfg.entry_trial_after if trial else NEVER
        tracker = CurveTracker(GRID, ANGLES, threshold=0.1,
                               config=replace(cfg, entry_trial_after=after))
        o, _, _ = _drive_mirrored(tracker, lambda t: 0.15, 300, curvature=0.0)
        assert tracker.active and tracker.branch == branch, trial
        assert tracker.turner.made + tracker.turner.rejected == int(trial)
        assert (np.mean(o[-50:]) > 0.195) == trial


def test_a_turn_that_loses_the_pulse_is_turned_back_and_tried_the_other_way():
    """A laser whose sign conventions are the other way round from the simulator's: K
    runs from -0.1 to 0.25 in 200 periods, the estimate passes the margin, the quarter turn in the
    simulator's direction starts losing O, the tracker turns back before O falls far,
    and after the cooldown turns the other way, onto the twin."""
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1, mirror_margin=0.2,
                         entry_trial_after=NEVER)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    tracker.turner.direction = 1.0                                  # the wrong way here
    ramp = lambda t: -0.1 + 0.35 * min(max(t - 300, 0) / 200, 1.0)  # noqa: E731
    o, commands, branch = _drive_mirrored(tracker, ramp, 1200)
    assert tracker.turner.abandoned == 1 and tracker.turner.direction == -1.0
    assert tracker.branch == -1 and tracker.turner.made == 1
    turned = np.array([c[1] - ANGLES[0, 1] for c in commands if c is not None])
    out = int(np.argmax(turned))                             # the furthest the wrong way
    assert 0 < turned[out] < QUARTER_TURN / 2                # part of the way round ...
    assert turned[out + 1:].max() < turned[out]              # ... and back
    steps = int(round(turned[out] / (QUARTER_TURN / TURN_PERIODS)))
    before = o[out - steps]                                  # O just before the turn
    under = np.flatnonzero(o[out - steps:out + 1] < cfg.turn_guard * before)
    assert under.size == 1 and under[0] == steps   # the first O under the guard turned it
    assert np.mean(o[-100:]) > 0.19                          # on the twin at K = 0.25


def test_a_turn_that_loses_the_pulse_on_the_way_is_tried_again_the_other_way():
    """K steps from -0.15 to 0.25 (O falls on the curve; the estimate, on a flat curve, says
    nothing); the trial's turn goes the way that loses the pulse and is turned back. It
    says nothing of the twin, so the branch keeps its best: after the wait the trial
    fires again, the other way round, and the twin stays."""
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1, mirror_margin=0.5,
                         entry_trial_after=NEVER)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    tracker.turner.direction = 1.0                                  # the wrong way here
    step = lambda t: -0.15 if t < 300 else 0.25                     # noqa: E731
    o, _, branch = _drive_mirrored(tracker, step, 300 + 3 * tracking.TURN_COOLDOWN,
                                   curvature=0.0)
    assert tracker.turner.abandoned == 1 and tracker.turner.made == 1
    assert branch[-1] == -1 and np.mean(o[-50:]) > 0.195    # the twin's 0.2, not 0.175


def _scripted_entry(config: TrackingConfig, objectives: list[float],
                    lost_landing: bool = False, wait: int = 0) -> CurveTracker:
    """A tracker entered where a scan locked (curve point -0.1, branch 1), fed the O
    values ``objectives`` one per period with the angles it asked for (``wait``: periods
    left of the wait after an earlier turn)."""
    tracker = CurveTracker(GRID, ANGLES, threshold=0.05, config=config)
    tracker.turner.lost_landing, tracker.turner.wait = lost_landing, wait
    tracker.enter_at(-0.1, 1, objectives[0])
    current = tracker.curve(tracker.estimate)
    for o in objectives:
        current = tracker.limits.apply(current, tracker.step(o, current))
    return tracker


def test_the_entry_trial_comes_entry_trial_after_periods_after_the_entry():
    cfg = TrackingConfig(entry_trial_after=4, trial_drop=0.0, mirror_margin=0.5)
    early = _scripted_entry(cfg, [0.15] * 4)
    assert not early.turner.busy
    due = _scripted_entry(cfg, [0.15] * 5)
    assert due.turner.busy
    # not after a turn that lost the pulse where it landed (until a turn is kept)
    assert not _scripted_entry(cfg, [0.15] * 5, lost_landing=True).turner.busy
    # the wait after an earlier turn does not hold back a scan's lock (a new start)
    assert _scripted_entry(cfg, [0.15] * 5, wait=50).turner.busy
    with pytest.raises(ValueError, match='entry_trial_after'):
        TrackingConfig(entry_trial_after=-1)


def test_a_turn_begun_on_a_crest_of_o_is_judged_by_the_median_of_the_latest_periods(
        monkeypatch):
    """A pulse just formed from noise swings from period to period: the entry trial
    begins on a crest (0.3 among 0.15) and the next period is a trough (0.12). Judged
    against the crest (turn_reference 1) the turn is given up; against the median of the
    latest three periods (0.15) it goes on; so it does against the crest with a turn
    guard of 0.35 (0.12 > 0.35 x 0.3)."""
    script = [0.15, 0.15, 0.3, 0.12, 0.15]
    for reference, guard, abandoned in ((3, 0.45, 0), (1, 0.45, 1), (1, 0.35, 0)):
        monkeypatch.setattr(tracking, 'TURN_REFERENCE', reference)
        cfg = TrackingConfig(entry_trial_after=2, turn_guard=guard, trial_drop=0.0,
                             mirror_margin=0.5)
        tracker = _scripted_entry(cfg, script + [0.15] * 10)
        assert tracker.turner.abandoned == abandoned, (reference, guard)


def test_a_turn_whose_pulse_goes_where_it_landed_is_taken_back_at_once():
    """The turn keeps O on the way, but at its landing point O falls under the turn
    guard: the laser is turned back in the next period, not after the ``verify`` periods
    (the way round is kept, and the next entry makes no trial); O above the guard is
    verified."""
    cfg = TrackingConfig()
    for landing, lost in ((0.05, True), (0.2, False)):
        turner = CurveTracker(GRID, ANGLES, threshold=0.05, config=cfg).turner
        assert turner.begin(ANGLES[20], GRID[20], 0.2)
        events = [turner.step(0.2)[1] for _ in range(TURN_PERIODS)]
        assert events[-1] is TurnEvent.ARRIVED
        command, event = turner.step(landing)
        if lost:                                     # the pulse is going at the landing
            assert command is not None and turner.lost_landing
            back = [turner.step(0.05)[1] for _ in range(TURN_PERIODS - 1)]
            assert back[-1] is TurnEvent.ABANDONED and turner.abandoned == 1
            assert turner.direction == -1.0          # the way round that kept the pulse
        else:
            assert command is None and event is TurnEvent.NONE and not turner.lost_landing


def test_after_a_turn_taken_back_from_its_landing_the_tracker_is_where_it_began():
    """The entry trial's turn arrives on the twin, the pulse goes there and the turn
    retraces to its start: the tracker is back on its branch at its estimate, and its next
    command is its own curve point, not the landing it gave up."""
    cfg = TrackingConfig(entry_trial_after=2, trial_drop=0.0, mirror_margin=0.5)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.05, config=cfg)
    tracker.enter_at(-0.1, 1, 0.15)
    current, events = tracker.curve(tracker.estimate), []
    script = [0.15] * (2 + TURN_PERIODS) + [0.01] * TURN_PERIODS  # lost where it landed
    for o in script:
        before = tracker.turner.abandoned
        current = tracker.limits.apply(current, tracker.step(o, current))
        events.append(tracker.turner.abandoned > before)
    assert events[-1] and tracker.turner.abandoned == 1 and not tracker.turner.busy
    assert tracker.branch == 1 and tracker.estimate == -0.1
    command = tracker.step(0.15, current)
    assert np.max(np.abs(command - tracker.curve(-0.1 + cfg.dither))) < 1e-12


def test_a_turn_whose_way_has_no_room_goes_the_other_way_and_does_not_turn_back():
    """Every turn far from K = 0 goes the way that kept the pulse, winding the servos; with
    a servo at the end of its range that way does not fit: the turn goes the other way and
    is kept even where it loses O (retracing the path that lost it saves nothing; the scan
    finds the pulse again), while the same turn with room is turned back."""
    limits = AngleLimits()
    wound = ANGLES[5] + np.array([0.0, 0.0, 0.0, limits.low + 1.0 - ANGLES[5, 3]])
    for start, forced in ((ANGLES[5], False), (wound, True)):
        turner = CurveTracker(GRID, ANGLES, threshold=0.05, limits=limits).turner
        assert turner.begin(start, GRID[5], 0.2)          # far from K = 0
        events = []
        while turner.busy:                                # O falls after two steps
            events.append(turner.step(0.2 if len(events) < 2 else 0.01)[1])
        if forced:   # the way round that kept the pulse (-1) would pass the low end
            assert events == ([TurnEvent.NONE] * (TURN_PERIODS - 1)
                              + [TurnEvent.ARRIVED, TurnEvent.KEPT])
            assert turner.direction == -1.0 and turner.made == 1
        else:        # turned back after the first O under the guard
            assert events == [TurnEvent.NONE] * 3 + [TurnEvent.ABANDONED]


def test_a_turn_stays_inside_the_servo_limits():
    """A curve whose angles sit near +pi turns the other way round."""
    high = ANGLES + np.array([0.0, 0.0, 2.9, 0.0])
    cfg = TrackingConfig(entry_patience=1, settle=0, start=-0.1)
    limits = AngleLimits()
    tracker = CurveTracker(GRID, high, threshold=0.1, config=cfg, limits=limits)
    drift = lambda t: -0.15 + 0.3 * min(t / 2500, 1.0)          # noqa: E731
    _, commands, _ = _drive_mirrored(tracker, drift, 3000, angles=high)
    assert tracker.branch == -1
    issued = np.array([c for c in commands if c is not None])
    assert issued.max() <= limits.high and issued.min() >= limits.low


@pytest.mark.parametrize('bad', [dict(dither=0), dict(step=-1), dict(block=0), dict(guard=0),
                                 dict(guard=1.5), dict(settle=-1),
                                 dict(mirror_margin=-0.1),
                                 dict(step=0.001), dict(step=0.05),
                                 dict(turn_guard=0),
                                 dict(trial_drop=1.0), dict(trial_drop=-0.1),
                                 dict(entry_trial_below=-0.1)])
def test_bad_tracking_settings_are_rejected(bad):
    with pytest.raises(ValueError):
        TrackingConfig(**bad)


def test_bad_curves_are_rejected():
    with pytest.raises(ValueError):
        CurveTracker(GRID[::-1], ANGLES, threshold=0.1)
    with pytest.raises(ValueError):
        CurveTracker(GRID, ANGLES[:, :3], threshold=0.1)
    with pytest.raises(ValueError):
        CurveTracker(GRID, ANGLES, threshold=0.0)


def test_dlmpc_tracks_once_locked_and_reports_its_estimate():
    cfg = DLMPCConfig(tracking=TrackingConfig(entry_patience=3, settle=0))
    ctrl = DLMPCController(cfg, target_objective=0.2, curve=(GRID, ANGLES, 0.2 + 0 * GRID))
    angles, modes = np.zeros(4), []
    for _ in range(30):
        o = _objective(angles, 0.1) if modes and modes[-1] == 'track' else 0.19
        step = ctrl.step(np.r_[o * 20.0, 20.0, angles], surrogate=0.0)
        modes.append(step.mode)
        angles = step.angles
    assert modes[:3] != ['track'] * 3 and modes[-1] == 'track'
    assert step.surrogate == pytest.approx(ctrl.tracker.estimate)
    assert ctrl.fresh().tracker is not None and not ctrl.fresh().tracker.active
    with pytest.raises(ValueError, match='tracking settings'):  # tracking off: the paper's
        DLMPCController(DLMPCConfig(tracking=None), 0.2, (GRID, ANGLES, GRID))


def test_an_entry_keeps_the_half_wave_plate_in_the_frame_the_scan_locked_in():
    """alpha3 and alpha3 + pi/2 are one setting: entered with the plate a quarter turn from
    the curve's (where a seeding sweep ends), the tracker commands the curve in that frame
    instead of turning the plate back through its period; in the curve's own frame, as is."""
    for offset, frame in ((0.0, 0.0), (QUARTER_TURN, QUARTER_TURN),
                          (-QUARTER_TURN + 0.1, QUARTER_TURN), (np.pi, 0.0)):
        tracker = CurveTracker(GRID, ANGLES, threshold=0.1)
        on_curve = tracker.curve(-0.1)
        here = on_curve + np.array([0.0, 0.0, offset, 0.0])
        tracker.enter_at(-0.1, 1, 0.2, here)
        command = tracker.step(0.2, here)   # the dither moves alpha3 by 0.03
        assert abs(command[2] - on_curve[2] - frame) <= 0.03 + 1e-12, offset
        np.testing.assert_allclose(command[[1, 3]], on_curve[[1, 3]])


class _GainPlanner:
    """A planner that turns the curve by 0.05 rad whenever it is asked for no more than
    ``gain`` of log O, and records what it was asked for."""

    def __init__(self, gain: float) -> None:
        self.gain, self.asked, self.undone = gain, [], 0

    def plan(self, u: float, theta: float, noise: float = 0.0, at_least: float = 0.0) -> float:
        self.asked.append(at_least)
        return 0.05 if at_least <= self.gain else 0.0

    def retract(self) -> float:
        return 0.0


def test_a_turn_to_a_weaker_branch_stays_where_a_turn_of_the_curve_is_predicted_to_do_better():
    """The twin holds 0.18 after the turn, under the 0.2 before: it is kept only if the
    planner expects turning the curve there to gain what the twin lacks,
    log(1.005 x 0.2 / 0.18), and then the curve is turned by the planner's turn."""
    for gain, kept in ((0.2, True), (0.1, False)):
        planner = _GainPlanner(gain)
        tracker = CurveTracker(GRID, ANGLES, threshold=0.05, config=TrackingConfig(),
                               planner=planner)
        turner = tracker.turner
        assert turner.begin(ANGLES[20], GRID[20], 0.2)
        [turner.step(0.2) for _ in range(TURN_PERIODS)]
        events = [turner.step(0.18)[1] for _ in range(tracking.VERIFY)]
        assert events[-1] is (TurnEvent.KEPT if kept else TurnEvent.NONE)
        assert turner.busy != kept and tracker.planned == (0.05 if kept else 0.0)
        assert planner.asked == [pytest.approx(np.log(1.005 * 0.2 / 0.18))]


def test_a_turn_asked_for_because_o_fell_is_judged_against_the_o_it_fell_to():
    """O falls from 0.15 to 0.10 in the last period of a dither block (K stepped): the
    branch trial fires at once, while the median of the latest periods still holds 0.15.
    The twin then holds 0.12: better than the 0.10 the laser fell to, so the turn stays
    (against the stale 0.15 it would go back to the 0.10); a twin holding 0.09 goes back."""
    cfg = TrackingConfig(settle=0, entry_trial_after=NEVER, mirror_margin=0.5)
    for landed, kept in ((0.12, True), (0.09, False)):
        tracker = CurveTracker(GRID, ANGLES, threshold=0.05, config=cfg)
        tracker.enter_at(-0.1, 1, 0.15)
        current, o = tracker.curve(tracker.estimate), 0.15
        for t in range(12 * cfg.block):
            if t == 9 * cfg.block - 1:  # the last period of the ninth block
                o = 0.10
            current = tracker.limits.apply(current, tracker.step(o, current))
            if tracker.turner.busy:
                break
        assert t == 9 * cfg.block - 1  # begun in the period of the fall
        script = [0.11] * (TURN_PERIODS - 1) + [landed] * tracking.VERIFY + [0.10] * 10
        for o in script:
            current = tracker.limits.apply(current, tracker.step(o, current))
        assert (tracker.branch, tracker.turner.made, tracker.turner.rejected) == \
            ((-1, 1, 0) if kept else (1, 0, 1))


def test_past_the_curves_end_the_tracker_follows_it_along_its_end_line():
    """The laser's best point lies past the curve's end (s = 0.36 on a curve over
    [-0.3, 0.3]): the tracker follows the curve on along the line fitted to its last
    ``REACH`` and settles at the peak, not pinned at the end; no further than ``REACH``."""
    cfg = TrackingConfig(entry_patience=1, settle=0, step=0.01, start=0.2)
    tracker = CurveTracker(GRID, ANGLES, threshold=0.1, config=cfg)
    assert np.allclose(tracker.on_curve(0.35), [0.7, 0.1, 0.15, 0.3])  # the toy's own line
    est, _ = _drive(tracker, lambda t: 0.36, 800)
    assert abs(np.nanmean(est[-60:]) - 0.36) < 0.02
    est, _ = _drive(tracker, lambda t: 0.6, 800)
    assert np.nanmax(est) == pytest.approx(0.3 + tracking.REACH)
