"""The DL-MPC's lock acquisition scan: when it takes over, where it goes, when it lets go."""

import numpy as np
import pytest
import torch

from dlmpc_ros.control.dlmpc import (CURVE_POINTS, TRAVEL_PERIODS, WEAK_FIELD, DLMPCController,
                                    LockSupervisor, ScanPoint)
from dlmpc_ros.control.dlmpc_config import AcquisitionConfig, DLMPCConfig
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.control.paper_loops import MapScan, PaperDLMPC, scan_surrogates
from dlmpc_ros.learning.kmap import KMap, KMapConfig
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig

from test.control.toy_curve import GRID, toy_curve


def _map(s: float) -> np.ndarray:
    return np.array([0.1 * s, -0.1 * s, 0.2, 0.0])


def test_scan_points_are_prior_quantiles():
    points = scan_surrogates(5)
    np.testing.assert_allclose(points, [-1.2816, -0.5244, 0.0, 0.5244, 1.2816], atol=1e-4)


def test_supervisor_waits_then_scans_nearest_first_and_lets_go_on_lock():
    sup = LockSupervisor(0.1, MapScan(_map, 5), AcquisitionConfig(
        patience=2, relock_patience=2, dwell_periods=2))
    here = np.zeros(4)
    assert sup.step(0.2, here, 0.6) is None        # locked: remembers the surrogate
    assert sup.step(0.01, here, 0.0) is None       # unlocked, patience 1
    assert sup.step(0.01, here, 0.0) is None       # patience 2
    first = sup.step(0.01, here, 0.0)              # scan: the point nearest 0.6 first
    np.testing.assert_allclose(first, _map(scan_surrogates(5)[3]))
    assert sup.step(0.01, here, 0.0) is first      # not there yet: keep going
    assert sup.step(np.nan, first, 0.0) is first   # there: dwell 1 (NaN O is unlocked)
    second = sup.step(0.01, first, 0.0)            # dwell 2 done: next nearest point
    np.testing.assert_allclose(second, _map(scan_surrogates(5)[2]))
    assert sup.step(0.15, second, 0.0) is None     # over the level: the loops take over
    assert sup.unlocked == 0 and sup.locked_at is not None
    np.testing.assert_allclose(sup.locked_at.angles, second)
    assert sup.step(0.15, second, 0.0) is None and sup.locked_at is None  # only once


def test_once_the_laser_has_been_locked_the_scan_waits_the_relock_patience():
    config = AcquisitionConfig(patience=1, relock_patience=4)
    sup = LockSupervisor(0.1, MapScan(_map, 5), config)
    here = np.zeros(4)
    assert sup.step(0.01, here, 0.0) is None and not sup.was_locked
    assert sup.step(0.01, here, 0.0) is not None   # cold: scans after 1 period
    sup = LockSupervisor(0.1, MapScan(_map, 5), config)
    assert sup.step(0.2, here, 0.0) is None and sup.was_locked
    waited = [sup.step(0.01, here, 0.0) is None for _ in range(5)]
    assert waited == [True] * 4 + [False]          # after a lock: 4 periods
    with pytest.raises(ValueError, match='relock_patience'):
        AcquisitionConfig(relock_patience=0)


def test_a_one_period_spike_does_not_set_the_level():
    """A pulse forming from noise overshoots: a one-period spike of O does not raise the
    laser's recent best (which would make its settled O look unlocked)."""
    sup = LockSupervisor(0.1, MapScan(_map, 5), AcquisitionConfig(patience=1, dwell_periods=2))
    here = np.zeros(4)
    sup.step(0.01, here, 0.0)
    target = sup.step(0.01, here, 0.0)             # scanning
    for o in (0.01, 0.3, 0.13):                    # a spike, then a settled weak pulse
        sup.step(o, target, 0.0)
    assert sup.locked_at is None and sup.unlocked == 0
    sup.step(0.13, target, 0.0)
    assert sup.level == pytest.approx(0.13)
    assert sup.locked(0.13)                        # not under 0.6 x the spike


def test_a_point_the_servos_cannot_reach_is_left_after_travel_periods():
    sup = LockSupervisor(0.1, MapScan(_map, 3), AcquisitionConfig(patience=1, dwell_periods=1))
    here = np.full(4, 1.0)
    sup.step(0.0, here, 0.0)
    targets = [sup.step(0.0, here, 0.0) for _ in range(TRAVEL_PERIODS + 2)]
    assert all(t is targets[0] for t in targets[:TRAVEL_PERIODS])
    assert not np.allclose(targets[TRAVEL_PERIODS], targets[0])


@pytest.mark.parametrize('bad', [{'lock_fraction': 0.0}, {'lock_fraction': 1.0},
                                 {'patience': 0}, {'dwell_periods': 0},
                                 {'relock_patience': 0}])
def test_bad_acquisition_settings_are_rejected(bad):
    with pytest.raises(ValueError):
        AcquisitionConfig(**bad)


def test_dlmpc_scans_within_the_servo_limits_while_unlocked():
    kmap = KMap(KMapConfig(hidden=16), generator=torch.Generator().manual_seed(0))
    mprnn = MPRNN(MPRNNConfig(window=2, horizon=4, n_hidden=16, n_latent=8))
    config = DLMPCConfig(acquisition=AcquisitionConfig(patience=3), error_threshold=1e6)
    ctrl = PaperDLMPC(kmap, mprnn, config, target_objective=0.2)
    assert ctrl.acquisition.threshold == pytest.approx(0.1)
    angles = np.zeros(4)
    modes, measured = [], []
    for _ in range(8):  # O = 0.3 / 30 = 0.01: off the pulse
        step = ctrl.step(np.r_[0.3, 30.0, angles], 0.0)
        assert np.abs(step.angles - angles).max() <= config.limits.max_step + 1e-12
        modes.append(step.mode)
        measured.append(step.measure)
        if step.mode == 'acquire':
            assert step.measure is not ctrl.acquisition.travelling
        angles = step.angles
    assert modes[:3] == ['inner'] * 3 and set(modes[3:]) == {'acquire'}
    # on the way to a scan point no measurement is needed: the next decision comes as
    # soon as the servos report the command reached; at the point it is measured again
    assert all(measured[:3]) and not all(measured[3:])
    assert ctrl.step(np.r_[6.0, 30.0, angles], 0.0).mode != 'acquire'  # O = 0.2: locked
    assert PaperDLMPC(kmap, mprnn, config).acquisition is None  # no target: no scan
    fresh = ctrl.fresh()
    assert fresh.acquisition is not ctrl.acquisition and fresh.acquisition.unlocked == 0


def test_with_a_tracking_curve_the_scan_visits_the_curve_and_its_twin_and_tracking_starts_there():
    curve = toy_curve()
    acquisition = AcquisitionConfig(patience=2, dwell_periods=2)
    config = DLMPCConfig(acquisition=acquisition, error_threshold=1e6,
                         limits=AngleLimits(max_step=10.0))  # servos arrive at once
    ctrl = DLMPCController(config, target_objective=0.2, curve=curve)
    reach = ctrl.tracker.low                                   # the end of the tracker's reach
    assert reach < GRID[0] and CURVE_POINTS[0] == pytest.approx(reach)
    assert np.all(np.diff(CURVE_POINTS) > 0)                   # from there inward
    first = ctrl.tracker.on_curve(reach)                       # c(-0.4), past the curve's end
    np.testing.assert_allclose(first[0], 2 * reach)            # on the end's line
    twin = first + np.pi / 2                                   # its twin, estimate 0.4
    angles = twin + 0.05  # nearer the twin than the curve point: the twin is scanned first
    targets = []
    for _ in range(6):  # O = 0.3 / 30 = 0.01: off the pulse; no surrogate: hold, then scan
        step = ctrl.step(np.r_[0.3, 30.0, angles], None)
        angles = step.angles
        targets.append((step.mode, angles.copy()))
    assert [m for m, _ in targets] == ['hold'] * 2 + ['acquire'] * 4
    np.testing.assert_allclose(np.cos(2 * (targets[2][1] - twin)), 1.0, atol=1e-9)  # twin
    np.testing.assert_allclose(np.cos(2 * (targets[4][1] - first)), 1.0, atol=1e-9)  # curve
    step = ctrl.step(np.r_[6.0, 30.0, angles], 0.0)           # O = 0.2: locked at c(-0.4)
    assert step.mode == 'track' and ctrl.tracker.active
    assert ctrl.tracker.branch == 1 and ctrl.tracker.estimate == pytest.approx(reach)


class _Pairs:
    """A scan source of fixed points (a pass is always the same list)."""

    def __init__(self, *points: ScanPoint) -> None:
        self.points = points

    def pass_order(self, current: np.ndarray) -> list[ScanPoint]:
        return list(self.points)

    def note_locked(self, surrogate: float) -> None:
        pass


_CURVE = ScanPoint(np.zeros(4), 1, -0.25)
_TWIN = ScanPoint(np.full(4, 0.5), -1, 0.25)


def test_the_scan_lets_go_at_the_first_point_that_locks():
    """Even on the weaker branch: the tracker's entry trial turns the laser onto the twin."""
    sup = LockSupervisor(0.1, _Pairs(_CURVE, _TWIN), AcquisitionConfig(patience=1))
    sup.step(0.01, np.full(4, -1.0), 0.0)
    sup.step(0.01, np.full(4, -1.0), 0.0)
    assert sup.step(0.2, _CURVE.angles, 0.0) is None and sup.locked_at is _CURVE


def test_the_scan_keeps_turn_room_from_the_ends_of_the_servo_range():
    """A servo wound near an end (alpha_p at -5.17 rad of the +-2 pi range) is not left
    at the point's nearest equivalent (1.1 - 2 pi), where a quarter turn one way would
    leave the range, but brought to the equivalent inside the room (1.1 - pi)."""
    limits = AngleLimits()
    point = ScanPoint(np.array([0.0, 0.0, 0.0, 1.1]))
    here = np.array([0.0, 0.0, 0.0, -5.17])
    sup = LockSupervisor(0.1, _Pairs(point), AcquisitionConfig(patience=1, dwell_periods=50),
                         limits)
    sup.step(0.01, here, 0.0)
    for _ in range(30):
        here = limits.apply(here, sup.step(0.01, here, 0.0))
    assert here[3] == pytest.approx(1.1 - np.pi)
    assert limits.low + 2.0 <= here[3] <= limits.high - 2.0
    near_middle = np.array([0.0, 0.0, 0.0, 0.5])   # inside the room: the point as it is
    sup = LockSupervisor(0.1, _Pairs(point), AcquisitionConfig(patience=1), limits)
    sup.step(0.01, near_middle, 0.0)
    np.testing.assert_allclose(sup.step(0.01, near_middle, 0.0), point.angles)


def _scan_to(sup: LockSupervisor, limits: AngleLimits, here: np.ndarray, energy: float,
             periods: int) -> list[np.ndarray]:
    """The servos' angles over ``periods`` unlocked periods at a measured E of ``energy``."""
    path = []
    for _ in range(periods):
        here = limits.apply(here, sup.step(0.01, here, 0.0, energy))
        path.append(here)
    return path


def test_the_scan_seeds_a_dead_point_by_turning_the_half_wave_plate_through_its_period():
    """Where the field has died (E under WEAK_FIELD of the last locked period's), the scan
    turns alpha3 forward by the servo step per period through a quarter turn (the same
    setting again) and dwells there; a live point, or a laser never locked, gets none."""
    limits = AngleLimits(max_step=0.25)
    point = ScanPoint(np.array([0.1, -0.2, 0.3, 0.4]))

    def supervisor(locked_energy: float) -> LockSupervisor:
        sup = LockSupervisor(0.1, _Pairs(point),
                             AcquisitionConfig(patience=1, relock_patience=1), limits)
        sup.step(0.2, point.angles, 0.0, locked_energy)    # locked
        sup.step(0.01, point.angles, 0.0, 0.1)             # patience
        return sup

    # the point, a period there, 7 periods of sweep, then the dwell at its end
    dead = _scan_to(supervisor(3.0), limits, point.angles, 3.0 * WEAK_FIELD * 0.5, 11)
    turned = np.array([a[2] - 0.3 for a in dead])
    np.testing.assert_allclose([a[[0, 1, 3]] for a in dead], [point.angles[[0, 1, 3]]] * 11)
    np.testing.assert_allclose(turned, [0, 0, 0.25, 0.5, 0.75, 1, 1.25, 1.5] + [np.pi / 2] * 3)
    live = _scan_to(supervisor(3.0), limits, point.angles, 3.0 * WEAK_FIELD * 2, 11)
    never = _scan_to(supervisor(float('nan')), limits, point.angles, 0.01, 11)
    for path in (live, never):
        np.testing.assert_allclose(path, [point.angles] * 11)
