"""Helper processes of the CLI: whether one may run beside this one, and writing to one.

Used by `gyro-ekf run`'s forked children (analysis.detect_ahead, io.streamed_products).
"""

from __future__ import annotations

import os

__all__ = ['spare_core', 'write_all']


def spare_core() -> bool:
    """Whether a child process could run beside this one (fork, and two usable cores)."""
    if not hasattr(os, 'fork') or not hasattr(os, 'sched_getaffinity'):
        return False
    return len(os.sched_getaffinity(0)) > 1


def write_all(fd: int, data: bytes) -> None:
    """Write all of data to a file descriptor (a pipe may take it in parts).

    Raises:
        OSError: as os.write (BrokenPipeError: the reader is gone).
    """
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]
