"""One ekf_node under test in a namespace of its own, fed by the probe (shared by node tests).

The tests check only the estimates and diagnostics of their own node, for messages they sent
themselves (stamps unique to each test).
"""

from __future__ import annotations

STEP_NS = 10_000_000
"""10 ms between samples (100 Hz IMU and odometry)."""
NS = 10 ** 9


def stamped(message, stamp_ns: int):
    """Set a message's header stamp from ns; return the message."""
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, NS)
    return message


class EkfUnderTest:
    """ekf_node in namespace `name` with reliable inputs, the probe's publishers and readers."""

    def __init__(self, ros_processes, diagnostics_of, name: str, *params: str,
                 node_args: tuple[str, ...] = ()):
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import Imu

        from gyro_ekf.nodes import qos

        self.processes, self.probe = ros_processes
        self.diagnostics_of = diagnostics_of
        self.name = name
        self.key = f'/{name}/ekf_node: gyro bias EKF'
        args = ['-r', f'__ns:=/{name}', *node_args, '-p', 'reliable_inputs:=true',
                '-p', 'diagnostics_period_s:=0.1']
        for param in params:
            args += ['-p', param]
        self._sim_time = 'use_sim_time:=true' in (*params, *node_args)
        self.processes.node('ekf_node', *args, name=name)
        node = self.probe.node
        self.imu = node.create_publisher(Imu, f'/{name}/imu', qos.LOSSLESS)
        self.odom = node.create_publisher(Odometry, f'/{name}/odom', qos.LOSSLESS)
        self.odometry: list = []
        # Kept: its matched-publisher count says when the node's output reaches the probe.
        self._odometry_sub = self.probe.node.create_subscription(
            Odometry, f'/{name}/ekf/odometry', self.odometry.append, qos.LOSSLESS)
        self.diagnostics = self.probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)

    def wait_for_node(self, *publishers) -> None:
        """Wait until the node reads imu, odom and every given publisher, and publishes."""
        # Matched endpoints both ways, not graph counts: the node skips an output nobody
        # reads, so an estimate published before its writer matched the probe's reader
        # never arrives (seen under load: 'the last estimate' awaited for 90 s in vain).
        # The node's side of the match is what it reports in /diagnostics (on its clock: a
        # node on sim time reports nothing before /clock runs, so there only the probe's).
        self.probe.spin_until(
            lambda: all(p.get_subscription_count() for p in (self.imu, self.odom, *publishers))
            and self._odometry_sub.get_publisher_count() > 0
            and (self._sim_time or int(self.values().get('odometry_readers') or 0) > 0), 20,
            f'the EKF node {self.name}')

    def _publish(self, publisher, message) -> None:
        # A reliable KEEP_ALL writer blocks while the reader's history is full and gives up
        # ("cannot publish data") after Fast DDS's max_blocking_time: on a loaded machine a
        # burst outruns the node. Waiting and sending again keeps every message (the tests
        # count them all) without asserting how fast they go.
        from rclpy.impl.implementation_singleton import rclpy_implementation
        for _ in range(600):
            try:
                publisher.publish(message)
                return
            except rclpy_implementation.RCLError:
                self.probe.executor.spin_once(timeout_sec=0.05)
        publisher.publish(message)

    def send_imu(self, stamp_ns: int, rate: float = 0.0) -> None:
        from sensor_msgs.msg import Imu
        message = Imu()
        message.angular_velocity.z = rate
        self._publish(self.imu, stamped(message, stamp_ns))

    def send_odom(self, stamp_ns: int, speed: float = 0.0) -> None:
        from nav_msgs.msg import Odometry
        message = Odometry()
        message.twist.twist.linear.x = speed
        self._publish(self.odom, stamped(message, stamp_ns))

    def values(self) -> dict[str, str]:
        return self.diagnostics_of(self.diagnostics, self.key) or {}

    def node_clock_ns(self) -> int:
        """The node's ROS time when it sent its newest diagnostics received (their stamp)."""
        for array in reversed(self.diagnostics):
            if any(self.key in status.name for status in array.status):
                return array.header.stamp.sec * 10 ** 9 + array.header.stamp.nanosec
        raise AssertionError(f'no diagnostics from {self.name}')

    def wait_for(self, condition, what: str, timeout_s: float = 30.0) -> dict[str, str]:
        self.probe.spin_until(lambda: condition(self.values()), timeout_s, what)
        return self.values()

    def log(self) -> str:
        return self.processes.log(self.name)


def run_and_replay(ros_processes, trip, folder, ekf_args=(), run_args=()):
    """A trip's bag through `gyro-ekf run` and through the detector and EKF nodes.

    ``ekf_args`` go to the EKF node (after the bag's params file), ``run_args`` to `run`.
    Returns summary.json, the EKF node's last diagnostics once every estimate is out
    ((level, message, values), as Probe.wait_for_every_estimate gives them) and the
    replayer's report.
    """
    import json

    from diagnostic_msgs.msg import DiagnosticArray

    from gyro_ekf.cli.main import main
    from gyro_ekf.io.bag_writer import write_trip_bag
    from gyro_ekf.nodes import qos

    bag = write_trip_bag(trip, folder / 'bag')
    assert main(['-q', 'run', str(bag), '-o', str(folder / 'out'), '--no-progress',
                 '--no-plots', '--no-bag', *run_args]) == 0
    offline = json.loads((folder / 'out' / 'summary.json').read_text())
    processes, probe = ros_processes
    diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics', qos.LOSSLESS)
    detectors = processes.lidar_nodes(bag, *ekf_args)
    probe.wait_for_lidar_nodes(diagnostics, detectors)
    replay = processes.replay_bag(bag)
    return offline, probe.wait_for_every_estimate(diagnostics, len(trip.imu.stamp_s)), replay
