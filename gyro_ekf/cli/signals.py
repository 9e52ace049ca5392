"""SIGINT and SIGTERM as a polite request to stop, for the long-running commands.

`record` and `replay` check the request in their loops and then finish cleanly (the bag
closed, the summary printed); a second signal interrupts at once. Both signals are
installed explicitly: a shell that starts `gyro-ekf record ... &` without job control sets
SIGINT to ignored, and Python leaves an inherited ignored SIGINT ignored.
"""

from __future__ import annotations

import signal
from typing import Any


class StopRequest:
    """Install the handlers; true once SIGINT or SIGTERM arrived (`requested` names it)."""

    def __init__(self) -> None:
        self.requested: str | None = None
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, self._handle)

    def _handle(self, number: int, frame: Any) -> None:
        if self.requested is not None:
            raise KeyboardInterrupt
        self.requested = signal.Signals(number).name

    def __bool__(self) -> bool:
        return self.requested is not None

    def __call__(self) -> bool:
        """Whether a stop was requested (for loops that take a callable)."""
        return self.requested is not None
