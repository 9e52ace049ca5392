"""ekf_node: pose and gyro bias from odometry speed, IMU yaw rate and pole observations.

Inputs (relative names): `imu` (sensor_msgs/Imu), `odom` (nav_msgs/Odometry, forward speed
in twist.linear.x), one or more observation topics (`landmark_topics`, default
[`landmarks`]: geometry_msgs/PoseArray from landmark_detector_node, whose frame_id picks the
LiDAR mount from the `lidar.*` parameters), `landmark_map` (PoseArray in `map`, transient
local) or the `landmarks_file` parameter, `initialpose` (PoseWithCovarianceStamped: resets
the pose, as RViz's "2D Pose Estimate" does) and, with `use_calibration`, `gyro_bias`
(Vector3Stamped from calibration_node: seeds the bias and its variance).

Messages go through the core's StreamMerger (stamp, then speed < observation < IMU, held
until every active input has passed them) into the same EventDriver `gyro-ekf run` uses, so the
node and an offline run of a bag give the same numbers. That order makes every pose wait for
the slowest input (half a scan period on average behind a 10 Hz LiDAR); with
`late_observation_history_s` > 0, speed and IMU go through at once instead and an observation
that comes after later inputs is replayed into the filter (core `LaggedObservations`): the
filter still ends where strict order ends, but a pose published before a scan arrived is a
prediction without it. Each IMU sample yields an estimate:
`ekf/pose` (PoseWithCovarianceStamped in `map`), `ekf/odometry` (nav_msgs/Odometry: pose
with covariance; speed and bias-corrected yaw rate in the twist) and `ekf/bias`
(Vector3Stamped in the IMU's frame, z = bias in rad/s), every `publish_every_n`-th sample;
`ekf/imu` (sensor_msgs/Imu: each input IMU message with the current online bias, plus the
gyro's wander when one was found, removed and its variance added to
angular_velocity_covariance[8], as imu_tools users expect). For
RViz and Foxglove (nodes.visuals, the same messages `gyro-ekf run` writes into its bag):
`ekf/path` (nav_msgs/Path, the last `path_length` poses, 1 Hz), `ekf/markers`
(MarkerArray: 2-sigma ellipse, heading, the last scan's associated detections with a line
to their landmark and its other detections, 2 Hz), latched `landmark_markers` (the map),
and with `publish_tf` TF `map -> base_link` (or `map -> odom_frame`, robot_localization's
rule) where the install has tf2_msgs. `/diagnostics`
reports the bias and its sigma in deg/s, associated/rejected observations, mean NIS, input
rates, time since the last associated landmark, the time since the first one spent in gaps
of over a second and its share (`dead_reckoned_s`, `dead_reckoned_share`: the verdict's,
core/health.py), the drop counts (with what `gyro-ekf
convert --skip-bad` dropped from the bag's log, as its sidecar records it:
`dropped_when_converted`, `dropped_when_converted_<stream>`, `converted_from`; the verdict
counts it as `gyro-ekf run` does), the matched readers of
ekf/odometry and ekf/bias (`odometry_readers`, `bias_readers`: neither is published without
one, to save the CPU), the zero-rate updates
(`standing_still`: they are being applied now, core/events.py), the start pose held
(`start_pose_held`, and why the hold ended, `start_pose_released`: core/held_start.py),
the samples each input's own stamps say were sent and never reached the filter
(`gyro_lost`, `gyro_received_share`, `odometry_*`: core/input_loss.py) and the scans each
LiDAR's detections lost on the way (`lidar_<name>_scans_lost`,
`lidar_<name>_scans_received_share`), the lone samples
far from both neighbours left out of it (`gyro_spikes`, `odometry_spikes`:
core/input_spikes.py), a gyro's repeats of one value left out (`gyro_frozen_runs`,
`gyro_frozen_samples`: core/input_frozen.py), the odometry samples taken with their own
sample-to-sample spread as their noise, larger than stated (`odometry_noise_widened`,
`odometry_noise_m_s`: core/events.py, learn_speed_noise), the health verdict
of the run since the start or the last reset (`verdict`, `verdict_reasons`: core.health's,
as `gyro-ekf run` writes it in summary.json; level WARN when degraded, ERROR when failed),
with each LiDAR's window figures (`lidar_<scan topic>_*`, `excluded` true while its
observations are kept out of the filter; each exclusion and readmission is logged), and the
LiDAR mounts in use (`mount_<topic>_{frame_id,x_m,y_m,yaw_deg}`: a params file from
`gyro-ekf calibrate-mounts` given after the bag's overrides the bag's mounts, and every
LiDAR but the one defining the body frame, `body_frame_lidar`, has its mount estimated
online, core/mount_online.py: `mount_<topic>_online{,_yaw_sigma_deg,
_yaw_sigma_with_heading_deg,_converged_s,_noise_scale,_noise_scale_reason,_pulls,
_first_pulls}` (the factor on its R and why; the stated mount read off with the pose pulled
its way, or the other way: then the body-frame LiDAR's R is scaled instead), and
`mount_<topic>_online_right_share` while the two LiDARs disagree and the pose published lies
between them, core/body_frame.py; `mount_<topic>_online_widened_m` while they disagree under
the change limits and the published covariance spans it), and
the odometry's speed scale and the first LiDAR's offset estimated online
(core/odometry_online.py: `odometry_scale` in use,
`odometry_scale_{applied,estimate,sigma}`, `odometry_scale_uncertainty` (how far the scale in
use may be off: the position random walk it adds), `odometry_first_lidar_offset_{x_m,y_m,found}`
and `odometry_first_lidar_yaw_{deg,found}` of the last fit,
`odometry_first_lidar_offset_{in_use_x_m,in_use_y_m,applied}`,
`odometry_first_lidar_yaw_in_use_deg` and `odometry_first_lidar_turn_vouched_{deg,by}`: a
first turn another LiDAR's confirmed stated mount vouched against;
`odometry_heading_widened_deg`, how much the published heading is widened for that
LiDAR's yaw: core/body_frame.py), and each LiDAR's range and bearing noise in use,
measured online (core/noise_online.py:
`lidar_<topic>_{range_noise_m,bearing_noise_deg}` in use,
`lidar_<topic>_measured_{range_noise_m,bearing_noise_deg}`, `_noise_measured` (in use),
`_noise_updates`), and each LiDAR's stamps against the gyro's, measured from its headings
(core/time_offset.py: `time_offset_<lidar>_{ms,sigma_ms,off}`, ms late, '' until enough
windows; `off` true when the verdict names it), and the scatter of each LiDAR's stamps
about when its scans were taken (core/stamp_jitter.py: `stamp_jitter_<lidar>_{ms,found}`,
'' until enough scans of a moving platform), and the mapped poles whose detections lie
elsewhere (core/map_poles.py: `map_poles_elsewhere`, their count, and
`map_pole_<index>_seen_at_m`, where each stands: x y in the map frame), and per LiDAR the
turns between its scans that voted on what the gyro reads and those that found it upside
down or its z axis blind to the turns (core/turn_sign.py:
`turn_sign_<lidar>_{votes,opposite,unseen_turns}`);
`ekf/mounts` (PoseArray in
`base_link`, latched) holds the same mounts, one pose per `lidar.topics` entry in that
order, published again when an online estimate replaces one.

Robustness: every value is checked where it enters, with core.validation and the
`limits.*` parameters (the core.config.InputLimits this node uses), and a bad message is
dropped and counted per reason in /diagnostics with a throttled warning: `non_finite`
(NaN/inf), `out_of_range` (a yaw rate, speed or coordinate beyond its limit), `bad_pose` (an
initialpose whose quaternion is not of unit norm or whose covariance is not symmetric
positive semi-definite), `zero_stamp`, `late` (older than what the filter already
processed), `stamp_jump`, and `empty_map`, `unknown_frame`, `filter_error`. A message of an
input (imu, odom, each LiDAR's detections, told apart by their frame_id as the merger does)
at the stamp of the newest message taken from it is dropped, the first one kept
(core/same_stamp.py: the offline rule of core.validation and the bag reader). With the
values the filter took from that one (yaw rate, speed or points, and the message's variance
when `use_message_covariance`) it is an exact repeat, `duplicate`: counted only, no bad
input (not in the verdict, no WARN status, as offline). With other values it is
`same_stamp`: warned about naming the topic, the stamp and the field that differs, and in
the verdict as the other drops (offline, `--skip-bad` drops such a sample and the run is
degraded). `ekf/imu` still carries a corrected copy of every IMU message as it came.

Time: a message stamped more than `limits.max_stamp_jump_s` ahead of the inputs' common time
is held, not predicted through (core StampGate). It is taken, with the gap, when another
input confirms the new time (every input paused and resumed together: a real gap), or after
ten consecutive messages of its input (StampGate's default), each close to the last, while no
other input spoke; if its input goes on near the common time instead, it was an outlier and
is dropped as `stamp_jump`. There is no common time until the first such confirmation, so
a lone first message far from the others cannot wedge the node. An input is silent
(STALE_INPUT_S, core StreamMerger) only when nothing of it was received while the newest
stamp received on any input moved that far on (the data's own ROS time, with or without
use_sim_time) and as long passed on the steady clock: an input whose messages wait in its
queue is served in every executor round, so a busy or starved machine, a /clock that runs
ahead of the queued messages, a burst of one input or a detector upstream that lags does
not make it stale, and its messages are not dropped as late. The filter resets only for a
reason it logs: ROS time jumping back (/clock going backwards, a looped bag with /clock),
stamps that restart (RESTART_AFTER_LATE messages in a row, from every active input,
LOOP_JUMP_S behind the filter: a looped bag without /clock), or `~/reset`
(std_srvs/Trigger). One input whose stamps fall behind only has its messages dropped as
late. The node never dies on input.

Parameters are what a user tunes (noise, priors, gate, map source, frames, calibration use,
observation history, QoS, visuals, TF; docs/parameters.md); the merger's internals are the
module constants below. A former parameter still given is warned about once and ignored
(REMOVED_PARAMETERS).
"""

from __future__ import annotations

import math
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseArray, PoseWithCovarianceStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMessage
from rclpy.clock import Clock, ClockType, JumpThreshold, TimeJump
from rclpy.duration import Duration
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from gyro_ekf import topics
from gyro_ekf.io.visual_bag import MARKERS_PERIOD_S, PATH_LENGTH, PATH_PERIOD_S, \
    PATH_SPACING_S
from gyro_ekf.core.angles import yaw_of_quaternion
from gyro_ekf.core.config import EkfConfig, InputLimits, RunOptions, with_stated_noise
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core import health
from gyro_ekf.core.event_records import Estimate, EventKind
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.input_loss import silences
from gyro_ekf.core.lagged import LaggedObservations, ObservationFate
from gyro_ekf.core.models import points_less_range, points_upright
from gyro_ekf.core.same_stamp import describe_repeat, DUPLICATE, Repeat, SAME_STAMP, \
    SameStampCheck
from gyro_ekf.core.stamps import NS_PER_S
from gyro_ekf.core.stream_order import StreamMerger
from gyro_ekf.core.stamp_gate import StampGate
from gyro_ekf.core.types import LandmarkMap, LidarMount
from gyro_ekf.core.validation import coordinate_problem, duplicate_landmark_problem, \
    initial_pose_problem, many_beyond, message_variance, \
    mount_problem, rate_problem, speed_problem, units_hint
from gyro_ekf.errors import GyroEkfError
from gyro_ekf.io import messages
from gyro_ekf.io.landmarks_file import read_landmarks_file
from gyro_ekf.io.params_file import NODE_LIMITS
from gyro_ekf.nodes import qos, visuals, wire
from gyro_ekf.nodes.conversions import (drop_reason, EstimateMessages, odometry_speed,
                                        online_corrected_imu, points_of, pose_and_covariance,
                                        pose_problem, quaternion_yaw, stamp_ns, TimeOrigin,
                                        yaw_quaternion)
from gyro_ekf.nodes.params import declare, declare_config, declare_sidecar, report_ignored
from gyro_ekf.nodes.runtime import log_repeat, run_node

DROP_REASONS = ('non_finite', 'out_of_range', 'bad_pose', 'zero_stamp', 'late', 'stamp_jump',
                'empty_map', 'bad_map', 'unknown_frame', 'filter_error', 'malformed',
                SAME_STAMP, DUPLICATE)
VERDICT_DROP_REASONS = tuple(r for r in DROP_REASONS if r not in ('late', DUPLICATE))
"""Drops the health verdict counts: all but late messages, which a live node under load
drops by design (the merger's window), not because the input was bad, and exact repeats
(nothing lost: offline a sample recorded twice is dropped without a degraded verdict too).
A message at a stamp already taken with other values counts, as `run --skip-bad` dropping
it does."""
QUIET_DROP_REASONS = (DUPLICATE,)
"""Drops that do not turn the status WARN ("dropping input"): no input was lost."""
_FIELDS = {EventKind.IMU: ('angular_velocity.z', 'angular_velocity_covariance[8]'),
           EventKind.SPEED: ('twist.twist.linear.x', 'twist.covariance[0]'),
           EventKind.OBSERVATION: ('poses', 'LiDAR mount')}
"""The message fields of each input's values the filter takes (event value order)."""
_LEVELS = {health.OK: DiagnosticStatus.OK, health.DEGRADED: DiagnosticStatus.WARN,
           health.FAILED: DiagnosticStatus.ERROR}


STALE_INPUT_S = 1.0
"""An input of which nothing arrived while the newest stamp received on any input moved this
far on, and for this long on the steady clock, stops holding the others back, s: ten periods
of a 10 Hz LiDAR, so a late scan is waited for, and a sensor that stopped costs the others
one second of latency once."""

STALE_RELIABLE_INPUT_WALL_S = 30.0
"""With `reliable_inputs` (every message is delivered, however late), the steady-clock part
of STALE_INPUT_S, s: a detector starved upstream (two CPU hogs per core and a second test
suite on two cores) lagged by more than 1 s, and each landmark message it then sent was
dropped as late although nothing was lost; at 10 s, one run of that kind in four still
dropped 740. A LiDAR that really stopped holds the others back this long, once (a replay,
which is what reliable inputs are for, loses nothing by it)."""

MAX_BUFFERED_EVENTS = 20_000
"""Most messages the merger (and the late-observation history) holds: bounds memory when an
input stalls without going stale; the oldest are released beyond it."""

IDLE_FLUSH_S = 0.5
"""Wall time without input after which held messages are processed, s: at the end of the
data nothing else releases them (the check runs every 0.25 s and needs two idle ticks).
Only up to each input's next expected stamp (core StreamMerger.release_idle): messages
behind an input that lags (with reliable inputs, a sample lost on the way and sent again
seconds later; a detector behind) wait until it catches up or goes stale, so its messages
are not dropped as late; inputs that ended together release everything."""

LOOP_JUMP_S = 1.0
"""A message this far behind the filter counts towards a restart of the data (a looped bag
without /clock), s; inputs that are merely out of step are far closer than that."""

RESTART_AFTER_LATE = 20
"""Consecutive messages LOOP_JUMP_S behind the filter, from every active input, that reset
it: one input that lags only loses its late messages."""

LIMITS_USED = NODE_LIMITS['ekf_node']
"""The InputLimits fields this node checks (declared as limits.*)."""

REMOVED_PARAMETERS = {
    'reorder_window_s': 'the merger waits until every active input has passed a stamp; a '
                        'window on top only added latency',
    'stale_input_s': f'now the constant STALE_INPUT_S = {STALE_INPUT_S:g} s',
    'max_buffered_events': f'now the constant MAX_BUFFERED_EVENTS = {MAX_BUFFERED_EVENTS}',
    'idle_flush_s': f'now the constant IDLE_FLUSH_S = {IDLE_FLUSH_S:g} s',
    'loop_jump_s': f'now the constant LOOP_JUMP_S = {LOOP_JUMP_S:g} s',
    'restart_after_late': f'now the constant RESTART_AFTER_LATE = {RESTART_AFTER_LATE}',
    'confirm_jump_after': 'now StampGate\'s default, 10 messages',
    'limits.max_duration_s': 'this node states no durations',
}
"""Former parameters -> what became of them (a user still giving one is warned once)."""


class EkfNode(Node):
    """The gyro-bias EKF as a ROS node (see the module docstring).

    Attributes:
        config: the EKF configuration in use (after any stated noise replaced its sigmas).
        driver: the core EventDriver (the filter is driver.ekf).
        dropped: messages dropped per reason.
        resets: filter resets (looped data, ~/reset, clock jumps).
        published: estimates published.
    """

    def __init__(self, **kwargs) -> None:
        """Declare parameters, build the driver, create topics, services and timers."""
        super().__init__('ekf_node', **kwargs)
        config = declare_config(self, EkfConfig)
        self._limits = limits = declare_config(self, InputLimits, prefix='limits.',
                                               names=LIMITS_USED)
        self._max_rate, self._max_speed = limits.max_yaw_rate_rad_s, limits.max_speed_m_s
        options = declare_config(self, RunOptions)
        sidecar = declare_sidecar(self)
        # Parameters enter the core too: a NaN mount or start pose is a configuration error.
        for topic, (frame, mount) in sidecar.lidars.items():
            problem = mount_problem(mount.x_m, mount.y_m, mount.yaw_rad, limits)
            if problem:
                raise GyroEkfError(f'node {self.get_fully_qualified_name()}: parameter '
                                   f'lidar.{topic} ({frame}): {problem}')
        x_m, y_m, yaw_rad = sidecar.initial_pose.tolist()
        problem = initial_pose_problem(x_m, y_m, yaw_rad, limits)
        if problem:
            raise GyroEkfError(f'node {self.get_fully_qualified_name()}: parameter '
                               f'initial_pose: {problem}')
        if options.use_stated_noise:
            config = with_stated_noise(config, sidecar.noise)
        self.config = config
        self._sidecar = sidecar
        # What convert --skip-bad dropped from the log this bag was written from (its
        # sidecar): missing from the input, counted by the verdict as `gyro-ekf run` does.
        converted = sidecar.converted
        self._dropped_when_converted = {} if converted is None else dict(
            converted.samples_dropped)
        self._converted_from = '' if converted is None else converted.source
        self._use_message_covariance = options.use_message_covariance
        self._use_calibration = options.use_calibration
        self._calibration_sigma = options.calibration_bias_sigma_rad_s
        landmarks_file = declare(self, 'landmarks_file', '',
                                 'Landmark map file (YAML landmarks: [[x, y], ...] or x y '
                                 'text); empty = wait for landmark_map')
        landmark_topics = declare(self, 'landmark_topics', [topics.LANDMARKS],
                                  'Observation topics (PoseArray of poles in a LiDAR frame)')
        history_s = declare(self, 'late_observation_history_s', 0.0,
                            '0: every input waits in stamp order (poses equal an offline run '
                            'but wait for the slowest input); > 0: speed and IMU are used at '
                            'once and observations up to this much stamp time late are '
                            'replayed into the filter (poses at IMU latency; each late scan '
                            'costs a replay of the inputs after it)', 's', 0.0, 5.0)
        self._publish_every = declare(self, 'publish_every_n', 1,
                                      'Publish every n-th estimate (one per IMU sample)', '',
                                      1, 100_000)
        lossless = declare(self, 'reliable_inputs', False,
                           'Reliable keep-all QoS on the inputs instead of sensor data QoS '
                           '(lossless replay, tests); an input then counts as stopped after '
                           f'{STALE_RELIABLE_INPUT_WALL_S:g} s without a message on the steady '
                           f'clock instead of {STALE_INPUT_S:g} s')
        period = declare(self, 'diagnostics_period_s', 1.0,
                         'Period of the /diagnostics status (node clock)', 's', 0.01, 3600.0)
        self._max_gap_s = declare(self, 'max_association_gap_s', 5.0,
                                  'Warn when no landmark was associated for this long', 's',
                                  0.0, 1e6)
        self._map_frame = declare(self, 'map_frame', topics.MAP_FRAME, 'Frame of the estimate')
        self._base_frame = declare(self, 'base_frame', topics.BASE_FRAME,
                                   'Child frame of ekf/odometry')
        publish_tf = declare(self, 'publish_tf', True,
                             'Broadcast the estimate on /tf (needs tf2_msgs: a ROS install '
                             'has it, the PyPI packages do not)')
        self._odom_frame = declare(self, 'odom_frame', '',
                                   'Frame of the odometry pose: set it to broadcast map -> '
                                   'odom_frame (so that map -> odom -> base_link is the '
                                   'estimate) instead of map -> base_frame')
        path_length = declare(self, 'path_length', PATH_LENGTH,
                              'Most poses in ekf/path (one every '
                              f'{PATH_SPACING_S:g} s)', '', 1, 1_000_000)
        report_ignored(self, REMOVED_PARAMETERS)

        landmarks = read_landmarks_file(landmarks_file, limits) if landmarks_file else None
        self.driver = EventDriver(self.config, landmarks=landmarks, pose=sidecar.initial_pose)
        # Health reports name each LiDAR by its scan topic, as summary.json does.
        self.driver.sensor_names = {mount: topic for topic, (_, mount) in sidecar.lidars.items()}
        # How well each mount's yaw is known: the body frame's widens the heading reported.
        self.driver.mount_yaw_sigmas = {mount: sidecar.yaw_sigmas[topic] for topic, (_, mount)
                                        in sidecar.lidars.items() if sidecar.yaw_sigmas.get(topic)}
        # Every LiDAR but the first has its mount estimated online (core/mount_online.py).
        lidars = [(mount, topic) for topic, (_, mount) in sidecar.lidars.items()]
        self.driver.track_mounts(lidar for lidar in lidars[1:] if lidar[0] != lidars[0][0])
        self._logged_transitions = 0
        self._first_imu_s: float | None = None
        self._initial_pose = sidecar.initial_pose
        # The first landmarks come later than the first IMU and odometry messages (the
        # detector works on each scan first), so wait for every configured LiDAR frame too,
        # or its first scans would be late; STALE_INPUT_S bounds the wait.
        expected = ['imu', 'odom']
        if history_s == 0.0:  # replayed observations do not pass the merger
            expected += [frame for frame, _ in sidecar.lidars.values()]
        # Silence is judged in the stamps received (the data's own ROS time: a paused
        # replay is no silence), and, so that a burst or a busy detector upstream is none
        # either, on the steady clock; never on /clock, which runs ahead of queued messages.
        self._buffer = StreamMerger(
            0.0, MAX_BUFFERED_EVENTS, STALE_INPUT_S, clock=time.monotonic,
            expected_streams=expected,
            stale_wall_s=STALE_RELIABLE_INPUT_WALL_S if lossless else STALE_INPUT_S)
        self._gate = StampGate(limits.max_stamp_jump_s)
        # One value per instant on each input (after the gate: an outlier far ahead never
        # becomes the newest stamp of its input).
        self._same_stamp = SameStampCheck()
        self._lagged = (LaggedObservations(self.driver, history_s, MAX_BUFFERED_EVENTS,
                                           on_refused=self._observation_refused)
                        if history_s > 0.0 else None)
        self._origin = TimeOrigin(sidecar.time_zero_ns)
        self._calibrated_bias: float | None = None
        self.dropped = dict.fromkeys(DROP_REASONS, 0)
        self.resets = 0
        self.published = 0
        self.covariances_ignored = 0
        self._estimates = 0
        self._late_streak = 0
        self._late_streams: set[str] = set()
        self._last_input = time.monotonic()
        self._idle_ticks = 0
        # Whether the diagnostics went out since the inputs last went quiet: with use_sim_time
        # the diagnostics timer stops with /clock, so the final counts need their own report.
        self._reported_quiet = True
        self._reported_drops = dict(self.dropped)
        self._received = dict.fromkeys(['imu', 'odom', 'landmarks'], 0)
        # Per input, samples refused beyond their limit and the largest: many read as
        # other units (_beyond).
        self._beyond_limit = dict.fromkeys(['imu', 'odom'], (0, 0.0))
        self._units_said: set[str] = set()
        self._rate_base = (self.get_clock().now(), dict(self._received))
        self._rates_hz = dict.fromkeys(self._received, 0.0)
        self._last_estimate: Estimate | None = None
        self._last_ns = 0
        self._last_report = None
        self._odom_pose: tuple[float, float, float] | None = None
        self._path = visuals.PathHistory(path_length, PATH_SPACING_S)
        # Serialized I/O (nodes/wire.py): inputs read from their CDR bytes, outputs written
        # into CDR templates; the same numbers as the rclpy messages, a fraction of the CPU.
        self._serialized = wire.serialized_io()
        self._messages = (wire.EstimateWire if self._serialized else EstimateMessages)(
            self._map_frame, self._base_frame, self.config.speed_noise_m_s,
            self.config.gyro_noise_rad_s)

        self._pose_pub = self.create_publisher(PoseWithCovarianceStamped, topics.EKF_POSE,
                                               qos.OUTPUT)
        self._odometry_pub = self.create_publisher(Odometry, topics.EKF_ODOMETRY, qos.OUTPUT)
        self._bias_pub = self.create_publisher(Vector3Stamped, topics.EKF_BIAS, qos.OUTPUT)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS,
                                                      qos.OUTPUT)
        self._imu_pub = self.create_publisher(Imu, topics.EKF_IMU, qos.stream_output(lossless))
        self._path_pub = self.create_publisher(PathMessage, topics.EKF_PATH, qos.OUTPUT)
        self._markers_pub = self.create_publisher(MarkerArray, topics.EKF_MARKERS, qos.OUTPUT)
        self._landmark_markers_pub = self.create_publisher(
            MarkerArray, topics.LANDMARK_MARKERS, qos.LATCHED)
        self._tf_pub = self._tf_publisher() if publish_tf else None
        # Per estimate: the publishers' C++ methods on the serialized path (wire.raw_publisher).
        senders = (wire.raw_publisher if self._serialized
                   else lambda p: (p.publish, p.get_subscription_count))
        self._send_pose, _ = senders(self._pose_pub)
        self._send_odometry, self._odometry_readers = senders(self._odometry_pub)
        self._send_bias, self._bias_readers = senders(self._bias_pub)
        self._send_imu, self._imu_readers = senders(self._imu_pub)
        # write() hands out its reused buffers (published before the next estimate).
        self._fill = self._messages.write if self._serialized else self._messages.fill
        if landmarks is not None:
            self._publish_landmark_markers(landmarks)
        # The LiDAR mounts in use, latched: one pose in base_link per lidar.topics entry,
        # published again (with the diagnostics) when an online estimate replaces one.
        self._mounts_pub = self.create_publisher(PoseArray, topics.EKF_MOUNTS, qos.LATCHED)
        self._published_mounts: list[LidarMount] = []
        self._publish_mounts()
        # Map, pose and bias first: the executor serves ready subscriptions in creation order.
        self.create_subscription(PoseArray, topics.LANDMARK_MAP, self._on_map, qos.LATCHED)
        self.create_subscription(PoseWithCovarianceStamped, topics.INITIAL_POSE,
                                 self._on_initial_pose, qos.OUTPUT)
        if self._use_calibration:
            self.create_subscription(Vector3Stamped, topics.GYRO_BIAS, self._on_bias,
                                     qos.LATCHED)
        sensor_qos = qos.sensor_input(lossless)
        if self._serialized:
            self.create_subscription(Odometry, topics.ODOM, self._on_odom_bytes, sensor_qos,
                                     raw=True)
            self.create_subscription(Imu, topics.IMU, self._on_imu_bytes, sensor_qos, raw=True)
        else:
            self.create_subscription(Odometry, topics.ODOM, self._on_odom, sensor_qos)
            self.create_subscription(Imu, topics.IMU, self._on_imu, sensor_qos)
        for name in landmark_topics:
            self.create_subscription(
                PoseArray, name, lambda message, topic=name: self._on_landmarks(message, topic),
                qos.stream_output(lossless))
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_timer(period, self._publish_diagnostics)
        self.create_timer(PATH_PERIOD_S, self._publish_path)
        self.create_timer(MARKERS_PERIOD_S, self._publish_markers)
        self.create_timer(min(IDLE_FLUSH_S / 2.0, 0.25), self._flush_when_idle,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(nanoseconds=-1_000_000),
                          on_clock_change=False),
            post_callback=self._on_time_jump)
        mounts = ', '.join(f'{frame} at ({m.x_m:g}, {m.y_m:g}, {m.yaw_rad:g})'
                           for frame, m in sidecar.lidars.values()) or 'none configured'
        self.get_logger().info(
            f'EKF ready: start pose {np.round(self._initial_pose, 4).tolist()}, LiDAR mounts '
            f'{mounts}, map {len(landmarks) if landmarks else "from " + topics.LANDMARK_MAP}')

    # Inputs -----------------------------------------------------------------------------

    def _drop(self, reason: str, why: str) -> None:
        self.dropped[reason] += 1
        self.get_logger().warn(f'dropped: {why} (counts {self.dropped})',
                               throttle_duration_sec=5.0)

    def _refuse(self, problem: str | None, what: str, otherwise: str = 'out_of_range') -> bool:
        """Drop and count a message whose value has a problem; tell whether it did."""
        if problem is None:
            return False
        self._drop(drop_reason(problem, otherwise), f'{what}: {problem}')
        return True

    def _beyond(self, stream: str, value: float, problem: str | None, unit: str,
                setting: str) -> str | None:
        """Return a refused value's problem, told when many of its stream's lie beyond.

        As the offline check (core.validation.units_hint): many samples beyond a limit are
        a series in other units (a speed in cm/s), not a few corrupt ones.
        """
        if problem is None or not math.isfinite(value):
            return problem
        count, largest = self._beyond_limit[stream]
        count, largest = count + 1, max(largest, abs(value))
        self._beyond_limit[stream] = (count, largest)
        if not many_beyond(count, self._received[stream]):
            return problem
        problem += units_hint(count, f"of the {self._received[stream]} received on "
                              f"'{stream}'", largest, unit, setting)
        if stream not in self._units_said:
            # Once, past the drop warning's throttle: the first drop read as one bad sample.
            self._units_said.add(stream)
            self.get_logger().error(f'dropping {stream}: {problem}')
        return problem

    def _on_imu(self, message: Imu) -> None:
        if not self._imu_usable(float(message.angular_velocity.z), message.header.frame_id):
            return
        # Corrected at once with the newest bias (it moves slowly), not after the merger.
        estimate = self._last_estimate
        if estimate is not None and self._imu_readers():
            self._send_imu(online_corrected_imu(message, estimate.gyro_error_rad_s,
                                                estimate.gyro_error_variance))
        self._queue_imu(stamp_ns(message.header.stamp), float(message.angular_velocity.z),
                        message.angular_velocity_covariance[8])

    def _on_imu_bytes(self, data: bytes) -> None:
        # Plain tuples and no closure: this runs for every IMU message (nodes/wire.py).
        try:
            data, sec, nanosec, frame_id, at, rate, covariance0, covariance8 = \
                wire.imu_yaw(data)
        except wire.WireError as err:
            self._received['imu'] += 1
            self._drop('malformed', f'{topics.IMU}: {err}')
            return
        if not self._imu_usable(rate, frame_id):
            return
        estimate = self._last_estimate
        if estimate is not None and self._imu_readers():
            self._send_imu(wire.patched_yaw_rate(
                data, at, rate - estimate.gyro_error_rad_s,
                wire.online_variance(covariance0, covariance8, estimate.gyro_error_variance)))
        self._queue_imu(sec * 1_000_000_000 + nanosec, rate, covariance8)

    def _imu_usable(self, rate: float, frame_id: str) -> bool:
        """Count an IMU sample (either path), check its yaw rate, follow its frame."""
        self._received['imu'] += 1
        # The comparison is the fast path (NaN fails it too); the check says why.
        if not -self._max_rate <= rate <= self._max_rate and self._refuse(
                self._beyond('imu', rate, rate_problem(rate, self._limits), 'rad/s',
                             'limits.max_yaw_rate_rad_s'), 'imu yaw rate'):
            return False
        if self._messages.bias_frame != frame_id:
            # The bias is the IMU's: ekf/bias is in its frame, live and offline.
            self._messages.bias_frame = frame_id or topics.IMU_FRAME
        return True

    def _queue_imu(self, ns: int, rate: float, rate_variance: float) -> None:
        """Queue a checked IMU sample (either path); rate_variance: covariance[8]."""
        variance = None
        if self._use_message_covariance:
            variance = self._variance(rate_variance, self._max_rate,
                                      'imu angular_velocity_covariance[8]')
        self._push(ns, EventKind.IMU, (rate, variance), 'imu', 'imu')

    def _on_odom(self, message: Odometry) -> None:
        pose = message.pose.pose
        self._take_odom(stamp_ns(message.header.stamp), odometry_speed(message),
                        message.twist.covariance[0],
                        lambda: (float(pose.position.x), float(pose.position.y),
                                 quaternion_yaw(pose.orientation)))

    def _on_odom_bytes(self, data: bytes) -> None:
        try:
            sample = wire.decode_odometry(data)
        except wire.WireError as err:
            self._received['odom'] += 1
            self._drop('malformed', f'{topics.ODOM}: {err}')
            return
        pose = sample.pose
        self._take_odom(stamp_ns(sample.stamp), sample.speed_m_s, sample.speed_variance,
                        lambda: (pose[0], pose[1], yaw_of_quaternion(*pose[3:])))

    def _take_odom(self, ns: int, speed: float, speed_variance: float, odom_pose) -> None:
        """Check and queue a speed sample (either path); odom_pose() is (x m, y m, yaw rad)."""
        self._received['odom'] += 1
        if not -self._max_speed <= speed <= self._max_speed and self._refuse(
                self._beyond('odom', speed, speed_problem(speed, self._limits), 'm/s',
                             'limits.max_speed_m_s'), 'odom speed'):
            return
        if self._odom_frame:
            self._odom_pose = odom_pose()
        variance = None
        if self._use_message_covariance:
            variance = self._variance(speed_variance, self._max_speed,
                                      'odom twist.covariance[0]')
        self._push(ns, EventKind.SPEED, (speed, variance), 'odom', 'odom')

    def _variance(self, value: float, limit: float, what: str) -> float | None:
        """Return the message's own variance, or None (the configured noise); count a bad one."""
        variance, bad = message_variance(float(value), limit)
        if bad:
            self.covariances_ignored += 1
            self.get_logger().warn(f'{what} = {float(value)!r} is NaN, negative or beyond '
                                   f'{limit:g}^2: the configured noise is used instead '
                                   f'({self.covariances_ignored} so far)',
                                   throttle_duration_sec=5.0)
        return variance

    def _on_landmarks(self, message: PoseArray, topic: str = topics.LANDMARKS) -> None:
        self._received['landmarks'] += 1
        mount = self._mount(message.header.frame_id)
        if mount is None:
            return
        points = points_of(message)
        if self._refuse(coordinate_problem(points.ravel().tolist(), self._limits),
                        'landmarks hold a bad point'):
            return
        ns = stamp_ns(message.header.stamp)
        offset_s = self._sidecar.time_offset_for_frame(message.header.frame_id)
        if offset_s and ns:
            # Scans stamped this late (lidar.<topic>.time_offset_s): taken at the stamp less
            # it, as `gyro-ekf run` takes them (io/params_file.with_lidar_mounts).
            ns -= round(offset_s * NS_PER_S)
        if self._sidecar.upside_down_for_frame(message.header.frame_id):
            # A LiDAR mounted upside down (lidar.<topic>.upside_down): its poles mirrored
            # into an upright one's frame, as `gyro-ekf run` takes them.
            points = points_upright(points)
        range_offset_m = self._sidecar.range_offset_for_frame(message.header.frame_id)
        if range_offset_m:
            # A LiDAR that reads long (lidar.<topic>.range_offset_m): its poles moved that
            # much toward it, as `gyro-ekf run` moves them (core/trip_run.py).
            points = points_less_range(points, range_offset_m)
        self._push(ns, EventKind.OBSERVATION, (points, mount), topic, message.header.frame_id)

    def _observe_lagged(self, stamp_s: float, points: np.ndarray, mount: LidarMount) -> None:
        # Not an input that ends the idle wait: held scans wait for the speed and IMU
        # samples, and are flushed when those stop (end of data).
        try:
            fate = self._lagged.observation(stamp_s, points, mount)
        except CoreError as err:
            self._observation_refused(stamp_s, err)
            return
        if fate == ObservationFate.TOO_LATE:
            filter_s = self.driver.stamp_s
            behind_s = 0.0 if filter_s is None else filter_s - stamp_s
            self._drop('late', f'landmarks stamp {behind_s:.3f} s behind the filter, older '
                       'than late_observation_history_s or than a pose, bias or map change')

    def _observation_refused(self, stamp_s: float, err: CoreError) -> None:
        self._drop('filter_error', f'the filter refused the observation at {stamp_s:.3f} s: '
                   f'{err}')

    def _mount(self, frame_id: str) -> LidarMount | None:
        if not self._sidecar.lidars:
            self.get_logger().warn(
                'no LiDAR mounts configured (lidar.* parameters): observations are taken at '
                'the platform origin', once=True)
            return LidarMount()
        mount = self._sidecar.mount_for_frame(frame_id)
        if mount is None:
            known = sorted(frame for frame, _ in self._sidecar.lidars.values())
            self._drop('unknown_frame', f'landmarks in frame {frame_id!r}; the LiDAR frames '
                       f'are {known}')
        return mount

    def _push(self, ns: int, kind: EventKind, value, what: str, stream: str) -> None:
        """Queue a checked message of stamp ns (dropped and counted when the stamp is 0)."""
        if kind is not EventKind.OBSERVATION or self._lagged is None:
            self._last_input = time.monotonic()
        self._reported_quiet = False
        if ns == 0:
            self._drop('zero_stamp', f'{what} message with a zero stamp')
            return
        self._offer(stream, self._origin.seconds(ns), (kind, ns, value, what))

    def _offer(self, stream: str, stamp_s: float, payload: tuple) -> None:
        """Pass a message through the stamp gate into the merger (or the lagged path)."""
        passed, dropped = self._gate.offer(stream, stamp_s, payload)
        if len(passed) == 1 and not dropped:  # the common case: this message, at once
            self._merge(*passed[0])
            return
        for _, dropped_s, (_, _, _, what) in dropped:
            common = self._gate.time_s
            self._drop('stamp_jump', f'{what} stamp {dropped_s:.3f} s is more than '
                       f'{self._gate.max_jump_s:g} s (limits.max_stamp_jump_s) ahead of the '
                       'other inputs' + ('' if common is None else f' ({common:.3f} s)')
                       + ' and its input did not go on from it')
        for name, stamp_s, message in passed:
            self._merge(name, stamp_s, message)

    def _merge(self, stream: str, stamp_s: float, payload: tuple) -> None:
        kind, ns, value, what = payload
        repeat = self._same_stamp.judge(stream, ns, value)
        if repeat is not None:
            self._repeated(repeat, kind, ns, stamp_s, what, stream)
            return
        if kind is EventKind.OBSERVATION and self._lagged is not None:
            self._observe_lagged(stamp_s, *value)
            return
        ready, late = self._buffer.push(stream, stamp_s, kind, (ns, value))
        if late:
            behind_s = self._buffer.released_s - stamp_s  # finite: something was released
            if behind_s > LOOP_JUMP_S:
                self._late_streak += 1
                self._late_streams.add(stream)
            else:
                self._late_streak, self._late_streams = 0, set()
            # Stamps restart only when every input goes back: one input that lags (a
            # starved queue, a clock behind) only loses its late messages.
            active = self._buffer.active_streams()
            if self._late_streak >= RESTART_AFTER_LATE and self._late_streams >= active:
                self.reset(f'stamps restarted: {self._late_streak} messages in a row from '
                           f'every input ({", ".join(sorted(self._late_streams))}) went back '
                           f'about {behind_s:.1f} s (looped data without /clock?)')
                self._offer(stream, stamp_s, payload)
            else:
                self._drop('late', f'{what} stamp {behind_s:.3f} s behind the filter')
            return
        self._late_streak, self._late_streams = 0, set()
        self._process(ready)

    def _repeated(self, repeat: Repeat, kind: EventKind, ns: int, stamp_s: float, what: str,
                  stream: str) -> None:
        """Count (and log) a message dropped at the stamp of the one taken on its input."""
        self.dropped[repeat.reason] += 1
        topic = self.resolve_topic_name(what)
        if kind is EventKind.OBSERVATION:
            topic += f' (frame {stream!r})'
        log_repeat(self, repeat.reason == DUPLICATE,
                   describe_repeat(repeat, topic, ns, stamp_s, _FIELDS[kind]), self.dropped)

    def _process(self, events) -> None:
        # With late observations replayed, only speed and IMU samples come through here.
        driver = self.driver if self._lagged is None else self._lagged
        for stamp_s, kind, (ns, value) in events:
            try:
                if kind is EventKind.IMU:
                    estimate = driver.on_imu(stamp_s, *value)
                    if self._first_imu_s is None:
                        self._first_imu_s = stamp_s
                    self._estimates += 1
                    self._last_estimate, self._last_ns = estimate, ns
                    if self._estimates % self._publish_every == 0:
                        self._publish(estimate, ns)
                elif kind is EventKind.SPEED:
                    driver.on_speed(stamp_s, *value)
                else:
                    self._last_report = self.driver.on_detections(stamp_s, value[0],
                                                                  value[1])
                    self._log_health_changes()
            except CoreError as err:
                self._drop('filter_error', f'the filter refused a {kind.name.lower()} event: '
                           f'{err}')

    def _publish(self, estimate: Estimate, ns: int) -> None:
        pose, odometry, bias = self._fill(estimate, ns)
        self._send_pose(pose)
        # Publishing costs more CPU than the filter step: skip outputs nobody reads.
        if self._odometry_readers():
            self._send_odometry(odometry)
        if self._bias_readers():
            self._send_bias(bias)
        x, y, yaw, _ = estimate.state.tolist()
        self._path.add(ns, x, y, yaw)
        if self._tf_pub is not None and self._tf_pub.get_subscription_count():
            t = visuals.tf_transform((x, y, yaw), self._map_frame, self._base_frame,
                                     self._odom_frame, self._odom_pose)
            self._tf_pub.publish(messages.serialize(messages.tf_message([
                messages.transform_stamped(ns, *t)])))
        self.published += 1

    def _tf_publisher(self):
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.get_logger().warn('publish_tf: tf2_msgs is not installed (ROS from PyPI has '
                                   'no tf2): no TF is broadcast; ekf/pose and ekf/odometry '
                                   'carry the estimate')
            return None
        # tf2_ros's TransformBroadcaster: reliable, volatile, depth 100.
        return self.create_publisher(TFMessage, topics.TF, 100)

    def _publish_path(self) -> None:
        if len(self._path) and self._path_pub.get_subscription_count():
            self._path_pub.publish(messages.serialize(self._path.message(self._map_frame)))

    def _publish_markers(self) -> None:
        estimate = self._last_estimate
        if estimate is not None and self._markers_pub.get_subscription_count():
            self._markers_pub.publish(visuals.markers_bytes(
                self._last_ns, estimate.state, estimate.covariance, self._last_report,
                self.driver.landmarks, self._map_frame))

    def _publish_landmark_markers(self, landmarks: LandmarkMap) -> None:
        self._landmark_markers_pub.publish(
            visuals.landmark_markers_bytes(landmarks, self._map_frame))

    def _on_map(self, message: PoseArray) -> None:
        points = points_of(message)
        if points.shape[0] == 0:
            self._drop('empty_map', f'{topics.LANDMARK_MAP} has no landmarks; keeping the '
                       'current map')
        elif (duplicate := duplicate_landmark_problem(points)) is not None:
            self._drop('bad_map', f'{topics.LANDMARK_MAP}: {duplicate}; keeping the current '
                       'map')
        elif not self._refuse(coordinate_problem(points.ravel().tolist(), self._limits),
                              f'{topics.LANDMARK_MAP} holds a bad landmark; keeping the '
                              'current map'):
            self.driver.landmarks = LandmarkMap(points)
            self._publish_landmark_markers(self.driver.landmarks)
            self._forget_history()
            self.get_logger().info(f'landmark map: {points.shape[0]} landmarks')

    def _on_initial_pose(self, message: PoseWithCovarianceStamped) -> None:
        if self._refuse(pose_problem(message, self._limits), topics.INITIAL_POSE, 'bad_pose'):
            return
        pose, covariance = pose_and_covariance(message)
        self.driver.ekf.set_pose(pose, covariance)
        self._forget_history()
        self.get_logger().info(f'pose set to {np.round(pose, 4).tolist()} '
                               f'({topics.INITIAL_POSE})')

    def _on_bias(self, message: Vector3Stamped) -> None:
        bias = float(message.vector.z)
        if self._refuse(rate_problem(bias, self._limits), topics.GYRO_BIAS):
            return
        self._calibrated_bias = bias
        self.driver.ekf.set_bias(bias, self._calibration_sigma)
        self._forget_history()
        self.get_logger().info(
            f'bias seeded from {topics.GYRO_BIAS}: {math.degrees(bias):+.4f} deg/s '
            f'(sigma {math.degrees(self._calibration_sigma):.4f} deg/s)')

    def _forget_history(self) -> None:
        # A replay restores states saved before this change and would undo it.
        if self._lagged is not None:
            self._lagged.forget_history()

    # Resets -----------------------------------------------------------------------------

    def reset(self, why: str) -> None:
        """Restart the filter at the initial pose (re-seeding a calibrated bias)."""
        self.driver.reset(self._initial_pose)
        if self._calibrated_bias is not None:
            self.driver.ekf.set_bias(self._calibrated_bias, self._calibration_sigma)
        self._buffer.clear()
        self._gate.clear()
        self._same_stamp.clear()
        if self._lagged is not None:
            self._lagged.reset()
        self._late_streak, self._late_streams = 0, set()
        self._logged_transitions = 0
        self._first_imu_s = None
        self._path.clear()
        self._last_report = None
        self.resets += 1
        self.get_logger().warn(f'filter reset: {why}')

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        self.reset('reset requested (~/reset)')
        response.success = True
        response.message = 'filter reset to the initial pose'
        return response

    def _on_time_jump(self, jump: TimeJump) -> None:
        delta_s = jump.delta.nanoseconds / 1e9
        if delta_s < 0.0:
            self.reset(f'ROS time jumped back {-delta_s:.3f} s (/clock went backwards: a '
                       'looped bag?)')

    # Housekeeping -----------------------------------------------------------------------

    def _flush_when_idle(self) -> None:
        held = len(self._buffer) + (self._lagged.held if self._lagged is not None else 0)
        quiet = time.monotonic() - self._last_input > IDLE_FLUSH_S
        idle = quiet and (held or not self._reported_quiet)
        # Idle on two ticks in a row: a process that was starved finds its timer due and its
        # queues full; the executor serves those queues before the next tick.
        self._idle_ticks = self._idle_ticks + 1 if idle else 0
        if self._idle_ticks >= 2:
            self._idle_ticks = 0
            # Not flush(): an input still on its way (a reliable sample sent again, a
            # detector behind) keeps what follows it until it comes or goes stale.
            self._process(self._buffer.release_idle())
            if self._lagged is not None:
                self._lagged.flush()
            self._publish_diagnostics()
            self._reported_quiet = True

    def _log_health_changes(self) -> None:
        """Log every LiDAR exclusion or readmission not logged yet."""
        monitor = self.driver.health
        new = monitor.transition_count - self._logged_transitions
        if new <= 0:
            return
        self._logged_transitions = monitor.transition_count
        for change in list(monitor.transitions)[-min(new, len(monitor.transitions)):]:
            self.get_logger().warn(f'LiDAR {change.sensor} {change.change} at '
                                   f'{change.stamp_s:.3f} s: {change.reason}')

    def _dead_reckoned(self, since: float | None) -> tuple[float, float]:
        """Return the time since the first update in gaps of over a second, and that time, s.

        The gaps the driver closed and the open one (``since``, the time since the last
        update), as summary.json's ``association`` counts them to the end of a run.
        """
        stats, now = self.driver.stats, self.driver.stamp_s
        first = stats.first_association_s
        since_first = 0.0 if first is None or now is None else now - first
        return stats.dead_reckoned_s + health.dead_reckoned(since or 0.0), since_first

    def _verdict(self, since: float | None) -> dict:
        """Return the health verdict since the start or the last reset, as summary.json has it.

        The figures are summary.json's (analysis/summary.py), counted from the first IMU
        sample to the last processed event instead of from the first to the last estimate.
        """
        stats = self.driver.stats
        start, now = self._first_imu_s, self.driver.stamp_s
        first = stats.first_association_s
        dead_reckoned, since_first = self._dead_reckoned(since)
        if start is None or now is None:
            start_gap = 0.0
        else:
            start_gap = (now if first is None else first) - start
        inputs = {name: loss.report() for name, loss in self.driver.input_loss.items()}
        figures = health.RunFigures(
            # Excluded LiDARs' detections have their own reason, not the share's.
            detections=stats.detections - stats.excluded, excluded=stats.excluded,
            matched=stats.outcomes.get('matched', 0), updates=stats.updates,
            nis_mean=stats.mean_nis,
            longest_gap_s=max(stats.longest_gap_s, since or 0.0), start_gap_s=start_gap,
            dead_reckoned_s=dead_reckoned, since_first_update_s=since_first,
            sensors=self.driver.health.report(), resets=self.resets,
            dropped={k: self.dropped[k] for k in VERDICT_DROP_REASONS},
            dropped_when_converted=health.samples_dropped_figures(
                self._dropped_when_converted),
            converted_from=self._converted_from,
            final_bias_rad_s=self.driver.ekf.bias_rad_s, unmapped=stats.unmapped,
            scans=stats.scans, bias_openings=stats.bias_openings,
            gate_starved=stats.gate_starved,
            bias_largest_opening_rad_s=stats.bias_largest_opening_rad_s,
            bias_wander_held=stats.bias_wander_held,
            bias_largest_rate_rad_s2=stats.bias_largest_rate_rad_s2,
            gyro_noise_scale_max=stats.gyro_noise_scale_max,
            gyro_rest_noise_scale=float(stats.gyro_rest_noise_scale),
            gyro_rest_noise_rad_s=float(stats.gyro_rest_noise_rad_s),
            speed_noise_m_s=float(stats.speed_noise_m_s),
            speed_noise_stated_m_s=float(stats.speed_noise_stated_m_s),
            gyro_wander_rad_s=stats.gyro_wander_rad_s,
            gyro_wander_found_s=stats.gyro_wander_found_s,
            gyro_wander_stated_rad_s=self.driver.config.gyro_wander_rad_s,
            gyro_wander_tau_s=self.driver.config.gyro_wander_tau_s,
            mounts=self.driver.mounts.report(), odometry=self.driver.odometry.report(),
            gyro_scale=self.driver.gyro_scale.report(),
            time_offsets=self.driver.time_offset_report(),
            stamp_jitter=self.driver.stamp_jitter_report(),
            map_poles=self.driver.map_poles_report(),
            turn_signs=self.driver.turn_sign_report(),
            rest_turns=self.driver.rest_turn_report(),
            input_loss=inputs,
            scan_loss={name: loss.report() for name, loss in self.driver.scan_loss.items()},
            input_spikes={name: gate.report()
                          for name, gate in self.driver.input_spikes.items()},
            gyro_frozen=self.driver.gyro_frozen.report(),
            # Since the last sample too: an input that stopped is silent while the others
            # go on (core/input_loss.py).
            input_gaps_s=silences(inputs, now),
            input_gap_limit_s=self.driver.config.max_prediction_step_s,
            final_bias_sigma_rad_s=math.sqrt(max(self.driver.ekf.bias_var, 0.0)),
            start_bias=stats.first_stop)
        return health.verdict(figures)

    def _publish_mounts(self) -> None:
        """Publish the LiDAR mounts in use on ekf/mounts when they changed."""
        used = [self.driver.mount_in_use(mount) for _, mount in self._sidecar.lidars.values()]
        if used == self._published_mounts:
            return
        self._published_mounts = used
        self._mounts_pub.publish(PoseArray(
            header=Header(stamp=self.get_clock().now().to_msg(), frame_id=self._base_frame),
            poses=[Pose(position=Point(x=float(mount.x_m), y=float(mount.y_m)),
                        orientation=yaw_quaternion(mount.yaw_rad)) for mount in used]))

    def _publish_diagnostics(self) -> None:
        self._log_health_changes()
        self._publish_mounts()
        now = self.get_clock().now()
        base_time, base_counts = self._rate_base
        elapsed_s = (now - base_time).nanoseconds / 1e9
        if elapsed_s > 0.0:
            self._rates_hz = {k: (self._received[k] - base_counts[k]) / elapsed_s
                              for k in self._received}
            self._rate_base = (now, dict(self._received))
        stats = self.driver.stats
        # The pose as published (with the two LiDARs' mixture, core/body_frame.py).
        estimate = self.driver.estimate()
        x, P = estimate.state, estimate.covariance
        outcomes = stats.outcomes
        rejected = sum(v for k, v in outcomes.items() if k != 'matched')
        since = (None if stats.last_association_s is None or self.driver.stamp_s is None
                 else self.driver.stamp_s - stats.last_association_s)
        dead_reckoned, since_first = self._dead_reckoned(since)
        map_poles = self.driver.map_poles_report()
        values = {
            'bias_deg_s': f'{math.degrees(x[3]):.5f}',
            'bias_sigma_deg_s': f'{math.degrees(math.sqrt(max(P[3, 3], 0.0))):.5f}',
            'x_m': f'{x[0]:.4f}', 'y_m': f'{x[1]:.4f}', 'yaw_deg': f'{math.degrees(x[2]):.3f}',
            'stamp_s': '' if self.driver.stamp_s is None else f'{self.driver.stamp_s:.6f}',
            'associated': str(stats.updates), 'rejected': str(rejected),
            **{f'rejected_{k}': str(v) for k, v in outcomes.items() if k != 'matched'},
            'mean_nis': f'{stats.mean_nis:.4f}',
            **{f'rate_{k}_hz': f'{v:.2f}' for k, v in self._rates_hz.items()},
            'time_since_association_s': '' if since is None else f'{since:.3f}',
            # The time since the first update spent in gaps of over a second (the verdict's).
            'dead_reckoned_s': f'{dead_reckoned:.3f}',
            'dead_reckoned_share': '' if not since_first else f'{dead_reckoned / since_first:.4f}',
            'estimates': str(self._estimates), 'published': str(self.published),
            # Matched readers: ekf/odometry and ekf/bias are not published without one.
            'odometry_readers': str(self._odometry_readers()),
            'bias_readers': str(self._bias_readers()),
            'buffered': str(len(self._buffer)), 'resets': str(self.resets),
            'ignored_covariances': str(self.covariances_ignored),
            'held_far_ahead': str(self._gate.held), 'long_gaps': str(stats.long_gaps),
            **({} if self._lagged is None else {
                'held_observations': str(self._lagged.held),
                'replayed_observations': str(self._lagged.stats.replays),
                'replayed_events': str(self._lagged.stats.replayed_events),
                'refused_held_observations': str(self._lagged.stats.refused)}),
            **{f'dropped_{k}': str(v) for k, v in self.dropped.items()},
            # What convert --skip-bad dropped from the bag's log (its sidecar), per stream.
            'dropped_when_converted': str(sum(self._dropped_when_converted.values())),
            **{f'dropped_when_converted_{stream}': str(n)
               for stream, n in self._dropped_when_converted.items()},
            'converted_from': self._converted_from,
            # The mounts in use (from the params files, e.g. calibrate-mounts' output, or
            # estimated online) and the online estimators' state.
            **{f'mount_{topic}_{key}': value
               for (topic, (frame, _)), mount in zip(self._sidecar.lidars.items(),
                                                     self._published_mounts)
               for key, value in (('frame_id', frame), ('x_m', f'{mount.x_m:.4f}'),
                                  ('y_m', f'{mount.y_m:.4f}'),
                                  ('yaw_deg', f'{math.degrees(mount.yaw_rad):.3f}'))},
            # Which LiDAR defines the body frame with the odometry (the first, until it
            # disagrees with the map and another takes over: mount_online's hand-over).
            'body_frame_lidar': ' '.join(
                topic for topic, (_, mount) in self._sidecar.lidars.items()
                if mount not in self.driver.mounts.trackers),
            **{f'mount_{online["name"]}_{key}': value for online in self.driver.mounts.report()
               for key, value in (
                   ('online', online['state']),
                   ('online_yaw_sigma_deg', '' if online['estimate'] is None
                    else f'{online["estimate"]["yaw_sigma_deg"]:.4f}'),
                   # With the filter's heading sigma over the fit's window: what a change
                   # of the mount is judged by.
                   ('online_yaw_sigma_with_heading_deg', '' if online['estimate'] is None
                    else f'{online["estimate"]["yaw_sigma_with_heading_deg"]:.4f}'),
                   # What this LiDAR's R is multiplied by: 9 for a mount estimated online
                   # or a stated one confirmed while its fit read it off, else 1.
                   ('online_noise_scale', f'{online["noise_scale"]:g}'),
                   # Whether the watch reads the stated mount off with the pose pulled
                   # its way (this LiDAR is the one off: the factor above is 9).
                   ('online_pulls', 'true' if online['pulls'] else 'false'),
                   # Whether it reads the two LiDARs apart with the pose pulled the other
                   # way: the body-frame LiDAR is the one off, and its R is multiplied by 9.
                   ('online_first_pulls', 'true' if online['first_pulls'] else 'false'),
                   ('online_noise_scale_reason', online['noise_scale_reason'] or ''),
                   ('online_converged_s', '' if online['converged_s'] is None
                    else f'{online["converged_s"]:.3f}'),
                   # The weight of this LiDAR being right in the pose published between
                   # it and the body frame's (core/body_frame.py); '' when none.
                   ('online_right_share', '' if online['right_share'] is None
                    else f'{online["right_share"]:.4f}'),
                   # How far apart this LiDAR's fit reads the two, under the change
                   # limits, when the published covariance spans it; '' when not.
                   ('online_widened_m', '' if online['widened_m'] is None
                    else f'{online["widened_m"]:.4f}'))},
            # The odometry's speed scale in use and its last online fit
            # (core/odometry_online.py).
            **{f'odometry_{key}': value for key, value in _odometry_values(
                self.driver.odometry.report()).items()},
            'excluded_detections': str(stats.excluded),
            'zero_rate_updates': str(stats.zero_rate_updates),
            'bias_reopened': str(stats.bias_openings),
            # Scans associated by map distance with the gate starving the filter.
            'gate_starved': str(stats.gate_starved),
            # Of those, where the modelled wander held one sign (core/gyro_wander.py).
            'bias_reopened_wander_held': str(stats.bias_wander_held),
            'gyro_noise_scale': f'{stats.gyro_noise_scale:.3f}',
            # The gyro's spread at a stop, where beyond chance above the stated noise.
            'gyro_rest_noise_deg_s': f'{math.degrees(stats.gyro_rest_noise_rad_s):.4f}',
            # The gyro's wander found and modelled (core/gyro_wander.py), 0 when none.
            'gyro_wander_deg_s': f'{math.degrees(stats.gyro_wander_rad_s):.4f}',
            # The largest wander a still stop's samples showed (core/stop_wander.py), 0
            # when none, and whether the blocks of driving ruled it out.
            'gyro_wander_stop_deg_s': f'{math.degrees(stats.gyro_wander_stop_rad_s):.4f}',
            'gyro_wander_stop_ruled_out':
                str(stats.gyro_wander_stop_ruled_out_s is not None).lower(),
            # The wander the filter models now: the prior until the blocks rule it out, the
            # one stated or found.
            'gyro_wander_modelled_deg_s':
                f'{math.degrees(self.driver.ekf.wander_sigma_rad_s):.4f}',
            # The gyro's scale measured against the LiDARs' heading (core/gyro_scale.py): e
            # of (1 + e), its standard error ('' until enough windows), and whether it lies
            # off the configured gyro_scale_error.
            **_scale_values(self.driver.gyro_scale.report()),
            # Each LiDAR's stamps against the gyro's (core/time_offset.py), ms late ('' until
            # enough windows), its standard error, and whether it lies clearly off.
            **{f'time_offset_{lidar["name"]}_{key}': value
               for lidar in self.driver.time_offset_report() for key, value in (
                   ('ms', _optional(_milli(lidar['offset_s']), '.2f')),
                   ('sigma_ms', _optional(_milli(lidar['offset_sigma_s']), '.2f')),
                   ('off', str(lidar['found']).lower()))},
            # Each LiDAR's stamps' scatter about when its scans were taken
            # (core/stamp_jitter.py), ms ('' until enough scans), and whether it is found.
            **{f'stamp_jitter_{lidar["name"]}_{key}': value
               for lidar in self.driver.stamp_jitter_report() for key, value in (
                   ('ms', _optional(_milli(lidar['jitter_s']), '.2f')),
                   ('found', str(lidar['found']).lower()))},
            # Per LiDAR, turns between its scans that voted, and those whose poles moved as
            # for the gyro's turn negated: an upside-down gyro or LiDAR (core/turn_sign.py).
            **{f'turn_sign_{lidar["name"]}_{key}': str(lidar[key])
               for lidar in self.driver.turn_sign_report()
               for key in ('votes', 'opposite', 'unseen_turns')},
            # Mapped poles whose detections lie elsewhere (core/map_poles.py): how many,
            # and each one's index and where it stands, m.
            'map_poles_elsewhere': str(len(map_poles)),
            **{f'map_pole_{pole["index"]}_seen_at_m': '{:.3f} {:.3f}'.format(
                *pole['seen_xy_m']) for pole in map_poles},
            # A ramping bias followed (core/bias_rate.py): its rate in use, 0 when none.
            'bias_rate_deg_s_per_min': f'{math.degrees(stats.bias_rate_rad_s2) * 60.0:.4f}',
            'standing_still': str(self.driver.zero_rate).lower(),
            # The start pose given exactly, held until the platform moved (core/held_start.py).
            'start_pose_held': str(self.driver.held_start.held).lower(),
            'start_pose_released': self.driver.held_start.reason,
            # Samples each input's stamps say were sent and did not reach the filter
            # (core/input_loss.py): lost on the way, or dropped by a node behind.
            **{f'{name}_received_share': f'{loss.share:.4f}'
               for name, loss in self.driver.input_loss.items()},
            **{f'{name}_lost': str(loss.lost) for name, loss in self.driver.input_loss.items()},
            # Stamps scattered about their grid (a driver stamping on arrival): a lost
            # sample can no longer be told from a late one.
            **{f'{name}_stamps_scatter': str(loss.scatters).lower()
               for name, loss in self.driver.input_loss.items()},
            # Each LiDAR's scans whose detections never arrived, by their stamps: the
            # landmarks topic keeps 10 and a node behind loses the oldest.
            **{f'lidar_{name}_scans_received_share': f'{loss.share:.4f}'
               for name, loss in self.driver.scan_loss.items()},
            **{f'lidar_{name}_scans_lost': str(loss.lost)
               for name, loss in self.driver.scan_loss.items()},
            # Lone samples far from both neighbours, left out (core/input_spikes.py).
            **{f'{name}_spikes': str(gate.spikes)
               for name, gate in self.driver.input_spikes.items()},
            # A gyro repeating one value, its repeats left out (core/input_frozen.py).
            'gyro_frozen_runs': str(self.driver.gyro_frozen.runs),
            'gyro_frozen_samples': str(self.driver.gyro_frozen.samples),
            # The odometry's own spread taken as its noise (EkfConfig.learn_speed_noise).
            'odometry_noise_widened': str(self.driver.stats.speed_noise_widened),
            'odometry_noise_m_s': f'{self.driver.stats.speed_noise_m_s:.4f}',
        }
        verdict = self._verdict(since)
        values['verdict'] = verdict['verdict']
        values['verdict_reasons'] = ' | '.join(verdict['reasons'])
        for lidar in self.driver.health.report():
            prefix = f'lidar_{lidar["name"]}_'
            values.update({
                prefix + 'window_share': f'{lidar["window_share"]:.3f}',
                prefix + 'window_nis_mean': f'{lidar["window_nis_mean"]:.3f}',
                prefix + 'window_bearing_innovation_deg':
                    f'{lidar["window_bearing_innovation_mean_deg"]:.3f}',
                prefix + 'excluded': str(lidar['excluded']).lower(),
                prefix + 'exclusions': str(lidar['exclusions']),
                prefix + 'excluded_s': f'{lidar["excluded_s"]:.1f}',
                prefix + 'disagreement': lidar['disagreement'] or ''})
        # Each LiDAR's range and bearing noise in use, measured online (core/noise_online.py).
        for lidar in self.driver.noise_report():
            prefix = f'lidar_{lidar["name"]}_'
            values.update({
                prefix + 'range_noise_m': f'{lidar["range_sigma_m"]:.4f}',
                prefix + 'bearing_noise_deg': f'{lidar["bearing_sigma_deg"]:.4f}',
                prefix + 'measured_range_noise_m': _optional(
                    lidar['measured_range_sigma_m'], '.4f'),
                prefix + 'measured_bearing_noise_deg': _optional(
                    lidar['measured_bearing_sigma_deg'], '.4f'),
                prefix + 'noise_measured': str(lidar['in_use']).lower(),
                prefix + 'noise_updates': str(lidar['updates'])})
        status = DiagnosticStatus(name=f'{self.get_fully_qualified_name()}: gyro bias EKF',
                                  hardware_id=self.resolve_topic_name(topics.IMU))
        rising = sorted(k for k, v in self.dropped.items()
                        if v > self._reported_drops[k] and k not in QUIET_DROP_REASONS)
        self._reported_drops = dict(self.dropped)
        if rising:
            status.level = DiagnosticStatus.WARN
            status.message = f'dropping input: {", ".join(rising)}'
        elif self._estimates == 0:
            status.level, status.message = DiagnosticStatus.WARN, 'no IMU data processed yet'
        elif self.driver.landmarks is None:
            status.level, status.message = DiagnosticStatus.WARN, 'no landmark map'
        elif since is None or since > self._max_gap_s:
            status.level = DiagnosticStatus.WARN
            status.message = 'no landmark associated recently'
        else:
            status.level, status.message = DiagnosticStatus.OK, 'tracking'
        # The verdict raises the level (WARN degraded, ERROR failed) and names its worst
        # reason first; what the node sees right now follows it.
        level = _LEVELS[verdict['verdict']]
        if level != DiagnosticStatus.OK:
            now_message = '' if status.level == DiagnosticStatus.OK else f' ({status.message})'
            status.level = max(status.level, level)
            status.message = f'{verdict["verdict"]}: {verdict["reasons"][0]}{now_message}'
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        self._diagnostics_pub.publish(DiagnosticArray(header=Header(stamp=now.to_msg()),
                                                      status=[status]))


def _optional(value: float | None, spec: str) -> str:
    """Format a figure for /diagnostics; '' when there is none."""
    return '' if value is None else format(value, spec)


def _milli(value: float | None) -> float | None:
    """Convert s to ms, None kept."""
    return None if value is None else 1000.0 * value


def _scale_values(report: dict) -> dict[str, str]:
    """Return the gyro scale estimate as /diagnostics values ('' before enough windows)."""
    return {'gyro_scale_error': _optional(report['scale_error'], '.5f'),
            'gyro_scale_error_sigma': _optional(report['scale_error_sigma'], '.5f'),
            'gyro_scale_windows': str(report['windows']),
            'gyro_scale_off': str(report['found']).lower(),
            # The scale the filter turns by: the configured one until one is applied online.
            'gyro_scale_error_in_use': format(report['in_use'], '.5f'),
            'gyro_scale_applied': str(report['applied'])}


def _odometry_values(report: dict) -> dict[str, str]:
    """Return the online odometry estimate as /diagnostics values (empty before a fit)."""
    estimate = report['estimate'] or {}
    vouched = report.get('first_lidar_turn_vouched')

    def figure(key: str, digits: int) -> str:
        value = estimate.get(key)
        return '' if value is None else f'{value:.{digits}f}'

    return {'scale': f'{report["scale"]:.5f}', 'scale_applied': str(report['applied']),
            'scale_estimate': figure('scale', 5), 'scale_sigma': figure('scale_sigma', 5),
            'scale_uncertainty': f'{report["scale_uncertainty"]:.5f}',
            'first_lidar_offset_x_m': figure('first_lidar_offset_x_m', 4),
            'first_lidar_offset_y_m': figure('first_lidar_offset_y_m', 4),
            'first_lidar_offset_found': str(report['first_lidar_offset_found']).lower(),
            'first_lidar_offset_in_use_x_m': f'{report["first_lidar_offset_in_use_x_m"]:.4f}',
            'first_lidar_offset_in_use_y_m': f'{report["first_lidar_offset_in_use_y_m"]:.4f}',
            'first_lidar_offset_applied': str(report['first_lidar_offset_applied']),
            'first_lidar_yaw_deg': figure('first_lidar_yaw_deg', 3),
            'first_lidar_yaw_found': str(report['first_lidar_yaw_found']).lower(),
            'first_lidar_yaw_in_use_deg': f'{report["first_lidar_yaw_in_use_deg"]:.3f}',
            # How much the published heading's sigma is widened for that LiDAR's yaw.
            'heading_widened_deg': f'{report["heading_widened_deg"]:.4f}',
            # The last first turn another LiDAR vouched against: its yaw and that LiDAR.
            'first_lidar_turn_vouched_deg': '' if vouched is None
            else f'{vouched["yaw_deg"]:.3f}',
            'first_lidar_turn_vouched_by': '' if vouched is None else vouched['by']}


def main(args: list[str] | None = None) -> int:
    """Entry point of the ekf_node executable."""
    return run_node(EkfNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
