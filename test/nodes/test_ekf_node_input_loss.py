"""ekf_node says an input that lost most of its samples in /diagnostics, as `gyro-ekf run` does.

The bag is a simulated 40-s trip (seed 2) whose gyro lost 60 % of its samples at random
after the static start, as a best-effort link that overflows loses them: the stamps of
those that arrived say how many were sent (core/input_loss.py). Its odometry has five lone
samples 2 m/s off (core/input_spikes.py), and its gyro freezes for 2 s (core/input_frozen.py).
The node and the offline run count the same samples, the same spikes, the same frozen
repeats and the same longest silence, and give the same verdict.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def lossy_run(ros_processes, tmp_path_factory):
    """The bag through the detector and EKF nodes, and through `gyro-ekf run`."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

    trip = simulate_trip(SimulationConfig(duration_s=40.0), 2)
    imu = trip.imu
    keep = (imu.stamp_s < 8.0) | (np.random.default_rng(1).random(len(imu.stamp_s)) > 0.6)
    imu = dataclasses.replace(
        imu, stamp_s=imu.stamp_s[keep], angular_velocity_rad_s=imu.angular_velocity_rad_s[keep],
        linear_acceleration_m_s2=None if imu.linear_acceleration_m_s2 is None
        else imu.linear_acceleration_m_s2[keep])
    assert imu.yaw_rate_variance is None
    # And it froze for 2 s (core/input_frozen.py): one value sent again and again.
    rates = imu.angular_velocity_rad_s.copy()
    frozen = np.flatnonzero((imu.stamp_s >= 20.0) & (imu.stamp_s < 22.0))
    rates[frozen] = rates[frozen[0]]
    imu = dataclasses.replace(imu, angular_velocity_rad_s=rates)
    speed = trip.speed.speed_m_s.copy()
    speed[[1000, 1500, 2000, 2500, 3000]] += 2.0  # 10-30 s, driving
    lossy = dataclasses.replace(trip, imu=imu,
                                speed=dataclasses.replace(trip.speed, speed_m_s=speed))
    return (int(keep.sum()),
            *run_and_replay(ros_processes, lossy, tmp_path_factory.mktemp('loss')))


def test_node_says_the_lost_gyro_samples_as_the_offline_run_does(lossy_run):
    received, offline, (_, _, values), replay = lossy_run
    assert 'all acknowledged: True' in replay
    gyro = offline['input_loss']['gyro']
    assert gyro['received'] == received and gyro['share'] < 0.6
    said = [r for r in offline['health']['reasons']
            if r.startswith('gyro: ') and 'repeated one value' not in r]
    assert len(said) == 1, offline['health']['reasons']
    # The same stamps: the same counts and the same reason, word for word.
    assert values['gyro_lost'] == str(gyro['lost'])
    assert values['gyro_received_share'] == f"{gyro['share']:.4f}"
    assert values['odometry_lost'] == '0'
    # Five lone speed samples left out by both, and said alike.
    assert offline['input_spikes']['odometry']['spikes'] == 5
    assert values['odometry_spikes'] == '5' and values['gyro_spikes'] == '0'
    assert any(r.startswith('odometry: 5 lone sample(s)') for r in offline['health']['reasons'])
    # The freeze: found by both, its repeats left out alike.
    frozen = offline['gyro_frozen']
    assert frozen['runs'] == 1 and frozen['samples'] > 100
    assert values['gyro_frozen_runs'] == '1'
    assert values['gyro_frozen_samples'] == str(frozen['samples'])
    assert values['verdict'] == 'degraded'
    assert said[0] in values['verdict_reasons'].split(' | ')
    # The input silences too, from the same counters (a run of lost samples longer than a
    # prediction step): the node's reasons are the offline run's, word for word.
    assert any(r.startswith('gyro silent for ') for r in offline['health']['reasons'])
    assert values['verdict_reasons'].split(' | ') == offline['health']['reasons']
