"""ROS parameters declared from the core config dataclasses, and node-level parameters.

`core/config.py` is the single source of every tunable: each dataclass field carries its
default, unit, description and bounds. `declare_config` turns the fields into
`declare_parameter` calls with a ParameterDescriptor (description with the unit, a
FloatingPointRange or IntegerRange, read-only because the nodes build their core objects
from them once) and builds the config back from the values the node received
(`--params-file`, `-p name:=value` or the defaults).

The bag sidecar (`gyro_ekf.io.sidecar`) is a params file too: `declare_sidecar` declares
its entries (initial pose, LiDAR mounts per scan topic, stated noise, time zero, what
`convert --skip-bad` dropped from the log) so a node started with `--params-file
BAG.params.yaml` gets them with no hand-typed flags.

A parameter a node does not declare would be ignored by rclpy without a word;
`report_ignored` warns once for each former or misspelt parameter the node is given.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from gyro_ekf.core.config import config_fields, ConfigT, make_config
from gyro_ekf.core.config import STATED_NOISE_FIELDS as NOISE_FIELDS
from gyro_ekf.core.time_offset import MAX_TIME_OFFSET_S
from gyro_ekf.core.types import FloatArray, LidarMount, NoiseFigures
from gyro_ekf.core.validation import InputReport, MAX_RANGE_OFFSET_M, MAX_YAW_SIGMA_RAD
from gyro_ekf.io.params_file import is_gyro_ekf_parameter
from gyro_ekf.io.sidecar import CONVERTED_KEYS, CONVERTED_PARAMETER, converted_report


def _range(low: float | None, high: float | None, integer: bool) -> dict[str, Any]:
    if low is None and high is None:
        return {}
    if integer:
        return {'integer_range': [IntegerRange(
            from_value=int(low if low is not None else -2 ** 62),
            to_value=int(high if high is not None else 2 ** 62), step=0)]}
    return {'floating_point_range': [FloatingPointRange(
        from_value=float(low if low is not None else -math.inf),
        to_value=float(high if high is not None else math.inf), step=0.0)]}


def declare(node: Node, name: str, default: Any, description: str, unit: str = '',
            low: float | None = None, high: float | None = None,
            read_only: bool = True) -> Any:
    """Declare one parameter with a descriptor and return its value.

    Float parameters accept integer values too (`-p window_length_s:=5`): they are declared
    with dynamic typing, and the caller converts; ranges are checked by rclpy for doubles
    and by the caller (``make_config``) for everything.

    Args:
        node: the node.
        name: parameter name (dots for nesting).
        default: default value; its type is the parameter's type. Parameter.Type.STRING_ARRAY
            or INTEGER_ARRAY declares a list that defaults to empty (ROS cannot infer the
            type of []).
        description: what it does (shown by `ros2 param describe`).
        unit: unit appended to the description, if any.
        low: smallest allowed value, or None.
        high: largest allowed value, or None.
        read_only: refuse changes after start (the node reads it once).

    Returns:
        The value the node received.
    """
    is_float = isinstance(default, float)
    text = f'{description} [{unit}]' if unit else description
    descriptor = ParameterDescriptor(
        description=text, read_only=read_only, dynamic_typing=is_float,
        **_range(low, high, isinstance(default, int) and not isinstance(default, bool)))
    value = node.declare_parameter(name, default, descriptor).value
    if default is Parameter.Type.STRING_ARRAY or default is Parameter.Type.INTEGER_ARRAY:
        return list(value or [])
    if is_float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    return value


def declare_config(node: Node, config_type: type[ConfigT], prefix: str = '',
                   names: Iterable[str] | None = None) -> ConfigT:
    """Declare one parameter per field of a core config dataclass and build the config.

    Args:
        node: the node.
        config_type: EkfConfig, CalibrationConfig, DetectorConfig, InputLimits or
            RunOptions.
        prefix: prepended to every field name (e.g. 'limits.').
        names: the fields to declare (those the node uses); None: all. The others keep
            their defaults.

    Returns:
        The config built from the received values.

    Raises:
        CoreError: a value of the wrong type or out of bounds (named in the message).
    """
    wanted = None if names is None else set(names)
    values = {}
    for spec in config_fields(config_type):
        if wanted is not None and spec.name not in wanted:
            continue
        meta = spec.metadata
        values[spec.name] = declare(
            node, prefix + spec.name, spec.default, meta['description'], meta['unit'],
            meta['min'], meta['max'], read_only=True)
    return make_config(config_type, values, source=f'node {node.get_fully_qualified_name()}')


def report_ignored(node: Node, removed: Mapping[str, str]) -> list[str]:
    """Warn once for each former or misspelt parameter the node was given; return them.

    rclpy drops a parameter nobody declares without a word, so a user who still sets one
    (an old params file, a script) would never learn that it does nothing now, nor one who
    wrote ``gyro_noize_rad_s`` that the gyro noise stayed at its default. A name one or two
    letters off a declared one, or a declared one behind a prefix (``ekf.gyro_noise_rad_s``),
    is taken as misspelt; a name no gyro_ekf node declares (``io.params_file``'s list, held
    to the nodes by a test) is warned of too. Another pipeline node's names are left alone
    (a ``/**`` section is meant for every node, each declaring only its own).

    Args:
        node: the node, after all its declarations.
        removed: former parameter name -> what became of it (shown in the warning).

    Returns:
        The former parameters given, in the order of ``removed``, then the others warned
        of.
    """
    # rclpy keeps the -p and --params-file values for this node here and has no public
    # getter for them (undeclared ones never become parameters).
    overrides = node._parameter_overrides
    given = [name for name in removed if name in overrides]
    for name in given:
        node.get_logger().warn(f'parameter {name!r} was removed after gyro_ekf 0.1.0 '
                               f'({removed[name]}); ignored')
    declared = sorted(node._parameters)
    for name in overrides:
        if name in node._parameters or name in removed:
            continue
        group, _, short = name.rpartition('.')
        topic = group.removeprefix('lidar.')
        if topic != group and 'lidar.topics' in node._parameters:
            topics = list(node.get_parameter('lidar.topics').value or [])
            if topic not in topics:
                # Not a misspelt lidar.<listed topic>.*: a LiDAR left out of the list.
                node.get_logger().warn(f'parameter {name!r}: {topic!r} is not one of '
                                       f'lidar.topics {topics}; ignored')
                given.append(name)
                continue
        if group and short in node._parameters:
            # `ekf.gyro_noise_rad_s`, or `gyro_noise_rad_s` nested under `ekf:` in a file.
            close = [short]
        else:
            close = difflib.get_close_matches(name, declared, n=1, cutoff=0.85)
        if close:
            node.get_logger().warn(f'parameter {name!r} is not a parameter of this node '
                                   f'(did you mean {close[0]!r}?); ignored')
            given.append(name)
        elif not is_gyro_ekf_parameter(name):
            # Not another pipeline node's either (a /** section serves them all).
            node.get_logger().warn(f'parameter {name!r} is not a parameter of any gyro_ekf '
                                   'node; ignored')
            given.append(name)
    return given


@dataclass(frozen=True, slots=True)
class SidecarParams:
    """The bag sidecar entries a node received (see gyro_ekf.io.sidecar).

    Attributes:
        time_zero_ns: `trip.log_time_zero_ns`, ns since the epoch; 0 when not given.
        initial_pose: shape (3,): x m, y m, yaw rad in `map`.
        lidars: scan topic -> (frame_id, mount).
        time_offsets: scan topic -> how late its scans are stamped against the gyro's, s
            (`lidar.<topic>.time_offset_s`, 0 unless given).
        range_offsets: scan topic -> how much its ranges read long, m
            (`lidar.<topic>.range_offset_m`, 0 unless given).
        upside_down: scan topics of LiDARs mounted upside down
            (`lidar.<topic>.upside_down`).
        yaw_sigmas: scan topic -> how well its mount's yaw is known, rad
            (`lidar.<topic>.yaw_sigma_rad`, 0 unless given).
        noise: stated noise figures (None = not stated).
        converted: what `gyro-ekf convert --skip-bad` dropped from the log the bag was
            written from (`trip.dropped_when_converted`: source, samples_dropped per stream,
            dropped per field and reason, ...), or None when nothing was recorded.
    """

    time_zero_ns: int
    initial_pose: FloatArray
    lidars: dict[str, tuple[str, LidarMount]] = field(default_factory=dict)
    noise: NoiseFigures = field(default_factory=NoiseFigures)
    converted: InputReport | None = None
    time_offsets: dict[str, float] = field(default_factory=dict)
    range_offsets: dict[str, float] = field(default_factory=dict)
    upside_down: frozenset[str] = frozenset()
    yaw_sigmas: dict[str, float] = field(default_factory=dict)

    def topic_for_frame(self, frame_id: str) -> str | None:
        """Scan topic of the LiDAR whose frame is frame_id, or None when no LiDAR has it."""
        return next((topic for topic, (frame, _) in self.lidars.items() if frame == frame_id),
                    None)

    def upside_down_for_frame(self, frame_id: str) -> bool:
        """Whether the LiDAR whose frame is frame_id is mounted upside down."""
        return self.topic_for_frame(frame_id) in self.upside_down

    def time_offset_for_frame(self, frame_id: str) -> float:
        """How late the scans of the LiDAR whose frame is frame_id are stamped, s (0: none)."""
        return self.time_offsets.get(self.topic_for_frame(frame_id), 0.0)

    def range_offset_for_frame(self, frame_id: str) -> float:
        """How much the LiDAR whose frame is frame_id reads long, m (0: none)."""
        return self.range_offsets.get(self.topic_for_frame(frame_id), 0.0)

    def mount_for_frame(self, frame_id: str) -> LidarMount | None:
        """Mount of the LiDAR whose frame is frame_id, or None when no LiDAR has it."""
        for frame, mount in self.lidars.values():
            if frame == frame_id:
                return mount
        return None


def declare_sidecar(node: Node, lidars: bool = True, noise: bool = True,
                    pose: bool = True) -> SidecarParams:
    """Declare the sidecar's parameters (all optional) and return their values.

    Args:
        node: the node.
        lidars: declare `lidar.topics` and
            `lidar.<topic>.{frame_id,x_m,y_m,yaw_rad,time_offset_s,range_offset_m,
            upside_down,yaw_sigma_rad}`.
        noise: declare `noise.{gyro_rad_s,speed_m_s,range_m,bearing_rad}` (0 = not stated)
            and `noise.landmark_m` (negative = not stated: 0 states an exact map).
        pose: declare `initial_pose.{x_m,y_m,yaw_rad}`.

    `trip.dropped_when_converted.*` (what `convert --skip-bad` dropped from the log) is
    always declared.

    Raises:
        BagError: a `trip.dropped_when_converted` record given in part or damaged (the
            sidecar's own check, naming the node and the parameter).
    """
    zero_ns = declare(node, 'trip.log_time_zero_ns', 0,
                      'Stamp of the log\'s time zero; stamps are converted to seconds since '
                      'it. 0 = since the first message received', 'ns since the epoch', 0, None)
    initial = [0.0, 0.0, 0.0]
    if pose:
        initial = [
            declare(node, 'initial_pose.x_m', 0.0, 'Initial x in the map frame', 'm'),
            declare(node, 'initial_pose.y_m', 0.0, 'Initial y in the map frame', 'm'),
            declare(node, 'initial_pose.yaw_rad', 0.0, 'Initial yaw in the map frame', 'rad',
                    -2.0 * math.pi, 2.0 * math.pi)]
    mounts: dict[str, tuple[str, LidarMount]] = {}
    offsets: dict[str, float] = {}
    ranges: dict[str, float] = {}
    yaw_sigmas: dict[str, float] = {}
    flipped: set[str] = set()
    if lidars:
        names = declare(node, 'lidar.topics', Parameter.Type.STRING_ARRAY,
                        'Scan topics of the LiDARs; each has lidar.<topic>.frame_id, its '
                        'mount lidar.<topic>.{x_m,y_m,yaw_rad} in base_link, how late its '
                        'scans are stamped, lidar.<topic>.time_offset_s, how long its '
                        'ranges read, lidar.<topic>.range_offset_m, whether it is mounted '
                        'upside down, lidar.<topic>.upside_down, and how well its yaw is '
                        'known, lidar.<topic>.yaw_sigma_rad')
        for topic in names:
            frame = declare(node, f'lidar.{topic}.frame_id', topic,
                            f'frame_id of the scans on {topic!r} (and of their landmarks)')
            mounts[topic] = (frame, LidarMount(
                declare(node, f'lidar.{topic}.x_m', 0.0, f'Forward offset of {topic!r}', 'm'),
                declare(node, f'lidar.{topic}.y_m', 0.0, f'Leftward offset of {topic!r}', 'm'),
                declare(node, f'lidar.{topic}.yaw_rad', 0.0, f'Yaw of {topic!r}', 'rad',
                        -2.0 * math.pi, 2.0 * math.pi)))
            offsets[topic] = float(declare(
                node, f'lidar.{topic}.time_offset_s', 0.0,
                f'How late the scans of {topic!r} are stamped against the gyro\'s (each '
                'scan is taken at its stamp less this; a run\'s verdict measures it)', 's',
                -MAX_TIME_OFFSET_S, MAX_TIME_OFFSET_S))
            ranges[topic] = float(declare(
                node, f'lidar.{topic}.range_offset_m', 0.0,
                f'How much the ranges of {topic!r} read long (its poles are moved this much '
                'toward it; a run\'s verdict measures it against the map)', 'm',
                -MAX_RANGE_OFFSET_M, MAX_RANGE_OFFSET_M))
            if declare(node, f'lidar.{topic}.upside_down', False,
                       f'{topic!r} is mounted upside down (half a turn about its x axis: its '
                       'poles are mirrored into an upright LiDAR\'s frame; the verdict says '
                       'when it turns the other way from the gyro)'):
                flipped.add(topic)
            yaw_sigmas[topic] = float(declare(
                node, f'lidar.{topic}.yaw_sigma_rad', 0.0,
                f'How well the yaw of {topic!r} is known (1 sigma; 0 = exact, as stated). '
                'While it defines the body frame (the first LiDAR) the reported heading '
                'is widened by it; calibrate-mounts writes it for a yaw it fitted against '
                'the odometry', 'rad', 0.0, MAX_YAW_SIGMA_RAD))
    figures = NoiseFigures()
    if noise:
        stated = {}
        for key, target in NOISE_FIELDS.items():
            if key == 'landmark_m':
                # A map can be exact, so "not stated" is a negative value here.
                value = declare(node, f'noise.{key}', -1.0,
                                f'Map figure the bag states; replaces {target} when '
                                'use_stated_noise is true. Negative = not stated, '
                                '0 = an exact map')
                stated[key] = value if value >= 0.0 else None
                continue
            value = declare(node, f'noise.{key}', 0.0,
                            f'Noise figure the bag states; replaces {target} when '
                            'use_stated_noise is true. 0 = not stated', '', 0.0, None)
            stated[key] = value if value > 0.0 else None
        figures = NoiseFigures(**stated)
    return SidecarParams(int(zero_ns), np.array(initial, dtype=np.float64), mounts, figures,
                         _declare_converted(node), offsets, ranges, frozenset(flipped),
                         yaw_sigmas)


CONVERTED_DESCRIPTIONS = {
    'source': 'the log it read (file names); empty = no record',
    'streams': 'the streams it dropped samples of (imu, speed, lidar.<topic>, ...)',
    'samples': 'samples dropped, per stream of streams',
    'time_breaks': 'times the stream\'s time went back, per stream of streams',
    'fields': 'the field of each count (with reasons, counts, first_indexes)',
    'reasons': 'the reason of each count',
    'counts': 'samples dropped, per field and reason',
    'first_indexes': 'the first index dropped, per field and reason, in the log\'s series',
}
"""What each entry of `trip.dropped_when_converted` says (written by `convert --skip-bad`)."""


def _declare_converted(node: Node) -> InputReport | None:
    """Declare `trip.dropped_when_converted.*`; return the record given, or None."""
    record = {}
    for key, kind in CONVERTED_KEYS:
        description = ('What gyro-ekf convert --skip-bad dropped from the bag\'s log (the '
                       f'verdict counts it): {CONVERTED_DESCRIPTIONS[key]}')
        if key == 'source':
            value = declare(node, f'{CONVERTED_PARAMETER}.{key}', '', description)
        else:
            value = declare(node, f'{CONVERTED_PARAMETER}.{key}',
                            Parameter.Type.STRING_ARRAY if kind is str
                            else Parameter.Type.INTEGER_ARRAY, description)
        if value:  # an entry not given is left out: the check names it as missing
            record[key] = value
    if not record:
        return None
    return converted_report(record, f'node {node.get_fully_qualified_name()}')
