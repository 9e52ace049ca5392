"""QoS profiles of the nodes, chosen on purpose (STYLE.md, "Nodes")."""

from __future__ import annotations

from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Reliable, transient local, depth 1: gyro_bias and landmark_map; late joiners get it."""

OUTPUT = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
"""Reliable, depth 10: estimates and other outputs."""

LOSSLESS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL,
                      reliability=ReliabilityPolicy.RELIABLE)
"""Reliable, keep all: nothing is dropped, a slow reader slows the writer down instead."""


SENSOR_INPUT = QoSProfile(depth=500, history=HistoryPolicy.KEEP_LAST,
                          reliability=qos_profile_sensor_data.reliability,
                          durability=qos_profile_sensor_data.durability)
"""Sensor data QoS (best effort, volatile) with a queue of 500 instead of 5.

Every IMU sample is integrated into the yaw, so a lost one is an error, not just a late
estimate. Depth 5 is 2.5 ms at a 10x replay of a 200 Hz log (2 kHz): one scheduler slice
of a busy machine, or a stall of the replay catching up, overflowed it (2-4 % of the IMU
messages lost, and with them the calibration's first static window). 500 is 0.25 s at
2 kHz and 2.5 s at 200 Hz; best effort still never slows a sensor driver down."""


def sensor_input(lossless: bool) -> QoSProfile:
    """Choose the QoS of a sensor subscription: SENSOR_INPUT (best effort) or LOSSLESS."""
    return LOSSLESS if lossless else SENSOR_INPUT


def stream_output(lossless: bool) -> QoSProfile:
    """Choose the QoS of a per-sample output stream (imu/corrected, landmarks)."""
    return LOSSLESS if lossless else OUTPUT
