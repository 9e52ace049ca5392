"""The rclpy half of `gyro-ekf record`: subscribe to topics and hand raw messages to a sink.

Types come from the command line (TOPIC:TYPE) or from the graph. A topic is subscribed once
a publisher for it appears, and the subscription QoS adapts to the publishers, as rosbag2
does: transient local when any publisher is (so a latched message published before the
match is still recorded), reliable unless a publisher is best effort. Messages stay
serialized.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from gyro_ekf.nodes.replayer import message_class

Sink = Callable[[str, str, int, bytes, bool], None]
"""sink(topic, msgtype, receive stamp ns, CDR bytes, latched)."""


@dataclass(slots=True)
class RecordedTopic:
    """A topic being recorded.

    Attributes:
        name: fully qualified topic name.
        msgtype: e.g. 'geometry_msgs/msg/Vector3Stamped', or '' until discovered.
        latched: subscribed transient local.
        count: messages received.
    """

    name: str
    msgtype: str = ''
    latched: bool = False
    count: int = 0


class Recorder(Node):
    """Records topics into a sink (see the module docstring).

    Attributes:
        recorded: topic name -> RecordedTopic.
        last_message: monotonic time of the last message received, or None; under
            use_sim_time, of the last one received once /clock runs (a node's report at
            its start, before a replay's /clock, does not count as recorded data).
    """

    def __init__(self, specs: list[str], sink: Sink, node_name: str = 'gyro_ekf_record',
                 **kwargs) -> None:
        """Subscribe to every TOPIC[:TYPE] spec (types not given are discovered).

        Raises:
            ValueError: a given message type that is not installed.
        """
        super().__init__(node_name, **kwargs)
        self._sink = sink
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        self.recorded: dict[str, RecordedTopic] = {}
        self.last_message: float | None = None
        self._by_topic = {}
        for spec in specs:
            name, _, msgtype = spec.partition(':')
            if msgtype:
                message_class(msgtype)
            full = self.resolve_topic_name(name)
            self.recorded[full] = RecordedTopic(full, msgtype)
        self._discover()
        if self.pending:
            # Wall-clock timer: with use_sim_time no /clock may arrive before the topics do.
            self._timer = self.create_timer(0.05, self._discover,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))

    @property
    def pending(self) -> list[str]:
        """Topics not subscribed yet (no publisher seen)."""
        return [name for name in self.recorded if name not in self._by_topic]

    @property
    def total(self) -> int:
        """Messages recorded on all topics."""
        return sum(topic.count for topic in self.recorded.values())

    def _discover(self) -> None:
        for name in self.pending:
            topic = self.recorded[name]
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            if not topic.msgtype:
                topic.msgtype = infos[0].topic_type
            latched = any(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for i in infos)
            best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
                              for i in infos)
            profile = QoSProfile(
                history=HistoryPolicy.KEEP_ALL, depth=1,
                reliability=(ReliabilityPolicy.BEST_EFFORT if best_effort
                             else ReliabilityPolicy.RELIABLE),
                durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                            else DurabilityPolicy.VOLATILE))
            topic.latched = latched
            self._by_topic[name] = self.create_subscription(
                message_class(topic.msgtype), name,
                lambda data, t=topic: self._on_message(t, data), profile, raw=True)
            self.get_logger().info(f'recording {name} ({topic.msgtype})')
        if not self.pending and getattr(self, '_timer', None) is not None:
            self._timer.cancel()

    def _on_message(self, topic: RecordedTopic, data: bytes) -> None:
        topic.count += 1
        stamp_ns = self.get_clock().now().nanoseconds
        # ROS time is 0 before /clock under use_sim_time: such a message starts no idle wait.
        if stamp_ns > 0 or not self._sim_time:
            self.last_message = time.monotonic()
        self._sink(topic.name, topic.msgtype, stamp_ns, data, topic.latched)
