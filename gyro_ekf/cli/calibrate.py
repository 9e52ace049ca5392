"""`gyro-ekf calibrate`: offline gyro bias over the static window of a course log or a bag."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from gyro_ekf.cli.convert import add_skip_bad_argument, warn_dropped
from gyro_ekf.core.calibration import calibrate_trip, measured_axes
from gyro_ekf.core.config import CalibrationConfig, field_bounds
from gyro_ekf.core.errors import CalibrationError
from gyro_ekf.core.types import BiasEstimate, Trip
from gyro_ekf.errors import GyroEkfError

HELP = 'estimate the gyro bias over the static start of a course log or bag'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('source', nargs='+', type=Path,
                        help='a bag folder, course log .mat file(s) / folder, or a trip .npz')
    defaults = CalibrationConfig()
    parser.add_argument('--window-start-s', type=float, default=defaults.window_start_s,
                        help='start of the static window after the first gyro sample, s')
    parser.add_argument('--window-length-s', type=float, default=defaults.window_length_s,
                        help='length of the static window, s')
    parser.add_argument('--ignore-speed', action='store_true',
                        help='do not use the speed stream to confirm the platform is still')
    parser.add_argument('--ignore-scans', action='store_true',
                        help='do not use the LiDAR scans to confirm the platform does not turn')
    parser.add_argument('--json', action='store_true', help='print JSON instead of a table')
    add_skip_bad_argument(parser)


BAG_FILE_SUFFIXES = ('.mcap', '.db3', '.yaml')
"""Files of a bag (storage, metadata.yaml, params sidecar): never a course log or trip file."""


def is_bag(path: Path) -> bool:
    """Whether a source is read as a bag rather than as a course log or trip file.

    A bag folder, and what a user may give for one: a folder of storage files without its
    metadata.yaml (a killed recorder), or one of a bag's files. The bag reader's refusal of
    those says what to give or run instead; the course-log reader called a .mcap not a
    MATLAB file.
    """
    if path.is_dir():
        if (path / 'metadata.yaml').is_file():
            return True
        try:
            return not any(path.glob('*.mat')) and any(
                p.suffix in BAG_FILE_SUFFIXES[:2] for p in path.iterdir())
        except OSError:
            return False  # an unreadable folder: the log reader names it
    return path.suffix in BAG_FILE_SUFFIXES


def stream_names(sources: list[Path]) -> dict[str, str]:
    """Name where the gyro ('imu'), speed ('speed') and scan ('lidar') streams come from.

    For errors about a stream as a whole (a refused static window), which the core reports
    without a source: a bag and its topic, or the file of a log that holds the stream (the
    2016 log spreads over three files), named as the log's other errors name it.
    """
    from gyro_ekf.io.bag_open import IMU_TOPIC, ODOM_TOPIC
    from gyro_ekf.io.sources import stream_files

    if is_bag(sources[0]):
        return {'imu': f"{sources[0]}: topic '{IMU_TOPIC}'",
                'speed': f"{sources[0]}: topic '{ODOM_TOPIC}'"}
    return {stream: path.name for stream, path in stream_files(sources).items()}


def stream_name(sources: list[Path], stream: str) -> str:
    """Name where a stream came from: stream_names', or a LiDAR's ('lidar:<scan topic>')."""
    topic = stream.removeprefix('lidar:')
    if topic == stream:
        return stream_names(sources)[stream]
    if is_bag(sources[0]):
        return f"{sources[0]}: topic '/{topic}'"
    return stream_names(sources)['lidar']  # a log's file holding its scans


def load_trip(sources: list[Path], skip_bad: bool = False) -> Trip:
    """Read a bag folder (with metadata.yaml), course log files or a simulator trip file.

    The trip passes the validation boundary: bad samples are refused, or dropped and
    counted with skip_bad.
    """
    if len(sources) == 1 and is_bag(sources[0]):
        from gyro_ekf.io.bag_reader import read_bag, validate_bag
        trip, report = validate_bag(read_bag(sources[0]), sources[0].name, skip_bad=skip_bad)
    else:
        from gyro_ekf.io.sources import load_checked_log
        # A calibration uses no landmarks: no map needed, and no warning that there is none.
        trip, report = load_checked_log(sources, skip_bad=skip_bad, landmarks=False)
    warn_dropped(report)
    return trip


def estimate_to_dict(estimate: BiasEstimate, axes_known: tuple[bool, bool, bool]) -> dict:
    """JSON-ready view: SI values plus degrees for people.

    An axis the source does not measure (x and y of the yaw-rate-only 2021 log) is None
    (JSON null) in every per-axis list: the estimator reports 0 there, which would read as
    a bias and a noise known to be exactly zero.
    """
    def measured(values: np.ndarray) -> list[float | None]:
        return measured_axes(values, axes_known)

    return {
        'axes': ['x', 'y', 'z'],
        'axes_known': list(axes_known),
        'bias_rad_s': measured(estimate.bias_rad_s),
        'sigma_rad_s': measured(estimate.sigma_rad_s),
        'bias_deg_s': measured(np.rad2deg(estimate.bias_rad_s)),
        'sigma_deg_s': measured(np.rad2deg(estimate.sigma_rad_s)),
        'standard_error_deg_s': measured(np.rad2deg(estimate.bias_standard_error_rad_s)),
        'n_samples': estimate.n_samples,
        'window_s': [estimate.window_start_s, estimate.window_end_s],
        # What each LiDAR that followed poles through the window saw the platform turn.
        'scan_turns': [{'topic': turn.topic, 'rate_deg_s': math.degrees(turn.rate_rad_s),
                        'sigma_deg_s': math.degrees(turn.sigma_rad_s),
                        'ruled_out_beyond_deg_s': math.degrees(turn.ruled_out_rad_s),
                        'poles': turn.poles, 'scans': turn.scans}
                       for turn in estimate.scan_turns],
    }


def check_options(args: argparse.Namespace) -> None:
    """Refuse a window option out of CalibrationConfig's bounds, or several bags at once.

    Raises:
        GyroEkfError: one line naming the option, or the bags.
    """
    from gyro_ekf.cli.main import check_number

    for option, field in (('--window-start-s', 'window_start_s'),
                          ('--window-length-s', 'window_length_s')):
        check_number(option, getattr(args, field), *field_bounds(CalibrationConfig, field),
                     unit='s')
    bags = [p for p in args.source if is_bag(p)]
    if bags and len(args.source) > 1:
        raise GyroEkfError(f'{bags[0]}: calibrate takes one bag at a time (got '
                           f'{len(args.source)} sources); run it once per bag')


def run(args: argparse.Namespace) -> int:
    """Calibrate and print the per-axis bias; a refused window is an error (exit 1)."""
    check_options(args)
    trip = load_trip(args.source, skip_bad=args.skip_bad)
    config = CalibrationConfig(window_start_s=args.window_start_s,
                               window_length_s=args.window_length_s)
    try:
        estimate = calibrate_trip(trip, config, use_speed=not args.ignore_speed,
                                  use_scans=not args.ignore_scans)
    except CalibrationError as err:
        raise CalibrationError(f'{stream_name(args.source, err.stream)}: {err}',
                               err.stream) from None
    report = estimate_to_dict(estimate, trip.imu.axes_known)
    if args.json:
        # Standard JSON: a NaN would be a bug upstream, so refuse it rather than print it.
        print(json.dumps(report, indent=2, allow_nan=False))
        return 0
    print(f'{trip.name}: static window {estimate.window_start_s:.2f}-'
          f'{estimate.window_end_s:.2f} s, {estimate.n_samples} samples')
    print(f'{"axis":<5}{"bias [deg/s]":>14}{"sigma [deg/s]":>15}{"std err [deg/s]":>17}')
    for i, axis in enumerate('xyz'):
        if not trip.imu.axes_known[i]:
            print(f'{axis:<5}{"not measured":>14}')
            continue
        print(f'{axis:<5}{report["bias_deg_s"][i]:>14.4f}{report["sigma_deg_s"][i]:>15.4f}'
              f'{report["standard_error_deg_s"][i]:>17.4f}')
    for turn in report['scan_turns']:
        print(f"LiDAR '{turn['topic']}': turned {turn['rate_deg_s']:+.4f} +- "
              f"{turn['sigma_deg_s']:.4f} deg/s ({turn['poles']} poles through "
              f"{turn['scans']} scans): no turn in place beyond "
              f"{turn['ruled_out_beyond_deg_s']:.3f} deg/s, which the z bias would carry")
    if trip.scans and not report['scan_turns'] and not args.ignore_scans:
        print('LiDAR: no pole followed through the window; a turn in place is not checked')
    return 0
