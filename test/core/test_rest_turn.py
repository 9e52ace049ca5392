"""A stop the odometry calls still while the LiDAR's poles turn (core/rest_turn.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.rest_turn import RestTurnWatch
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.types import LidarMount

POLES = np.array([[4.0, 1.0], [6.0, -2.0], [3.0, 3.5], [8.0, 0.5], [5.0, -4.0]])
MOUNT = LidarMount(0.5, 0.0, 0.1)


def _scan(yaw_rad, rng):
    """Poles seen from a platform at the origin turned by yaw_rad, in the LiDAR's frame."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    body = POLES @ np.array([[c, -s], [s, c]])  # R(yaw)^T p, row by row
    lidar = body - [MOUNT.x_m, MOUNT.y_m]
    cm, sm = math.cos(MOUNT.yaw_rad), math.sin(MOUNT.yaw_rad)
    sensor = lidar @ np.array([[cm, -sm], [sm, cm]])
    return sensor + rng.normal(0.0, 0.003, sensor.shape)


def _stop(watch, rate_deg_s, seconds, start_s=0.0, hz=10.0, seed=0):
    rng = np.random.default_rng(seed)
    for k in range(int(seconds * hz)):
        t = start_s + k / hz
        watch.add('scan', t, _scan(math.radians(rate_deg_s) * t, rng), MOUNT)


def test_a_turn_in_place_is_found_and_a_still_stop_is_not():
    watch = RestTurnWatch()
    _stop(watch, 0.0, 6.0)
    watch.close(6.0)
    assert watch.turns == []
    _stop(watch, 0.2, 6.0, start_s=10.0)
    [turn] = watch.report(16.0)  # under way
    assert turn['rate_deg_s'] == pytest.approx(0.2, abs=0.03)
    assert turn['lidar'] == 'scan' and turn['poles'] == len(POLES)
    watch.close(16.0)
    assert [t['start_s'] for t in watch.turns] == [10.0]
    assert watch.report() == watch.turns


def test_a_short_stop_is_not_judged():
    # A turn the poles of under 2 s could show is the gyro's to see.
    watch = RestTurnWatch()
    _stop(watch, 1.0, 1.5)
    watch.close(1.5)
    assert watch.turns == []


def test_save_and_restore_put_the_stop_back():
    watch = RestTurnWatch()
    _stop(watch, 0.0, 3.0)
    saved = watch.save()
    _stop(watch, 0.5, 5.0, start_s=3.0, seed=1)
    watch.close(8.0)
    assert watch.turns
    watch.restore(saved)
    assert watch.turns == [] and watch.report(3.0) == []
    _stop(watch, 0.0, 3.0, start_s=3.0, seed=2)
    watch.close(6.0)
    assert watch.turns == []


def test_the_stop_under_way_is_judged_again_every_2_s_of_scans(monkeypatch):
    # The EKF node asks at every 1-Hz diagnostics tick; a long stop's judgement costs some
    # 20 ms, so it is kept until the scans run MIN_STOP_S past it.
    from gyro_ekf.core import rest_turn
    calls = []

    def counted(*args):
        calls.append(args[0][-1])
        return pole_turn(*args)

    pole_turn = rest_turn.pole_turn
    monkeypatch.setattr(rest_turn, 'pole_turn', counted)
    watch = RestTurnWatch()
    reports = []
    for second in range(20):
        _stop(watch, 0.3, 1.0, start_s=float(second), seed=second)
        reports.append(watch.report(second + 1.0))
    # Judged from the first report whose scans span 2 s (0-2.9 s), then once they run 2 s
    # past the last judgement (asked each second: 2 s after it, or 3 by rounding).
    spacing = np.diff(calls)
    assert calls[0] == 2.9 and 7 <= len(calls) <= 9
    assert np.all((spacing > 1.99) & (spacing < 3.01))
    # Found once judged, its end the stamp asked about.
    assert [len(found) for found in reports] == [0, 0] + [1] * 18
    assert reports[-1][0]['end_s'] == 20.0 and reports[-2][0]['end_s'] == 19.0
    # A restored stop is judged anew: the judgement of the scans it let go is not its.
    saved = watch.save()
    watch.restore(saved)
    judged = len(calls)
    assert watch.report(20.0) == reports[-1] and len(calls) == judged + 1
    still = RestTurnWatch()
    _stop(still, 0.0, 3.0)
    before = still.save()
    _stop(still, 1.0, 3.0, start_s=3.0, seed=1)
    assert still.report(6.0)
    still.restore(before)
    assert still.report(3.0) == []
    # The stop's close judges it whole, whatever was kept.
    watch.close(20.5)
    assert watch.turns[0]['end_s'] == 20.5 and watch.turns[0]['scans'] >= 190


def test_a_long_stop_is_kept_thinned_end_to_end():
    watch = RestTurnWatch()
    _stop(watch, 0.1, 150.0)  # 1500 scans, over the 1024 kept
    [turn] = watch.report(150.0)
    assert turn['scans'] < 1024 and turn['start_s'] == 0.0
    assert turn['rate_deg_s'] == pytest.approx(0.1, abs=0.01)


@pytest.mark.parametrize('turn_deg_s', [0.0, 0.2])
def test_the_verdict_names_a_turn_the_odometry_called_still(turn_deg_s):
    # The filter's zero-rate updates take the gyro's rate at the stop for bias; turning on
    # the spot, that is the turn. The verdict named everything but it.
    trip = simulate_trip(SimulationConfig(duration_s=30.0, static_s=10.0,
                                          static_turn_rad_s=math.radians(turn_deg_s)), 4)
    summary = summarize(run_trip(trip))
    said = [r for r in summary['health']['reasons'] if 'turned in place' in r]
    if turn_deg_s == 0.0:
        assert said == [] and summary['rest_turns'] == []
        return
    [turn] = summary['rest_turns']
    assert turn['rate_deg_s'] == pytest.approx(turn_deg_s, abs=0.03)
    assert summary['health']['verdict'] != 'ok'
    assert summary['health']['reasons'][0] == said[0]
    assert said[0].startswith(f'the platform turned in place at {turn["rate_deg_s"]:+.3f} '
                              'deg/s')
