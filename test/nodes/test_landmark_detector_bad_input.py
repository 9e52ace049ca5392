"""landmark_detector_node fed scans whose beam geometry is not one: dropped and counted.

The test checks only the landmarks and diagnostics of its own node, for scans it sent.
"""

from __future__ import annotations

import math
import time

import pytest

pytestmark = pytest.mark.ros


def _scan(stamp_s: int, increment: float, ranges: list[float]):
    from sensor_msgs.msg import LaserScan
    scan = LaserScan()
    scan.header.stamp.sec = stamp_s
    scan.header.frame_id = 'laser'
    scan.angle_min = -math.pi / 2
    scan.angle_increment = increment
    scan.angle_max = -math.pi / 2 + math.radians(0.5) * (361 - 1)
    scan.range_min, scan.range_max = 0.0, 50.0
    scan.ranges = ranges
    return scan


def test_scans_with_a_broken_beam_geometry_are_dropped_and_counted(ros_processes,
                                                                   diagnostics_of):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseArray
    from sensor_msgs.msg import LaserScan

    from gyro_ekf.nodes import qos

    processes, probe = ros_processes
    name = 'detector_bad'
    processes.node('landmark_detector_node', '-r', f'__ns:=/{name}',
                   '-p', 'reliable_inputs:=true', '-p', 'diagnostics_period_s:=0.1',
                   name=name)
    scans = probe.node.create_publisher(LaserScan, f'/{name}/scan', qos.LOSSLESS)
    landmarks = probe.subscribe(PoseArray, f'/{name}/landmarks', qos.LOSSLESS)
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    probe.spin_until(lambda: scans.get_subscription_count() > 0
                     and probe.node.count_publishers(f'/{name}/landmarks') > 0, 20,
                     'the detector')
    # A wall at 5 m with one pole 8 cm wide at 3 m: a real scan finds one pole.
    ranges = [5.0] * 361
    for beam in range(179, 182):
        ranges[beam] = 3.0
    increment = math.radians(0.5)
    stamps = lambda: [m.header.stamp.sec for m in landmarks]  # noqa: E731
    # The detector's landmarks publisher matches this probe's subscription on its own
    # discovery, which can come after the probe sees the publisher: a landmarks message
    # sent before then is lost. Good scans stamped before the test's, one a second, until
    # one comes back.
    warm_ups: list[float] = []

    def warmed_up() -> bool:
        if not warm_ups or time.monotonic() - warm_ups[-1] > 1.0:
            scans.publish(_scan(1_700_001_000 + len(warm_ups), increment, ranges))
            warm_ups.append(time.monotonic())
        return any(s < 1_700_002_000 for s in stamps())

    probe.spin_until(warmed_up, 20, 'a first landmarks message of the detector')
    scans.publish(_scan(1_700_002_001, 0.0, ranges))  # every beam at one bearing
    scans.publish(_scan(1_700_002_002, increment, ranges[:200]))  # count disagrees
    scans.publish(_scan(1_700_002_003, math.nan, ranges))
    scans.publish(_scan(1_700_002_004, increment, ranges))  # good
    probe.spin_until(lambda: 1_700_002_004 in stamps(), 20, 'the good scan')
    key = f'/{name}/landmark_detector_node: pole detector'
    good_scans = str(len(warm_ups) + 1)
    probe.spin_until(lambda: (diagnostics_of(diagnostics, key) or {}).get('scans')
                     == good_scans, 20, 'diagnostics after the scans')
    values = diagnostics_of(diagnostics, key)
    assert values['dropped_bad_scan'] == '3'
    assert [s for s in stamps() if 1_700_002_000 < s < 1_700_002_010] == [1_700_002_004]
    good = next(m for m in landmarks if m.header.stamp.sec == 1_700_002_004)
    assert len(good.poses) == 1
    assert 'angle_increment is 0' in processes.log(name)
