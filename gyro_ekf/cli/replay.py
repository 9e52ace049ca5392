"""`gyro-ekf replay`: publish a bag over DDS (a stand-in for `ros2 bag play`)."""

from __future__ import annotations

import argparse
import logging
import re
from collections.abc import Iterator
from pathlib import Path

from gyro_ekf.core.stamps import NS_PER_S

HELP = 'publish a bag over DDS with its recorded QoS and, with --clock, /clock'

log = logging.getLogger(__name__)


def _wait_spec(text: str) -> tuple[str | None, int]:
    """Parse N (every topic) or TOPIC:N."""
    match = re.fullmatch(r'(?:(.+):)?(\d+)', text)
    if not match:
        raise argparse.ArgumentTypeError(f'expected N or TOPIC:N, got {text!r}')
    return match.group(1), int(match.group(2))


def _rate(text: str) -> float:
    value = float(text)
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def _positive(text: str) -> float:
    value = float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f'must be > 0, got {text}')
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be >= 1, got {text}')
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""
    parser.add_argument('bag', type=Path, help='rosbag2 folder (mcap or sqlite3)')
    parser.add_argument('--rate', type=_rate, default=1.0,
                        help='speed-up factor; 0 publishes as fast as possible')
    parser.add_argument('--clock', action='store_true',
                        help='publish /clock from the bag stamps (for use_sim_time)')
    parser.add_argument('--clock-hz', type=float, default=100.0,
                        help='/clock messages per second of bag time')
    parser.add_argument('--loop', action='store_true',
                        help='start over at the end, until SIGINT/SIGTERM')
    parser.add_argument('--loops', type=_count, default=None, metavar='N',
                        help='with or without --loop: stop after N passes over the bag')
    parser.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='replay only these topics (default: all)')
    parser.add_argument('--start-s', type=float, default=0.0,
                        help='skip this much of the bag (latched topics are still sent)')
    parser.add_argument('--duration-s', type=float, default=None,
                        help='replay only this much bag time after --start-s')
    parser.add_argument('--wait-for', type=_wait_spec, action='append', default=[],
                        metavar='N|TOPIC:N',
                        help='before starting, wait until every topic (or TOPIC) has N '
                        'matched subscriptions; repeatable')
    parser.add_argument('--wait-timeout-s', type=float, default=10.0,
                        help='give up waiting for subscribers after this long')
    parser.add_argument('--no-verify', action='store_true',
                        help='publish without first reading the whole bag through to check '
                        'its bytes (CRCs, lengths, log times; about 1-2 s per hour of bag): '
                        'damage then ends the replay only when it is reached, after the '
                        'messages before it were published')
    parser.add_argument('--ack-timeout-s', type=_positive, default=30.0,
                        help='longest wait for reliable readers to acknowledge: while one '
                        'holds the replay back (its history full), and at the end for every '
                        'message; exceeded, the replay fails naming the topic')


def check_options(args: argparse.Namespace) -> None:
    """Refuse bad numbers before the bag is opened or rclpy starts (one line each).

    --start-s beyond the bag's end is refused by BagSource, which knows its duration.

    Raises:
        GyroEkfError: naming the option.
    """
    from gyro_ekf.cli.main import check_number

    check_number('--start-s', args.start_s, 0.0, unit='s')
    check_number('--duration-s', args.duration_s, 0.0, unit='s', above=True)
    check_number('--clock-hz', args.clock_hz, 0.0, unit='Hz', above=True)
    check_number('--wait-timeout-s', args.wait_timeout_s, 0.0, unit='s')
    check_number('--rate', args.rate, 0.0)


class BagSource:
    """Raw messages of a bag in stamp order, re-iterable (for --loop).

    The bag's bytes are checked when it is opened, as `info` and `run` check them, so a
    damaged bag is refused before a message is published (`verify` false, `--no-verify`,
    skips that read); reading is still guarded, since a bag the check cannot cover
    (sqlite3), one changed since or one not checked can fail mid-replay. A params file
    beside the bag written with another bag is refused too: the nodes given it with the
    replay would run this trip with another's pose, mounts and noise.
    """

    def __init__(self, path: Path, topic_names: list[str] | None, start_s: float,
                 duration_s: float | None, verify: bool = True):
        """Check the bag's bytes (unless verify is false), open its metadata, choose topics.

        Raises:
            BagError: missing, unreadable or damaged bag (a CRC mismatch names the file and
                the chunk's offset), a requested topic it lacks, or a params file beside it
                that cannot be read or was written with another bag.
        """
        from rosbags.interfaces import QosDurability, QosReliability
        from rosbags.rosbag2 import Reader
        from rosbags.rosbag2.errors import ReaderError

        from gyro_ekf.errors import one_line
        from gyro_ekf.io.bag_info import verify_bag
        from gyro_ekf.io.errors import BagError
        from gyro_ekf.io.sidecar import read_sidecar
        from gyro_ekf.nodes.replayer import ReplayTopic

        self.path = path
        if not (path / 'metadata.yaml').exists():
            raise BagError(f'{path}: not a rosbag2 folder (no metadata.yaml)')
        # rosbags finds a damaged chunk only when it reaches it, after every message before
        # it is published. Reading the whole bag first costs about 0.5 s per hour of
        # uncompressed bag (io/bag_info.py): 0.06-0.15 s for the 2016 log's 76 MB.
        if verify:
            verify_bag(path)
        read_sidecar(path)
        try:
            with Reader(path) as reader:
                connections = list(reader.connections)
                self.start_ns = reader.start_time
                self.duration_ns = reader.duration if reader.message_count else 0
        except (ReaderError, OSError, KeyError, ValueError) as err:
            # One line: without the check a YAML error in metadata.yaml first shows here.
            raise BagError(f'{path}: cannot read the bag: {one_line(err)}') from None
        present = {c.topic for c in connections}
        if topic_names:
            wanted = {t if t.startswith('/') else '/' + t for t in topic_names}
            missing = sorted(wanted - present)
            if missing:
                raise BagError(f"{path}: no topic '{missing[0]}' (the bag has "
                               f'{sorted(present)})')
            connections = [c for c in connections if c.topic in wanted]
        self.connections = connections
        self.topics = []
        for connection in connections:
            profiles = getattr(connection.ext, 'offered_qos_profiles', []) or []
            latched = any(p.durability == QosDurability.TRANSIENT_LOCAL for p in profiles)
            reliable = not profiles or all(
                p.reliability != QosReliability.BEST_EFFORT for p in profiles)
            self.topics.append(ReplayTopic(connection.topic, connection.msgtype, latched,
                                           reliable))
        self.latched = {t.name for t in self.topics if t.latched}
        bag_s = self.duration_ns / NS_PER_S
        if start_s > bag_s:
            raise BagError(f'--start-s: {start_s:g} s is beyond the end of {path} (the bag '
                           f'lasts {bag_s:.3f} s)')
        self.from_ns = self.start_ns + int(start_s * NS_PER_S)
        self.until_ns = (None if duration_s is None
                         else self.from_ns + int(duration_s * NS_PER_S))

    def __call__(self) -> Iterator[tuple[str, int, bytes]]:
        """Iterate afresh over (topic, stamp ns, CDR bytes) in stamp order.

        Raises:
            BagError: the bag cannot be read on (naming it, and how many messages of this
                pass were handed out before).
        """
        from rosbags.rosbag2 import Reader

        from gyro_ekf.io.bag_open import reading
        from gyro_ekf.io.errors import BagError

        held: dict[str, tuple[str, int, bytes]] = {}
        sent = 0
        try:
            # Whatever rosbags raises on bytes it cannot read (ReaderError, ZstdError, ...)
            # becomes a BagError naming the bag: one line, not a traceback.
            with reading(self.path), Reader(self.path) as reader:
                for connection, stamp, data in reader.messages(connections=self.connections):
                    if stamp < self.from_ns:
                        if connection.topic in self.latched:
                            held[connection.topic] = (connection.topic, stamp, bytes(data))
                        continue
                    if held:
                        for message in sorted(held.values(), key=lambda m: m[1]):
                            yield message
                            sent += 1
                        held.clear()
                    if self.until_ns is not None and stamp > self.until_ns:
                        return
                    yield connection.topic, stamp, bytes(data)
                    sent += 1
        except BagError as err:
            # The messages before the damage are out already: say how far the replay got.
            raise BagError(f'{err} (the replay stopped after {sent} messages of this pass)'
                           ) from None


def run(args: argparse.Namespace) -> int:
    """Replay the bag; returns the exit code."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    from gyro_ekf.cli.signals import StopRequest
    from gyro_ekf.errors import GyroEkfError
    from gyro_ekf.nodes.replayer import Replayer

    # SIGINT/SIGTERM end the replay between two messages: the summary is still printed.
    check_options(args)
    stop = StopRequest()
    source = BagSource(args.bag, args.topics, args.start_s, args.duration_s,
                       verify=not args.no_verify)
    rclpy.init(args=['gyro-ekf-replay', *args.ros_args],
               signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = Replayer(source.topics, args.clock)
        except ValueError as err:
            raise GyroEkfError(f'{args.bag}: {err}') from None
        node.stop = stop
        node.backpressure_timeout_s = args.ack_timeout_s
        needs: dict[str, int] = {}
        for topic, count in args.wait_for:
            names = [t.name for t in source.topics if not t.latched] if topic is None else [
                topic if topic.startswith('/') else '/' + topic]
            for name in names:
                if name not in node.publishers_by_topic:
                    raise GyroEkfError(f'--wait-for: topic {name!r} is not replayed')
                needs[name] = max(needs.get(name, 0), count)
        short = node.wait_for_subscribers(
            needs, args.wait_timeout_s,
            lambda name, count, need: log.info('--wait-for: %s has %d of %d subscribers',
                                               name, count, need))
        if stop:
            log.info('stopped by %s before the replay began', stop.requested)
            return 0
        if short:
            raise GyroEkfError(f'subscribers did not appear within {args.wait_timeout_s} s: '
                               + ', '.join(f'{k} has {v} of {needs[k]}'
                                           for k, v in short.items()))
        report = node.play(source, args.rate, args.loop or args.loops is not None,
                           args.clock_hz, ack_timeout_s=args.ack_timeout_s,
                           max_loops=args.loops)
        print(report.summary(), flush=True)
        # A stop request is the normal end of --loop; then unacknowledged messages of a
        # reader that was still busy are no failure.
        if report.acknowledged or stop:
            return 0
        raise GyroEkfError(f'reliable readers of {", ".join(report.unacknowledged)} did not '
                           f'acknowledge every message within --ack-timeout-s '
                           f'{args.ack_timeout_s:g} s (a stuck or frozen subscriber?)')
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
