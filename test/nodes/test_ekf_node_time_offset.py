"""ekf_node says a LiDAR stamped off the gyro in /diagnostics, as `gyro-ekf run` does.

The bag is a simulated 120-s trip (seed 3) whose scans are stamped 30 ms late. Taken at
their stamps, the LiDAR's heading runs behind the gyro's in every turn; its own headings
measure the offset (core/time_offset.py), and both say so with the same figure.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import dataclasses

import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros

SAID = 'LiDAR scan and the gyro disagree in time: '


@pytest.fixture(scope='module')
def late_run(ros_processes, tmp_path_factory):
    """The bag through the detector and EKF nodes, and through `gyro-ekf run`."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

    trip = simulate_trip(SimulationConfig(duration_s=120.0), 3)
    late = dataclasses.replace(trip, scans=[
        dataclasses.replace(scans, stamp_s=scans.stamp_s + 0.03) for scans in trip.scans])
    return run_and_replay(ros_processes, late, tmp_path_factory.mktemp('late'))


def test_node_says_the_time_offset_as_the_offline_run_does(late_run):
    offline, (_, _, values), replay = late_run
    assert 'all acknowledged: True' in replay
    offset = offline['time_offsets']['scan']
    assert offset['found'] and abs(offset['offset_s'] - 0.03) < 0.003, offset
    assert offline['health']['reasons'][0].startswith(SAID), offline['health']['reasons']
    print(f"time offset: node {values['time_offset_scan_ms']} +- "
          f"{values['time_offset_scan_sigma_ms']} ms, offline {1000 * offset['offset_s']:.2f}")
    assert values['time_offset_scan_off'] == 'true'
    # The same windows of the same data: the same figure, to the digits shown.
    assert values['time_offset_scan_ms'] == f"{1000 * offset['offset_s']:.2f}"
    assert values['verdict'] == 'degraded'
    assert values['verdict_reasons'].split(' | ')[0].startswith(SAID)
    # An offset is no scatter (core/stamp_jitter.py takes each scan's about their mean):
    # not found, and the node's figure is the offline run's.
    jitter = offline['stamp_jitter']['scan']
    assert not jitter['found'] and values['stamp_jitter_scan_found'] == 'false'
    assert values['stamp_jitter_scan_ms'] == f"{1000 * jitter['jitter_s']:.2f}"
