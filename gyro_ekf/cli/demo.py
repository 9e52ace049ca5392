"""`gyro-ekf demo`: the three nodes on a replayed bag, recorded and summarised.

Starts calibration_node, one landmark_detector_node per LiDAR and ekf_node as separate
processes (use_sim_time, the bag's params sidecar, lossless QoS), records `gyro_bias`,
`ekf/pose`, `ekf/bias` and `/diagnostics` into OUTDIR/bag, replays the bag with /clock at a
speed-up, stops everything (SIGINT, then kill after a timeout) and prints a summary: offline
bias, calibration-node bias, online bias with its sigma, true bias and final position error.
It says what it is doing while it runs (a line per stage on stderr), writes the live
trajectory figure (OUTDIR/trajectory.png) and checks its own result (`verdict`): it exits 1
naming each problem when the online bias is more than 0.02 deg/s from the truth, the final
position error is above 5 cm, or ekf_node's diagnostics report a filter reset.

Discovery stays on this machine: every process gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
and a ROS_DOMAIN_ID (42 unless the environment sets one).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import subprocess
import sys
import time
from pathlib import Path

from gyro_ekf.errors import GyroEkfError

HELP = 'run the nodes on a replayed bag, record their output and print a summary'

log = logging.getLogger(__name__)

DEFAULT_DOMAIN_ID = '42'
RECORDED = ('gyro_bias', 'ekf/pose', 'ekf/bias', '/diagnostics')
BIAS_LIMIT_DEG_S = 0.02
"""Largest accepted distance of the online bias from the true bias, deg/s."""
POSITION_LIMIT_M = 0.05
"""Largest accepted final position error, m."""
END_LIMIT_S = 0.5
"""Largest accepted time between the last pose recorded and the bag's last gyro sample, s.

The recorder stops after a few seconds with no message; a node stalled that long after the
replay (a busy machine) would leave the recording short, and its last pose compared with the
truth at that earlier stamp. Published every ``publish_every_n`` samples, the last pose lies
within a few of them of the end."""
EKF_STATUS = 'ekf_node: gyro bias EKF'


def _say(text: str) -> None:
    """One progress line on stderr (the summary table goes to stdout)."""
    print(f'demo: {text}', file=sys.stderr, flush=True)


def verdict(summary: dict, bias_limit_deg_s: float = BIAS_LIMIT_DEG_S,
            position_limit_m: float = POSITION_LIMIT_M) -> list[str]:
    """List what is wrong with a demo's result; empty when it is right.

    Args:
        summary: the demo summary (`_summary`): online_bias_deg_s, true_bias_deg_s,
            final_position_error_m, ekf_resets, has_ground_truth, last_pose_s, bag_end_s.
        bias_limit_deg_s: largest accepted |online - true bias|, deg/s.
        position_limit_m: largest accepted final position error, m.

    Returns:
        One sentence per problem.
    """
    problems = []
    online, truth = summary.get('online_bias_deg_s'), summary.get('true_bias_deg_s')
    if online is None:
        problems.append('ekf_node published no bias (/ekf/bias not recorded)')
    elif truth is not None and not abs(online - truth) <= bias_limit_deg_s:
        problems.append(f'online bias {online:+.4f} deg/s is {abs(online - truth):.4f} deg/s '
                        f'from the true {truth:+.4f} (limit {bias_limit_deg_s:g})')
    error = summary.get('final_position_error_m')
    if error is None:
        if summary.get('has_ground_truth'):
            problems.append('no final position error: ekf_node published no pose '
                            '(/ekf/pose not recorded)')
    elif not error <= position_limit_m:
        problems.append(f'final position error {error:.3f} m is above {position_limit_m:g} m')
    last, end = summary.get('last_pose_s'), summary.get('bag_end_s')
    if last is not None and end is not None and not end - last <= END_LIMIT_S:
        # Every figure above is then of an earlier moment, not of the run's end.
        problems.append(f'the recording ends early: the last pose ekf_node published that '
                        f'was recorded is at {last:.3f} s, the bag\'s last gyro sample at '
                        f'{end:.3f} s ({end - last:.1f} s later, limit {END_LIMIT_S:g} s): a '
                        f'node stalled after the replay, or its output was lost')
    if summary.get('ekf_verdict') == 'failed':
        # The node's own health verdict: without ground truth the only judge of the pose.
        problems.append('ekf_node judged its run failed: '
                        + (summary.get('ekf_verdict_reasons') or 'no reason given'))
    resets = summary.get('ekf_resets')
    if resets is None:
        problems.append("no diagnostics from ekf_node: its filter resets are unknown")
    elif resets > 0:
        problems.append(f'ekf_node reset its filter {resets} time(s) '
                        '(see ekf_node.log for the reason)')
    return problems


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
    parser.add_argument('--force', action='store_true',
                        help='write into a non-empty output folder, replacing the products '
                        'of an earlier demo (never other files; its summary.json and '
                        'trajectory.png are removed at the start, so a demo that fails '
                        'leaves none behind)')


def check_options(args: argparse.Namespace) -> None:
    """Refuse a bad --rate, --timeout-s or --publish-every-n before anything starts.

    Raises:
        GyroEkfError: one line naming the option.
    """
    from gyro_ekf.cli.main import check_number

    check_number('--rate', args.rate, 0.0)
    check_number('--timeout-s', args.timeout_s, 0.0, unit='s', above=True)
    check_number('--publish-every-n', args.publish_every_n, 1)


def _environment(output: Path) -> dict[str, str]:
    """Build the environment of every process: loopback discovery, a domain, a log dir.

    The domain is the environment's ROS_DOMAIN_ID (the Makefile's GYRO_EKF_DOMAIN_ID), else
    DEFAULT_DOMAIN_ID; the log dir the environment's ROS_LOG_DIR, else output/ros_log.
    """
    from gyro_ekf.ros_env import child_env

    domain = int(os.environ.get('ROS_DOMAIN_ID') or DEFAULT_DOMAIN_ID)
    return child_env(domain, os.environ.get('ROS_LOG_DIR') or output / 'ros_log')


def _config_file() -> Path | None:
    """config/gyro_ekf.yaml from the source tree or the ament share folder."""
    import gyro_ekf

    candidates = [Path(gyro_ekf.__file__).resolve().parents[1] / 'config' / 'gyro_ekf.yaml',
                  Path(sys.prefix) / 'share' / 'gyro_ekf' / 'config' / 'gyro_ekf.yaml']
    return next((p for p in candidates if p.exists()), None)


def _wait_for_recorder(env: dict[str, str], timeout_s: float) -> None:
    """Wait until the recorder subscribed to the node outputs (graph discovery)."""
    import rclpy

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
    from gyro_ekf.io.results import write_summary_json
    from gyro_ekf.core.stamps import seconds_since
    from gyro_ekf.ros_env import ChildProcesses

    from gyro_ekf.io.output_dir import prepare_demo_dir

    check_options(args)
    started = time.monotonic()
    bag: Path = args.bag
    if not (bag / 'metadata.yaml').exists():
        raise BagError(f'{bag}: no such bag (make it with `make bags` or `gyro-ekf simulate`)')
    params = read_sidecar(bag)
    output = prepare_demo_dir(args.output, force=args.force)
    for product in ('summary.json', 'trajectory.png'):
        # An earlier demo's verdict must not outlive this one: a demo that fails before
        # writing its own would leave that one's "ok" beside its new logs.
        (output / product).unlink(missing_ok=True)
    env = _environment(output)
    log.info('discovery: %s, ROS_DOMAIN_ID %s', env['ROS_AUTOMATIC_DISCOVERY_RANGE'],
             env['ROS_DOMAIN_ID'])
    scan_topics = list(params.lidars) if params is not None and params.lidars else ['scan']
    node_args = ['-p', 'use_sim_time:=true', '-p', 'reliable_inputs:=true']
    files = [str(f) for f in (_config_file(), bag.parent / (bag.name + '.params.yaml'))
             if f is not None and f.exists()]
    params_files = [arg for f in files for arg in ('--params-file', f)]
    group = ChildProcesses(env, output)
    _say(f'starting calibration_node, {len(scan_topics)} landmark detector(s), ekf_node and '
         f'the recorder (logs in {output})')
    try:
        group.start('calibration_node', 'gyro_ekf.nodes.calibration_node', '--ros-args',
                    *params_files, *node_args)
        for topic in scan_topics:
            group.start(f'landmark_detector_{topic}', *[
                'gyro_ekf.nodes.landmark_detector_node', '--ros-args', *params_files,
                *node_args, '-r', f'scan:={topic}', '-r', f'__node:=landmark_detector_{topic}'])
        group.start('ekf_node', *[
            'gyro_ekf.nodes.ekf_node', '--ros-args', *params_files, *node_args,
            '-p', 'use_calibration:=true', '-p', f'publish_every_n:={args.publish_every_n}'])
        recorder = group.start('record', *[
            'gyro_ekf.cli.main', 'record', *RECORDED, '-o', str(output / 'bag'), '--force',
            '--use-sim-time', '--idle-exit-s', '3'])
        _say('waiting for the nodes and the recorder to discover each other')
        _wait_for_recorder(env, 30.0)
        present = {t.name.lstrip('/') for t in bag_summary(bag).topics}
        latched = [t for t in ('landmark_map', 'initialpose') if t in present]
        replay_args = ['gyro_ekf.cli.main', 'replay', str(bag), '--rate', str(args.rate),
                       '--clock', '--topics', 'imu', 'odom', *scan_topics, *latched,
                       '--wait-for', 'imu:2', '--wait-for', 'odom:2']
        replay_args += [arg for t in scan_topics for arg in ('--wait-for', f'{t}:1')]
        replay = group.start('replay', *replay_args)
        duration_s = seconds_since(bag_summary(bag).duration_ns, 0)
        code = _wait_replay(replay, bag, args, duration_s)
        if code != 0:
            raise BagError(f'{bag}: the replay failed (exit {code}); see '
                           f'{output / "replay.log"}')
        _say('replay done; waiting for the recorder to see the outputs settle')
        recorder.wait(timeout=60)
    finally:
        _say('stopping the nodes')
        group.stop_all(
            on_kill=lambda name: log.warning('%s did not stop on SIGINT; killing it', name))
    _say('reading the recorded bag')
    summary = _summary(bag, output / 'bag', params)
    summary['wall_time_s'] = round(time.monotonic() - started, 1)
    summary['replay'] = (output / 'replay.log').read_text().strip().splitlines()[-1]
    pose_xy = summary.pop('pose_xy_m')
    trip = summary.pop('trip')
    problems = verdict(summary)
    summary['verdict'] = {'ok': not problems, 'problems': problems,
                          'bias_limit_deg_s': BIAS_LIMIT_DEG_S,
                          'position_limit_m': POSITION_LIMIT_M}
    if len(pose_xy):
        from gyro_ekf.analysis.plots import plot_live_trajectory

        figure = plot_live_trajectory(trip, pose_xy, output / 'trajectory.png',
                                      f'{trip.name}: live ekf_node at x{args.rate:g}')
        _say(f'wrote {figure}')
    write_summary_json(output / 'summary.json', summary)
    _print(summary)
    if problems:
        raise DemoFailed('the result is wrong: ' + '; '.join(problems)
                         + f' (details in {output})')
    print(f'verdict: OK ({ok_clauses(summary)})')
    return 0


def ok_clauses(summary: dict) -> str:
    """Say what an OK demo was checked against: the truth only where the bag has it."""
    checked = []
    if summary.get('true_bias_deg_s') is not None:
        checked.append(f'online bias within {BIAS_LIMIT_DEG_S:g} deg/s of the truth')
    if summary.get('final_position_error_m') is not None:
        checked.append(f'final position within {POSITION_LIMIT_M * 100:g} cm')
    if not checked:
        checked.append('the bag has no ground truth nor true bias to compare with')
    checked.append(f"ekf_node's health verdict {summary.get('ekf_verdict') or 'unknown'}")
    checked.append('no filter reset')
    return ', '.join(checked)


class DemoFailed(GyroEkfError):
    """The demo ran but its own result is wrong (see `verdict`)."""


def _wait_replay(replay: subprocess.Popen, bag: Path, args: argparse.Namespace,
                 duration_s: float) -> int:
    """Wait for the replay, saying every few seconds how far it should be; its exit code."""
    from gyro_ekf.io.errors import BagError

    expected_s = duration_s / args.rate if args.rate > 0 else 0.0
    _say(f'replaying {bag} ({duration_s:.0f} s of data) at x{args.rate:g}: about '
         f'{expected_s:.0f} s')
    began = time.monotonic()
    while True:
        try:
            return replay.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            elapsed = time.monotonic() - began
            if elapsed > args.timeout_s:
                raise BagError(f'{bag}: the replay did not finish within {args.timeout_s} s'
                               ) from None
            _say(f'replaying: {elapsed:.0f} s of about {expected_s:.0f} s')


def _summary(bag: Path, recorded: Path, params) -> dict:
    import numpy as np

    from gyro_ekf.core.calibration import calibrate_trip
    from gyro_ekf.core.errors import CalibrationError
    from gyro_ekf.core.stamps import seconds_since
    from gyro_ekf.io import iter_bag_messages, read_bag
    from gyro_ekf.io.messages import from_time

    bag_trip = read_bag(bag)
    trip = bag_trip.trip
    summary: dict = {'bag': str(bag), 'recorded': str(recorded)}
    try:
        offline = calibrate_trip(trip)
        summary['offline_bias_deg_s'] = math.degrees(offline.bias_rad_s[2])
    except CalibrationError as err:
        summary['offline_bias_deg_s'] = None
        summary['offline_note'] = str(err)
    last: dict = {}
    pose_xy = []
    resets = None
    for message in iter_bag_messages(recorded):
        if message.topic == '/diagnostics':
            for status in message.message.status:
                if status.name.endswith(EKF_STATUS):
                    last['diagnostics'] = {kv.key: kv.value for kv in status.values}
                    # Cumulative in the node; the largest seen counts (the last may be lost).
                    resets = max(resets or 0, int(last['diagnostics'].get('resets', 0)))
        else:
            last[message.topic] = message.message
            if message.topic == '/ekf/pose':
                position = message.message.pose.pose.position
                pose_xy.append((position.x, position.y))
    summary['ekf_resets'] = resets
    summary['has_ground_truth'] = trip.ground_truth is not None
    if len(trip.imu.stamp_s):
        summary['bag_end_s'] = float(trip.imu.stamp_s[-1])
    summary['pose_xy_m'] = np.array(pose_xy, dtype=np.float64).reshape(-1, 2)
    summary['trip'] = trip
    if '/gyro_bias' in last:
        summary['calibration_node_bias_deg_s'] = math.degrees(last['/gyro_bias'].vector.z)
    if '/ekf/bias' in last:
        summary['online_bias_deg_s'] = math.degrees(last['/ekf/bias'].vector.z)
    if 'diagnostics' in last:
        summary['online_bias_sigma_deg_s'] = float(last['diagnostics']['bias_sigma_deg_s'])
        summary['ekf_verdict'] = last['diagnostics'].get('verdict')
        summary['ekf_verdict_reasons'] = last['diagnostics'].get('verdict_reasons', '')
    if params is not None and params.true_gyro_bias_rad_s is not None:
        summary['true_bias_deg_s'] = math.degrees(params.true_gyro_bias_rad_s[2])
    pose = last.get('/ekf/pose')
    if pose is not None:
        summary['last_pose_s'] = seconds_since(from_time(pose.header.stamp),
                                               bag_trip.start_time_ns)
    if pose is not None and trip.ground_truth is not None:
        stamp_s = summary['last_pose_s']
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
        ('ekf_node filter resets', '-' if summary.get('ekf_resets') is None
         else str(summary['ekf_resets'])),
        ('wall time', f'{summary["wall_time_s"]:.1f} s'),
    ]
    width = max(len(name) for name, _ in rows)
    print('\n'.join(f'{name:<{width}}  {value}' for name, value in rows))
    print(summary['replay'])
