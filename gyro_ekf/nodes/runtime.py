"""The Jazzy entry-point pattern shared by the node executables."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from gyro_ekf.errors import GyroEkfError
from gyro_ekf.nodes import wire

_SPIN_RETURN_S = 0.2
"""Longest time the EventsExecutor blocks in C++ before Python may handle a signal, s."""


def run_node(make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, spin the node until Ctrl-C or shutdown, clean up; return the exit code.

    The executor is wire.executor()'s (EventsExecutor unless GYRO_EKF_NODE_IO=rclpy).

    A configuration error (bad parameter value) is logged as one line and gives exit code 1.
    """
    rclpy.init(args=args)
    node = None
    try:
        # rclpy's EventsExecutor (C++) on the serialized path: the Python executor rebuilds
        # its wait set for every message, which costs more than the node's own work.
        executor = wire.executor()
        node = make_node()
        if executor is None:
            rclpy.spin(node)
        else:
            _spin_events(node, executor)
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


def _spin_events(node: Node, executor) -> None:
    """Spin an EventsExecutor until shutdown, returning to Python often enough for Ctrl-C.

    Its spin() and untimed spin_once() block in C++, where Python never sees SIGINT; a
    timed spin_once returns to the interpreter, which then runs the signal handler.
    """
    executor.add_node(node)
    try:
        while executor.context.ok():
            executor.spin_once(timeout_sec=_SPIN_RETURN_S)
    finally:
        executor.remove_node(node)
        executor.shutdown()
