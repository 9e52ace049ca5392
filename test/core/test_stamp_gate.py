"""StampGate: stamps far ahead are held until confirmed, outliers dropped, nothing wedges."""

from __future__ import annotations

import math

import pytest

from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.stamp_gate import StampGate


def _offer_all(gate, messages):
    passed, dropped = [], []
    for stream, stamp in messages:
        now, gone = gate.offer(stream, stamp, f'{stream}@{stamp:g}')
        passed += [p for _, _, p in now]
        dropped += [p for _, _, p in gone]
    return passed, dropped


def test_the_start_waits_for_a_second_input_or_a_run_and_passes_everything():
    gate = StampGate(max_jump_s=30.0, confirm_after=3)
    assert gate.offer('imu', 100.0, 'a') == ([], [])
    assert gate.time_s is None and gate.held == 1
    passed, dropped = gate.offer('odom', 99.99, 'b')  # another input agrees
    assert [p for _, _, p in passed] == ['b', 'a'] and dropped == []
    assert gate.time_s == 100.0 and gate.held == 0
    # A lone input sets the time after confirm_after messages.
    lone = StampGate(max_jump_s=30.0, confirm_after=3)
    passed, dropped = _offer_all(lone, [('imu', 1.0), ('imu', 1.01), ('imu', 1.02)])
    assert passed == ['imu@1', 'imu@1.01', 'imu@1.02'] and dropped == []


def test_a_first_message_far_ahead_is_dropped_and_does_not_wedge_the_rest():
    gate = StampGate(max_jump_s=30.0, confirm_after=5)
    passed, dropped = _offer_all(gate, [('imu', 200.0), ('imu', 100.0), ('odom', 100.0),
                                        ('imu', 100.01), ('odom', 100.01)])
    assert dropped == ['imu@200']
    assert passed == ['imu@100', 'odom@100', 'imu@100.01', 'odom@100.01']
    assert gate.time_s == pytest.approx(100.01)


def test_a_stamp_far_ahead_is_dropped_when_its_stream_goes_on_as_before():
    gate = StampGate(max_jump_s=30.0, confirm_after=5)
    _offer_all(gate, [('imu', 0.0), ('odom', 0.0)])
    passed, dropped = _offer_all(gate, [('imu', 1e6), ('odom', 0.01), ('imu', 0.01)])
    assert passed == ['odom@0.01', 'imu@0.01'] and dropped == ['imu@1e+06']
    assert gate.time_s == 0.01
    # A lone stream far ahead while the others still talk is never confirmed: at most
    # confirm_after of its messages are held, the older ones dropped.
    for k in range(20):
        gate.offer('imu', 4e8 + k, k)
        gate.offer('odom', 0.02 + k * 0.01, k)
    assert gate.held == 5 and gate.time_s < 1.0


def test_a_gap_every_input_agrees_on_is_taken_whole():
    gate = StampGate(max_jump_s=5.0, confirm_after=50)
    _offer_all(gate, [('imu', 0.0), ('odom', 0.0)])
    # Both publishers stop for 10 s and resume.
    passed, dropped = _offer_all(gate, [('imu', 10.0), ('imu', 10.01), ('odom', 10.0),
                                        ('imu', 10.02)])
    assert passed == ['imu@10', 'odom@10', 'imu@10.01', 'imu@10.02'] and dropped == []
    assert gate.time_s == 10.02


def test_a_lone_input_that_resumes_after_a_gap_is_taken_after_a_run():
    gate = StampGate(max_jump_s=5.0, confirm_after=3)
    _offer_all(gate, [('imu', 0.0), ('imu', 0.01), ('imu', 0.02)])
    passed, dropped = _offer_all(gate, [('imu', 60.0), ('imu', 60.01)])
    assert passed == [] and dropped == []
    passed, _ = _offer_all(gate, [('imu', 60.02)])
    assert passed == ['imu@60', 'imu@60.01', 'imu@60.02'] and gate.time_s == 60.02


def test_clear_forgets_the_time_and_a_bad_stamp_is_refused():
    gate = StampGate(max_jump_s=5.0, confirm_after=2)
    _offer_all(gate, [('imu', 100.0), ('odom', 100.0)])
    gate.clear()
    assert gate.time_s is None
    passed, _ = _offer_all(gate, [('imu', 0.0), ('odom', 0.0)])
    assert passed == ['imu@0', 'odom@0'] and gate.time_s == 0.0  # 0.0 is a time
    with pytest.raises(CoreError, match='not finite'):
        gate.offer('imu', math.inf, None)
    with pytest.raises(CoreError):
        StampGate(max_jump_s=0.0)
