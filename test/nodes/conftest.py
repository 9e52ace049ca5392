"""Multi-process fixtures: nodes as subprocesses, the test process as an rclpy probe.

Every process runs with loopback-only discovery, its own ROS_DOMAIN_ID and a temporary
ROS_LOG_DIR. Tests wait on conditions (matched endpoints, received messages, diagnostics)
with timeouts, never on fixed sleeps.
"""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from gyro_ekf.ros_env import ChildProcesses, child_env, claim_domain, DomainLease

REPO = Path(__file__).resolve().parents[2]
# Domains handed out by node_env() without a fixture to give them back: held until the
# session ends (ros_processes gives its own back at the end of its module).
_session_leases: list[DomainLease] = []


def _env_in_domain(tmp_path: Path, lease: DomainLease) -> dict[str, str]:
    log_dir = tmp_path / 'ros_log'
    log_dir.mkdir(parents=True, exist_ok=True)
    return child_env(lease.domain_id, log_dir)


def node_env(tmp_path: Path) -> dict[str, str]:
    """Environment for processes of one test: loopback, own domain, own log dir.

    No other test or run on this machine gets the domain until this test session ends.
    """
    lease = claim_domain()
    _session_leases.append(lease)
    return _env_in_domain(tmp_path, lease)


class Processes(ChildProcesses):
    """Subprocesses of a test (gyro_ekf.ros_env.ChildProcesses run from the repository)."""

    def __init__(self, env: dict[str, str], log_dir: Path):
        super().__init__(env, log_dir, cwd=REPO)

    def node(self, executable: str, *ros_args: str, name: str | None = None
             ) -> subprocess.Popen:
        """Start a node executable of gyro_ekf.nodes with --ros-args."""
        return self.start(name or executable, f'gyro_ekf.nodes.{executable}', '--ros-args',
                          *ros_args)

    def run(self, name: str, *args: str, timeout_s: float) -> str:
        """Run `python -m <args...>` to completion; return its output (assert exit 0)."""
        process = self.start(name, *args)
        try:
            code = process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            raise AssertionError(f'{name} did not finish in {timeout_s} s:\n{self.log(name)}')
        output = self.log(name)
        assert code == 0, f'{name} exited with {code}:\n{output}'
        return output

    def lidar_nodes(self, bag: Path, *ekf_args: str, scans: tuple[str, ...] = ('scan',)
                    ) -> tuple[str, ...]:
        """Start a detector per LiDAR (scan, then e.g. scan2) and the EKF node, lossless inputs.

        The EKF node takes the bag's params file, then `ekf_args` (more params files or
        -p overrides), and publishes /diagnostics every 0.2 s.

        Returns:
            The detectors' node names (for Probe.wait_for_landmarks_readers).
        """
        lossless = ('-p', 'reliable_inputs:=true')
        names = []
        for scan in scans:
            if scan == 'scan':
                self.node('landmark_detector_node', *lossless)
                names.append('landmark_detector_node')
            else:
                self.node('landmark_detector_node', *lossless, '-r', f'scan:={scan}',
                          '-r', f'__node:=landmark_detector_{scan}', name=f'detector_{scan}')
                names.append(f'landmark_detector_{scan}')
        self.node('ekf_node', '--params-file', f'{bag}.params.yaml', *ekf_args, *lossless,
                  '-p', 'diagnostics_period_s:=0.2')
        return tuple(names)

    def two_lidar_nodes(self, bag: Path, *ekf_args: str) -> tuple[str, ...]:
        """lidar_nodes for a two-LiDAR bag (scan, scan2)."""
        return self.lidar_nodes(bag, *ekf_args, scans=('scan', 'scan2'))

    def replay_bag(self, bag: Path, scans: tuple[str, ...] = ('scan',)) -> str:
        """Replay a bag at 5x once every input has a reader; return its output."""
        waits = [arg for topic in ('imu', 'odom', *scans) for arg in ('--wait-for', f'{topic}:1')]
        return self.run(
            'replay', 'gyro_ekf.cli.main', 'replay', str(bag), '--rate', '5',
            '--topics', 'imu', 'odom', *scans, 'landmark_map', 'initialpose', *waits,
            timeout_s=150)

    def replay_two_lidar_bag(self, bag: Path) -> str:
        """replay_bag for a two-LiDAR bag (scan, scan2)."""
        return self.replay_bag(bag, ('scan', 'scan2'))


MIN_WAIT_S = 90.0
"""Shortest wait for a message or a state before a test fails (see Probe.spin_until)."""


class Probe:
    """The test process's rclpy node in its own context and domain."""

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('test_probe', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def subscribe(self, msg_type: Any, topic: str, qos: Any) -> list[Any]:
        """Subscribe; received messages are appended to the returned list."""
        received: list[Any] = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def spin_until(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Spin until condition() holds; fail after timeout_s saying what was awaited.

        A timeout only says "stuck", never "slow": it is at least MIN_WAIT_S, since with a
        second copy of the suite on the same two cores a message can take tens of seconds.
        """
        timeout_s = max(timeout_s, MIN_WAIT_S)
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout_s} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.05)

    def wait_for_landmarks_readers(self, diagnostics: list[Any],
                                   detectors: Iterable[str] = ('landmark_detector_node',)
                                   ) -> None:
        """Spin until each detector's /diagnostics says its landmarks writer matched a reader.

        The writer matches the EKF node's reader on the detector's own discovery, which can
        come after the probe sees both ends; the first scans' landmarks would then be lost and
        the estimates would not be the offline run's. `diagnostics` is the probe's
        /diagnostics subscription. The detector reports once a period on its node clock and
        at once when a reader of its landmarks or diagnostics matches, so this works under
        use_sim_time before /clock runs too.
        """
        detectors = tuple(detectors)

        def matched(node: str) -> bool:
            values = diagnostic_values(diagnostics, f'/{node}: pole detector') or {}
            return int(values.get('landmarks_readers') or 0) > 0
        self.spin_until(lambda: all(matched(node) for node in detectors), 60,
                        f'landmarks_readers > 0 in the /diagnostics of {", ".join(detectors)}'
                        ' (their landmarks writers matched the EKF node\'s reader)')

    def wait_for_lidar_nodes(self, diagnostics: list[Any], detectors: tuple[str, ...]) -> None:
        """Spin until the detectors and the EKF node of Processes.lidar_nodes are linked.

        Every detector publishes /landmarks, the EKF node reads them and publishes
        ekf/odometry, and each detector's landmarks writer matched the EKF node's reader.
        """
        self.spin_until(lambda: self.node.count_publishers('/landmarks') == len(detectors)
                        and self.node.count_subscribers('/landmarks') == 1
                        and self.node.count_publishers('/ekf/odometry') == 1, 20,
                        f'{len(detectors)} detector(s) and the EKF node on /landmarks')
        self.wait_for_landmarks_readers(diagnostics, detectors)

    def wait_for_every_estimate(self, diagnostics: list[Any], imu_samples: int
                                ) -> tuple[int, str, dict[str, str]]:
        """Spin until the EKF node has an estimate per IMU sample; return its newest status.

        Its /diagnostics counts the estimates; two statuses more are awaited, so the scans
        after the last IMU sample are in too (the idle flush). The status is ``ekf_status``.
        """
        n_imu = str(imu_samples)
        self.spin_until(
            lambda: (ekf_status(diagnostics) or (0, '', {}))[2].get('estimates') == n_imu,
            60, f'{n_imu} estimates in /diagnostics')
        seen = len(diagnostics)
        self.spin_until(lambda: len(diagnostics) >= seen + 2, 10, 'two more diagnostics')
        status = ekf_status(diagnostics)
        assert status is not None
        return status

    def close(self) -> None:
        """Destroy the node and shut the context down."""
        self.node.destroy_node()
        self.context.try_shutdown()


def diagnostic_values(messages: list[Any], name_part: str) -> dict[str, str] | None:
    """Key/values of the newest diagnostic status whose name contains name_part."""
    for array in reversed(messages):
        for status in array.status:
            if name_part in status.name:
                return {kv.key: kv.value for kv in status.values}
    return None


EKF_STATUS = '/ekf_node: gyro bias EKF'
"""Part of the name of the EKF node's diagnostic status."""


def ekf_status(messages: list[Any]) -> tuple[int, str, dict[str, str]] | None:
    """Return the EKF node's newest diagnostic status: (level, message, key/values)."""
    for array in reversed(messages):
        for status in array.status:
            if EKF_STATUS in status.name:
                return status.level, status.message, {kv.key: kv.value for kv in status.values}
    return None


@pytest.fixture(scope='session')
def diagnostics_of():
    """The diagnostic_values helper."""
    return diagnostic_values


@pytest.fixture(scope='module')
def ros_processes(tmp_path_factory) -> Iterator[tuple[Processes, Probe]]:
    """Processes and a probe sharing one loopback-only domain for a whole test module."""
    tmp = tmp_path_factory.mktemp('ros')
    lease = claim_domain()
    env = _env_in_domain(tmp, lease)
    saved = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID',
                                            'ROS_LOG_DIR')}
    for key in saved:
        os.environ[key] = env[key]
    processes = Processes(env, tmp)
    probe = Probe(int(env['ROS_DOMAIN_ID']))
    try:
        yield processes, probe
    finally:
        processes.stop_all()
        probe.close()
        lease.release()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@pytest.fixture(scope='session')
def real_bag(tmp_path_factory, shared_data) -> Path:
    """The 2016 real log converted to a bag (with its params sidecar)."""
    from gyro_ekf.io import load_course_log, write_trip_bag

    trip = load_course_log([shared_data('2016_project1'),
                            shared_data('2021_aas01/MapMTRN4010.mat')])
    return write_trip_bag(trip, tmp_path_factory.mktemp('bags') / 'real2016')


@pytest.fixture(scope='session')
def sim_bag(tmp_path_factory) -> Path:
    """A seeded 60 s simulated trip with known bias, as a bag."""
    import dataclasses

    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io import write_trip_bag

    config = dataclasses.replace(SimulationConfig(), duration_s=60.0)
    return write_trip_bag(simulate_trip(config, seed=3),
                          tmp_path_factory.mktemp('bags') / 'sim60')


@pytest.fixture(scope='session')
def ros_harness():
    """Give the harness to tests that start their own processes.

    `from conftest import ...` would pick whichever conftest module pytest imported first.
    """
    return SimpleNamespace(Probe=Probe, Processes=Processes, node_env=node_env)
