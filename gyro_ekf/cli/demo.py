"""`gyro-ekf demo`: the three nodes on a replayed bag, recorded and summarised.

Starts calibration_node, one landmark_detector_node per LiDAR and ekf_node as separate
processes (use_sim_time, the bag's params sidecar, lossless QoS), records `gyro_bias`,
`ekf/pose`, `ekf/bias` and `/diagnostics` into OUTDIR/bag, replays the bag with /clock at a
speed-up, stops everything (SIGINT, then kill after a timeout) and prints a summary: offline
bias, calibration-node bias, online bias with its sigma, true bias and final position error.

Discovery stays on this machine: every process gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
and a ROS_DOMAIN_ID (42 unless the environment sets one).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

HELP = 'run the nodes on a replayed bag, record their output and print a summary'

log = logging.getLogger(__name__)

DEFAULT_DOMAIN_ID = '42'
RECORDED = ('gyro_bias', 'ekf/pose', 'ekf/bias', '/diagnostics')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, help='bag folder written by gyro-ekf (with sidecar)')
    parser.add_argument('-o', '--output', type=Path, required=True,
                        help='output folder (recorded bag, logs, summary.json)')
    parser.add_argument('--rate', type=float, default=6.0,
                        help='replay speed-up factor (about what 2 cores sustain)')
    parser.add_argument('--timeout-s', type=float, default=300.0,
                        help='give up on the replay after this long')
    parser.add_argument('--publish-every-n', type=int, default=4,
                        help='EKF publishes every n-th estimate (one per IMU sample)')


def _environment(output: Path) -> dict[str, str]:
    """Build the environment of every process: loopback discovery, a domain, a log dir."""
    import gyro_ekf

    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = env.get('ROS_AUTOMATIC_DISCOVERY_RANGE') or \
        'LOCALHOST'
    env['ROS_DOMAIN_ID'] = env.get('ROS_DOMAIN_ID') or DEFAULT_DOMAIN_ID
    env.setdefault('ROS_LOG_DIR', str(output / 'ros_log'))
    env['PYTHONUNBUFFERED'] = '1'
    package_root = str(Path(gyro_ekf.__file__).resolve().parents[1])
    env['PYTHONPATH'] = os.pathsep.join(p for p in (package_root, env.get('PYTHONPATH')) if p)
    return env


def _config_file() -> Path | None:
    """config/gyro_ekf.yaml from the source tree or the ament share folder."""
    import gyro_ekf

    candidates = [Path(gyro_ekf.__file__).resolve().parents[1] / 'config' / 'gyro_ekf.yaml',
                  Path(sys.prefix) / 'share' / 'gyro_ekf' / 'config' / 'gyro_ekf.yaml']
    return next((p for p in candidates if p.exists()), None)


class _Group:
    """Child processes with their logs; stopped with SIGINT, then killed."""

    def __init__(self, env: dict[str, str], log_dir: Path):
        self.env = env
        self.log_dir = log_dir
        self.children: list[tuple[str, subprocess.Popen]] = []

    def start(self, name: str, args: list[str]) -> subprocess.Popen:
        with (self.log_dir / f'{name}.log').open('w') as out:
            child = subprocess.Popen([sys.executable, '-m', *args], env=self.env, stdout=out,
                                     stderr=subprocess.STDOUT)
        self.children.append((name, child))
        return child

    def stop(self, timeout_s: float = 10.0) -> None:
        for _, child in self.children:
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for name, child in self.children:
            try:
                child.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning('%s did not stop on SIGINT; killing it', name)
                child.kill()
                child.wait()


def _wait_for_recorder(env: dict[str, str], timeout_s: float) -> None:
    """Wait until the recorder subscribed to the node outputs (graph discovery)."""
    import rclpy

    from gyro_ekf.errors import GyroEkfError

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('gyro_ekf_demo', context=context)
    try:
        deadline = time.monotonic() + timeout_s
        topics = ['/gyro_bias', '/ekf/pose', '/ekf/bias']
        while any(node.count_subscribers(t) < 1 for t in topics):
            if time.monotonic() > deadline:
                raise GyroEkfError(f'the recorder did not subscribe to {topics} within '
                                   f'{timeout_s} s')
            time.sleep(0.02)
    finally:
        node.destroy_node()
        context.try_shutdown()


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns the exit code."""
    from gyro_ekf.io import bag_summary, read_sidecar
    from gyro_ekf.io.errors import BagError

    started = time.monotonic()
    bag: Path = args.bag
    if not (bag / 'metadata.yaml').exists():
        raise BagError(f'{bag}: no such bag (make it with `make bags` or `gyro-ekf simulate`)')
    params = read_sidecar(bag)
    output: Path = args.output
    output.mkdir(parents=True, exist_ok=True)
    env = _environment(output)
    log.info('discovery: %s, ROS_DOMAIN_ID %s', env['ROS_AUTOMATIC_DISCOVERY_RANGE'],
             env['ROS_DOMAIN_ID'])
    scan_topics = list(params.lidars) if params is not None and params.lidars else ['scan']
    node_args = ['-p', 'use_sim_time:=true', '-p', 'reliable_inputs:=true']
    files = [str(f) for f in (_config_file(), bag.parent / (bag.name + '.params.yaml'))
             if f is not None and f.exists()]
    params_files = [arg for f in files for arg in ('--params-file', f)]
    group = _Group(env, output)
    try:
        group.start('calibration_node', ['gyro_ekf.nodes.calibration_node', '--ros-args',
                                         *params_files, *node_args])
        for topic in scan_topics:
            group.start(f'landmark_detector_{topic}', [
                'gyro_ekf.nodes.landmark_detector_node', '--ros-args', *params_files,
                *node_args, '-r', f'scan:={topic}', '-r', f'__node:=landmark_detector_{topic}'])
        group.start('ekf_node', [
            'gyro_ekf.nodes.ekf_node', '--ros-args', *params_files, *node_args,
            '-p', 'use_calibration:=true', '-p', 'reorder_window_s:=1.0',
            '-p', f'publish_every_n:={args.publish_every_n}'])
        recorder = group.start('record', [
            'gyro_ekf.cli.main', 'record', *RECORDED, '-o', str(output / 'bag'), '--force',
            '--use-sim-time', '--idle-exit-s', '3'])
        _wait_for_recorder(env, 30.0)
        present = {t.name.lstrip('/') for t in bag_summary(bag).topics}
        latched = [t for t in ('landmark_map', 'initialpose') if t in present]
        replay_args = ['gyro_ekf.cli.main', 'replay', str(bag), '--rate', str(args.rate),
                       '--clock', '--topics', 'imu', 'odom', *scan_topics, *latched,
                       '--wait-for', 'imu:2', '--wait-for', 'odom:2']
        replay_args += [arg for t in scan_topics for arg in ('--wait-for', f'{t}:1')]
        replay = group.start('replay', replay_args)
        try:
            code = replay.wait(timeout=args.timeout_s)
        except subprocess.TimeoutExpired:
            raise BagError(f'{bag}: the replay did not finish within {args.timeout_s} s') from None
        if code != 0:
            raise BagError(f'{bag}: the replay failed (exit {code}); see '
                           f'{output / "replay.log"}')
        recorder.wait(timeout=60)
    finally:
        group.stop()
    summary = _summary(bag, output / 'bag', params)
    summary['wall_time_s'] = round(time.monotonic() - started, 1)
    summary['replay'] = (output / 'replay.log').read_text().strip().splitlines()[-1]
    (output / 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')
    _print(summary)
    return 0


def _summary(bag: Path, recorded: Path, params) -> dict:
    import numpy as np

    from gyro_ekf.core.calibration import estimate_gyro_bias
    from gyro_ekf.core.errors import CalibrationError
    from gyro_ekf.io import iter_bag_messages, read_bag
    from gyro_ekf.io.messages import from_time

    bag_trip = read_bag(bag)
    trip = bag_trip.trip
    summary: dict = {'bag': str(bag), 'recorded': str(recorded)}
    try:
        offline = estimate_gyro_bias(trip.imu.stamp_s, trip.imu.angular_velocity_rad_s,
                                     speed_stamp_s=trip.speed.stamp_s,
                                     speed_m_s=trip.speed.speed_m_s,
                                     axes_known=trip.imu.axes_known)
        summary['offline_bias_deg_s'] = math.degrees(offline.bias_rad_s[2])
    except CalibrationError as err:
        summary['offline_bias_deg_s'] = None
        summary['offline_note'] = str(err)
    last: dict = {}
    for message in iter_bag_messages(recorded):
        if message.topic == '/diagnostics':
            for status in message.message.status:
                if status.name.endswith('ekf_node: gyro bias EKF'):
                    last['diagnostics'] = {kv.key: kv.value for kv in status.values}
        else:
            last[message.topic] = message.message
    if '/gyro_bias' in last:
        summary['calibration_node_bias_deg_s'] = math.degrees(last['/gyro_bias'].vector.z)
    if '/ekf/bias' in last:
        summary['online_bias_deg_s'] = math.degrees(last['/ekf/bias'].vector.z)
    if 'diagnostics' in last:
        summary['online_bias_sigma_deg_s'] = float(last['diagnostics']['bias_sigma_deg_s'])
    if params is not None and params.true_gyro_bias_rad_s is not None:
        summary['true_bias_deg_s'] = math.degrees(params.true_gyro_bias_rad_s[2])
    pose = last.get('/ekf/pose')
    if pose is not None and trip.ground_truth is not None:
        stamp_s = (from_time(pose.header.stamp) - bag_trip.start_time_ns) / 1e9
        truth = trip.ground_truth
        x = np.interp(stamp_s, truth.stamp_s, truth.pose[:, 0])
        y = np.interp(stamp_s, truth.stamp_s, truth.pose[:, 1])
        summary['final_stamp_s'] = stamp_s
        summary['final_position_error_m'] = float(math.hypot(
            pose.pose.pose.position.x - x, pose.pose.pose.position.y - y))
    return summary


def _print(summary: dict) -> None:
    def number(key: str, unit: str, digits: int = 4) -> str:
        value = summary.get(key)
        return '-' if value is None else f'{value:+.{digits}f} {unit}'

    sigma = summary.get('online_bias_sigma_deg_s')
    rows = [
        ('offline bias (static window, core)', number('offline_bias_deg_s', 'deg/s')),
        ('calibration_node bias', number('calibration_node_bias_deg_s', 'deg/s')),
        ('online bias (ekf_node)', number('online_bias_deg_s', 'deg/s')
         + ('' if sigma is None else f' +- {sigma:.4f} (1 sigma)')),
        ('true bias', number('true_bias_deg_s', 'deg/s')),
        ('final position error', number('final_position_error_m', 'm', 3)),
        ('wall time', f'{summary["wall_time_s"]:.1f} s'),
    ]
    width = max(len(name) for name, _ in rows)
    print('\n'.join(f'{name:<{width}}  {value}' for name, value in rows))
    print(summary['replay'])
