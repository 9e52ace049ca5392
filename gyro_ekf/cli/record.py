"""`gyro-ekf record`: record topics into a bag (a stand-in for `ros2 bag record`)."""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

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
    parser.add_argument('--force', action='store_true', help='replace an existing bag')
    parser.add_argument('--use-sim-time', action='store_true',
                        help='stamp messages with /clock time instead of the system clock')
    parser.add_argument('--duration-s', type=float, default=None,
                        help='stop after this much wall time')
    parser.add_argument('--idle-exit-s', type=float, default=None,
                        help='stop when no message arrived for this long (after the first)')


class BagSink:
    """Writes raw messages into a bag folder staged aside and renamed into place on close."""

    def __init__(self, path: Path, storage: str, force: bool):
        """Open a staged writer beside path.

        Raises:
            BagError: the output exists and force is not set.
        """
        from rosbags.rosbag2 import StoragePlugin, Writer

        from gyro_ekf.io.errors import BagError

        if path.exists() and not force:
            raise BagError(f'{path}: exists already; use --force to replace it')
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._aside = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.tmp',
                                            dir=path.parent))
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._writer = Writer(self._aside / path.name, version=9, storage_plugin=plugin)
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self.count = 0

    def __call__(self, topic: str, msgtype: str, stamp_ns: int, data: bytes,
                 latched: bool) -> None:
        """Write one message."""
        connection = self._connections.get(topic)
        if connection is None:
            from gyro_ekf.io import messages
            from gyro_ekf.io.bag_writer import LATCHED_QOS, SENSOR_QOS

            qos = LATCHED_QOS if latched else SENSOR_QOS
            connection = self._writer.add_connection(topic, msgtype,
                                                     typestore=messages.TYPESTORE,
                                                     offered_qos_profiles=[qos])
            self._connections[topic] = connection
        self._writer.write(connection, stamp_ns, data)
        self.count += 1

    def close(self) -> Path:
        """Finish the bag and move it into place."""
        try:
            self._writer.close()
            if self.path.exists():
                shutil.rmtree(self.path)
            os.replace(self._aside / self.path.name, self.path)
        finally:
            shutil.rmtree(self._aside, ignore_errors=True)
        return self.path

    def abort(self) -> None:
        """Drop the staged bag."""
        shutil.rmtree(self._aside, ignore_errors=True)


def run(args: argparse.Namespace) -> int:
    """Record until Ctrl-C, --duration-s or --idle-exit-s; returns the exit code."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from gyro_ekf.errors import GyroEkfError
    from gyro_ekf.nodes.recorder import Recorder

    sink = BagSink(args.output, args.storage, args.force)
    # SIGINT and SIGTERM end the loop below as KeyboardInterrupt, so the bag is closed.
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    rclpy.init(args=['gyro-ekf-record', *args.ros_args],
               signal_handler_options=SignalHandlerOptions.NO)
    node = None
    interrupted = False
    try:
        try:
            node = Recorder(args.topics, sink, parameter_overrides=[
                Parameter('use_sim_time', value=bool(args.use_sim_time))])
        except ValueError as err:
            raise GyroEkfError(str(err)) from None
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        started = time.monotonic()
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if args.duration_s is not None and now - started >= args.duration_s:
                break
            if (args.idle_exit_s is not None and node.last_message is not None
                    and now - node.last_message >= args.idle_exit_s):
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        interrupted = True
    except BaseException:
        sink.abort()
        raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    path = sink.close()
    counts = {t.name: t.count for t in node.recorded.values()} if node else {}
    log.info('%s: %d messages %s%s', path, sink.count, counts,
             ' (interrupted)' if interrupted else '')
    return 0
