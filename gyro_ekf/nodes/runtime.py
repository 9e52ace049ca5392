"""The Jazzy entry-point pattern shared by the node executables."""

from __future__ import annotations

import os
from pathlib import Path
import sys
import time
from collections.abc import Callable

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
# rclpy exports the C layer's error class only from its extension module.
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.task import Future

from gyro_ekf.errors import GyroEkfError
from gyro_ekf.nodes import wire

_SPIN_RETURN_S = 0.2
"""Longest time the EventsExecutor blocks in C++ before Python may handle a signal, s."""

_DRAIN_S = 0.0003
"""How long a batch's events are served after its gathering pause (event_batch_s), s."""

_BACKLOG_S = 0.0001
"""An event served sooner than this after the executor was asked was already waiting, s."""

FASTDDS_PROFILES_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
"""Fast DDS 2.x (Jazzy's rmw_fastrtps) reads its default XML profiles from this file."""

FASTDDS_WRITER_PROFILE = Path(__file__).with_name('fastdds_writer.xml')
"""The node processes' default writer profile: NACK suppression 10 ms (see the file)."""


def use_writer_profile(environ=os.environ, cwd: Path | None = None) -> bool:
    """Point Fast DDS at FASTDDS_WRITER_PROFILE unless the user configures Fast DDS.

    The user does when FASTRTPS_DEFAULT_PROFILES_FILE is set, when the working directory
    holds a DEFAULT_FASTRTPS_PROFILES.xml (Fast DDS loads that one too), or when
    RMW_FASTRTPS_USE_QOS_FROM_XML is set (rmw would then take the QoS from the XML
    profiles, which this file leaves out). Must run before rclpy.init (Fast DDS reads the
    file when it creates the participant). Returns whether the variable was set here.
    """
    cwd = Path.cwd() if cwd is None else cwd
    if (environ.get(FASTDDS_PROFILES_VARIABLE) or environ.get('RMW_FASTRTPS_USE_QOS_FROM_XML')
            or (cwd / 'DEFAULT_FASTRTPS_PROFILES.xml').exists()
            or not FASTDDS_WRITER_PROFILE.is_file()):
        return False
    environ[FASTDDS_PROFILES_VARIABLE] = str(FASTDDS_WRITER_PROFILE)
    return True


def params_files(argv: list[str]) -> list[str]:
    """Return the files given with --params-file among the ROS arguments of a command line."""
    files = []
    inside = False
    for i, arg in enumerate(argv):
        if arg == '--ros-args':
            inside = True
        elif arg == '--':
            inside = False
        elif inside and arg == '--params-file' and i + 1 < len(argv):
            files.append(argv[i + 1])
    return files


def params_file_problem(path: str) -> str | None:
    """Say in one line why rcl would refuse a --params-file (None when it may be fine).

    Covers what rcl's parser refuses with a multi-line traceback: a missing or unreadable
    file, one that is not UTF-8 text or not YAML, a list where node names go, and a value
    before `ros__parameters`. rcl remains the judge of the rest (run_node catches its
    error too).
    """
    import yaml

    from gyro_ekf.io.products import os_reason

    try:
        text = Path(path).read_bytes().decode('utf-8')
    except FileNotFoundError:
        return f'--params-file {path}: no such file'
    except OSError as err:
        return f'--params-file {path}: cannot read it: {os_reason(err)}'
    except UnicodeDecodeError:
        return f'--params-file {path}: not a YAML file (not UTF-8 text)'
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        reason = getattr(err, 'problem', None) or type(err).__name__
        return f'--params-file {path}: not a YAML file: {reason}{where}'
    shape = 'expected NODE_NAME: {ros__parameters: {NAME: VALUE, ...}}'
    if isinstance(data, list):
        return f'--params-file {path}: not a ROS 2 params file: a list, {shape}'
    pending = [(data, '')] if isinstance(data, dict) else []
    while pending:
        mapping, prefix = pending.pop()
        for key, value in mapping.items():
            if key == 'ros__parameters':
                if isinstance(value, dict):
                    continue
                return (f'--params-file {path}: not a ROS 2 params file: {prefix}{key} is '
                        f'not a mapping, {shape}')
            if not isinstance(value, dict):
                return (f"--params-file {path}: not a ROS 2 params file: '{prefix}{key}' has "
                        f'a value where a node name or ros__parameters goes, {shape}')
            pending.append((value, f'{prefix}{key}.'))
    return None


def run_node(make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, spin the node until Ctrl-C or shutdown, clean up; return the exit code.

    The executor is wire.executor()'s (EventsExecutor unless GYRO_EKF_NODE_IO=rclpy). A node
    with an `event_batch_s` attribute above 0 has its events served in batches (_spin_events).

    A configuration error (bad parameter value) is logged as one line and gives exit code 1.
    Fast DDS gets the project's writer profile (use_writer_profile) unless the user set one.
    """
    # Each reliable sample woke Fast DDS' event thread once per reader: a fifth of the CPU of
    # ekf_node at 1 kHz went to it (fastdds_writer.xml says why and what it changes).
    use_writer_profile()
    for path in params_files(sys.argv if args is None else args):
        problem = params_file_problem(path)
        if problem is not None:
            print(f'[FATAL] {problem}', file=sys.stderr)
            return 1
    try:
        rclpy.init(args=args)
    except _rclpy.RCLError as err:
        # rcl refuses its arguments (a params file it cannot parse): its own line, no
        # traceback. The message ends in C source locations (", at /project/src/...").
        print(f'[FATAL] {str(err).split(", at /")[0].strip()}', file=sys.stderr)
        return 1
    node = None
    try:
        # rclpy's EventsExecutor (C++) on the serialized path: the Python executor rebuilds
        # its wait set for every message, which costs more than the node's own work.
        executor = wire.executor()
        node = make_node()
        if executor is None:
            rclpy.spin(node)
        else:
            _spin_events(node, executor, float(getattr(node, 'event_batch_s', 0.0)))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except GyroEkfError as err:
        print(f'[FATAL] {err}', file=sys.stderr)
        return 1
    except (InvalidParameterTypeException, InvalidParameterValueException) as err:
        # rclpy's own range and type checks of declared parameters (`-p path_length:=0`).
        print(f'[FATAL] {err}', file=sys.stderr)
        return 1
    except Exception:
        # A callback that was running when Ctrl-C shut the context down fails to publish;
        # that is a clean shutdown, anything else is a bug and propagates.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _spin_events(node: Node, executor, batch_s: float = 0.0) -> None:
    """Spin an EventsExecutor until shutdown, returning to Python often enough for Ctrl-C.

    Its spin() and untimed spin_once() block in C++, where Python never sees SIGINT. A timed
    spin_until_future_complete on a future that never completes serves every event of
    _SPIN_RETURN_S in C++ and then returns to the interpreter, which runs the signal handler;
    a timed spin_once would return after each message (a round trip through Python, the
    context lock and the executor's set-up per message: about a tenth of a node's CPU).

    batch_s > 0 serves events in batches: the first event of a batch is served when it comes,
    then the thread sleeps batch_s while the next ones gather and serves them in one go. Each
    event served as it comes costs a wake-up of this thread and a hand-off from Fast DDS'
    receive thread (futex wake-ups, context switches: at 1 kHz about a quarter of
    calibration_node's CPU); a batch pays them once. The cost is latency: an event waits up
    to batch_s + _DRAIN_S. An event that was already waiting (spin_once came back within
    _BACKLOG_S) skips the pause, so a node behind its input catches up without pauses; a
    batch is a small part of the input queues (SENSOR_INPUT: 500 messages).
    """
    executor.add_node(node)
    never = Future()
    try:
        while executor.context.ok():
            if batch_s <= 0.0:
                executor.spin_until_future_complete(never, timeout_sec=_SPIN_RETURN_S)
                continue
            asked = time.monotonic()
            executor.spin_once(timeout_sec=_SPIN_RETURN_S)
            if time.monotonic() - asked > _BACKLOG_S:
                time.sleep(batch_s)
            executor.spin_until_future_complete(never, timeout_sec=_DRAIN_S)
    finally:
        executor.remove_node(node)
        executor.shutdown()


def log_repeat(node: Node, duplicate: bool, text: str, counts: dict[str, int]) -> None:
    """Log a message dropped at the stamp of the one taken on its input (core/same_stamp.py).

    An exact repeat (``duplicate``) lost nothing: said once, at info. Another value for one
    instant is bad input: a warning naming it with the drop counts, at most every 5 s.
    """
    if duplicate:
        node.get_logger().info(f'{text}; such copies are counted in /diagnostics '
                               'dropped_duplicate', once=True)
    else:
        node.get_logger().warn(f'{text} (counts {counts})', throttle_duration_sec=5.0)
