"""Live latency and CPU of ekf_node over Fast DDS on loopback (the live part of `make bench`).

The node runs as a child process (``python -m gyro_ekf.nodes.ekf_node``) with a known
initial pose and a small landmark map (``landmarks_file``); this process is an rclpy node
that publishes ``odom`` then ``imu`` with the same header stamp every step, at a fixed rate,
optionally pole observations on ``landmarks`` (so the filter also updates), and listens to
``ekf/pose`` (raw CDR, only the stamp is read, so the listener costs little) and counts
``ekf/odometry`` and ``ekf/bias`` (so the node publishes all three for every step: it skips
outputs nobody reads).

Message path: each case runs the node with GYRO_EKF_NODE_IO set to its ``node_io``
(``serialized``: CDR bytes and the EventsExecutor, the default; ``rclpy``: rclpy messages and
the SingleThreadedExecutor, the path before nodes/wire.py), so both are measured in one run.

Latency. ekf_node holds every message in its reorder buffer until each active input has
delivered a stamp at least as new and ``reorder_window_s`` of stamp time has passed, so the
pose of IMU stamp t leaves the node only after the message that *completes* step t. Two
figures are reported for every pose, matched to its inputs by header stamp:

- ``latency_ms``: from just before the IMU message of stamp t was published to the moment
  this process's subscription callback received the pose of stamp t (what a consumer of the
  pose sees; it includes the hold of the reorder buffer);
- ``completion_latency_ms``: from just before the message that completed step t (worked
  out from the send order with the node's release rule) was published to the same moment
  (transport + executor + filter + publish; the node's own processing latency).

With ``reorder_window_s`` = 0 and odom sent before imu the IMU message completes its own
step, so both figures are equal. Both include serialization, loopback Fast DDS both ways and
the rclpy executors of the node and of this process. Poses released only by the node's idle
flush at the end (their completing message was never sent) are counted, not timed.

CPU: utime + stime of the child from /proc/<pid>/stat over the measured phase (first
measured send to the end of the drain), per step (one imu + one odom) and per input message.

`measure_node` does the same for calibration_node (IMU messages in, imu/corrected out, after
its static window; the window itself is timed too) and landmark_detector_node (361-beam
scans in, landmarks out), with reliable inputs so that every message sent is processed.

Every rclpy process here runs with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, an explicit
ROS_DOMAIN_ID (unless given, one claimed through gyro_ekf.ros_env, so no concurrent test or
benchmark on this machine shares it) and ROS_LOG_DIR in a temporary directory, set by this
module whatever the caller's environment.
"""

from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from gyro_ekf import topics
from gyro_ekf.ros_env import claim_domain, ros_env_values

NODE_IO_VARIABLE = 'GYRO_EKF_NODE_IO'
"""The nodes' message-path switch (gyro_ekf.nodes.wire; not imported: it needs rclpy)."""

log = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[1]
LANDMARKS_XY_M = ((5.0, 0.0), (0.0, 5.0), (-5.0, 0.0), (0.0, -5.0), (7.0, 7.0))
STAMP_ZERO_NS = 1_800_000_000 * 1_000_000_000
_CLOCK = time.perf_counter
DRAIN_S = 10.0
"""Default longest wait after the last send for the measured outputs, s."""
NODE_REPORT_S = 3.0
"""Default longest wait after the drain for ekf_node's report of all its estimates, s."""


@dataclass(frozen=True, slots=True)
class LiveCase:
    """One live measurement.

    Attributes:
        rate_hz: steps per second (one odom and one imu message each).
        duration_s: measured length, s (the number of measured steps is rate_hz * duration_s).
        reorder_window_s: the node's reorder_window_s parameter, s.
        landmarks_hz: rate of pole observations on `landmarks`; 0 = none.
        reliable_inputs: the node's reliable_inputs parameter (keep-all instead of sensor data
            QoS on its inputs; this process publishes with the matching QoS).
        warmup_s: length of the stream sent before the measurement (at least until poses
            come back), s.
        late_observation_history_s: the node's late_observation_history_s parameter, s (> 0:
            observations no longer hold the other inputs back, they are replayed).
        node_io: the node's message path (GYRO_EKF_NODE_IO): 'serialized' or 'rclpy'.
    """

    rate_hz: float
    duration_s: float
    reorder_window_s: float = 0.0
    landmarks_hz: float = 0.0
    reliable_inputs: bool = False
    warmup_s: float = 1.0
    late_observation_history_s: float = 0.0
    node_io: str = 'serialized'

    @property
    def name(self) -> str:
        """Short label of the case."""
        parts = [f'{self.rate_hz:g} Hz']
        if self.node_io != 'serialized':
            parts.append(f'{self.node_io} messages')
        if self.reorder_window_s:
            parts.append(f'window {self.reorder_window_s:g} s')
        if self.landmarks_hz:
            parts.append(f'landmarks {self.landmarks_hz:g} Hz')
        if self.reliable_inputs:
            parts.append('reliable')
        if self.late_observation_history_s:
            parts.append('late observations replayed')
        return ', '.join(parts)


@contextlib.contextmanager
def ros_environment(domain_id: int | None = None) -> Iterator[dict[str, str]]:
    """Set loopback discovery, a domain id and a temporary log dir for this process.

    Yields the environment for child processes. Without domain_id a free domain is claimed
    (gyro_ekf.ros_env) for the life of the context. The previous values of this process's
    variables are restored and the temporary directory removed on exit.
    """
    with contextlib.ExitStack() as stack:
        if domain_id is None:
            domain_id = stack.enter_context(claim_domain()).domain_id
        work = Path(tempfile.mkdtemp(prefix='gyro_ekf_live_'))
        stack.callback(shutil.rmtree, work, ignore_errors=True)
        values = ros_env_values(int(domain_id), work / 'ros_log')
        saved = {key: os.environ.get(key) for key in values}
        stack.callback(_restore, saved)
        os.environ.update(values)
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(
            [str(REPO), env.get('PYTHONPATH', '')]).rstrip(os.pathsep)
        env['GYRO_EKF_LIVE_WORK'] = str(work)
        yield env


def _restore(saved: dict[str, str | None]) -> None:
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of a process so far, s (from /proc/<pid>/stat)."""
    stat = Path(f'/proc/{pid}/stat').read_text()
    fields = stat[stat.rindex(')') + 2:].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def completion_indices(streams: list[str], stamps_ns: np.ndarray, window_s: float,
                       zero_ns: int, targets_ns: np.ndarray) -> np.ndarray:
    """Index of the send that lets the node release each target stamp; -1 if none did.

    Applies ekf_node's release rule (StreamMerger): after a message arrives, everything up
    to min(newest stamp - window_s, newest stamp of every stream seen) is released. Stamps
    are turned into seconds as the node does (TimeOrigin), so float rounding agrees.

    Args:
        streams: stream of every sent message, in send order, shape (n,).
        stamps_ns: header stamp of every sent message, ns, shape (n,).
        window_s: the node's reorder_window_s, s.
        zero_ns: the node's time zero (the first stamp it received), ns.
        targets_ns: the IMU stamps to complete, ns, ascending, shape (m,).

    Returns:
        For each target, the index of the completing send, shape (m,), int; -1 when no sent
        message completes it (the node's idle flush releases it).
    """
    targets_s = (targets_ns - zero_ns) / 1e9
    result = np.full(targets_s.shape, -1, dtype=np.int64)
    newest: dict[str, float] = {}
    overall = -np.inf
    target = 0
    for index, (stream, ns) in enumerate(zip(streams, stamps_ns.tolist())):
        stamp_s = (ns - zero_ns) / 1e9
        newest[stream] = max(newest.get(stream, -np.inf), stamp_s)
        overall = max(overall, stamp_s)
        released_s = min(overall - window_s, min(newest.values()))
        while target < targets_s.size and targets_s[target] <= released_s:
            result[target] = index
            target += 1
        if target == targets_s.size:
            break
    return result


def _percentiles(values_s: np.ndarray) -> dict[str, float | None]:
    if values_s.size == 0:
        return {'p50': None, 'p90': None, 'p99': None, 'max': None, 'mean': None}
    ms = values_s * 1e3
    p50, p90, p99 = np.percentile(ms, [50, 90, 99])
    return {'p50': float(p50), 'p90': float(p90), 'p99': float(p99), 'max': float(ms.max()),
            'mean': float(ms.mean())}


def _stamp_ns(data: bytes) -> int:
    """Header stamp of a serialized message that begins with a std_msgs/Header, ns.

    A pose, an Imu, a PoseArray: CDR, little endian, after the 4-byte encapsulation header.
    """
    sec, nanosec = struct.unpack_from('<iI', data, 4)
    return sec * 1_000_000_000 + nanosec


class _Session:
    """This process's rclpy side of one run: publishers, raw pose listener, diagnostics."""

    def __init__(self, domain_id: int, case: LiveCase):
        import rclpy

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        try:
            self._create(case)
        except BaseException:
            self.context.try_shutdown()
            raise

    def _create(self, case: LiveCase) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Pose, PoseArray, PoseWithCovarianceStamped, Vector3Stamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu

        from gyro_ekf import topics
        from gyro_ekf.nodes import qos

        self.node = rclpy.create_node('live_bench', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        sensor = qos.sensor_input(case.reliable_inputs)
        self.imu_pub = self.node.create_publisher(Imu, topics.IMU, sensor)
        self.odom_pub = self.node.create_publisher(Odometry, topics.ODOM, sensor)
        self.landmarks_pub = None
        if case.landmarks_hz > 0.0:
            self.landmarks_pub = self.node.create_publisher(
                PoseArray, topics.LANDMARKS, qos.stream_output(case.reliable_inputs))
        keep_all = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL,
                              reliability=ReliabilityPolicy.RELIABLE)
        self.received: list[tuple[int, float]] = []
        self.node.create_subscription(PoseWithCovarianceStamped, topics.EKF_POSE,
                                      self._on_pose, keep_all, raw=True)
        # The node publishes odometry and bias only to subscribers: count them, unread.
        self.outputs = {topics.EKF_ODOMETRY: 0, topics.EKF_BIAS: 0}
        for msg_type, topic in ((Odometry, topics.EKF_ODOMETRY),
                                (Vector3Stamped, topics.EKF_BIAS)):
            self.node.create_subscription(msg_type, topic, self._counter(topic), keep_all,
                                          raw=True)
        self.diagnostics: list[tuple[float, dict[str, str]]] = []
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS,
                                      self._on_diagnostics, qos.OUTPUT)
        self.imu = Imu()
        self.imu.header.frame_id = topics.IMU_FRAME
        self.odom = Odometry()
        self.odom.header.frame_id = topics.ODOM_FRAME
        self.odom.child_frame_id = topics.BASE_FRAME
        self.observations = PoseArray()
        self.observations.header.frame_id = 'scan'
        for x, y in LANDMARKS_XY_M[:3]:
            pose = Pose()
            pose.position.x, pose.position.y = x, y
            self.observations.poses.append(pose)

    def _counter(self, topic: str) -> Callable[[bytes], None]:
        def count(_: bytes) -> None:
            self.outputs[topic] += 1
        return count

    def _on_pose(self, data: bytes) -> None:
        now = _CLOCK()
        self.received.append((_stamp_ns(data), now))

    def _on_diagnostics(self, message: Any) -> None:
        for status in message.status:
            if 'ekf_node' in status.name:
                self.diagnostics.append((_CLOCK(), {kv.key: kv.value for kv in status.values}))

    def spin_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until condition() holds or timeout_s passes; tell whether it held."""
        deadline = _CLOCK() + timeout_s
        while not condition():
            remaining = deadline - _CLOCK()
            if remaining <= 0.0:
                return False
            self.executor.spin_once(timeout_sec=min(remaining, 0.05))
        return True

    def spin_until_time(self, deadline: float) -> None:
        """Serve callbacks until the perf_counter deadline."""
        while True:
            remaining = deadline - _CLOCK()
            if remaining <= 0.0:
                return
            self.executor.spin_once(timeout_sec=remaining)

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


class _Sender:
    """Paced sending of steps and observations, with a record of every send."""

    def __init__(self, session: _Session, case: LiveCase):
        self.session = session
        self.period_s = 1.0 / case.rate_hz
        self.period_ns = round(1e9 / case.rate_hz)
        self.landmark_every = (max(1, round(case.rate_hz / case.landmarks_hz))
                               if case.landmarks_hz > 0.0 else 0)
        self.streams: list[str] = []
        self.stamps_ns: list[int] = []
        self.times_s: list[float] = []
        self.imu_sent: dict[int, float] = {}
        self.step = 0
        self.lateness_s: list[float] = []
        self._next_s: float | None = None

    def stamp_of(self, step: int) -> int:
        """Header stamp of a step, ns."""
        return STAMP_ZERO_NS + step * self.period_ns

    def _publish(self, stream: str, publisher: Any, message: Any, ns: int) -> float:
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(ns, 1_000_000_000)
        sent = _CLOCK()
        publisher.publish(message)
        self.streams.append(stream)
        self.stamps_ns.append(ns)
        self.times_s.append(sent)
        return sent

    def send_step(self) -> None:
        """Publish odom, then imu (and observations every n-th step) of the next step."""
        session, ns = self.session, self.stamp_of(self.step)
        if self.landmark_every and self.step % self.landmark_every == 0:
            self._publish('landmarks', session.landmarks_pub, session.observations, ns)
        self._publish('odom', session.odom_pub, session.odom, ns)
        self.imu_sent[ns] = self._publish('imu', session.imu_pub, session.imu, ns)
        self.step += 1

    def run(self, steps: int, until: Callable[[], bool] | None = None) -> None:
        """Send steps at the rate (one absolute schedule across calls, spinning in between).

        Stops after `steps` steps, or earlier once until() holds.
        """
        if self._next_s is None:
            self._next_s = _CLOCK()
        for _ in range(steps):
            deadline = self._next_s
            self.session.spin_until_time(deadline)
            self.lateness_s.append(_CLOCK() - deadline)
            self.send_step()
            self._next_s = deadline + self.period_s
            if until is not None and until():
                return


def _node_command(case: LiveCase, map_file: Path) -> list[str]:
    params = {
        'initial_pose.x_m': '0.0', 'initial_pose.y_m': '0.0', 'initial_pose.yaw_rad': '0.0',
        'initial_position_sigma_m': '0.05', 'initial_yaw_sigma_rad': '0.01',
        'landmarks_file': str(map_file),
        'reliable_inputs': 'true' if case.reliable_inputs else 'false',
        'diagnostics_period_s': '0.5', 'publish_every_n': '1',
        'late_observation_history_s': f'{case.late_observation_history_s:g}',
    }
    if case.reorder_window_s:  # a removed parameter (the node warns and ignores it)
        params['reorder_window_s'] = f'{case.reorder_window_s:g}'
    args = [sys.executable, '-m', 'gyro_ekf.nodes.ekf_node', '--ros-args']
    for name, value in params.items():
        args += ['-p', f'{name}:={value}']
    return args


def _stop(child: subprocess.Popen, timeout_s: float = 5.0) -> None:
    if child.poll() is None:
        child.send_signal(signal.SIGINT)
        try:
            child.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def _tail(path: Path, chars: int = 1500) -> str:
    try:
        return path.read_text(errors='replace')[-chars:]
    except OSError:
        return ''


def _warnings(path: Path, most: int = 10) -> list[str]:
    try:
        lines = path.read_text(errors='replace').splitlines()
    except OSError:
        return []
    return [line[:300] for line in lines if '[WARN]' in line or '[ERROR]' in line][-most:]


def measure(case: LiveCase, env: dict[str, str], startup_timeout_s: float = 30.0,
            settle_timeout_s: float | None = None) -> dict[str, Any]:
    """Run ekf_node in a child process and measure one case (see the module docstring).

    Args:
        case: rate, length and node settings.
        env: environment from ros_environment() (this process must run inside it).
        startup_timeout_s: longest wait for matched endpoints and the first poses, s.
        settle_timeout_s: longest wait after the last send for the measured poses (the
            drain, which also ends after 1.5 s without a pose), and then for the node's
            report counting every IMU message from the first it answered, s. None:
            DRAIN_S and NODE_REPORT_S, short, so that a run that lost messages ends soon
            (its figures say what came back). Either way the newest report is taken.

    Returns:
        JSON-ready results: the case, counts (sent, received, missing), latency and
        completion latency percentiles (ms), node CPU (s, us per step and per message) and
        the node's own diagnostics counters ('node_report_complete': whether they count
        every IMU message sent from the first one answered); 'error' when the run could not
        be measured.
    """
    work = Path(env['GYRO_EKF_LIVE_WORK'])
    map_file = work / 'map.yaml'
    map_file.write_text('landmarks:\n' + ''.join(f'  - [{x}, {y}]\n'
                                                 for x, y in LANDMARKS_XY_M))
    node_log = work / f'ekf_node_{case.rate_hz:g}hz_{os.getpid()}_{time.time_ns()}.log'
    result: dict[str, Any] = {'case': asdict(case), 'name': case.name}
    session = _Session(int(env['ROS_DOMAIN_ID']), case)
    child = None
    try:
        with node_log.open('w') as output:
            child = subprocess.Popen(_node_command(case, map_file),
                                     env={**env, NODE_IO_VARIABLE: case.node_io}, cwd=work,
                                     stdout=output, stderr=subprocess.STDOUT)
        result['node_pid'] = child.pid
        publishers = [session.imu_pub, session.odom_pub]
        if session.landmarks_pub is not None:
            publishers.append(session.landmarks_pub)
        matched = session.spin_until(
            lambda: child.poll() is not None
            or (all(p.get_subscription_count() > 0 for p in publishers)
                and all(session.node.count_publishers('/' + topic) > 0
                        for topic in (topics.EKF_POSE, *session.outputs))), startup_timeout_s)
        if not matched or child.poll() is not None:
            result['error'] = (f'ekf_node exited with {child.returncode}'
                               if child.poll() is not None else
                               f'no matched endpoints within {startup_timeout_s} s')
            result['node_log_tail'] = _tail(node_log)
            return result
        sender = _Sender(session, case)
        # Warm-up: a continuous stream until poses come back (first samples may be lost while
        # the node's side of discovery settles), then the measurement continues the stream.
        # Odometry and bias too: the node skips them while their writers have no reader, and
        # each matches this process's reader on its own, possibly after the pose's.
        warm_deadline = _CLOCK() + startup_timeout_s
        warmup_steps = max(10, round(case.rate_hz * case.warmup_s))
        while _CLOCK() < warm_deadline and child.poll() is None and (
                sender.step < warmup_steps or len(session.received) < 10
                or not all(session.outputs.values())):
            sender.run(warmup_steps - sender.step if sender.step < warmup_steps else 10)
        if not session.received:
            result['error'] = f'no ekf/pose within {startup_timeout_s} s of warm-up'
            result['node_log_tail'] = _tail(node_log)
            return result
        warmup_sent, first_measured = sender.step, len(sender.streams)
        zero_ns = sender.stamp_of(0)
        steps = max(1, round(case.rate_hz * case.duration_s))
        measured = [sender.stamp_of(warmup_sent + k) for k in range(steps)]
        wanted = set(measured)
        got: set[int] = set()
        seen = [0]

        def all_in() -> bool:
            for stamp, _ in session.received[seen[0]:]:
                if stamp in wanted:
                    got.add(stamp)
            seen[0] = len(session.received)
            return len(got) == len(wanted)

        cpu_before, wall_before = cpu_seconds(child.pid), _CLOCK()
        own_before = time.process_time()
        outputs_before = dict(session.outputs)
        sender.lateness_s.clear()
        sender.run(steps)
        send_end = _CLOCK()
        # Drain: until every measured pose is in, or none came for longer than the node's
        # idle flush (0.5 s) needs, bounded. The CPU window ends at the last pose received
        # (not after the quiet wait that follows a drop).
        drain_s = DRAIN_S if settle_timeout_s is None else settle_timeout_s
        drain_deadline = send_end + drain_s
        last = [len(session.received), _CLOCK(), cpu_seconds(child.pid),
                time.process_time()]

        def drained() -> bool:
            if len(session.received) != last[0]:
                last[:] = [len(session.received), _CLOCK(), cpu_seconds(child.pid),
                           time.process_time()]
            return all_in() or _CLOCK() - last[1] > 1.5 or _CLOCK() > drain_deadline
        session.spin_until(drained, drain_s + 1.0)
        _, wall_after, cpu_after, own_after = last
        own_cpu_s = own_after - own_before

        # The node's counters, from a report with an estimate for every IMU message sent
        # from the first one it answered (the earliest pose stamp; the messages before it
        # were lost while its reader matched this process's writer): made after its last
        # estimate. The drain may end while the node still works, and a report received
        # after it may predate its last estimates. (Had the first poses been lost instead,
        # this asks for a few estimates too few.) A message lost later never lets a report
        # count them all: then the newest, after the wait.
        def complete() -> bool:
            first_pose_ns = min(stamp for stamp, _ in session.received)
            answered = sender.step - (first_pose_ns - zero_ns) // sender.period_ns
            return bool(session.diagnostics) and int(
                session.diagnostics[-1][1].get('estimates') or 0) >= answered
        report_complete = session.spin_until(
            complete, NODE_REPORT_S if settle_timeout_s is None else settle_timeout_s)
        result.update(_summarize(case, sender, session, measured, zero_ns, first_measured,
                                 send_end - wall_before))
        cpu_s = cpu_after - cpu_before
        messages = len(sender.streams) - first_measured
        result.update({
            'outputs_received': {topic: session.outputs[topic] - outputs_before[topic]
                                 for topic in session.outputs},
            'node_cpu_s': cpu_s, 'wall_s': wall_after - wall_before,
            'node_cpu_share': cpu_s / (wall_after - wall_before),
            'node_cpu_us_per_step': cpu_s / steps * 1e6,
            'node_cpu_us_per_message': cpu_s / messages * 1e6,
            'bench_cpu_share': own_cpu_s / (wall_after - wall_before),
            'cpu_clock_tick_s': 1.0 / os.sysconf('SC_CLK_TCK'),
        })
        if session.diagnostics:
            values = session.diagnostics[-1][1]
            result['node'] = {key: int(values[key]) for key in values
                              if key in ('estimates', 'published', 'associated', 'resets',
                                         'replayed_observations', 'replayed_events')
                              or key.startswith('dropped_')}
            result['node']['imu_sent_total'] = sender.step
            result['node_report_complete'] = report_complete
            result['node']['imu_lost_incl_warmup'] = sender.step - result['node'].get(
                'estimates', 0)
        if child.poll() is not None:
            result['error'] = f'ekf_node exited with {child.returncode} during the run'
            result['node_log_tail'] = _tail(node_log)
        result['node_warnings'] = _warnings(node_log)
        result['measured'] = 'error' not in result
        return result
    finally:
        if child is not None:
            _stop(child)
        session.close()


def _summarize(case: LiveCase, sender: _Sender, session: _Session, measured: list[int],
               zero_ns: int, first_measured: int, send_s: float) -> dict[str, Any]:
    """Match poses to inputs by stamp; counts and latency percentiles."""
    arrival: dict[int, float] = {}
    duplicates = 0
    for stamp, at in session.received:
        if stamp in arrival:
            duplicates += 1
        else:
            arrival[stamp] = at
    targets = np.array(measured, dtype=np.int64)
    # Replayed observations hold nothing back: only speed and IMU decide the release.
    held_back = [i for i, stream in enumerate(sender.streams)
                 if not (case.late_observation_history_s and stream == 'landmarks')]
    completing = completion_indices([sender.streams[i] for i in held_back],
                                    np.array(sender.stamps_ns, dtype=np.int64)[held_back],
                                    case.reorder_window_s, zero_ns, targets)
    # Back from positions among the held-back sends to positions among all sends.
    completing = np.where(completing >= 0,
                          np.asarray(held_back, dtype=np.int64)[np.maximum(completing, 0)], -1)
    times = np.array(sender.times_s)
    latency, completion, flushed, missing = [], [], 0, []
    for step, (stamp, index) in enumerate(zip(measured, completing.tolist())):
        out = arrival.get(stamp)
        if out is None:
            missing.append(step)
        elif index < 0:
            flushed += 1
        else:
            latency.append(out - sender.imu_sent[stamp])
            completion.append(out - times[index])
    steps = len(measured)
    lateness = np.array(sender.lateness_s)
    return {
        'steps': steps, 'messages_sent': len(sender.streams) - first_measured,
        'send_rate_hz': steps / send_s if send_s > 0 else None,
        'send_lateness_ms': _percentiles(lateness),
        'poses_received': steps - len(missing), 'poses_missing': len(missing),
        'missing_steps_first': missing[:20],
        'poses_released_by_idle_flush': flushed, 'duplicate_poses': duplicates,
        'drop_share': len(missing) / steps,
        'latency_ms': _percentiles(np.array(latency)),
        'completion_latency_ms': _percentiles(np.array(completion)),
    }


DEFAULT_CASES = (
    LiveCase(200.0, 10.0),
    LiveCase(200.0, 10.0, node_io='rclpy'),
    LiveCase(1000.0, 10.0),
    LiveCase(1000.0, 10.0, node_io='rclpy'),
    LiveCase(1000.0, 10.0, reliable_inputs=True),
    LiveCase(200.0, 10.0, landmarks_hz=10.0),
    LiveCase(200.0, 10.0, landmarks_hz=10.0, late_observation_history_s=0.5),
)
"""The cases of `make bench`: the two rates with no reorder window (the pure pipeline; sensor
data QoS, on the serialized path and on the rclpy-message path, and reliable keep-all inputs at
1 kHz), and 10 Hz pole observations as a third input stream, held in stamp order (the
default) or replayed when late. (ekf_node no longer has a reorder window: main removed
reorder_window_s.)"""


@dataclass(frozen=True, slots=True)
class NodeCase:
    """CPU of calibration_node or landmark_detector_node per input message.

    Attributes:
        node: 'calibration_node' (IMU in, imu/corrected out after its static window) or
            'landmark_detector_node' (361-beam LaserScan in, landmarks out).
        rate_hz: input messages per second.
        duration_s: measured length after the warm-up (for calibration_node: after the
            static window), s.
        node_io: the node's message path (GYRO_EKF_NODE_IO).
        reliable_inputs: the node's reliable_inputs parameter (reliable keep-all inputs and
            outputs, so every message sent is processed; default: the node's default QoS).
    """

    node: str
    rate_hz: float
    duration_s: float
    node_io: str = 'serialized'
    reliable_inputs: bool = False

    @property
    def name(self) -> str:
        """Short label of the case."""
        io = '' if self.node_io == 'serialized' else f', {self.node_io} messages'
        reliable = ', reliable' if self.reliable_inputs else ''
        return f'{self.node} {self.rate_hz:g} Hz{io}{reliable}'


class _ChildExited(RuntimeError):
    """The measured node process ended during the run."""


CALIBRATION_WINDOW_S = 2.0
SCAN_BEAMS = 361


def _scan_message(stamp_ns: int) -> Any:
    """Build a 361-beam half-turn scan of a wall at 8 m with three reflective poles at 4-6 m."""
    from sensor_msgs.msg import LaserScan

    scan = LaserScan()
    scan.header.frame_id = 'laser'
    scan.header.stamp.sec, scan.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    scan.angle_min, scan.angle_max = -np.pi / 2, np.pi / 2
    scan.angle_increment = np.pi / (SCAN_BEAMS - 1)
    scan.range_min, scan.range_max = 0.1, 80.0
    ranges = np.full(SCAN_BEAMS, 8.0, dtype=np.float32)
    intensities = np.zeros(SCAN_BEAMS, dtype=np.float32)
    for beam, distance in ((60, 4.0), (180, 5.0), (300, 6.0)):
        ranges[beam - 1:beam + 2] = distance
        intensities[beam - 1:beam + 2] = 2.0
    scan.ranges = ranges.tolist()
    scan.intensities = intensities.tolist()
    return scan


def measure_node(case: NodeCase, env: dict[str, str], startup_timeout_s: float = 30.0,
                 settle_timeout_s: float | None = None) -> dict[str, Any]:
    """Run calibration_node or landmark_detector_node in a child; CPU per input message.

    With `reliable_inputs` every message sent is processed and the output count checks it;
    with the default QoS (best effort in) a message the node lost shows as a missing output.
    For calibration_node the static window
    (CALIBRATION_WINDOW_S of still IMU samples) is timed on its own
    (`window_cpu_us_per_message`), then `duration_s` of corrected IMU messages.

    `settle_timeout_s` bounds the waits for the node: for the bias (beyond the window's
    stamps) and for the outputs of the measured messages. None: 30 and 10 s, short, so that
    a run that lost messages ends soon (the counts say so).

    Returns:
        JSON-ready results: the case, messages sent and outputs received (of those
        messages, told by stamp), node CPU (s, us per message, share of a core); 'error'
        when the run could not be measured.
    """
    import rclpy
    from geometry_msgs.msg import PoseArray, Vector3Stamped
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from gyro_ekf.nodes import qos

    work = Path(env['GYRO_EKF_LIVE_WORK'])
    result: dict[str, Any] = {'case': asdict(case), 'name': case.name}
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    child = None
    node_log = work / f'{case.node}_{os.getpid()}_{time.time_ns()}.log'
    try:
        node = rclpy.create_node('live_bench_nodes', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        calibration = case.node == 'calibration_node'
        received = [0]
        # Outputs of the measured messages, told by their stamps (the input's): an output
        # of the warm-up that comes late is not one of them.
        measured_from_ns: list[int | None] = [None]
        measured_outputs = [0]
        bias: list[bytes] = []

        def count(data: bytes) -> None:
            received[0] += 1
            if measured_from_ns[0] is not None and _stamp_ns(data) >= measured_from_ns[0]:
                measured_outputs[0] += 1
        if calibration:
            publisher = node.create_publisher(Imu, topics.IMU,
                                              qos.sensor_input(case.reliable_inputs))
            node.create_subscription(Imu, topics.IMU_CORRECTED, count, qos.LOSSLESS, raw=True)
            node.create_subscription(Vector3Stamped, topics.GYRO_BIAS, bias.append, qos.LATCHED,
                                     raw=True)
            params = {'use_odom': 'false', 'window_length_s': f'{CALIBRATION_WINDOW_S:g}'}
            outputs = (topics.IMU_CORRECTED, topics.GYRO_BIAS)
            rng = np.random.default_rng(0)
            message = Imu()
            message.header.frame_id = topics.IMU_FRAME

            def fill(ns: int) -> Any:
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(
                    ns, 1_000_000_000)
                message.angular_velocity.z = float(-0.017 + 0.001 * rng.standard_normal())
                return message
        else:
            from sensor_msgs.msg import LaserScan

            publisher = node.create_publisher(LaserScan, topics.SCAN,
                                              qos.sensor_input(case.reliable_inputs))
            node.create_subscription(PoseArray, topics.LANDMARKS, count, qos.LOSSLESS,
                                     raw=True)
            params, outputs = {}, (topics.LANDMARKS,)
            scan = _scan_message(STAMP_ZERO_NS)

            def fill(ns: int) -> Any:
                scan.header.stamp.sec, scan.header.stamp.nanosec = divmod(ns, 1_000_000_000)
                return scan
        params['reliable_inputs'] = 'true' if case.reliable_inputs else 'false'
        command = [sys.executable, '-m', f'gyro_ekf.nodes.{case.node}', '--ros-args']
        for name, value in params.items():
            command += ['-p', f'{name}:={value}']
        with node_log.open('w') as output:
            child = subprocess.Popen(command, env={**env, NODE_IO_VARIABLE: case.node_io},
                                     cwd=work, stdout=output, stderr=subprocess.STDOUT)
        result['node_pid'] = child.pid

        def spin_until(condition: Callable[[], bool], timeout_s: float) -> bool:
            deadline = _CLOCK() + timeout_s
            while not condition() and child.poll() is None:
                if _CLOCK() > deadline:
                    return False
                executor.spin_once(timeout_sec=0.01)
            return condition()
        if not spin_until(lambda: publisher.get_subscription_count() > 0 and all(
                node.count_publishers('/' + topic) > 0 for topic in outputs),
                startup_timeout_s):
            result['error'] = f'{case.node}: no matched endpoints within {startup_timeout_s} s'
            result['node_log_tail'] = _tail(node_log)
            return result
        period_ns = round(1e9 / case.rate_hz)
        sent = [0]
        next_s = [_CLOCK()]

        def send(until: Callable[[], bool], most: int) -> None:
            """Publish at the rate until until() holds or `most` messages went out."""
            for _ in range(most):
                remaining = next_s[0] - _CLOCK()
                if remaining > 0.0:
                    executor.spin_once(timeout_sec=remaining)
                    while _CLOCK() < next_s[0]:
                        executor.spin_once(timeout_sec=max(next_s[0] - _CLOCK(), 0.0))
                publisher.publish(fill(STAMP_ZERO_NS + sent[0] * period_ns))
                sent[0] += 1
                next_s[0] += 1.0 / case.rate_hz
                if until():
                    return

        def node_cpu_s() -> float:
            try:
                return cpu_seconds(child.pid)
            except OSError:  # the child is gone: say so, with its log
                child.wait()
                raise _ChildExited(f'{case.node} exited with {child.returncode}') from None
        if calibration:
            # The static window: from the first sample to the published bias.
            cpu_before, wall_before = node_cpu_s(), _CLOCK()
            send(lambda: bool(bias), round(case.rate_hz * (CALIBRATION_WINDOW_S + (
                30.0 if settle_timeout_s is None else settle_timeout_s))))
            if not bias:
                result['error'] = 'calibration_node published no bias'
                result['node_log_tail'] = _tail(node_log)
                return result
            window_cpu = node_cpu_s() - cpu_before
            result.update({'window_messages': sent[0], 'window_cpu_s': window_cpu,
                           'window_cpu_us_per_message': window_cpu / sent[0] * 1e6,
                           'window_wall_s': _CLOCK() - wall_before})
        else:  # warm-up: the first scans load code and fill caches
            send(lambda: False, max(10, round(case.rate_hz)))
        # The node's output writer matches this process's reader on the node's own discovery,
        # which can come after the endpoints were seen above: an output sent before then is
        # lost (calibration_node even skips imu/corrected without a reader). More warm-up
        # until one comes back, so none of the measured messages' outputs is lost that way.
        send(lambda: received[0] > 0, round(case.rate_hz * startup_timeout_s))
        if not received[0]:
            result['error'] = f'{case.node}: no output within {startup_timeout_s} s of warm-up'
            result['node_log_tail'] = _tail(node_log)
            return result
        # Let the node catch up with the warm-up before its CPU is measured (bounded: the
        # count below goes by stamp, whatever of the warm-up is still to come).
        spin_until(lambda: received[0] >= sent[0] - (1 if calibration else 0), 5.0)
        first_sent = sent[0]
        measured_from_ns[0] = STAMP_ZERO_NS + first_sent * period_ns
        messages = max(1, round(case.rate_hz * case.duration_s))
        next_s[0] = _CLOCK()  # a new schedule: no burst to catch up after the waits
        cpu_before, wall_before = node_cpu_s(), _CLOCK()
        send(lambda: False, messages)
        spin_until(lambda: measured_outputs[0] >= messages,
                   10.0 if settle_timeout_s is None else settle_timeout_s)
        cpu_s, wall_s = node_cpu_s() - cpu_before, _CLOCK() - wall_before
        result.update({
            'messages_sent': sent[0] - first_sent,
            'outputs_received': measured_outputs[0],
            'node_cpu_s': cpu_s, 'wall_s': wall_s, 'node_cpu_share': cpu_s / wall_s,
            'node_cpu_us_per_message': cpu_s / messages * 1e6,
            'cpu_clock_tick_s': 1.0 / os.sysconf('SC_CLK_TCK'),
        })
        if child.poll() is not None:
            result['error'] = f'{case.node} exited with {child.returncode} during the run'
            result['node_log_tail'] = _tail(node_log)
        result['node_warnings'] = _warnings(node_log)
        result['measured'] = 'error' not in result
        return result
    except _ChildExited as err:
        result.update({'error': str(err), 'node_log_tail': _tail(node_log), 'measured': False})
        return result
    finally:
        if child is not None:
            _stop(child)
        context.try_shutdown()


NODE_CASES = (
    NodeCase('calibration_node', 1000.0, 10.0),
    NodeCase('calibration_node', 1000.0, 10.0, node_io='rclpy'),
    NodeCase('landmark_detector_node', 40.0, 10.0),
    NodeCase('landmark_detector_node', 40.0, 10.0, node_io='rclpy'),
)
"""calibration_node at 1 kHz and landmark_detector_node at 40 scans/s, on both message
paths."""


def live_suite(cases: tuple[LiveCase, ...] = DEFAULT_CASES, domain_id: int | None = None,
               node_cases: tuple[NodeCase, ...] = (), startup_timeout_s: float = 30.0,
               settle_timeout_s: float | None = None) -> dict[str, Any]:
    """Measure every case, each with a fresh ekf_node child, in one ROS environment.

    Args:
        cases: what to measure.
        domain_id: ROS domain; None claims a free one (gyro_ekf.ros_env).
        node_cases: calibration_node and landmark_detector_node cases (measure_node).
        startup_timeout_s, settle_timeout_s: passed to measure and measure_node (tests on
            a busy machine give long ones; the defaults are the bench's).

    Returns:
        {'measured': True when every case was, 'domain_id', 'runs': [per-case results],
        'node_runs': [per node case]}.
    """
    with ros_environment(domain_id) as env:
        runs = []
        for case in cases:
            log.info('live ekf_node latency: %s for %.0f s', case.name, case.duration_s)
            try:
                runs.append(measure(case, env, startup_timeout_s, settle_timeout_s))
            except Exception as err:  # noqa: BLE001 - one failed case must not end the bench
                log.warning('live case %s failed: %s', case.name, err)
                runs.append({'case': asdict(case), 'name': case.name, 'measured': False,
                             'error': f'{type(err).__name__}: {err}'})
        node_runs = []
        for node_case in node_cases:
            log.info('live %s for %.0f s', node_case.name, node_case.duration_s)
            try:
                node_runs.append(measure_node(node_case, env, startup_timeout_s,
                                              settle_timeout_s))
            except Exception as err:  # noqa: BLE001 - one failed case must not end the bench
                log.warning('live case %s failed: %s', node_case.name, err)
                node_runs.append({'case': asdict(node_case), 'name': node_case.name,
                                  'measured': False, 'error': f'{type(err).__name__}: {err}'})
        return {'measured': all(run.get('measured') for run in runs + node_runs),
                'domain_id': int(env['ROS_DOMAIN_ID']), 'runs': runs, 'node_runs': node_runs}
