"""ekf_node with late scans replayed (late_observation_history_s), fed a replayed bag.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_ekf_node import _offline, _pipeline, _rows, PUBLISH_EVERY

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def lagged_run(ros_processes, sim_bag, diagnostics_of):
    """The simulated bag through the pipeline with late scans replayed, and drive_trip."""
    # The bag plays in real time with the longest history the node takes (5 s): a scan may
    # wait 5 s of wall time for the detector. At 5x with 3 s (0.6 s of wall time) a CI run
    # beside a second copy of the suite dropped 155 scans as late.
    odometry, _, diagnostics, replay, bag_trip = _pipeline(
        ros_processes, diagnostics_of, sim_bag, 1.0, PUBLISH_EVERY,
        ('-p', 'late_observation_history_s:=5.0'))
    _, probe = ros_processes
    _, run = _offline(sim_bag)
    # Replayed scans bypass the merger, so every estimate can reach the probe while the
    # detector still has scans queued, and a count of diagnostics messages includes the
    # detector's. Wait instead for the EKF status that has taken every scan: none held, the
    # offline run's updates and final bias (the last scans come after the last IMU sample:
    # the idle flush releases them). A scan lost or dropped as late shows as a timeout
    # naming the expected and the last values.
    final = {'held_observations': '0', 'associated': str(run.stats.updates),
             'bias_deg_s': f'{math.degrees(run.estimates.state[-1, 3]):.5f}'}
    key = '/ekf_node: gyro bias EKF'

    def status() -> dict[str, str]:
        return diagnostics_of(diagnostics, key) or {}
    try:
        probe.spin_until(lambda: all(status().get(k) == v for k, v in final.items()), 120,
                         f'the EKF status with {final}')
    except AssertionError as err:
        last = {k: status().get(k) for k in final}
        raise AssertionError(f'{err}; the last one has {last}') from None
    return odometry, status(), replay, bag_trip, run


def test_poses_stay_close_to_the_offline_core(lagged_run):
    odometry, _, replay, bag_trip, run = lagged_run
    assert 'all acknowledged: True' in replay
    offline = run.estimates
    rows = np.searchsorted(offline.stamp_s, _rows(odometry, bag_trip.start_time_ns))
    assert len(odometry) == len(offline.stamp_s) // PUBLISH_EVERY
    live = np.array([(m.pose.pose.position.x, m.pose.pose.position.y) for m in odometry])
    print(f'largest distance from the offline pose: '
          f'{np.abs(live - offline.state[rows, :2]).max() * 1e3:.2f} mm')
    # A pose published before the detector's scan reached the filter is a prediction
    # without it: close to the offline one, not equal.
    assert np.abs(live - offline.state[rows, :2]).max() < 0.01


def test_the_filter_ends_where_the_offline_core_ends(lagged_run):
    _, values, _, _, run = lagged_run
    assert values is not None
    print(f"replayed {values['replayed_observations']} scans, "
          f"{values['replayed_events']} inputs again")
    assert int(values['replayed_observations']) > 0
    assert values['dropped_late'] == '0', values
    assert values['held_observations'] == '0', values
    # Every scan arrived within the history: the same updates, the same final bias.
    assert int(values['associated']) == run.stats.updates
    assert values['bias_deg_s'] == f'{math.degrees(run.estimates.state[-1, 3]):.5f}'
