"""The rclpy half of `gyro-ekf replay`: publish recorded messages over DDS on their stamps.

A stand-in for `ros2 bag play` where rosbag2 is not installed. Messages are published as
they were recorded (serialized CDR, no decoding) on the topic's relative name, so
`--ros-args -r __ns:=/robot` and remaps work. Timing follows the bag stamps divided by a rate
factor; with `clock` it also publishes `/clock` (rosgraph_msgs/Clock) for `use_sim_time`.
Transient-local topics (the landmark map, the initial pose) are published latched. Reliable
topics use reliable keep-all publishers: a reliable reader gets every message (a slow one
delays the replay rather than losing data), and best-effort readers still match.

Timing jitter (publish time minus the scheduled time) is measured for every message and
reported at the end, in constant memory (a histogram), so `--loop` can run for days.
A stop request (SIGINT/SIGTERM, see cli/signals.py) ends the replay between two messages.

Waiting on reliable readers is bounded by ``ack_timeout_s`` (`gyro-ekf replay
--ack-timeout-s`): a reader that takes no message for that long while the writer's history
is full raises ``AckTimeoutError`` naming the topic, and at the end the topics not
acknowledged in time are listed in the report (``unacknowledged``).
"""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from gyro_ekf import topics
from gyro_ekf.core.stamps import NS_PER_S, seconds_since
from gyro_ekf.errors import GyroEkfError
from gyro_ekf.nodes import qos
from gyro_ekf.nodes.conversions import to_stamp

_STOP_POLL_S = 0.05
"""Longest sleep between two looks at a stop request, s."""
_STOPPED_ACK_S = 2.0
"""After a stop request, wait at most this long for readers to acknowledge, s."""
_JITTER_BINS_PER_DECADE = 200
_JITTER_DECADES = (-6, 3)
"""Jitter histogram: 1 us to 1000 s in bins 1.2 % wide (the p95 is read to that)."""

RawMessage = tuple[str, int, bytes]
"""(topic as recorded, stamp ns since the epoch, serialized CDR)."""
ACK_TIMEOUT_S = 30.0
"""Default longest wait for reliable readers to acknowledge, s (`replay --ack-timeout-s`)."""


class AckTimeoutError(GyroEkfError):
    """A reliable reader acknowledged nothing for ack_timeout_s while the replay waited."""


def message_class(type_name: str) -> Any:
    """Import the rclpy message class of a type name like 'sensor_msgs/msg/Imu'.

    Raises:
        ValueError: a malformed name, or a type whose package is not installed.
    """
    parts = type_name.split('/')
    if len(parts) != 3 or parts[1] != 'msg':
        raise ValueError(f'message type {type_name!r}: expected package/msg/Name')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f'message type {type_name!r} is not installed') from None


@dataclass(frozen=True, slots=True)
class ReplayTopic:
    """A topic to replay.

    Attributes:
        name: topic as recorded ('/imu').
        msgtype: e.g. 'sensor_msgs/msg/Imu'.
        latched: recorded as transient local (published with a latched QoS).
        reliable: recorded as reliable (False = best effort).
    """

    name: str
    msgtype: str
    latched: bool = False
    reliable: bool = True


@dataclass(frozen=True, slots=True)
class ReplayReport:
    """What a replay did.

    Attributes:
        messages: messages published.
        loops: passes over the bag.
        wall_s: wall time from the first to the last publish, s.
        bag_s: bag time covered, s (summed over loops).
        jitter_mean_ms: mean of publish time minus scheduled time, ms.
        jitter_p95_ms: 95th percentile of it, ms.
        jitter_max_ms: largest of it, ms.
        backpressure_waits: retries while a reliable reader was behind (each delays the
            replay by about 2 ms).
        acknowledged: every reliable reader acknowledged every message at the end.
        stopped_by: the signal that stopped the replay early ('SIGINT', 'SIGTERM'), or None.
        unacknowledged: topics whose readers had not acknowledged every message at the end.
    """

    messages: int
    loops: int
    wall_s: float
    bag_s: float
    jitter_mean_ms: float
    jitter_p95_ms: float
    jitter_max_ms: float
    backpressure_waits: int
    acknowledged: bool
    stopped_by: str | None = None
    unacknowledged: tuple[str, ...] = ()

    def summary(self) -> str:
        """One line for humans."""
        speed = self.bag_s / self.wall_s if self.wall_s > 0 else math.inf
        return (f'replayed {self.messages} messages ({self.loops} pass(es), {self.bag_s:.1f} s '
                f'of bag in {self.wall_s:.1f} s, x{speed:.1f}); timing jitter mean '
                f'{self.jitter_mean_ms:.2f} ms, p95 {self.jitter_p95_ms:.2f} ms, max '
                f'{self.jitter_max_ms:.2f} ms; backpressure waits {self.backpressure_waits}; '
                f'all acknowledged: {self.acknowledged}'
                + (f' (stopped by {self.stopped_by})' if self.stopped_by else ''))


class JitterStats:
    """Mean, 95th percentile and maximum of jitter samples in constant memory."""

    def __init__(self) -> None:
        low, high = _JITTER_DECADES
        self._bins = [0] * ((high - low) * _JITTER_BINS_PER_DECADE + 2)
        self.count = 0
        self.total_s = 0.0
        self.max_s = 0.0

    def add(self, value_s: float) -> None:
        """Count one sample, s (negative counts as 0: published on time)."""
        value_s = max(0.0, value_s)
        self.count += 1
        self.total_s += value_s
        self.max_s = max(self.max_s, value_s)
        self._bins[self._bin(value_s)] += 1

    def _bin(self, value_s: float) -> int:
        low, high = _JITTER_DECADES
        if value_s < 10.0 ** low:
            return 0
        index = 1 + int((math.log10(value_s) - low) * _JITTER_BINS_PER_DECADE)
        return min(index, len(self._bins) - 1)

    def quantile(self, share: float) -> float:
        """Return the sample at share of the count (upper edge of its bin, at most the max), s."""
        if not self.count:
            return 0.0
        rank = min(self.count - 1, int(share * self.count))
        seen = 0
        for index, n in enumerate(self._bins):
            seen += n
            if seen > rank:
                low = _JITTER_DECADES[0]
                edge = 10.0 ** (low + index / _JITTER_BINS_PER_DECADE) if index else 0.0
                return min(edge, self.max_s)
        return self.max_s


class Replayer(Node):
    """Publishes raw recorded messages on their relative topic names."""

    def __init__(self, replay_topics: Iterable[ReplayTopic], clock: bool,
                 node_name: str = 'gyro_ekf_replay', **kwargs) -> None:
        """Create one publisher per topic (and /clock when clock is true).

        Raises:
            ValueError: a message type that is not installed.
        """
        super().__init__(node_name, **kwargs)
        self.topics = {t.name: t for t in replay_topics}
        self.publishers_by_topic = {}
        for topic in self.topics.values():
            if topic.latched:
                profile = qos.LATCHED
            elif topic.reliable:
                profile = qos.LOSSLESS
            else:
                profile = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.publishers_by_topic[topic.name] = self.create_publisher(
                message_class(topic.msgtype), topic.name.lstrip('/'), profile)
        self._clock_pub = self.create_publisher(Clock, topics.CLOCK, 10) if clock else None
        self.backpressure_timeout_s = ACK_TIMEOUT_S
        self.backpressure_waits = 0
        self.stop: Callable[[], bool] = lambda: False

    def _running(self) -> bool:
        return rclpy.ok() and not self.stop()

    def _publish(self, publisher: Any, data: bytes, topic: str) -> None:
        """Publish, waiting while a reliable keep-all reader is behind (backpressure).

        Fast DDS refuses a write when the writer's history is full of samples a reliable
        reader has not acknowledged yet; waiting and retrying slows the replay down to that
        reader instead of losing the message.

        Raises:
            AckTimeoutError: the write was refused for backpressure_timeout_s.
        """
        deadline = time.monotonic() + self.backpressure_timeout_s
        while True:
            try:
                publisher.publish(data)
                return
            except Exception as err:  # rclpy's RCLError: 'cannot publish data' (history full)
                if not self._running():
                    raise
                if time.monotonic() > deadline:
                    raise AckTimeoutError(
                        f'{topic}: a reliable reader acknowledged nothing for '
                        f'{self.backpressure_timeout_s:g} s while the writer\'s history was '
                        f'full ({err}); is a subscriber stuck? Raise --ack-timeout-s for a '
                        'slow one') from None
                self.backpressure_waits += 1
                time.sleep(0.002)

    def wait_for_subscribers(self, needs: dict[str, int], timeout_s: float,
                             progress: Callable[[str, int, int], None] | None = None
                             ) -> dict[str, int]:
        """Wait until each topic has at least the given number of matched subscriptions.

        Args:
            needs: topic as recorded -> subscriptions needed.
            timeout_s: give up after this long, s.
            progress: called with (topic, matched, needed) for each topic short at the
                start, and again whenever a topic's count of matched subscriptions
                changes, so a user waiting on a replay sees who has come and who is
                missing.

        Returns:
            The topics still short of subscribers -> their current count (empty on success).
        """
        deadline = time.monotonic() + timeout_s
        seen: dict[str, int] = {}
        while True:
            counts = {name: self.publishers_by_topic[name].get_subscription_count()
                      for name in needs}
            short = {name: count for name, count in counts.items() if count < needs[name]}
            if progress is not None:
                for name, count in counts.items():
                    if seen.get(name) != count and (name in short or name in seen):
                        progress(name, count, needs[name])
                    seen[name] = count
            if not short or time.monotonic() > deadline or not self._running():
                return short
            time.sleep(0.01)

    def _sleep_until(self, target: float) -> None:
        """Sleep until perf_counter() reaches target, in slices so a stop request is seen."""
        while self._running():
            delay = target - time.perf_counter()
            if delay <= 0:
                return
            time.sleep(min(delay, _STOP_POLL_S))

    def play(self, messages: Callable[[], Iterator[RawMessage]], rate: float, loop: bool,
             clock_hz: float = 100.0, ack_timeout_s: float = ACK_TIMEOUT_S,
             latch_ack_timeout_s: float = 2.0, max_loops: int | None = None) -> ReplayReport:
        """Publish every message at its stamp / rate (rate 0 = as fast as possible).

        Args:
            messages: returns a fresh iterator over the bag's messages in stamp order.
            rate: speed-up factor (2 = twice as fast as recorded); 0 = no waiting.
            loop: start over at the end until interrupted.
            clock_hz: /clock messages per second of bag time (when clock is on).
            ack_timeout_s: at the end, wait this long for reliable readers to acknowledge
                (at most _STOPPED_ACK_S after a stop request).
            latch_ack_timeout_s: after the first latched message, wait this long for its
                acknowledgement so readers have it before the sensor stream starts.
            max_loops: with loop, stop after this many passes (None = until stopped).

        Raises:
            GyroEkfError: the source broke off (a bag damaged mid-pass), raised after the
                end's wait for acknowledgements, saying whether every reader has what was
                published; AckTimeoutError: a reliable reader stuck (see _publish).
        """
        jitter = JitterStats()
        published = 0
        loops = 0
        bag_s = 0.0
        clock_period_ns = int(NS_PER_S / clock_hz) if clock_hz > 0 else 0
        first_publish = last_publish = None
        clock_message = Clock()
        broken: list[GyroEkfError] = []

        def until_broken() -> Iterator[RawMessage]:
            # The source breaking off (a bag damaged mid-pass) ends the replay as its end
            # would: what went out before is acknowledged first, then the error is raised.
            try:
                yield from messages()
            except GyroEkfError as err:
                broken.append(err)

        while self._running():
            loops += 1
            if loop:
                self.get_logger().info(f'pass {loops}'
                                       + (f' of {max_loops}' if max_loops else ''))
            start_ns = None
            last_clock_ns = None
            wall_start = time.perf_counter()
            stamp = None
            source = until_broken()
            try:
                for name, stamp, data in source:
                    if not self._running():
                        break
                    if start_ns is None:
                        start_ns = stamp
                    if rate > 0:
                        target = wall_start + seconds_since(stamp, start_ns) / rate
                        self._sleep_until(target)
                    if self._clock_pub is not None and (
                            last_clock_ns is None or stamp - last_clock_ns >= clock_period_ns):
                        clock_message.clock = to_stamp(stamp)
                        self._clock_pub.publish(clock_message)
                        last_clock_ns = stamp
                    publisher = self.publishers_by_topic.get(name)
                    if publisher is None:
                        continue
                    self._publish(publisher, data, name)
                    published += 1
                    now = time.perf_counter()
                    if rate > 0:
                        jitter.add(now - target)
                    first_publish = first_publish or now
                    last_publish = now
                    if self.topics[name].latched and publisher.get_subscription_count():
                        publisher.wait_for_all_acked(Duration(seconds=latch_ack_timeout_s))
            finally:
                close = getattr(source, 'close', None)
                if close is not None:
                    close()  # a generator's reader is closed now, not at garbage collection
            if start_ns is not None and stamp is not None:
                bag_s += seconds_since(stamp, start_ns)
            if (broken or not loop or start_ns is None
                    or (max_loops is not None and loops >= max_loops)):
                break
        stopped = self.stop()
        timeout = min(ack_timeout_s, _STOPPED_ACK_S) if stopped else ack_timeout_s
        # One deadline for all: each topic waits for what is left of it.
        deadline = time.monotonic() + timeout
        unacknowledged = tuple(
            name for name, p in self.publishers_by_topic.items()
            if not rclpy.ok() or not p.wait_for_all_acked(
                Duration(seconds=max(0.0, deadline - time.monotonic()))))
        if broken:
            acknowledged = (f'reliable readers of {", ".join(unacknowledged)} had not '
                            f'acknowledged every message within {timeout:g} s'
                            if unacknowledged else 'every reliable reader acknowledged the '
                            f'{published} messages published before it')
            raise type(broken[0])(f'{broken[0]}; {acknowledged}') from None
        return ReplayReport(
            messages=published,
            loops=loops,
            wall_s=(last_publish - first_publish) if first_publish else 0.0,
            bag_s=bag_s,
            jitter_mean_ms=1e3 * jitter.total_s / jitter.count if jitter.count else 0.0,
            jitter_p95_ms=1e3 * jitter.quantile(0.95),
            jitter_max_ms=1e3 * jitter.max_s,
            backpressure_waits=self.backpressure_waits,
            acknowledged=not unacknowledged,
            stopped_by=getattr(self.stop, 'requested', None) if stopped else None,
            unacknowledged=unacknowledged)
