"""landmark_detector_node: poles in a LaserScan, as a PoseArray in the scan's frame.

Subscribes `scan` (sensor_msgs/LaserScan, sensor-data QoS) and publishes `landmarks`
(geometry_msgs/PoseArray, same header: the scan's frame and stamp) with the pole centres the
core's detector finds, one pose per pole at (x, y, 0); a scan with no pole gives an empty
PoseArray, so the filter still sees when the scan was taken. Run one node per LiDAR by
remapping: `--ros-args -r scan:=scan2 -r __node:=landmark_detector_scan2`.

A scan whose beam geometry is not one (angle_increment 0, angles not finite, a ranges count
that disagrees with angle_min/max/increment, more than one turn, bad range limits:
core.validation's scan check) would place poles at made-up bearings: it is dropped and
counted as `dropped_bad_scan` in /diagnostics, as is a scan with a zero stamp
(`dropped_zero_stamp`) and bytes that are not a LaserScan (`dropped_malformed`: scans are read
serialized, nodes/wire.py). Ranges themselves may be inf or NaN (REP-117: no return).
Each scan is passed on as it comes: two scans with one stamp give two landmarks messages
with that stamp, and ekf_node keeps the first (core/same_stamp.py). /diagnostics also says
how many readers `landmarks` has matched (`landmarks_readers`, this node's side of
discovery: a landmarks message published before the EKF node's reader matched is lost),
every period and at once when a reader of `landmarks` or `/diagnostics` matches or leaves
(so also before /clock runs under use_sim_time).
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Header

from gyro_ekf import topics
from gyro_ekf.core.config import DetectorConfig
from gyro_ekf.core.detection import detect_poles
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.validation import scan_geometry_problem
from gyro_ekf.nodes import qos, wire
from gyro_ekf.nodes.conversions import (beam_bearings, points_message, scan_arrays,
                                        scan_problem, stamp_ns)
from gyro_ekf.nodes.params import declare, declare_config, report_ignored
from gyro_ekf.nodes.runtime import run_node


class LandmarkDetectorNode(Node):
    """Pole detection as a ROS node (see the module docstring).

    Attributes:
        config: the detector configuration.
        scans: scans processed.
        poles: poles published.
        dropped: scans dropped per reason.
    """

    def __init__(self, **kwargs) -> None:
        """Declare parameters, create the subscription, publisher and timer."""
        super().__init__('landmark_detector_node', **kwargs)
        self.config = declare_config(self, DetectorConfig)
        lossless = declare(self, 'reliable_inputs', False,
                           'Reliable keep-all QoS on scan and landmarks instead of sensor data '
                           'QoS (lossless replay, tests)')
        period = declare(self, 'diagnostics_period_s', 1.0,
                         'Period of the /diagnostics status', 's', 0.01, 3600.0)
        report_ignored(self, {})
        self.scans = 0
        self.poles = 0
        self.dropped = {'zero_stamp': 0, 'bad_scan': 0, 'malformed': 0}
        # A reader of either topic that comes or goes is reported at once, not at the next
        # period: under use_sim_time the timer waits for /clock, and whoever starts the
        # replay once the landmarks reach the EKF node would wait for ever.
        report = PublisherEventCallbacks(matched=lambda _status: self._publish_diagnostics())
        self._publisher = self.create_publisher(PoseArray, topics.LANDMARKS,
                                                qos.stream_output(lossless),
                                                event_callbacks=report)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS,
                                                      qos.OUTPUT, event_callbacks=report)
        # Serialized I/O (nodes/wire.py): ranges read in place from the scan's bytes and the
        # poles written as PoseArray bytes; the same numbers as rclpy messages.
        serialized = wire.serialized_io()
        self.create_subscription(LaserScan, topics.SCAN,
                                 self._on_scan_bytes if serialized else self._on_scan,
                                 qos.sensor_input(lossless), raw=serialized)
        self.create_timer(period, self._publish_diagnostics)

    def _on_scan(self, message: LaserScan) -> None:
        if self._usable(stamp_ns(message.header.stamp), scan_problem(message)):
            self._detect(*scan_arrays(message),
                         lambda points: points_message(message.header, points))

    def _on_scan_bytes(self, data: bytes) -> None:
        try:
            scan = wire.decode_scan(data)
        except wire.WireError as err:
            self._drop('malformed', f'{topics.SCAN}: {err}')
            return
        beams = len(scan.ranges)
        if self._usable(stamp_ns(scan.stamp), scan_geometry_problem(
                scan.angle_min, scan.angle_max, scan.angle_increment, beams, scan.range_min,
                scan.range_max)):
            intensities = scan.intensities if beams and len(scan.intensities) == beams else None
            self._detect(scan.ranges, beam_bearings(scan.angle_min, scan.angle_increment, beams),
                         intensities, lambda points: wire.points_bytes(scan.header, points))

    def _usable(self, ns: int, problem: str | None) -> bool:
        """Tell whether a scan can be used; count it dropped if not."""
        if ns == 0:
            self._drop('zero_stamp', 'scan with a zero stamp')
        elif problem is not None:
            self._drop('bad_scan', problem)
        else:
            return True
        return False

    def _detect(self, ranges, angles, intensities, landmarks) -> None:
        """Detect poles and publish landmarks(points) (a PoseArray or its bytes)."""
        try:
            detections = detect_poles(ranges, angles, intensities, self.config)
        except CoreError as err:
            self._drop('bad_scan', str(err))
            return
        self.scans += 1
        self.poles += len(detections)
        self._publisher.publish(landmarks(detections.points_sensor_m))

    def _drop(self, reason: str, why: str) -> None:
        self.dropped[reason] += 1
        self.get_logger().warn(f'dropped a scan: {why} (counts {self.dropped})',
                               throttle_duration_sec=5.0)

    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name=f'{self.get_fully_qualified_name()}: pole detector',
                                  hardware_id=self.resolve_topic_name(topics.SCAN))
        status.level = DiagnosticStatus.OK if self.scans else DiagnosticStatus.WARN
        status.message = 'detecting' if self.scans else 'no scans yet'
        values = {'scans': self.scans, 'poles': self.poles,
                  'landmarks_readers': self._publisher.get_subscription_count(),
                  **{f'dropped_{k}': v for k, v in self.dropped.items()}}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        self._diagnostics_pub.publish(DiagnosticArray(
            header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def main(args: list[str] | None = None) -> int:
    """Entry point of the landmark_detector_node executable."""
    return run_node(LandmarkDetectorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
