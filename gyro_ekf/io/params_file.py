"""Read a ROS 2 params YAML (`--params-file`) into the core config dataclasses.

The file has the layout `ros2 run ... --ros-args --params-file` takes::

    /**:                       # every node
      ros__parameters:
        gyro_noise_rad_s: 0.02
    landmark_detector_node:    # one node (a namespace may precede it: /robot/...)
      ros__parameters:
        max_width_m: 0.2

Sections of the pipeline's nodes (`/**`, `ekf_node`, `calibration_node`,
`landmark_detector_node`) are read; sections of other nodes are skipped. Inside a read
section, a name that is a field of EkfConfig, CalibrationConfig or DetectorConfig sets that
field, and a name that is a field of RunOptions (`use_stated_noise`, `use_calibration`,
...) sets that option: bare, as the nodes declare them (`detector: {max_width_m: 0.2}`
nests to `detector.max_width_m`, which no node declares, so it is warned of and ignored, as
the nodes ignore it). The nodes' own live-side names (frames, topics, QoS, periods:
`NODE_ONLY_PARAMETERS`) are skipped quietly; a name no gyro_ekf node declares is warned
of, so a parameter that does nothing is never taken in silence. A value set in a node
section overrides the same value under `/**`. Values are checked by
`core.config.make_config` (a switch takes true or false only), and every error names the
file and parameter. Defaults are the dataclasses' own, as for the nodes.

LiDAR mounts are read in the EKF node's (and the bag sidecar's) layout, `lidar.topics` and
`lidar.<topic>.{frame_id, x_m, y_m, yaw_rad}` (x, y and yaw required, frame_id optional);
`gyro-ekf calibrate-mounts` writes them. `lidar.<topic>.time_offset_s` (optional, and
alone without the mount too) says how late that LiDAR's scans are stamped against the
gyro's, as a run's verdict measures it (core/time_offset.py), and
`lidar.<topic>.range_offset_m` (optional too) how much its ranges read long, as a run's
verdict measures it against the map (its poles are moved that much toward it), and
`lidar.<topic>.upside_down` (true or false) a LiDAR mounted upside down (half a turn about
its x axis: its poles are mirrored into an upright one's frame), and
`lidar.<topic>.yaw_sigma_rad` (optional) how well its yaw is known (calibrate-mounts writes
it for a first LiDAR's yaw it fitted against the odometry; the LiDAR that defines the body
frame widens the reported heading by it); the EKF node declares all four.
`with_lidar_mounts` puts them on a trip's scans, overriding the mounts the bag states for
those topics, taking each scan at its stamp less the offset and giving each its range
offset, whether it is upside down and its yaw's sigma.

The map file is read as the EKF node declares it, `landmarks_file` (a path from the working
folder): `with_landmarks_file` gives a trip that map instead of the bag's (`gyro-ekf run`
writes `landmarks_seen.yaml` when a pole stands elsewhere than the map has it).

The start pose is read as the EKF node declares it, `initial_pose.{x_m, y_m, yaw_rad}` (all
three, in `map`). `with_initial_pose` starts a trip there unless the bag holds an
`/initialpose` message: the node, given the same file, starts there too, and a replay of the
bag then sets its pose from that message, so `run` keeps the message's pose and says so.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import difflib
import fnmatch
import logging
import math
from pathlib import Path
import re
from typing import Any

import numpy as np
import yaml

from gyro_ekf.errors import one_line
from gyro_ekf.io.errors import ParamsFileError
from gyro_ekf.core.config import (CalibrationConfig, DetectorConfig, EkfConfig, InputLimits,
                                  make_config, RunOptions)
from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.stamps import NS_PER_S, ns_at, seconds_since
from gyro_ekf.core.types import LidarMount, Trip
from gyro_ekf.core.validation import (initial_pose_problem, mount_problem,
                                      range_offset_problem, time_offset_problem,
                                      yaw_sigma_problem)

log = logging.getLogger(__name__)

PIPELINE_NODES = ('ekf_node', 'calibration_node', 'landmark_detector_node')
"""Node names whose sections configure the filter."""

_CONFIG_TYPES: dict[str, type] = {
    'ekf': EkfConfig, 'calibration': CalibrationConfig, 'detector': DetectorConfig}
_FIELD_OWNER = {f.name: group for group, kind in _CONFIG_TYPES.items()
                for f in dataclasses.fields(kind)}
_OPTIONS = frozenset(f.name for f in dataclasses.fields(RunOptions))
_LIMITS = frozenset(f.name for f in dataclasses.fields(InputLimits))
_GROUP_NODE = {'ekf': 'ekf_node', 'calibration': 'calibration_node',
               'detector': 'landmark_detector_node'}
"""The node that declares each config group's fields (RunOptions: the EKF node)."""

NODE_LIMITS = {
    'ekf_node': ('max_yaw_rate_rad_s', 'max_speed_m_s', 'max_stamp_jump_s', 'max_coordinate_m',
                 'max_mount_offset_m', 'max_angle_rad', 'quaternion_norm_tolerance'),
    'calibration_node': ('max_yaw_rate_rad_s', 'max_speed_m_s', 'max_stamp_jump_s'),
}
"""The InputLimits fields each node checks (declares as limits.*); `run` checks them all."""

_KNOWN = sorted(set(_FIELD_OWNER) | _OPTIONS | {f'limits.{name}' for name in _LIMITS}
                | {'path_length'})
"""Every name `run` reads (besides lidar.*, initial_pose.* and landmarks_file): a name in a
pipeline section close to one of them is a typo."""

NODE_ONLY_PARAMETERS: dict[str, tuple[str, ...]] = {
    'ekf_node': ('base_frame', 'diagnostics_period_s', 'landmark_topics',
                 'late_observation_history_s', 'map_frame', 'max_association_gap_s',
                 'odom_frame', 'publish_every_n', 'publish_tf', 'reliable_inputs'),
    'calibration_node': ('diagnostics_period_s', 'event_batch_s', 'landmark_topics',
                         'reliable_inputs', 'use_odom'),
    'landmark_detector_node': ('diagnostics_period_s', 'reliable_inputs'),
}
"""What each pipeline node declares that `run` has no use for: the live side (frames, topics,
QoS, periods, when to publish). Kept here, without ROS, so that `run` can tell a node's name
from one no node has; test_launch_and_params starts each node and checks this list against
what it declares."""

ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')
"""What rclpy declares on every node."""

SIDECAR_PREFIXES = ('noise.', 'trip.', 'true_gyro_bias_rad_s')
"""A bag sidecar's own entries (io/sidecar.py; its start pose and LiDARs are parameters too):
`run` takes them from the bag's own sidecar."""


def is_gyro_ekf_parameter(name: str) -> bool:
    """Whether a pipeline node declares `name` or `run` reads it (a /** section serves all).

    Besides the lists above: the LiDARs' `lidar.topics` and `lidar.<topic>.*`, the start
    pose and the map file. A name that passes is not checked further here: `run` and each
    node judge their own.
    """
    if name in _KNOWN or name in ROS_PARAMETERS or name.startswith(SIDECAR_PREFIXES):
        return True
    if name.startswith(('lidar.', 'initial_pose.')) or name == 'landmarks_file':
        return True
    return any(name in names for names in NODE_ONLY_PARAMETERS.values())


class _RosLoader(yaml.SafeLoader):
    """YAML as ROS 2 reads a params file: `1e-3` and `1.0e3` are numbers.

    PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent, so it read
    `gyro_noise_rad_s: 1e-3` as text and `run` refused it while the nodes took 0.001.
    """


_RosLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$'),
    list('-+0123456789.'))


@dataclass(frozen=True, slots=True)
class PipelineParams:
    """Configuration read from a params file.

    Attributes:
        ekf: EKF noise model and association.
        calibration: static-window calibration.
        detector: pole detection.
        explicit: names of the fields the file set, per group ('ekf', 'calibration',
            'detector', 'options').
        options: the run options (defaults where the file sets none).
        lidars: scan topic (no slash) -> (frame_id or None, mount) the file sets.
        lidar_time_offsets: scan topic -> how late its scans are stamped, s (the file's
            `lidar.<topic>.time_offset_s`).
        lidar_range_offsets: scan topic -> how much its ranges read long, m (the file's
            `lidar.<topic>.range_offset_m`).
        lidars_upside_down: scan topics of LiDARs mounted upside down (the file's
            `lidar.<topic>.upside_down: true`).
        lidar_yaw_sigmas: scan topic -> how well its mount's yaw is known, rad (the file's
            `lidar.<topic>.yaw_sigma_rad`).
        limits: the plausible input ranges (``limits.*``, as the nodes take them).
        initial_pose: (x m, y m, yaw rad) in `map` the file sets, or None.
        landmarks_file: the map file the file sets (`landmarks_file`, the EKF node's
            parameter), or None: the bag's map.
        path_length: most poses per ekf/path message (`path_length`, the EKF node's
            parameter), or None: the default.
    """

    ekf: EkfConfig = field(default_factory=EkfConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    explicit: dict[str, tuple[str, ...]] = field(default_factory=dict)
    options: RunOptions = field(default_factory=RunOptions)
    lidars: dict[str, tuple[str | None, LidarMount]] = field(default_factory=dict)
    lidar_time_offsets: dict[str, float] = field(default_factory=dict)
    lidar_range_offsets: dict[str, float] = field(default_factory=dict)
    lidars_upside_down: frozenset[str] = frozenset()
    lidar_yaw_sigmas: dict[str, float] = field(default_factory=dict)
    limits: InputLimits = field(default_factory=InputLimits)
    initial_pose: tuple[float, float, float] | None = None
    landmarks_file: str | None = None
    path_length: int | None = None


def _flatten(tree: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _section_nodes(key: str) -> tuple[str, ...]:
    """Return the pipeline nodes a section applies to, as rclpy matches it (not namespaces).

    `/**`, `/*` and `/robot1/**` name every node, `/**/ekf_*` the EKF node by its pattern,
    `/robot1/ekf_node` that node in any namespace (a run has none).
    """
    last = key.rstrip('/').rsplit('/', 1)[-1]
    return tuple(node for node in PIPELINE_NODES if fnmatch.fnmatchcase(node, last))


def _declared_by(name: str) -> tuple[str, ...] | None:
    """Return the pipeline nodes declaring a name `run` reads; None: run's own (a duration)."""
    group, _, short = name.rpartition('.')
    if group == 'limits':
        return tuple(node for node, used in NODE_LIMITS.items() if short in used) or None
    if group and not name.startswith(('lidar.', 'initial_pose.')):
        return None
    if group or short in _OPTIONS or short in ('path_length', 'landmarks_file'):
        return ('ekf_node',)
    owner = _FIELD_OWNER.get(short)
    return None if owner is None else (_GROUP_NODE[owner],)


def _require_finite(source: str, name: str, value: Any) -> None:
    """Refuse .nan and .inf: NaN passes every bounds comparison of make_config."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ParamsFileError(f"{source}: parameter '{name}' = {value} is not finite")


def read_params_text(text: str, source: str = 'parameters') -> PipelineParams:
    """Parse params-file text; see the module docstring for what is read.

    Args:
        text: YAML text.
        source: file name used in error messages.

    Raises:
        ParamsFileError: not YAML, not the params-file layout, or a bad value.
    """
    try:
        tree = yaml.load(text, Loader=_RosLoader)
    except yaml.YAMLError as err:
        raise ParamsFileError(f'{source}: not valid YAML: {one_line(err)}') from None
    if tree is None:
        tree = {}
    if not isinstance(tree, dict):
        raise ParamsFileError(f'{source}: expected a mapping of node names to '
                              f'{{ros__parameters: ...}}, found {type(tree).__name__}')
    # Sections of every node first, so a node's own overrides them.
    sections = sorted(tree.items(), key=lambda item: 0 if len(_section_nodes(str(item[0])))
                      == len(PIPELINE_NODES) else 1)
    values: dict[str, dict[str, Any]] = {group: {} for group in _CONFIG_TYPES}
    options: dict[str, Any] = {}
    lidar_values: dict[str, Any] = {}
    pose_values: dict[str, Any] = {}
    landmarks_file: str | None = None
    path_length: int | None = None
    limits: dict[str, Any] = {}
    sidecar_names: list[str] = []
    read = 0
    for node, body in sections:
        nodes = _section_nodes(str(node))
        if not nodes:
            near = difflib.get_close_matches(str(node).rstrip('/').rsplit('/', 1)[-1],
                                             PIPELINE_NODES, n=1, cutoff=0.8)
            if near:
                log.warning('%s: section %r is not one of the pipeline\'s nodes (did you '
                            'mean %r?); skipped', source, node, near[0])
            else:
                log.debug('%s: skipping the section of node %r', source, node)
            continue
        read += 1
        if not isinstance(body, dict) or not isinstance(body.get('ros__parameters'), dict):
            raise ParamsFileError(f"{source}: section {node!r} has no 'ros__parameters' "
                                  'mapping')
        for name, value in _flatten(body['ros__parameters']).items():
            owners = _declared_by(name)
            if owners is not None and not set(owners) & set(nodes):
                # As the nodes take it: a node section's name is that node's, and rclpy
                # drops one it does not declare (run used it, and the section order decided
                # between two nodes' values).
                log.warning('%s: %s: %r is not a parameter of %s (it is %s\'s: set it in '
                            'that section or /**); ignored', source, node, name,
                            ' or '.join(nodes), ' and '.join(owners))
                continue
            if name.startswith('lidar.'):
                lidar_values[name[len('lidar.'):]] = value
                continue
            if name.startswith('initial_pose.'):
                pose_values[name] = value
                continue
            if name == 'landmarks_file':
                if not isinstance(value, str):
                    raise ParamsFileError(f"{source}: parameter 'landmarks_file' must be a "
                                          f'file name (a string), got {value!r}')
                landmarks_file = value or None
                continue
            if name == 'path_length':
                path_length = _path_length(source, value)
                continue
            group, _, short = name.rpartition('.')
            if short in _OPTIONS and not group:
                options[short] = value
                continue
            if group == 'limits' and short in _LIMITS:
                limits[short] = value
                continue
            owner = _FIELD_OWNER.get(short)
            if owner is None or group:
                if name.startswith(SIDECAR_PREFIXES):
                    sidecar_names.append(name)
                else:
                    _skipped(source, str(node), name)
                continue
            values[owner][short] = value
    if sidecar_names:
        # A bag's sidecar given as the params file too, or a stated figure written by hand:
        # either way the run states what the bag's own sidecar states.
        shown = sorted({name.split('.')[0] + ('.*' if '.' in name else '')
                        for name in sidecar_names})
        log.warning("%s: %s: a bag sidecar's own entries; run takes them from the bag's "
                    'sidecar (BAG.params.yaml), not from --params-file (to set a sigma, '
                    'write e.g. gyro_noise_rad_s with use_stated_noise: false); ignored',
                    source, ', '.join(shown))
    if not read:
        # A bag's metadata.yaml or another tool's file: nothing in it reaches the filter.
        log.warning('%s: no section for /**, %s: nothing read', source,
                    ', '.join(PIPELINE_NODES))
    for named in values.values():
        for short, value in named.items():
            _require_finite(source, short, value)
    for name, value in options.items():
        _require_finite(source, name, value)
    for name, value in limits.items():
        _require_finite(source, f'limits.{name}', value)
    built: dict[str, Any] = {}
    try:
        for group, kind in _CONFIG_TYPES.items():
            built[group] = make_config(kind, values[group], source=source)
        run_options = make_config(RunOptions, options, source=source)
        input_limits = make_config(InputLimits, limits, source=source)
    except CoreError as err:
        raise ParamsFileError(str(err)) from None
    mounts, (time_offsets, range_offsets, yaw_sigmas), upside_down = _lidar_mounts(
        lidar_values, source)
    return PipelineParams(
        ekf=built['ekf'], calibration=built['calibration'], detector=built['detector'],
        explicit={**{group: tuple(sorted(v)) for group, v in values.items()},
                  'options': tuple(sorted(options))},
        options=run_options, lidars=mounts, lidar_time_offsets=time_offsets,
        lidar_range_offsets=range_offsets, lidars_upside_down=upside_down,
        lidar_yaw_sigmas=yaw_sigmas,
        limits=input_limits, initial_pose=_initial_pose(pose_values, source, input_limits),
        landmarks_file=landmarks_file, path_length=path_length)


def _path_length(source: str, value: Any) -> int:
    """Return the EKF node's `path_length` (a whole number >= 1), or raise naming it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ParamsFileError(f"{source}: parameter 'path_length' must be a whole number of "
                              f'poses >= 1, got {value!r}')
    return value


def _skipped(source: str, node: str, name: str) -> None:
    """Say a name `run` does not read: quietly a node's own, else a warning.

    The nodes' own names (frames, topics, QoS) belong in these sections too, so they are no
    error; but a name one or two letters off a parameter (``gyro_noize_rad_s``), one behind a
    group prefix (``ekf.gyro_noise_rad_s``: the nodes declare it bare) or one no gyro_ekf
    node has would leave a parameter at its default without a word, in `run` and the nodes.
    """
    group, _, short = name.rpartition('.')
    if group and short in _FIELD_OWNER:
        # The name is right, the prefix is not: every node declares its parameters bare.
        log.warning('%s: %s: %r is not a parameter (the nodes declare %r bare, with no '
                    '%s. before it); ignored', source, node, name, short, group)
        return
    if is_gyro_ekf_parameter(name):
        log.debug('%s: %s: %r is a node\'s own, not the filter\'s; skipped', source, node,
                  name)
        return
    # Behind a group prefix (detector.max_widht_m), the name after it is the one meant.
    wanted = short if group in _CONFIG_TYPES else name
    candidates = sorted(set(_KNOWN).union(*NODE_ONLY_PARAMETERS.values()))
    close = difflib.get_close_matches(wanted, candidates, n=1, cutoff=0.85)
    if not close:
        # A unit suffix left out (gyro_noise for gyro_noise_rad_s) is too short a name for
        # the closeness cut-off, and as wrong: the value would be taken in no unit at all.
        close = [known for known in _KNOWN if known.startswith(wanted + '_')][:1]
    if close:
        log.warning('%s: %s: %r is not a parameter (did you mean %r?); ignored', source,
                    node, name, close[0])
    else:
        log.warning('%s: %s: %r is not a parameter of any gyro_ekf node; ignored', source,
                    node, name)


_POSE_NAMES = ('initial_pose.x_m', 'initial_pose.y_m', 'initial_pose.yaw_rad')


def _number(source: str, name: str, value: Any) -> float:
    """Return a finite number as a float (an int too), or raise a ParamsFileError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamsFileError(f"{source}: parameter '{name}' must be a number, got "
                              f'{value!r}')
    _require_finite(source, name, float(value))
    return float(value)


_YAW_LIMIT_RAD = 2.0 * math.pi
"""The range the nodes declare for `initial_pose.yaw_rad` and `lidar.<topic>.yaw_rad`."""


def _yaw(source: str, name: str, value: float) -> float:
    """Return a yaw within the nodes' declared range (they would refuse it too), or raise."""
    if abs(value) > _YAW_LIMIT_RAD:
        raise ParamsFileError(f"{source}: parameter '{name}' = {value:g} rad lies outside "
                              f'[-{_YAW_LIMIT_RAD:g}, {_YAW_LIMIT_RAD:g}] rad, the range the '
                              'nodes declare (a yaw in degrees?)')
    return value


def _initial_pose(values: dict[str, Any], source: str, limits: InputLimits
                  ) -> tuple[float, float, float] | None:
    """Return the start pose of the flattened `initial_pose.*` names (None when none is set).

    All three are required: a file that set x and y only would start the filter at yaw 0
    where the bag states another heading, with nothing said.
    """
    if not values:
        return None
    for name in sorted(set(values) - set(_POSE_NAMES)):
        close = difflib.get_close_matches(name, _POSE_NAMES, n=1, cutoff=0.8)
        hint = f' (did you mean {close[0]!r}?)' if close else ''
        raise ParamsFileError(f"{source}: parameter '{name}' is not one of "
                              f"{', '.join(_POSE_NAMES)}{hint}")
    pose = []
    for name in _POSE_NAMES:
        if name not in values:
            raise ParamsFileError(f"{source}: parameter '{name}' is missing (a start pose "
                                  f"takes {', '.join(_POSE_NAMES)})")
        pose.append(_number(source, name, values[name]))
    _yaw(source, _POSE_NAMES[2], pose[2])
    problem = initial_pose_problem(*pose, limits)
    if problem:
        raise ParamsFileError(f"{source}: parameter 'initial_pose': {problem}")
    return pose[0], pose[1], pose[2]


_LIDAR_KEYS = ('frame_id', 'x_m', 'y_m', 'yaw_rad', 'time_offset_s', 'range_offset_m',
               'upside_down', 'yaw_sigma_rad')
"""What `lidar.<topic>.*` holds, as the EKF node declares it (nodes/params.py)."""


def _lidar_mounts(values: dict[str, Any], source: str
                  ) -> tuple[dict[str, tuple[str | None, LidarMount]],
                             tuple[dict[str, float], dict[str, float], dict[str, float]],
                             frozenset[str]]:
    """Mounts, (time offsets, range offsets, yaw sigmas), LiDARs upside down: `lidar.*`."""
    if not values:
        return {}, ({}, {}, {}), frozenset()
    topics = values.get('topics')
    if not isinstance(topics, list) or not all(isinstance(t, str) and t for t in topics):
        raise ParamsFileError(f"{source}: parameter 'lidar.topics' must be a list of scan "
                              f'topics, got {topics!r}')
    # The node warns of these too (a name close to one it declares); without a word the
    # bag's mount would stay (yaw_deg for yaw_rad, a LiDAR left out of lidar.topics).
    unlisted: dict[str, list[str]] = {}
    for name in sorted(values):
        topic, _, key = name.rpartition('.')
        if name == 'topics' or (topic in topics and key in _LIDAR_KEYS):
            continue
        if topic in topics:
            close = difflib.get_close_matches(key, _LIDAR_KEYS, n=1, cutoff=0.6)
            log.warning("%s: 'lidar.%s' is not a parameter (a LiDAR's are %s%s); ignored",
                        source, name, ', '.join(_LIDAR_KEYS),
                        f': did you mean {close[0]!r}?' if close else '')
        else:
            unlisted.setdefault(topic or name, []).append(f'lidar.{name}')
    for topic, names in unlisted.items():
        log.warning('%s: %s: %r is not one of lidar.topics %s; ignored', source,
                    ', '.join(names), topic, topics)
    mounts: dict[str, tuple[str | None, LidarMount]] = {}
    offsets: dict[str, float] = {}
    ranges: dict[str, float] = {}
    yaw_sigmas: dict[str, float] = {}
    flipped: set[str] = set()
    for topic in topics:
        upside_down = values.get(f'{topic}.upside_down', False)
        if not isinstance(upside_down, bool):
            raise ParamsFileError(f"{source}: parameter 'lidar.{topic}.upside_down' must be "
                                  f'true or false, got {upside_down!r}')
        if upside_down:
            flipped.add(topic)
        for key, found, problem_of in (('time_offset_s', offsets, time_offset_problem),
                                       ('range_offset_m', ranges, range_offset_problem),
                                       ('yaw_sigma_rad', yaw_sigmas, yaw_sigma_problem)):
            name = f'lidar.{topic}.{key}'
            offset = values.get(f'{topic}.{key}')
            if offset is None and f'{topic}.{key}' in values:
                # YAML's null (or an empty value): not 0, and never dropped in silence.
                raise ParamsFileError(f"{source}: parameter '{name}' must be a number, got "
                                      'null')
            if offset is not None:
                found[topic] = _number(source, name, offset)
                problem = problem_of(found[topic])
                if problem:
                    raise ParamsFileError(f"{source}: parameter '{name}': {problem}")
        if not any(f'{topic}.{key}' in values for key in ('x_m', 'y_m', 'yaw_rad')) and (
                topic in offsets or topic in ranges or topic in yaw_sigmas
                or f'{topic}.upside_down' in values):
            continue  # the offsets alone: the bag's mount stays
        numbers = []
        for key in ('x_m', 'y_m', 'yaw_rad'):
            name = f'lidar.{topic}.{key}'
            value = values.get(f'{topic}.{key}')
            if value is None:
                raise ParamsFileError(f"{source}: parameter '{name}' is missing")
            numbers.append(_number(source, name, value))
        _yaw(source, f'lidar.{topic}.yaw_rad', numbers[2])
        problem = mount_problem(*numbers)
        if problem:
            raise ParamsFileError(f"{source}: parameter 'lidar.{topic}': {problem}")
        frame = values.get(f'{topic}.frame_id')
        if frame is not None and not isinstance(frame, str):
            raise ParamsFileError(f"{source}: parameter 'lidar.{topic}.frame_id' must be a "
                                  f'string, got {frame!r}')
        mounts[topic] = (frame, LidarMount(*numbers))
    return mounts, (offsets, ranges, yaw_sigmas), frozenset(flipped)


def stamps_less(stamp_s: np.ndarray, offset_s: float) -> np.ndarray:
    """Return the stamps less a LiDAR's time offset (`lidar.<topic>.time_offset_s`), s.

    In whole ns, as the node moves a message's stamp: a scan moved onto an IMU sample's
    stamp then sorts before it in both (the same order, the same numbers).
    """
    return seconds_since(ns_at(0, stamp_s) - round(offset_s * NS_PER_S), 0)


def with_lidar_mounts(trip: Trip, params: PipelineParams) -> Trip:
    """Return the trip with the params file's LiDAR mounts and offsets on its scans.

    A mount replaces the one the bag states for that topic; a time offset takes each scan
    at its stamp less the offset, and a range offset moves its poles that much toward the
    LiDAR (the EKF node does the same). Each is logged; a topic the trip has no scans of is
    logged and skipped (the file may serve several bags).
    """
    if not (params.lidars or params.lidar_time_offsets or params.lidar_range_offsets
            or params.lidars_upside_down or params.lidar_yaw_sigmas):
        return trip
    scans = []
    for series in trip.scans:
        frame, mount = params.lidars.get(series.topic, (None, series.mount))
        if mount != series.mount:
            log.info("%s: LiDAR '%s' mount from the params file (%g m, %g m, %g rad); the "
                     'bag states (%g m, %g m, %g rad)', trip.name, series.topic, mount.x_m,
                     mount.y_m, mount.yaw_rad, series.mount.x_m, series.mount.y_m,
                     series.mount.yaw_rad)
        stamps = series.stamp_s
        offset = params.lidar_time_offsets.get(series.topic, 0.0)
        if offset:
            log.info("%s: LiDAR '%s' scans taken %g ms before their stamps (the params "
                     "file's time_offset_s)", trip.name, series.topic, 1000.0 * offset)
            stamps = stamps_less(stamps, offset)
        range_offset = params.lidar_range_offsets.get(series.topic, series.range_offset_m)
        if range_offset:
            log.info("%s: LiDAR '%s' ranges read %+g cm long (the params file's "
                     'range_offset_m): its poles moved that much toward it', trip.name,
                     series.topic, 100.0 * range_offset)
        upside_down = series.upside_down or series.topic in params.lidars_upside_down
        if upside_down:
            log.info("%s: LiDAR '%s' mounted upside down (the params file's upside_down): "
                     "its poles mirrored into an upright one's frame", trip.name, series.topic)
        yaw_sigma = params.lidar_yaw_sigmas.get(series.topic, series.yaw_sigma_rad)
        if yaw_sigma:
            log.info("%s: LiDAR '%s' yaw known to +-%.4f deg (the params file's "
                     'yaw_sigma_rad): %s', trip.name, series.topic, math.degrees(yaw_sigma),
                     'the heading reported is known no better' if series is trip.scans[0]
                     else 'it widens the heading only if this LiDAR comes to define the '
                     'body frame (the first one does)')
        scans.append(dataclasses.replace(series, mount=mount, stamp_s=stamps,
                                         frame_id=frame or series.frame_id,
                                         range_offset_m=range_offset,
                                         upside_down=upside_down, yaw_sigma_rad=yaw_sigma))
    for topic in sorted((set(params.lidars) | set(params.lidar_time_offsets)
                         | set(params.lidar_range_offsets) | params.lidars_upside_down
                         | set(params.lidar_yaw_sigmas))
                        - {s.topic for s in trip.scans}):
        log.warning("%s: the params file sets LiDAR '%s', which has no scans in this trip; "
                    'ignored', trip.name, topic)
    return dataclasses.replace(trip, scans=tuple(scans))


def with_landmarks_file(trip: Trip, params: PipelineParams) -> Trip:
    """Return the trip with the map of the params file's `landmarks_file`, if it sets one.

    As the EKF node takes it (a path from the working folder). `gyro-ekf run` writes
    `landmarks_seen.yaml` when poles stand elsewhere than the map has them (core/map_poles.py).

    Raises:
        LandmarksFileError: the file cannot be read, or a landmark is bad (named).
    """
    if params.landmarks_file is None:
        return trip
    from gyro_ekf.io.landmarks_file import read_landmarks_file
    landmarks = read_landmarks_file(params.landmarks_file, params.limits)
    log.info("%s: the map from the params file's landmarks_file %s (%d landmarks; the bag has "
             '%d)', trip.name, params.landmarks_file, len(landmarks), len(trip.landmarks))
    return dataclasses.replace(trip, landmarks=landmarks)


def with_initial_pose(trip: Trip, params: PipelineParams, stated_by_message: bool) -> Trip:
    """Return the trip started at the params file's pose, as the EKF node starts.

    Args:
        trip: the trip as read (its pose from the bag's /initialpose message, its sidecar,
            or the origin).
        params: the params file read.
        stated_by_message: whether the trip's pose came from an /initialpose message in the
            bag: the node sets its pose from that message when the bag is replayed, so it
            is kept (and the file's pose named in a warning).
    """
    if params.initial_pose is None:
        return trip
    wanted = np.asarray(params.initial_pose, dtype=np.float64)
    stated = np.asarray(trip.initial_pose, dtype=np.float64)
    # To a nanometre and a nanoradian: a pose written out and read back (a message's
    # quaternion and its yaw) differs in the last bits, and is the same pose.
    if np.allclose(wanted, stated, rtol=0.0, atol=1e-9):
        return trip
    if stated_by_message:
        log.warning('%s: the params file sets initial_pose (%g m, %g m, %g rad), but the '
                    "bag's /initialpose message states (%g m, %g m, %g rad): the run starts "
                    'there, as ekf_node does once a replay of the bag publishes it',
                    trip.name, *wanted.tolist(), *stated.tolist())
        return trip
    log.info('%s: start pose from the params file (%g m, %g m, %g rad); the bag states '
             '(%g m, %g m, %g rad)', trip.name, *wanted.tolist(), *stated.tolist())
    return dataclasses.replace(trip, initial_pose=wanted)


def read_params_file(path: Path | str) -> PipelineParams:
    """Read a ROS 2 params YAML file into the core configs.

    Raises:
        ParamsFileError: missing or unreadable file, bad layout or a bad value; the message
            names the file and the parameter.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as err:
        raise ParamsFileError(f'{path}: cannot read the params file: {err.strerror}') from None
    except UnicodeDecodeError as err:
        raise ParamsFileError(f'{path}: not UTF-8 text (byte {err.start}): not a params '
                              'file') from None
    return read_params_text(text, source=str(path))
