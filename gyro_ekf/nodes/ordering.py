"""Merging live input streams into one stamp-ordered event sequence.

The core's ReorderBuffer holds every event ``window_s`` of stamp time behind the newest
stamp seen on any topic. That is not enough live: when the filter falls behind, the
executor serves each subscription's queue one message at a time, so a 200 Hz IMU queue
drains no faster than a 100 Hz odometry queue and the odometry stamps run ahead of the
IMU's by more than any fixed window. ``StreamMerger`` therefore also waits for a
watermark: an event is released only when every active stream has delivered a stamp at
or beyond it. A stream that delivered nothing for ``stale_after_s`` of wall time (a
stopped LiDAR) stops holding the others back; the buffer stays bounded by ``max_events``
and by ``flush`` (the node flushes when all input is idle).

Events sharing a stamp are released in the same order as ``core.events``: speed, then
observation, then IMU (then arrival order), exactly like ReorderBuffer and
iter_trip_events, so a live run feeds the EventDriver what an offline run does.

This is plain ordering logic with no ROS in it; it belongs next to ReorderBuffer in
``core/events.py`` and is kept here until it moves there.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
from collections.abc import Callable
from typing import Any

from gyro_ekf.core.events import EventKind

Ready = list[tuple[float, EventKind, Any]]


class StreamMerger:
    """Releases events in (stamp, kind, arrival) order behind a per-stream watermark.

    An event with stamp t is released once t <= newest stamp of any stream - window_s and
    t <= the newest stamp of every active stream. An event older than one already released
    is late: ``push`` returns it in ``late`` instead of releasing it out of order.
    """

    def __init__(self, window_s: float, max_events: int = 20_000, stale_after_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic):
        """Hold events window_s of stamp time at least, at most max_events at once.

        Args:
            window_s: least stamp time an event waits behind the newest stamp, s.
            max_events: the oldest events are released beyond this many.
            stale_after_s: a stream silent for this long (wall time, s) stops holding
                events back.
            clock: wall clock (monotonic seconds); replaceable in tests.
        """
        self.window_s = window_s
        self.max_events = max_events
        self.stale_after_s = stale_after_s
        self._clock = clock
        self._heap: list[tuple[float, int, int, Any]] = []
        self._arrival = itertools.count()
        self._streams: dict[str, tuple[float, float]] = {}
        self._newest_s = -math.inf
        self._released_s = -math.inf

    def __len__(self) -> int:
        return len(self._heap)

    @property
    def released_s(self) -> float:
        """Stamp of the last released event (-inf before the first)."""
        return self._released_s

    def push(self, stream: str, stamp_s: float, kind: EventKind, payload: Any
             ) -> tuple[Ready, list[Any]]:
        """Add an event of a stream; return (events now ready in order, late payloads)."""
        if stamp_s < self._released_s:
            return [], [payload]
        now = self._clock()
        newest_of_stream = self._streams.get(stream, (-math.inf, now))[0]
        self._streams[stream] = (max(newest_of_stream, stamp_s), now)
        self._newest_s = max(self._newest_s, stamp_s)
        heapq.heappush(self._heap, (stamp_s, int(kind), next(self._arrival), payload))
        watermark = min((newest for newest, seen in self._streams.values()
                         if now - seen <= self.stale_after_s), default=math.inf)
        return self._release(min(self._newest_s - self.window_s, watermark)), []

    def flush(self) -> Ready:
        """Release everything held."""
        return self._release(math.inf)

    def clear(self) -> None:
        """Drop everything and forget the streams and stamps seen (after a reset)."""
        self._heap.clear()
        self._streams.clear()
        self._newest_s = -math.inf
        self._released_s = -math.inf

    def _release(self, until_s: float) -> Ready:
        ready = []
        while self._heap and (self._heap[0][0] <= until_s or len(self._heap) > self.max_events):
            stamp_s, kind, _, payload = heapq.heappop(self._heap)
            self._released_s = stamp_s
            ready.append((stamp_s, EventKind(kind), payload))
        return ready
