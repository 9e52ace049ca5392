"""Whether this process may start a helper beside itself (the CLI's forked children)."""

from __future__ import annotations

import os

__all__ = ['spare_core']


def spare_core() -> bool:
    """Whether a child process could run beside this one (fork, and two usable cores)."""
    if not hasattr(os, 'fork') or not hasattr(os, 'sched_getaffinity'):
        return False
    return len(os.sched_getaffinity(0)) > 1
