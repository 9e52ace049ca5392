"""`gyro-ekf calibrate` (placeholder until its owner lands it)."""

from __future__ import annotations

import argparse

HELP = 'not implemented yet'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add this command's arguments."""


def run(args: argparse.Namespace) -> int:
    """Run the command; returns the exit code."""
    raise NotImplementedError('gyro-ekf calibrate')
