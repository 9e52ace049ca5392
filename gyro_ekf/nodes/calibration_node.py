"""calibration_node: gyro bias from a static window, then bias-corrected IMU messages.

Subscribes `imu` (sensor_msgs/Imu), `odom` (nav_msgs/Odometry, optional: any speed above
max_speed_m_s in the window refuses it) and the pole topics `landmark_topics` (default
[`landmarks`], geometry_msgs/PoseArray from landmark_detector_node: poles that turn about
the platform through the window refuse it, core.calibration.confirm_still; a turn in place
shows no speed and a steady gyro rate, which the mean would take for bias). Collects the
static window (by default the first 5 s of IMU messages) in the core's
StaticWindowCalibrator, waiting up to POLE_WAIT_S of gyro time for a LiDAR's late scans.
On success it publishes
`gyro_bias` (geometry_msgs/Vector3Stamped, rad/s; reliable, transient local, so a late
subscriber still gets it), logs the bias in deg/s with the noise sigma per axis, and from
then on republishes every IMU message on `imu/corrected` with the bias removed. A refused
window is logged with the reason and a new window starts. `~/recalibrate` (std_srvs/Trigger)
starts a new window on demand. Status goes to `/diagnostics` once per diagnostics_period_s.
Messages are served in batches gathered for up to `event_batch_s` (runtime._spin_events):
fewer wake-ups per message for that much latency of imu/corrected.

Bad input is dropped and counted per reason in /diagnostics: `zero_stamp`, `non_finite`,
`out_of_range` (a rate or speed beyond the `limits.*` parameters, core.config.InputLimits),
`malformed` (bytes that are not the topic's type: the inputs are read serialized,
nodes/wire.py) and, while collecting, `stamp_jump`: a stamp more than
`limits.max_stamp_jump_s` ahead of the inputs is held until odom confirms it or ten IMU
messages (StampGate's default) go on from it, so a lone message far ahead can neither end a
window nor set where the next one starts. While collecting, a message of imu or odom at the
stamp of the newest one the window took from it is dropped, so the window never takes a
sample twice (core/same_stamp.py, as ekf_node and the offline readers): with the same values
(rates and angular_velocity_covariance diagonal, or speed) as `duplicate`, with other values
as `same_stamp` and a throttled warning naming the topic, the stamp and the field; the first
message is the one kept. The IMU messages republished on `imu/corrected` after the window
are not judged: each input message gives its corrected copy. A former parameter still given
is warned about once and ignored (REMOVED_PARAMETERS).
"""

from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from gyro_ekf import topics
from gyro_ekf.core.calibration import StaticWindowCalibrator
from gyro_ekf.core.config import CalibrationConfig, InputLimits
from gyro_ekf.core.errors import CalibrationError
from gyro_ekf.core.same_stamp import describe_repeat, DUPLICATE, Repeat, SAME_STAMP, \
    SameStampCheck
from gyro_ekf.core.stamp_gate import StampGate
from gyro_ekf.core.types import BiasEstimate
from gyro_ekf.core.validation import rate_problem, speed_problem
from gyro_ekf.io.params_file import NODE_LIMITS
from gyro_ekf.nodes import qos, wire
from gyro_ekf.nodes.conversions import (axes_known, bias_message, corrected_imu, drop_reason,
                                        finite, imu_rates, odometry_speed, stamp_ns,
                                        TimeOrigin, to_stamp)
from gyro_ekf.nodes.params import declare, declare_config, report_ignored
from gyro_ekf.nodes.runtime import log_repeat, run_node

_AXES = 'xyz'

_FIELDS = {'imu': ('angular_velocity', 'angular_velocity_covariance'),
           'odom': ('twist.twist.linear.x',)}
"""The message fields of each input's values the window takes, in their order."""

LIMITS_USED = NODE_LIMITS['calibration_node']
"""The InputLimits fields this node checks (declared as limits.*)."""

REMOVED_PARAMETERS = {
    'confirm_jump_after': 'now StampGate\'s default, 10 messages',
    **{f'limits.{name}': 'this node never checked it' for name in (
        'max_coordinate_m', 'max_mount_offset_m', 'max_angle_rad', 'max_duration_s',
        'quaternion_norm_tolerance')},
}
"""Former parameters -> what became of them (a user still giving one is warned once)."""


class CalibrationNode(Node):
    """Static-window gyro calibration as a ROS node (see the module docstring).

    Attributes:
        calibrator: the core's StaticWindowCalibrator.
        result: the accepted BiasEstimate, or None while collecting.
        dropped: messages dropped per reason.
    """

    def __init__(self, **kwargs) -> None:
        """Declare parameters, create the calibrator, topics, service and timer."""
        super().__init__('calibration_node', **kwargs)
        self.config = declare_config(self, CalibrationConfig)
        self._limits = declare_config(self, InputLimits, prefix='limits.', names=LIMITS_USED)
        use_odom = declare(self, 'use_odom', True,
                           'Subscribe odom and refuse a window in which the platform moves')
        lossless = declare(self, 'reliable_inputs', False,
                           'Reliable keep-all QoS on inputs and imu/corrected instead of sensor '
                           'data QoS (lossless replay, tests)')
        period = declare(self, 'diagnostics_period_s', 1.0,
                         'Period of the /diagnostics status', 's', 0.01, 3600.0)
        self.event_batch_s = declare(
            self, 'event_batch_s', 0.01,
            'Serve incoming messages in batches gathered for up to this long (fewer wake-ups '
            'per message, up to this much latency of imu/corrected); 0: each as it comes',
            's', 0.0, 0.1)
        pole_topics = declare(self, 'landmark_topics', [topics.LANDMARKS],
                              'Pole topics (PoseArray in a LiDAR frame, landmark_detector_node) '
                              'whose poles must not turn about the platform through the '
                              'window: a turn in place shows no speed and a steady gyro rate; '
                              '[] = the gyro and odom alone')
        report_ignored(self, REMOVED_PARAMETERS)
        self.calibrator = StaticWindowCalibrator(self.config)
        self._pole_messages = 0
        self.result: BiasEstimate | None = None
        self.dropped = {'non_finite': 0, 'out_of_range': 0, 'zero_stamp': 0,
                        'stamp_jump': 0, 'malformed': 0, SAME_STAMP: 0, DUPLICATE: 0}
        self._origin = TimeOrigin()
        self._gate = StampGate(self._limits.max_stamp_jump_s)
        # One sample per instant and input in the window (after the gate, as in ekf_node).
        self._same_stamp = SameStampCheck()
        self._window_from_s: float | None = None
        self._axes_known: tuple[bool, bool, bool] | None = None
        self._imu_count = 0
        self._corrected_count = 0
        self._last_refusal = ''

        self._bias_pub = self.create_publisher(Vector3Stamped, topics.GYRO_BIAS, qos.LATCHED)
        self._corrected_pub = self.create_publisher(Imu, topics.IMU_CORRECTED,
                                                    qos.stream_output(lossless))
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS,
                                                      qos.OUTPUT)
        # Serialized I/O (nodes/wire.py): the IMU read from its bytes and imu/corrected
        # patched into them; the same numbers as rclpy messages, a fraction of the CPU.
        self._serialized = wire.serialized_io()
        self._send_corrected, self._corrected_readers = (
            wire.raw_publisher(self._corrected_pub) if self._serialized else
            (self._corrected_pub.publish, self._corrected_pub.get_subscription_count))
        self._max_rate = self._limits.max_yaw_rate_rad_s
        self._bias_floats = (0.0, 0.0, 0.0)  # result.bias_rad_s as floats, once calibrated
        if self._serialized:
            self.create_subscription(Imu, topics.IMU, self._on_imu_bytes,
                                     qos.sensor_input(lossless), raw=True)
        else:
            self.create_subscription(Imu, topics.IMU, self._on_imu, qos.sensor_input(lossless))
        self._pole_topics = list(pole_topics)
        self._pole_subs: list = []
        self._use_odom = use_odom
        self._witness_qos = qos.sensor_input(lossless)
        self._odom_sub = None
        self._subscribe_witnesses()
        self.create_service(Trigger, '~/recalibrate', self._on_recalibrate)
        self.create_timer(period, self._publish_diagnostics)
        self.get_logger().info(
            f'collecting a {self.config.window_length_s:g} s static window from '
            f'{self.resolve_topic_name(topics.IMU)}')

    def _subscribe_witnesses(self) -> None:
        """Subscribe to the window's witnesses: the poles, and the speed if used."""
        if not self._pole_subs:
            self._pole_subs = [
                self.create_subscription(PoseArray, name,
                                         lambda message, name=name: self._on_poles(message, name),
                                         self._witness_qos)
                for name in self._pole_topics]
        if self._use_odom and self._odom_sub is None:
            self._odom_sub = self.create_subscription(
                Odometry, topics.ODOM,
                self._on_odom_bytes if self._serialized else self._on_odom, self._witness_qos,
                raw=self._serialized)

    def _usable(self, ns: int, problem: str | None) -> bool:
        if ns == 0:
            self._drop('zero_stamp', 'a message with a zero stamp')
        elif problem is not None:
            self._drop(drop_reason(problem, 'out_of_range'), problem)
        else:
            return True
        return False

    def _drop(self, reason: str, why: str) -> None:
        self.dropped[reason] += 1
        self.get_logger().warn(f'dropped: {why} (counts {self.dropped})',
                               throttle_duration_sec=5.0)

    def _on_poles(self, message: PoseArray, topic: str) -> None:
        """Give a scan's poles to the window (in the LiDAR's frame: see add_poles)."""
        if not self.calibrator.collecting:
            return
        ns = stamp_ns(message.header.stamp)
        points = [(pose.position.x, pose.position.y) for pose in message.poses
                  if finite(pose.position.x, pose.position.y)]
        if ns == 0:
            return  # no time to place it at (a detector always stamps its scans)
        self._pole_messages += 1
        self.calibrator.add_poles(message.header.frame_id or topic, self._origin.seconds(ns),
                                  points)

    def _on_odom(self, message: Odometry) -> None:
        self._take_speed(stamp_ns(message.header.stamp), odometry_speed(message))

    def _on_odom_bytes(self, data: bytes) -> None:
        try:
            sample = wire.decode_odometry(data)
        except wire.WireError as err:
            self._drop('malformed', f'{topics.ODOM}: {err}')
            return
        self._take_speed(stamp_ns(sample.stamp), sample.speed_m_s)

    def _take_speed(self, ns: int, speed: float) -> None:
        if self.calibrator.collecting and self._usable(ns, speed_problem(speed, self._limits)):
            self._offer('odom', ns, speed, (speed,))

    def _on_imu(self, message: Imu) -> None:
        covariance = message.angular_velocity_covariance
        self._take_imu(message.header.stamp, message.header.frame_id, imu_rates(message),
                       (covariance[0], covariance[4], covariance[8]),
                       lambda bias: corrected_imu(message, bias))

    def _on_imu_bytes(self, data: bytes) -> None:
        if self.result is not None:
            self._correct_imu_bytes(data)
            return
        try:
            sample = wire.decode_imu(data)
        except wire.WireError as err:
            self._drop('malformed', f'{topics.IMU}: {err}')
            return
        self._take_imu(sample.stamp, sample.frame_id, sample.rates, sample.covariance,
                       lambda bias: wire.corrected_imu(sample, bias))

    def _correct_imu_bytes(self, data: bytes) -> None:
        """After the window: check an IMU message and publish it corrected, from its bytes.

        _take_imu's checks and counts without its objects: the message is read with
        wire.imu_rates and imu/corrected is a copy of its bytes with the rates patched.
        """
        try:
            data, sec, nanosec, at, x, y, z = wire.imu_rates(data)
        except wire.WireError as err:
            self._drop('malformed', f'{topics.IMU}: {err}')
            return
        ns = sec * 1_000_000_000 + nanosec  # conversions.stamp_ns
        limit = self._max_rate
        # The comparisons are the fast path (NaN fails them too); _usable says why.
        if not (ns and -limit <= x <= limit and -limit <= y <= limit and -limit <= z <= limit):
            problem = next((p for p in (rate_problem(r, self._limits) for r in (x, y, z)) if p),
                           None)
            if not self._usable(ns, problem):
                return
        self._imu_count += 1
        # Building the corrected copy costs more than the callback; skip it unheard.
        if self._corrected_readers():
            bx, by, bz = self._bias_floats
            self._send_corrected(wire.patched_imu(data, at, x - bx, y - by, z - bz))
            self._corrected_count += 1

    def _take_imu(self, stamp, frame_id: str, rates: tuple[float, float, float],
                  covariance: tuple[float, float, float], corrected) -> None:
        """Check an IMU sample (either path); corrected(bias) is its imu/corrected copy.

        covariance: angular_velocity_covariance[0], [4], [8].
        """
        ns = stamp_ns(stamp)
        problem = next((p for p in (rate_problem(r, self._limits) for r in rates) if p), None)
        if not self._usable(ns, problem):
            return
        self._imu_count += 1
        if self.result is not None:
            # Building the corrected copy costs more than the callback; skip it unheard.
            if self._corrected_readers():
                self._send_corrected(corrected(self.result.bias_rad_s))
                self._corrected_count += 1
            return
        self._offer('imu', ns, (rates, (stamp, frame_id, covariance)), (rates, covariance))

    def _offer(self, stream: str, ns: int, payload, values: tuple) -> None:
        """Pass a sample through the stamp gate to the calibrator.

        values: what the window takes from the message, compared when a second message of
        the stream comes at the stamp of the newest one taken (core.same_stamp).
        """
        passed, dropped = self._gate.offer(stream, self._origin.seconds(ns),
                                           (ns, values, payload))
        for name, stamp_s, _ in dropped:
            self._drop('stamp_jump', f'{name} stamp {stamp_s:.3f} s is more than '
                       f'{self._gate.max_jump_s:g} s (limits.max_stamp_jump_s) ahead of the '
                       'other samples and its input did not go on from it')
        for name, stamp_s, (taken_ns, taken, value) in passed:
            repeat = self._same_stamp.judge(name, taken_ns, taken)
            if repeat is not None:
                self._repeated(repeat, name, taken_ns, stamp_s)
            elif name == 'odom':
                if self.calibrator.collecting:
                    self.calibrator.add_speed(stamp_s, value)
            elif self.result is None:
                self._collect(stamp_s, *value)

    def _repeated(self, repeat: Repeat, stream: str, ns: int, stamp_s: float) -> None:
        """Count (and log) a sample dropped at the stamp of the one taken on its input."""
        self.dropped[repeat.reason] += 1
        topic = self.resolve_topic_name(topics.IMU if stream == 'imu' else topics.ODOM)
        log_repeat(self, repeat.reason == DUPLICATE,
                   describe_repeat(repeat, topic, ns, stamp_s, _FIELDS[stream]), self.dropped)

    def _collect(self, stamp_s: float, rates: tuple[float, float, float],
                 message: tuple) -> None:
        """Add a sample to the window; message: (stamp, frame_id, covariance diagonal)."""
        if self._window_from_s is None:
            self._window_from_s = stamp_s + self.config.window_start_s
            self._axes_known = axes_known(*message[2])
        if stamp_s < self._window_from_s:
            return
        try:
            result = self.calibrator.add_imu(stamp_s, rates, self._axes_known)
        except CalibrationError as err:
            self._last_refusal = str(err)
            self.get_logger().warn(f'static window refused: {err}; starting a new window')
            return
        if result is not None:
            self._accept(result, message)

    def _accept(self, result: BiasEstimate, message: tuple) -> None:
        self.result = result
        self._bias_floats = tuple(float(b) for b in result.bias_rad_s)
        if self._odom_sub is not None:
            # Speed only matters while collecting; stop paying for its callbacks.
            self.destroy_subscription(self._odom_sub)
            self._odom_sub = None
        for subscription in self._pole_subs:
            # Nor do the poles (a LiDAR's scans come 10-40 times a second).
            self.destroy_subscription(subscription)
        self._pole_subs = []
        stamp, frame_id, _ = message
        self._bias_pub.publish(bias_message(to_stamp(stamp_ns(stamp)), frame_id,
                                            result.bias_rad_s))
        known = self._axes_known or (True, True, True)
        text = ', '.join(
            f'{axis} {math.degrees(b):+.4f} deg/s (sigma {math.degrees(s):.4f})'
            for axis, b, s, k in zip(_AXES, result.bias_rad_s, result.sigma_rad_s, known) if k)
        seen = ''.join(f"; LiDAR '{turn.topic}' saw a turn of "
                       f'{math.degrees(turn.rate_rad_s):+.4f} deg/s ({turn.poles} poles): none '
                       f'beyond {math.degrees(turn.ruled_out_rad_s):.3f} deg/s'
                       for turn in result.scan_turns)
        self.get_logger().info(
            f'gyro bias from {result.n_samples} samples over '
            f'{result.window_end_s - result.window_start_s:.2f} s: {text}{seen}')

    def _on_recalibrate(self, request: Trigger.Request, response: Trigger.Response
                        ) -> Trigger.Response:
        self.restart('recalibration requested')
        response.success = True
        response.message = (f'collecting a new {self.config.window_length_s:g} s static '
                            'window; keep the platform still')
        return response

    def restart(self, why: str) -> None:
        """Drop the current result and collect a new static window."""
        self.calibrator.restart()
        self.result = None
        self._window_from_s = None
        self._gate.clear()
        self._same_stamp.clear()
        self._subscribe_witnesses()
        self.get_logger().info(f'{why}: collecting a new static window')

    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name=f'{self.get_fully_qualified_name()}: gyro calibration',
                                  hardware_id=self.resolve_topic_name(topics.IMU))
        values = {'state': 'calibrated' if self.result is not None else 'collecting',
                  'imu_messages': str(self._imu_count),
                  'corrected_messages': str(self._corrected_count),
                  'refused_windows': str(self.calibrator.refusals),
                  'last_refusal': self._last_refusal,
                  # Scans of poles taken while collecting (the turn-in-place check's).
                  'pole_messages': str(self._pole_messages)}
        values.update({f'dropped_{k}': str(v) for k, v in self.dropped.items()})
        if self.result is not None:
            status.level = DiagnosticStatus.OK
            status.message = 'bias calibrated'
            for axis, b, s in zip(_AXES, self.result.bias_rad_s, self.result.sigma_rad_s):
                values[f'bias_{axis}_deg_s'] = f'{math.degrees(b):.5f}'
                values[f'sigma_{axis}_deg_s'] = f'{math.degrees(s):.5f}'
            for turn in self.result.scan_turns:
                values[f'lidar_{turn.topic}_turn_deg_s'] = f'{math.degrees(turn.rate_rad_s):.5f}'
        elif self._imu_count == 0:
            status.level = DiagnosticStatus.WARN
            status.message = 'no IMU messages yet'
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'collecting the static window'
            if self.calibrator.refusals:
                status.level = DiagnosticStatus.WARN
                status.message = 'collecting again after a refused window'
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        self._diagnostics_pub.publish(DiagnosticArray(
            header=Header(stamp=self.get_clock().now().to_msg()), status=[status]))


def main(args: list[str] | None = None) -> int:
    """Entry point of the calibration_node executable."""
    return run_node(CalibrationNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
