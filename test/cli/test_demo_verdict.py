"""The demo's own check of its result (`verdict`), as a pure function."""

from __future__ import annotations

import pytest

from gyro_ekf.cli.demo import (BIAS_LIMIT_DEG_S, END_LIMIT_S, POSITION_LIMIT_M, DemoFailed,
                               ok_clauses, verdict)
from gyro_ekf.errors import GyroEkfError

GOOD = {'online_bias_deg_s': -0.9012, 'true_bias_deg_s': -0.9000,
        'final_position_error_m': 0.004, 'ekf_resets': 0, 'has_ground_truth': True,
        'last_pose_s': 89.995, 'bag_end_s': 89.995}


def test_a_good_result_has_no_problem():
    assert verdict(GOOD) == []
    # At the limits themselves, still good.
    edge = dict(GOOD, online_bias_deg_s=GOOD['true_bias_deg_s'] + BIAS_LIMIT_DEG_S / 2,
                final_position_error_m=POSITION_LIMIT_M)
    assert verdict(edge) == []


def test_a_bias_far_from_the_truth_is_named():
    problems = verdict(dict(GOOD, online_bias_deg_s=-0.870))
    assert len(problems) == 1
    assert 'online bias -0.8700 deg/s is 0.0300 deg/s from the true -0.9000' in problems[0]


def test_a_large_final_position_error_is_named():
    """The failure issue 13 saw: +16.142 m and exit 0."""
    problems = verdict(dict(GOOD, final_position_error_m=16.142))
    assert problems == ['final position error 16.142 m is above 0.05 m']


def test_a_recording_that_ends_early_is_a_failure():
    """A helper's find: ekf_node stalled 5 s after the replay, the recorder stopped idle, and
    the demo said OK of a pose at 75.5 s of a 90-s bag (compared with the truth there)."""
    problems = verdict(dict(GOOD, last_pose_s=75.495))
    assert problems == [
        "the recording ends early: the last pose ekf_node published that was recorded is at "
        "75.495 s, the bag's last gyro sample at 89.995 s (14.5 s later, limit 0.5 s): a node "
        "stalled after the replay, or its output was lost"]
    # At the limit still good; a bag without gyro samples or a run without a pose is judged
    # by the other checks.
    assert verdict(dict(GOOD, last_pose_s=89.995 - END_LIMIT_S)) == []
    assert verdict(dict(GOOD, bag_end_s=None)) == []
    assert verdict(dict(GOOD, last_pose_s=float('nan'))) != []


def test_a_filter_reset_is_a_failure():
    problems = verdict(dict(GOOD, ekf_resets=1))
    assert len(problems) == 1 and 'reset its filter 1 time(s)' in problems[0]


@pytest.mark.parametrize('missing,expected', [
    ('online_bias_deg_s', 'published no bias'),
    ('final_position_error_m', 'published no pose'),
    ('ekf_resets', 'no diagnostics from ekf_node'),
])
def test_a_missing_output_is_a_failure(missing, expected):
    problems = verdict(dict(GOOD, **{missing: None}))
    assert len(problems) == 1 and expected in problems[0]


def test_nan_values_fail():
    problems = verdict(dict(GOOD, online_bias_deg_s=float('nan'),
                            final_position_error_m=float('nan')))
    assert len(problems) == 2


def test_without_ground_truth_only_what_can_be_checked_is():
    result = dict(GOOD, true_bias_deg_s=None, final_position_error_m=None,
                  has_ground_truth=False)
    assert verdict(result) == []
    assert verdict(dict(result, ekf_resets=2)) != []
    # The OK line said "within 0.02 deg/s of the truth" with no truth to compare.
    assert ok_clauses(dict(result, ekf_verdict='ok')) == (
        "the bag has no ground truth nor true bias to compare with, ekf_node's health "
        'verdict ok, no filter reset')
    assert ok_clauses(dict(GOOD, ekf_verdict='degraded')).startswith(
        'online bias within 0.02 deg/s of the truth, final position within 5 cm, '
        "ekf_node's health verdict degraded")


def test_the_nodes_own_failed_verdict_fails_the_demo():
    # Without ground truth it is the only judge of the pose (a blind LiDAR ran 60 s).
    problems = verdict(dict(GOOD, true_bias_deg_s=None, final_position_error_m=None,
                            has_ground_truth=False, ekf_verdict='failed',
                            ekf_verdict_reasons='no landmark update in 60.0 s'))
    assert problems == ["ekf_node judged its run failed: no landmark update in 60.0 s"]
    assert verdict(dict(GOOD, ekf_verdict='degraded')) == []


def test_every_problem_is_listed_and_the_error_is_one_cli_line():
    problems = verdict({'online_bias_deg_s': 0.5, 'true_bias_deg_s': 0.0,
                        'final_position_error_m': 1.0, 'ekf_resets': 3,
                        'has_ground_truth': True})
    assert len(problems) == 3
    assert issubclass(DemoFailed, GyroEkfError)
