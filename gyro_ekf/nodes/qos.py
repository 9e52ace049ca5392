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


def sensor_input(lossless: bool) -> QoSProfile:
    """Choose the QoS of a sensor subscription: sensor data (best effort, depth 5) or LOSSLESS."""
    return LOSSLESS if lossless else qos_profile_sensor_data


def stream_output(lossless: bool) -> QoSProfile:
    """Choose the QoS of a per-sample output stream (imu/corrected, landmarks)."""
    return LOSSLESS if lossless else OUTPUT
