"""ekf_node says a run dead-reckoned for over its share in /diagnostics, as `gyro-ekf run` does.

The bag is a simulated 40-s trip (seed 1) whose LiDAR drops out for 3.1 s at 22.5 s: no
gap reaches the 5-s limit, but 3.2 s of the 40 without a landmark update is 8 % of the run
dead-reckoned (core/health.py, ``VERDICT_MAX_DEAD_RECKONED_SHARE``). The node counts the
gaps as the offline run does and gives the same verdict.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def dropout_run(ros_processes, tmp_path_factory):
    """The bag through the detector and EKF nodes, and through `gyro-ekf run`."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

    trip = simulate_trip(SimulationConfig(duration_s=40.0, lidar_dropouts=1,
                                          lidar_dropout_s=3.1), 1)
    return run_and_replay(ros_processes, trip, tmp_path_factory.mktemp('dead_reckoned'))


def test_node_says_the_dead_reckoned_share_as_the_offline_run_does(dropout_run):
    offline, (_, _, values), replay = dropout_run
    assert 'all acknowledged: True' in replay
    association = offline['association']
    assert association['longest_gap_s'] < 5.0
    assert association['dead_reckoned_s'] > 0.05 * association['since_first_update_s']
    said = [r for r in offline['health']['reasons'] if 'dead-reckoned' in r]
    assert len(said) == 1, offline['health']['reasons']
    assert values['dead_reckoned_s'] == f"{association['dead_reckoned_s']:.3f}"
    assert float(values['dead_reckoned_share']) == pytest.approx(
        association['dead_reckoned_s'] / association['since_first_update_s'], abs=1e-3)
    assert values['verdict'] == 'degraded'
    assert values['verdict_reasons'].split(' | ') == offline['health']['reasons']
