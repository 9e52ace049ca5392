"""`gyro-ekf record`: record topics into a bag (a stand-in for `ros2 bag record`).

The bag is written where it stays (OUT/OUT.mcap) and made readable on disk every
`--flush-s` (`io.recording`), so a `kill -9` loses at most that much; SIGINT and SIGTERM
(also in a background job) finish it cleanly. It prints where the bag goes when it starts.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import time
from pathlib import Path

HELP = 'record topics into a rosbag2 folder (mcap, metadata version 9)'

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('topics', nargs='+', metavar='TOPIC[:TYPE]',
                        help='topics to record; a type like geometry_msgs/msg/Vector3Stamped '
                        'is discovered from the graph when not given')
    parser.add_argument('-o', '--output', type=Path, required=True, help='bag folder to create')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                        help='storage plugin')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing bag (never a folder holding other files)')
    parser.add_argument('--use-sim-time', action='store_true',
                        help='stamp messages with /clock time instead of the system clock')
    parser.add_argument('--duration-s', type=float, default=None,
                        help='stop after this much wall time')
    parser.add_argument('--idle-exit-s', type=float, default=None,
                        help='stop when no message arrived for this long (after the first; '
                        'with --use-sim-time, the first once /clock runs)')
    parser.add_argument('--flush-s', type=float, default=1.0,
                        help='make the bag readable on disk (index, metadata.yaml) this '
                        'often, s: what a kill -9 can lose')


def check_options(args: argparse.Namespace) -> None:
    """Refuse a --duration-s, --idle-exit-s or --flush-s that is not a positive number.

    Checked before the bag folder is claimed or rclpy starts.

    Raises:
        GyroEkfError: one line naming the option.
    """
    from gyro_ekf.cli.main import check_number

    for option, value in (('--duration-s', args.duration_s),
                          ('--idle-exit-s', args.idle_exit_s), ('--flush-s', args.flush_s)):
        check_number(option, value, 0.0, unit='s', above=True)


class BagSink:
    """Writes raw messages into the bag folder where it stays, checkpointed (io.recording)."""

    def __init__(self, path: Path, storage: str, force: bool, flush_s: float = 1.0):
        """Claim the folder (with force, replacing only an earlier bag) and start the bag.

        Raises:
            BagError: the output exists without force, holds something that is not part of
                a bag, or cannot be written.
        """
        from gyro_ekf.io.bag_writer import LATCHED_QOS, SENSOR_QOS, claim_bag_target
        from gyro_ekf.io.errors import BagError
        from gyro_ekf.io.products import os_reason
        from gyro_ekf.io.recording import RecordingBag

        claim_bag_target(path, force, sidecar=False)
        try:
            if path.exists():
                shutil.rmtree(path)  # an earlier bag only (checked above)
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise BagError(f'{path}: cannot record: {os_reason(err)}') from None
        self.path = path
        self._qos = {True: LATCHED_QOS, False: SENSOR_QOS}
        self._bag = RecordingBag(path, storage, flush_s)
        self.storage_file = self._bag.storage_file

    @property
    def count(self) -> int:
        """Messages written."""
        return self._bag.count

    def __call__(self, topic: str, msgtype: str, stamp_ns: int, data: bytes,
                 latched: bool) -> None:
        """Write one message."""
        self._bag.write(topic, msgtype, stamp_ns, data, self._qos[bool(latched)])

    def tick(self) -> None:
        """Checkpoint now and then (called from the spin loop)."""
        self._bag.tick()

    def close(self) -> Path:
        """Finish the bag in place."""
        return self._bag.close()

    def discard(self) -> Path:
        """Close and remove the bag (nothing was recorded)."""
        self._bag.close()
        shutil.rmtree(self.path, ignore_errors=True)
        return self.path


def run(args: argparse.Namespace) -> int:
    """Record until SIGINT/SIGTERM, --duration-s or --idle-exit-s; returns the exit code."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from gyro_ekf.cli.signals import StopRequest
    from gyro_ekf.errors import GyroEkfError
    from gyro_ekf.nodes.recorder import Recorder

    check_options(args)
    stop = StopRequest()
    sink = BagSink(args.output, args.storage, args.force, args.flush_s)
    print(f'recording into {sink.storage_file} (metadata.yaml refreshed every '
          f'{args.flush_s:g} s; if this process is killed, the bag holds what came before '
          f'the last refresh: `gyro-ekf reindex {args.output}` repairs a torn end)',
          flush=True)
    rclpy.init(args=['gyro-ekf-record', *args.ros_args],
               signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = Recorder(args.topics, sink, parameter_overrides=[
                Parameter('use_sim_time', value=bool(args.use_sim_time))])
        except ValueError as err:
            raise GyroEkfError(str(err)) from None
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        started = time.monotonic()
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.05)
            sink.tick()
            now = time.monotonic()
            if args.duration_s is not None and now - started >= args.duration_s:
                break
            if (args.idle_exit_s is not None and node.last_message is not None
                    and now - node.last_message >= args.idle_exit_s):
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        stop.requested = stop.requested or 'interrupt'
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        # Whatever ended the loop (a signal, an error), the bag is finished in place; one
        # that never got its node (a bad type) is removed.
        path = sink.close() if node is not None else sink.discard()
    counts = {t.name: t.count for t in node.recorded.values()} if node else {}
    log.info('%s: %d messages %s%s', path, sink.count, counts,
             f' (stopped by {stop.requested})' if stop else '')
    silent = [name for name, count in counts.items() if count == 0]
    if silent:
        log.warning('%s: no message on %s (not published while recording, or a misspelt '
                    'name?)', path, ', '.join(silent))
    return 0
