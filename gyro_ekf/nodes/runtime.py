"""The Jazzy entry-point pattern shared by the node executables."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from gyro_ekf.errors import GyroEkfError


def run_node(make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, spin the node until Ctrl-C or shutdown, clean up; return the exit code.

    A configuration error (bad parameter value) is logged as one line and gives exit code 1.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
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
