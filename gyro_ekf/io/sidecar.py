"""The params YAML written beside a bag: what the bag needs and no message carries.

A bag folder `OUT` gets `OUT.params.yaml` next to it (never inside, so the folder stays
exactly what rosbag2 expects). It is a ROS 2 parameters file, so nodes take it with
`--ros-args --params-file OUT.params.yaml` and `gyro-ekf run` finds it by itself:

    /**:
      ros__parameters:
        trip:
          name: data019b
          log_time_zero_ns: 1700000000000000000   # bag stamp of the log's time zero
          static_duration_s: 0.0
          bag:                                    # the bag this file was written with
            message_count: 26120
            first_stamp_ns: 1700000000000000000   # its first and last message (log time)
            last_stamp_ns: 1700000261190000000
          dropped_when_converted:                 # only when convert --skip-bad dropped any
            source: data019b.mat
            streams: [imu]                        # per stream: samples dropped, time breaks
            samples: [10]
            time_breaks: [0]
            fields: [imu.angular_velocity.z]      # per field and reason: count, first index
            reasons: [not finite]
            counts: [10]
            first_indexes: [20000]                # in the log's series
        initial_pose: {x_m: 2.780846, y_m: 11.278871, yaw_rad: -0.0206156}
        lidar:
          topics: [scan]                          # scan topics in the bag (no slash)
          scan: {frame_id: laser, x_m: 0.4, y_m: 0.0, yaw_rad: 0.0}
        noise:                                    # only the figures the log states
          gyro_rad_s: 0.01745329
          speed_m_s: 0.08
          landmark_m: 0.0                         # a simulator's map is exact
        true_gyro_bias_rad_s: [0.0, 0.0, 0.005235988]   # only when known

All values are SI; names end in their unit. Unknown entries are left out (ROS parameters have
no null). `trip.dropped_when_converted` keeps what `convert --skip-bad` dropped from the log
with the bag, so a run on the bag counts it, and so does the EKF node, which declares these
names (nodes/params.py; parallel lists: ROS parameters hold no lists of mappings).

`trip.bag` is the fingerprint of the bag the file was written with: its message count and
the log times of its first and last message. A params file copied from another trip would
give this one that trip's initial pose, LiDAR mounts, noise and true bias, and every run and
truth comparison would be silently wrong; so every reader compares the two (`check_belongs`)
and refuses a mismatch in one line naming both files and both fingerprints. `read_bag` (run,
calibrate, calibrate-mounts, demo) compares the messages it reads; `info` (after holding
metadata.yaml to the data), `replay` and `read_sidecar` compare what metadata.yaml states.
Neither costs another read of the data (metadata.yaml is a small file every opening of a
bag reads), and both survive `gyro-ekf reindex`, which rebuilds the index and metadata.yaml
from the same messages. Two trips simulated with the same settings and start that differ
only in their seed have the same fingerprint (same count, same stamps): it tells trips
apart, not seeds. Their sidecars hold the same values but the trip's name (`simulate
--seed 1` and `--seed 2`: initial pose, mounts, noise and true bias alike), so one taken for
the other changes the name in the outputs and no figure.
A sidecar without `trip.bag` (written before it existed, or by hand) is taken unchecked, and
`info` says so. The nodes do not declare `trip.bag.*` (a node has no bag to compare with;
rclpy ignores names nobody declares).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from gyro_ekf.core.types import FloatArray, LidarMount, NoiseFigures, Trip
from gyro_ekf.core.validation import (InputReport, duration_problem, initial_pose_problem,
                                      mount_problem)
from gyro_ekf.errors import one_line
from gyro_ekf.io.errors import BagError

SUFFIX = '.params.yaml'
NOISE_KEYS = ('gyro_rad_s', 'speed_m_s', 'range_m', 'bearing_rad', 'landmark_m')


class BagFingerprint(NamedTuple):
    """What identifies a bag cheaply: its message count, first and last log time.

    Attributes:
        message_count: messages in the bag, all topics.
        first_stamp_ns: log (receive) time of its first message, ns since the epoch.
        last_stamp_ns: log time of its last message, ns since the epoch.
    """

    message_count: int
    first_stamp_ns: int
    last_stamp_ns: int

    def describe(self) -> str:
        """Say it in words, for a message naming two of them."""
        if not self.message_count:
            return 'no messages'
        span_s = (self.last_stamp_ns - self.first_stamp_ns) / 1e9
        return (f'{self.message_count} messages from {self.first_stamp_ns} to '
                f'{self.last_stamp_ns} ns ({span_s:.3f} s)')


BAG_PARAMETER = 'trip.bag'
"""Where the fingerprint of the bag a sidecar was written with is recorded."""
BAG_KEYS = BagFingerprint._fields


@dataclass(frozen=True, slots=True)
class BagParams:
    """The contents of a bag's sidecar params file.

    Attributes:
        name: trip name.
        log_time_zero_ns: bag stamp, ns since the epoch, of the log's time zero.
        static_duration_s: how long the trip is known to start static, s.
        initial_pose: shape (3,): x m, y m, yaw rad in `map`.
        lidars: scan topic (no slash) -> (frame_id, mount).
        noise: noise figures the log states.
        true_gyro_bias_rad_s: shape (3,), rad/s, or None when not known.
        converted: what `convert --skip-bad` dropped from the log the bag was written from
            (an InputReport with source, dropped, first_index, samples_dropped and
            time_breaks), or None when it dropped nothing.
        bag: the fingerprint of the bag the file was written with, or None when it has
            none (written by an older gyro_ekf, or by hand).
    """

    name: str
    log_time_zero_ns: int
    static_duration_s: float = 0.0
    initial_pose: FloatArray = field(default_factory=lambda: np.zeros(3))
    lidars: dict[str, tuple[str, LidarMount]] = field(default_factory=dict)
    noise: NoiseFigures = field(default_factory=NoiseFigures)
    true_gyro_bias_rad_s: FloatArray | None = None
    converted: InputReport | None = None
    bag: BagFingerprint | None = None


def sidecar_path(bag_path: Path | str) -> Path:
    """Where the params file of bag folder `bag_path` lives: `<bag>.params.yaml` beside it."""
    bag_path = Path(bag_path)
    return bag_path.parent / (bag_path.name + SUFFIX)


def params_of_trip(trip: Trip, log_time_zero_ns: int,
                   converted: InputReport | None = None,
                   bag: BagFingerprint | None = None) -> BagParams:
    """Collect the sidecar contents of a trip whose time zero is at `log_time_zero_ns`.

    `converted` is the report of the validation the trip passed on its way from a log; what
    it dropped is recorded (a report that dropped nothing is left out). `bag` is the
    fingerprint of the bag written with it.
    """
    return BagParams(
        name=trip.name, log_time_zero_ns=int(log_time_zero_ns),
        static_duration_s=float(trip.static_duration_s),
        initial_pose=np.asarray(trip.initial_pose, dtype=np.float64),
        lidars={s.topic: (s.frame_id, s.mount) for s in trip.scans},
        noise=trip.noise,
        true_gyro_bias_rad_s=None if trip.true_gyro_bias_rad_s is None else np.asarray(
            trip.true_gyro_bias_rad_s, dtype=np.float64),
        converted=converted if converted is not None and converted.total_dropped else None,
        bag=bag)


CONVERTED_PARAMETER = 'trip.dropped_when_converted'
"""Where what `convert --skip-bad` dropped from the log is recorded."""
CONVERTED_KEYS = (('source', str), ('streams', str), ('samples', int), ('time_breaks', int),
                  ('fields', str), ('reasons', str), ('counts', int), ('first_indexes', int))
"""The entries of `trip.dropped_when_converted` and their (element) types: source is a text,
the others are lists."""


def _converted_values(report: InputReport) -> dict[str, Any]:
    streams = list(report.samples_dropped)
    keys = list(report.dropped)
    return {'source': report.source, 'streams': streams,
            'samples': [int(report.samples_dropped[s]) for s in streams],
            'time_breaks': [int(report.time_breaks.get(s, 0)) for s in streams],
            'fields': [f for f, _ in keys], 'reasons': [r for _, r in keys],
            'counts': [int(report.dropped[k]) for k in keys],
            'first_indexes': [int(report.first_index[k]) for k in keys]}


def _parse_converted(tree: dict[str, Any], path: Path) -> InputReport | None:
    """Read `trip.dropped_when_converted` back into an InputReport, or None without it.

    Raises:
        BagError: as converted_report.
    """
    trip = tree.get('trip')
    if not isinstance(trip, dict) or 'dropped_when_converted' not in trip:
        return None
    return converted_report(trip['dropped_when_converted'], path.name)


def converted_report(record: Any, where: str) -> InputReport:
    """Check a `trip.dropped_when_converted` record and return it as an InputReport.

    Args:
        record: its entries by name (CONVERTED_KEYS: source, streams, samples, ...), as the
            sidecar holds them or a node received them as parameters.
        where: what an error names first (the sidecar's file name, or the node).

    Raises:
        BagError: an entry missing, of the wrong type, a negative count, or lists of
            different lengths.
    """
    tree = {'trip': {'dropped_when_converted': record}}
    source = _get(tree, f'{CONVERTED_PARAMETER}.source', str, where)
    lists = {}
    for key, kind in CONVERTED_KEYS[1:]:
        values = _get(tree, f'{CONVERTED_PARAMETER}.{key}', list, where)
        for value in values:
            if not isinstance(value, kind) or isinstance(value, bool) or (
                    kind is int and value < 0):
                what = 'texts' if kind is str else 'non-negative whole numbers'
                raise BagError(f"{where}: parameter '{CONVERTED_PARAMETER}.{key}' must be a "
                               f'list of {what}, got {value!r} in it')
        lists[key] = values
    for group in (('streams', 'samples', 'time_breaks'),
                  ('fields', 'reasons', 'counts', 'first_indexes')):
        lengths = {len(lists[key]) for key in group}
        if len(lengths) != 1 or not lists[group[0]]:
            raise BagError(f"{where}: parameter '{CONVERTED_PARAMETER}': "
                           f"{', '.join(group)} must be lists of one non-zero length")
    report = InputReport(source=source, skip_bad=True)
    for stream, n, breaks in zip(lists['streams'], lists['samples'], lists['time_breaks']):
        report.samples_dropped[stream] = n
        if breaks:
            report.time_breaks[stream] = breaks
    for field_name, reason, n, first in zip(lists['fields'], lists['reasons'],
                                            lists['counts'], lists['first_indexes']):
        report.count(field_name, reason, first, n)
    return report


def to_yaml(params: BagParams) -> str:
    """Render a sidecar as ROS 2 params-file text."""
    x, y, yaw = (float(v) for v in params.initial_pose)
    values: dict[str, Any] = {
        'trip': {'name': params.name, 'log_time_zero_ns': int(params.log_time_zero_ns),
                 'static_duration_s': float(params.static_duration_s)},
        'initial_pose': {'x_m': x, 'y_m': y, 'yaw_rad': yaw},
    }
    if params.bag is not None:
        values['trip']['bag'] = {key: int(value) for key, value in params.bag._asdict().items()}
    if params.converted is not None and params.converted.total_dropped:
        values['trip']['dropped_when_converted'] = _converted_values(params.converted)
    if params.lidars:
        lidar: dict[str, Any] = {'topics': list(params.lidars)}
        for topic, (frame_id, mount) in params.lidars.items():
            lidar[topic] = {'frame_id': frame_id, 'x_m': float(mount.x_m),
                            'y_m': float(mount.y_m), 'yaw_rad': float(mount.yaw_rad)}
        values['lidar'] = lidar
    noise = {key: float(getattr(params.noise, key)) for key in NOISE_KEYS
             if getattr(params.noise, key) is not None}
    if noise:
        values['noise'] = noise
    if params.true_gyro_bias_rad_s is not None:
        values['true_gyro_bias_rad_s'] = [float(v) for v in params.true_gyro_bias_rad_s]
    header = ('# gyro_ekf bag parameters (SI): LiDAR mounts per scan topic, initial pose,\n'
              '# noise figures the log states and the injected gyro bias when known;\n'
              '# trip.bag: the bag written with this file (refused beside another bag).\n')
    return header + yaml.safe_dump({'/**': {'ros__parameters': values}}, sort_keys=False,
                                   default_flow_style=False)


def _get(tree: dict[str, Any], dotted: str, kind: type | tuple[type, ...],
         path: Path | str) -> Any:
    """Return the entry at a dotted name; an error names path (its file name) and the entry."""
    where = path.name if isinstance(path, Path) else path
    value: Any = tree
    for part in dotted.split('.'):
        if not isinstance(value, dict) or part not in value:
            raise BagError(f"{where}: parameter '{dotted}' is missing")
        value = value[part]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise BagError(f"{where}: parameter '{dotted}' = {value!r} has the wrong type")
    return value


def parse_yaml(text: str, path: Path) -> BagParams:
    """Parse sidecar text (see the module docstring).

    Raises:
        BagError: not YAML, not a params file, or a parameter missing or of the wrong type.
    """
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise BagError(f'{path.name}: not valid YAML: {one_line(err)}') from None
    if not isinstance(document, dict) or not isinstance(document.get('/**'), dict) or \
            not isinstance(document['/**'].get('ros__parameters'), dict):
        raise BagError(f"{path.name}: expected a ROS 2 params file ('/**: ros__parameters:')")
    tree = document['/**']['ros__parameters']
    number = (int, float)
    lidars: dict[str, tuple[str, LidarMount]] = {}
    if 'lidar' in tree:
        for topic in _get(tree, 'lidar.topics', list, path):
            key = f'lidar.{topic}'
            lidars[str(topic)] = (str(_get(tree, key + '.frame_id', str, path)), LidarMount(
                float(_get(tree, key + '.x_m', number, path)),
                float(_get(tree, key + '.y_m', number, path)),
                float(_get(tree, key + '.yaw_rad', number, path))))
    noise = tree.get('noise') or {}
    if not isinstance(noise, dict):
        raise BagError(f"{path.name}: parameter 'noise' must be a mapping")
    bias = None
    if 'true_gyro_bias_rad_s' in tree:
        values = _get(tree, 'true_gyro_bias_rad_s', list, path)
        if len(values) != 3 or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                       for v in values):
            raise BagError(f"{path.name}: parameter 'true_gyro_bias_rad_s' must be 3 numbers")
        bias = np.array(values, dtype=np.float64)
        if not np.all(np.isfinite(bias)):
            raise BagError(f"{path.name}: parameter 'true_gyro_bias_rad_s' must be 3 numbers")
    pose = [float(_get(tree, f'initial_pose.{k}', number, path))
            for k in ('x_m', 'y_m', 'yaw_rad')]
    # YAML spells NaN and inf (.nan, .inf); a NaN mount would leave every detection
    # unassociated with no error, so the values are checked here where they enter.
    problem = initial_pose_problem(*pose)
    if problem:
        raise BagError(f"{path.name}: parameter 'initial_pose': {problem}")
    for topic, (_, mount) in lidars.items():
        problem = mount_problem(mount.x_m, mount.y_m, mount.yaw_rad)
        if problem:
            raise BagError(f"{path.name}: parameter 'lidar.{topic}': {problem} "
                           f'({mount.x_m}, {mount.y_m}, {mount.yaw_rad})')
    static_s = float(_get(tree, 'trip.static_duration_s', number, path))
    problem = duration_problem(static_s)
    if problem:
        raise BagError(f"{path.name}: parameter 'trip.static_duration_s': {problem}")
    for key in NOISE_KEYS:
        if key in noise:
            value = _get(tree, f'noise.{key}', number, path)
            if not math.isfinite(value) or value < 0.0:
                raise BagError(f"{path.name}: parameter 'noise.{key}' must be a "
                               f'non-negative number, got {value}')
    return BagParams(
        name=str(_get(tree, 'trip.name', str, path)),
        log_time_zero_ns=int(_get(tree, 'trip.log_time_zero_ns', int, path)),
        static_duration_s=static_s,
        initial_pose=np.array(pose),
        lidars=lidars,
        noise=NoiseFigures(**{k: float(noise[k]) if k in noise else None
                              for k in NOISE_KEYS}),
        true_gyro_bias_rad_s=bias,
        converted=_parse_converted(tree, path),
        bag=_parse_fingerprint(tree, path))


def _parse_fingerprint(tree: dict[str, Any], path: Path) -> BagFingerprint | None:
    """Read `trip.bag` back, or None without it (a sidecar written before it existed).

    Raises:
        BagError: `trip.bag` given in part, or an entry that is no non-negative whole number
            (a fingerprint in part would check nothing and pass for one).
    """
    trip = tree.get('trip')
    if not isinstance(trip, dict) or 'bag' not in trip:
        return None
    values = [_get(tree, f'{BAG_PARAMETER}.{key}', int, path) for key in BAG_KEYS]
    fingerprint = BagFingerprint(*values)
    if min(values) < 0 or fingerprint.first_stamp_ns > fingerprint.last_stamp_ns:
        raise BagError(f"{path.name}: parameter '{BAG_PARAMETER}': expected non-negative "
                       f'whole numbers, the first stamp not after the last, got '
                       f'{dict(fingerprint._asdict())}')
    return fingerprint


def fingerprint_of(meta: dict[str, Any], bag_path: Path) -> BagFingerprint:
    """Return the fingerprint a bag's metadata.yaml states (rosbag2_bagfile_information).

    Raises:
        BagError: an entry missing or no whole number, naming metadata.yaml.
    """
    try:
        count = meta['message_count']
        start = meta['starting_time']['nanoseconds_since_epoch']
        duration = meta['duration']['nanoseconds']
    except (KeyError, TypeError) as err:
        raise BagError(f"{bag_path / 'metadata.yaml'}: missing or invalid entry {err}"
                       ) from None
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (count, start, duration)):
        raise BagError(f"{bag_path / 'metadata.yaml'}: message_count, starting_time and "
                       f'duration must be whole numbers, got {count!r}, {start!r}, '
                       f'{duration!r}')
    return stated_fingerprint(count, start, duration)


def stated_fingerprint(message_count: int, starting_time_ns: int,
                       duration_ns: int) -> BagFingerprint:
    """Return the fingerprint of a bag stating these (metadata.yaml's entries, ns).

    rosbag2 states the span from the first to the last message's log time; a bag of no
    messages states no start (the largest int64) and is (0, 0, 0).
    """
    if not message_count:
        return BagFingerprint(0, 0, 0)
    return BagFingerprint(message_count, starting_time_ns, starting_time_ns + duration_ns)


def check_belongs(bag_path: Path | str, params: BagParams | None, found: BagFingerprint,
                  source: str = 'as its metadata.yaml states') -> None:
    """Refuse a sidecar written with another bag than the one at `bag_path`.

    A sidecar without a fingerprint (params.bag None, an older gyro_ekf's) passes: there is
    nothing to compare, and refusing it would break every bag written before.

    Args:
        bag_path: the bag folder.
        params: its sidecar as read, or None when it has none.
        found: the bag's own fingerprint (`fingerprint_of` its metadata.yaml, or what a
            read of its messages found).
        source: where `found` comes from, for the message.

    Raises:
        BagError: one line naming the sidecar, the bag and both fingerprints.
    """
    if params is None or params.bag is None or params.bag == found:
        return
    bag_path = Path(bag_path)
    raise BagError(
        f'{sidecar_path(bag_path)}: belongs to a bag of {params.bag.describe()}; bag '
        f'{bag_path} has {found.describe()} ({source}): a params file of another trip would '
        'give this one its initial pose, LiDAR mounts, noise and true bias; put the params '
        'file written with this bag beside it')


def read_sidecar(bag_path: Path | str, check: bool = True) -> BagParams | None:
    """Read the params file beside bag folder `bag_path`; None when there is none.

    Args:
        bag_path: the bag folder.
        check: refuse a sidecar whose fingerprint (`trip.bag`) is not what the bag's
            metadata.yaml states (`check_belongs`); False leaves that to the caller. A
            folder without metadata.yaml has no bag to compare with (and every reader of
            the bag refuses it).

    Raises:
        BagError: the file exists but cannot be read or parsed, or (check) it was written
            with another bag.
    """
    path = sidecar_path(bag_path)
    if not path.exists():
        return None
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as err:
        raise BagError(f'{path}: cannot read: {err}') from None
    except UnicodeDecodeError as err:
        raise BagError(f'{path}: not UTF-8 text (byte {err.start}): not a params file') from None
    params = parse_yaml(text, path)
    bag_path = Path(bag_path)
    if check and params.bag is not None and (bag_path / 'metadata.yaml').is_file():
        from gyro_ekf.io.bag_open import metadata  # bag_open imports this module

        check_belongs(bag_path, params, fingerprint_of(metadata(bag_path), bag_path))
    return params


def check_finite(params: BagParams) -> None:
    """Refuse NaN or infinite values, which a params file cannot carry meaningfully.

    Raises:
        BagError: names the offending parameter.
    """
    checks = {'initial_pose': params.initial_pose, 'trip.static_duration_s':
              [params.static_duration_s]}
    for topic, (_, mount) in params.lidars.items():
        checks[f'lidar.{topic}'] = [mount.x_m, mount.y_m, mount.yaw_rad]
    for name, values in checks.items():
        if not all(math.isfinite(float(v)) for v in values):
            raise BagError(f"parameter '{name}' = {list(values)} is not finite")
