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
import sys

from gyro_ekf.errors import GyroEkfError

COMMANDS = ('convert', 'info', 'simulate', 'calibrate', 'calibrate_mounts', 'run', 'demo',
            'replay', 'record', 'reindex', 'make_bags', 'stress')

log = logging.getLogger('gyro_ekf')


def build_parser() -> argparse.ArgumentParser:
    """Build the argparse tree of all subcommands."""
    parser = argparse.ArgumentParser(
        prog='gyro-ekf', description='Gyro bias calibration and pose/bias EKF tools.',
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument('-v', '--verbose', action='count', default=0, help='more logging')
    parser.add_argument('-q', '--quiet', action='store_true', help='warnings and errors only')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for name in COMMANDS:
        module = importlib.import_module(f'gyro_ekf.cli.{name}')
        sub = commands.add_parser(name.replace('_', '-'), help=module.HELP,
                                  description=module.HELP,
                                  formatter_class=argparse.ArgumentDefaultsHelpFormatter)
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


if __name__ == '__main__':
    sys.exit(main())
