"""ekf_node with use_sim_time fed hostile timing: inputs that stop, run ahead, a clock going back.

The test process publishes /clock together with the data (as `gyro-ekf replay --clock`
does), stamps unique to each test, and a node per test in its own namespace. The node must
stay up, count what it drops in /diagnostics and reset only for a reason it logs, saying
which: ROS time jumping back, or stamps that restart.
"""

from __future__ import annotations

import re
import signal
import subprocess

import pytest

from ekf_harness import EkfUnderTest, NS, STEP_NS

pytestmark = pytest.mark.ros


class SimTimeEkf(EkfUnderTest):
    """One ekf_node (use_sim_time) in namespace `name`; the probe publishes /clock and data."""

    def __init__(self, ros_processes, diagnostics_of, name: str, *params: str):
        from rclpy.qos import QoSProfile
        from rosgraph_msgs.msg import Clock

        super().__init__(ros_processes, diagnostics_of, name, *params,
                         node_args=('-p', 'use_sim_time:=true'))
        # /clock is global: each test's node is stopped before the next test starts.
        self.clock = self.probe.node.create_publisher(Clock, '/clock', QoSProfile(depth=10))
        self.wait_for_node(self.clock)
        self._ticker = None
        self.clock_ns = 0
        """The last /clock sent, ns."""
        # The tests await estimates on ekf/odometry, which the node skips while its writer
        # has no reader; that writer matches the probe's reader on the node's own discovery,
        # which can come after the probe sees it. Only the node's diagnostics say it has,
        # and on sim time they wait for /clock: it runs from 1 s (a jump forward to every
        # test's stamps later, no reset) until a report counts the reader.
        self.send_clock(NS)
        self.tick()
        try:
            self.probe.spin_until(lambda: int(self.values().get('odometry_readers') or 0) > 0,
                                  20, f'the EKF node {name} to match the odometry reader')
        finally:
            self.stop_ticking()

    def send_clock(self, stamp_ns: int) -> None:
        from rosgraph_msgs.msg import Clock

        from gyro_ekf.nodes.conversions import to_stamp
        self.clock.publish(Clock(clock=to_stamp(stamp_ns)))
        self.clock_ns = stamp_ns

    def send_steps(self, clock_ns: int, first: int, last: int, imu_ns: int | None = None,
                   odom_ns: int | None = None, speed: float = 0.0) -> None:
        """Send /clock, odometry and IMU for steps first..last-1 (None: that input is silent).

        clock_ns, imu_ns, odom_ns: stamps of step 0 on each.
        """
        for i in range(first, last):
            self.send_clock(clock_ns + i * STEP_NS)
            if odom_ns is not None:
                self.send_odom(odom_ns + i * STEP_NS, speed)
            if imu_ns is not None:
                self.send_imu(imu_ns + i * STEP_NS)
            if i % 50 == 0:  # let the probe take what the node sent
                self.probe.executor.spin_once(timeout_sec=0.0)

    def tick(self) -> None:
        """Keep /clock running on from the last sent, 20 ms per 20 ms (the node's timers)."""
        def tick() -> None:
            self.send_clock(self.clock_ns + 20_000_000)
        self.stop_ticking()
        self._ticker = self.probe.node.create_timer(0.02, tick)

    def stop_ticking(self) -> None:
        if self._ticker is not None:
            self.probe.node.destroy_timer(self._ticker)
            self._ticker = None

    def wait_for(self, condition, what: str, timeout_s: float = 60.0) -> dict[str, str]:
        return super().wait_for(condition, what, timeout_s)

    def estimate_at(self, stamp_ns: int):
        found = [m for m in self.odometry
                 if m.header.stamp.sec * NS + m.header.stamp.nanosec == stamp_ns]
        return found[0] if found else None


@pytest.fixture
def start_ekf(ros_processes, diagnostics_of):
    """Start an ekf_node with use_sim_time in a namespace of its own; stop its /clock after."""
    started = []

    def start(name, *params):
        ekf = SimTimeEkf(ros_processes, diagnostics_of, name, *params)
        started.append(ekf)
        return ekf
    yield start
    for ekf in started:
        ekf.stop_ticking()
        # /clock is global: the node must not hear the next test's clock.
        for name, child in ekf.processes.started:
            if name == ekf.name and child.poll() is None:
                child.send_signal(signal.SIGINT)
                try:
                    child.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    child.kill()
                    child.wait()


def _at_least(key: str, count: int):
    return lambda values: int(values.get(key, '0') or 0) >= count


def _no_drops(values: dict[str, str]) -> bool:
    return all(v == '0' for k, v in values.items() if k.startswith('dropped_'))


def test_odometry_that_stops_for_10_s_of_clock_and_resumes_costs_nothing(start_ekf):
    ekf = start_ekf('odom_pause')
    start = 1_700_010_000 * NS
    ekf.send_steps(start, 0, 100, imu_ns=start, odom_ns=start, speed=1.0)
    # Odometry stops for 10 s of /clock; the IMU goes on. After STALE_INPUT_S of received
    # stamps (and as long on the steady clock) the odometry no longer holds the IMU back.
    ekf.send_steps(start, 100, 1100, imu_ns=start)
    ekf.wait_for(_at_least('estimates', 1000), 'the IMU samples of the pause processed')
    ekf.send_steps(start, 1100, 1200, imu_ns=start, odom_ns=start, speed=1.0)
    ekf.tick()
    values = ekf.wait_for(_at_least('estimates', 1200), 'every IMU sample processed')
    assert values['resets'] == '0' and 'filter reset' not in ekf.log()
    assert _no_drops(values), values
    assert int(values['estimates']) == 1200
    # Dead reckoning went on at the last speed through the pause: 1 m/s for 11.99 s.
    ekf.probe.spin_until(lambda: ekf.estimate_at(start + 1199 * STEP_NS), 20,
                         'the last estimate')
    assert ekf.estimate_at(start + 1199 * STEP_NS).pose.pose.position.x == pytest.approx(
        11.99)


def test_an_input_stamped_5_s_ahead_of_clock_and_the_others_is_held_not_dropped(start_ekf):
    ekf = start_ekf('odom_ahead')
    start = 1_700_020_000 * NS
    # /clock and the IMU agree; odometry's stamps are 5 s ahead of both.
    ekf.send_steps(start, 0, 800, imu_ns=start, odom_ns=start + 5 * NS, speed=1.0)
    ekf.tick()
    values = ekf.wait_for(_at_least('estimates', 800), 'every IMU sample processed')
    assert values['resets'] == '0' and 'filter reset' not in ekf.log()
    assert _no_drops(values), values
    assert int(values['estimates']) == 800
    # The IMU went through 5 s (500 samples) before the first odometry message's stamp:
    # the filter stood still until then, and moved at 1 m/s from there.
    ekf.probe.spin_until(lambda: ekf.estimate_at(start + 799 * STEP_NS), 20,
                         'the last estimate')
    assert ekf.estimate_at(start + 799 * STEP_NS).pose.pose.position.x == pytest.approx(2.99)


def test_clock_going_back_or_stamps_restarting_reset_with_the_reason_logged(start_ekf):
    ekf = start_ekf('clock_back')
    start = 1_700_030_000 * NS
    ekf.send_steps(start, 0, 100, imu_ns=start, odom_ns=start)
    ekf.tick()
    ekf.wait_for(_at_least('estimates', 100), 'the first samples')
    ekf.stop_ticking()
    assert ekf.values()['resets'] == '0'
    # The node's time before the jump: at least what its diagnostics were stamped with, at
    # most the last /clock sent (it reads /clock best effort, depth 1: it may miss ticks).
    least_before, most_before = ekf.node_clock_ns(), ekf.clock_ns
    # /clock goes back 50 s with the data (a looped bag replayed with --clock): one reset,
    # saying it was ROS time.
    back = start - 50 * NS
    ekf.send_steps(back, 0, 100, imu_ns=back, odom_ns=back)
    ekf.tick()
    values = ekf.wait_for(lambda v: _at_least('resets', 1)(v) and _at_least('estimates', 100)(v)
                          and float(v.get('stamp_s') or 0.0) < 0.0, 'the reset')
    ekf.stop_ticking()
    assert values['resets'] == '1' and _no_drops(values), values
    # The node's time after the jump: the first /clock it read from `back` on, no later
    # than the stamp of the diagnostics that reported the reset. The wait above lasts as
    # long as the machine makes it (the clock ticks on meanwhile), so the jump is bounded
    # by these stamps, not a fixed 51 s; 0.5 ms: the log's 3 decimals.
    jumps = re.findall(r'filter reset: ROS time jumped back (\d+\.\d{3}) s', ekf.log())
    assert len(jumps) == 1, ekf.log()
    least = (least_before - ekf.node_clock_ns()) / NS - 0.0005
    most = (most_before - back) / NS + 0.0005
    assert least <= float(jumps[0]) <= most, (jumps[0], least, most)
    # /clock runs on, but the stamps start over 30 s back (a looped bag without --clock):
    # the messages are dropped as late until every input has gone back RESTART_AFTER_LATE
    # times in a row, then one reset, saying it was the stamps.
    again = back - 30 * NS
    ekf.send_steps(ekf.clock_ns + STEP_NS, 0, 100, imu_ns=again, odom_ns=again)
    ekf.tick()
    values = ekf.wait_for(_at_least('resets', 2), 'the second reset')
    log = ekf.log()
    assert 'filter reset: stamps restarted:' in log and 'went back about 3' in log
    assert log.count('filter reset') == 2
    values = ekf.wait_for(lambda v: int(v['estimates']) + int(v['dropped_late']) >= 100,
                          'the restarted samples processed')
    assert values['resets'] == '2'
    assert int(values['dropped_late']) >= 1  # counted before the restart was certain
