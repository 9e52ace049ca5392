"""ekf_node takes a LiDAR's scans at their stamps less `lidar.<topic>.time_offset_s`.

The bag is the simulated 120-s trip (seed 3) whose scans are stamped 30 ms late, as in
test_ekf_node_time_offset.py, whose ranges read 3 cm long, and whose LiDAR is mounted
upside down (its beams in reverse order); here the EKF node is given what a verdict
measures, and `gyro-ekf run` the same in a params file. Both take each scan 30 ms before
its stamp, its poles 3 cm nearer (`range_offset_m`) and mirrored into an upright LiDAR's
frame (`upside_down`), measure what is left near zero and say nothing of it. Its yaw is
given a sigma (`yaw_sigma_rad`, small beside the heading's own): both widen the heading
they report by it alike.

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros

OFFSET_S = 0.03
RANGE_OFFSET_M = 0.03
YAW_SIGMA_RAD = 0.0001


@pytest.fixture(scope='module')
def corrected_run(ros_processes, tmp_path_factory):
    """The bag through the nodes with the offset set, and through `run --params-file`."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

    trip = simulate_trip(SimulationConfig(duration_s=120.0), 3)
    late = dataclasses.replace(trip, scans=[
        dataclasses.replace(
            scans, stamp_s=scans.stamp_s + OFFSET_S,
            ranges_m=np.ascontiguousarray(scans.ranges_m[:, ::-1] + RANGE_OFFSET_M,
                                          dtype=np.float32),
            intensities=None if scans.intensities is None
            else np.ascontiguousarray(scans.intensities[:, ::-1]))
        for scans in trip.scans])
    folder = tmp_path_factory.mktemp('corrected')
    params = folder / 'offset.yaml'
    params.write_text('/**:\n  ros__parameters:\n    lidar:\n      topics: [scan]\n'
                      f'      scan: {{time_offset_s: {OFFSET_S}, '
                      f'range_offset_m: {RANGE_OFFSET_M}, upside_down: true, '
                      f'yaw_sigma_rad: {YAW_SIGMA_RAD}}}\n')
    return run_and_replay(ros_processes, late, folder,
                          ekf_args=('-p', f'lidar.scan.time_offset_s:={OFFSET_S}',
                                    '-p', f'lidar.scan.range_offset_m:={RANGE_OFFSET_M}',
                                    '-p', 'lidar.scan.upside_down:=true',
                                    '-p', f'lidar.scan.yaw_sigma_rad:={YAW_SIGMA_RAD}'),
                          run_args=('--params-file', str(params)))


def test_node_takes_the_scans_less_the_offset_as_the_offline_run_does(corrected_run):
    offline, (_, _, values), replay = corrected_run
    assert 'all acknowledged: True' in replay
    offset = offline['time_offsets']['scan']
    assert not offset['found'] and abs(offset['offset_s']) < 0.003, offset
    truth = offline['ground_truth']
    assert truth['nees_share_in_band'] >= 0.9 and truth['position_rmse_m'] <= 0.02
    assert offline['health']['verdict'] == 'ok', offline['health']['reasons']
    print(f"left after the offset: node {values['time_offset_scan_ms']} ms, offline "
          f"{1000 * offset['offset_s']:.2f}")
    assert values['time_offset_scan_off'] == 'false'
    # The same scans at the same moments: the same figure, to the digits shown.
    assert values['time_offset_scan_ms'] == f"{1000 * offset['offset_s']:.2f}"
    assert values['verdict'] == 'ok', values['verdict_reasons']
    # The ranges too: the range innovations' mean as near zero as an exact LiDAR's.
    whiteness = offline['health']['lidars'][0]['whiteness']
    assert abs(whiteness['range_mean_m']) < 0.003, whiteness
    # The heading widened by the yaw's sigma (or more, by what the path fit reads), alike.
    widened = offline['online_odometry']['heading_widened_deg']
    assert widened >= math.degrees(YAW_SIGMA_RAD) - 1e-12
    assert values['odometry_heading_widened_deg'] == f'{widened:.4f}'
