"""`gyro-ekf`: one CLI with a subcommand per tool.

Each command module exposes HELP, add_arguments(parser) and run(args) -> int. GyroEkfError
is caught here once and printed as one line; argparse keeps exit code 2 for usage errors.
"""

from __future__ import annotations

# Before numpy loads (see the module).
import gyro_ekf.blas_threads  # noqa: F401

import argparse
import importlib
import logging
import math
import os
import signal
import sys

from gyro_ekf.errors import GyroEkfError

COMMANDS = ('convert', 'info', 'simulate', 'calibrate', 'calibrate_mounts', 'run', 'demo',
            'replay', 'record', 'reindex', 'make_bags', 'stress')

log = logging.getLogger('gyro_ekf')


def check_number(option: str, value: float | None, low: float | None = None,
                 high: float | None = None, unit: str = '', above: bool = False) -> None:
    """Refuse a numeric option that is not finite or out of range, naming the option.

    Args:
        option: the option as the user typed it (`--duration-s`).
        value: its value; None (not given) passes.
        low, high: the accepted range (either may be None); low itself is refused when
            above is true.
        unit: the option's unit, for the message.

    Raises:
        GyroEkfError: one line such as `--duration-s: nan is not a finite number`.
    """
    if value is None:
        return
    if not math.isfinite(value):
        raise GyroEkfError(f'{option}: {value} is not a finite number')
    unit = f' {unit}' if unit else ''
    if low is not None and high is not None and not above and not low <= value <= high:
        raise GyroEkfError(f'{option}: must be within [{low:g}, {high:g}]{unit}, got '
                           f'{value:g}')
    if low is not None and (value <= low if above else value < low):
        raise GyroEkfError(f'{option}: must be {">" if above else ">="} {low:g}{unit}, got '
                           f'{value:g}')
    if high is not None and value > high:
        raise GyroEkfError(f'{option}: must be <= {high:g}{unit}, got {value:g}')


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Show an option's default, but not a None one (its help says what happens then)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """Build the argparse tree of all subcommands."""
    parser = argparse.ArgumentParser(
        prog='gyro-ekf', description='Gyro bias calibration and pose/bias EKF tools.',
        formatter_class=_HelpFormatter)
    parser.add_argument('-v', '--verbose', action='count', default=0, help='more logging')
    parser.add_argument('-q', '--quiet', action='store_true', help='warnings and errors only')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for name in COMMANDS:
        module = importlib.import_module(f'gyro_ekf.cli.{name}')
        sub = commands.add_parser(name.replace('_', '-'), help=module.HELP,
                                  description=module.HELP,
                                  formatter_class=_HelpFormatter)
        module.add_arguments(sub)
        sub.set_defaults(handler=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `gyro-ekf` console script."""
    if argv is None:
        argv = sys.argv[1:]
    # ROS arguments (--ros-args ...) belong to the nodes a command starts, not to argparse.
    ros_args: list[str] = []
    if '--ros-args' in argv:
        split = argv.index('--ros-args')
        argv, ros_args = argv[:split], argv[split:]
    args = build_parser().parse_args(argv)
    args.ros_args = ros_args
    level = logging.WARNING if args.quiet else (logging.DEBUG if args.verbose else logging.INFO)
    logging.basicConfig(level=level, format='%(levelname)s %(name)s: %(message)s',
                        stream=sys.stderr)
    try:
        return int(args.handler(args) or 0)
    except GyroEkfError as err:
        print(f'gyro-ekf {args.command}: error: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader of stdout went away (`| head`): stop as a command killed by SIGPIPE
        # would, without a traceback, and keep Python's own final flush from raising again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE


if __name__ == '__main__':
    sys.exit(main())
