"""Stream ordering for live use: release events from several topics in driver order.

An offline run knows every event of a trip and sorts them (`trip_run.iter_trip_events`); a
live node receives each topic on its own subscription, out of order across topics, and
must decide when an event can no longer be overtaken. ``StreamMerger`` holds events behind
a watermark and releases them in the order the ``EventDriver`` expects (stamp, then speed <
observation < IMU). `core.lagged.LaggedObservations` is the other live policy: the fast
inputs go through at once and a late observation is replayed into a short history.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
import heapq
import itertools
import math
import time
from typing import Any

from gyro_ekf.core.event_records import EventKind

__all__ = ['ReadyEvents', 'StreamMerger']


ReadyEvents = list[tuple[float, EventKind, Any]]

IDLE_STAMP_TOLERANCE_S = 1e-6
"""Stamps this close past a stream's next expected one count as at it (release_idle), s:
the stamps of periodic streams written through decimal text (the course logs' CSVs)."""


class StreamMerger:
    """Releases live events in driver order: (stamp, kind, arrival), behind a watermark.

    Live topics arrive out of order across subscriptions, and when the filter falls behind
    the executor serves each subscription's queue one message at a time, so a 200 Hz IMU
    queue drains no faster than a 100 Hz odometry queue and the odometry stamps run ahead
    by more than any fixed window. So an event with stamp t is released once
    t <= newest stamp of any stream - window_s and t <= the newest stamp of every active
    stream.

    A stream is stale (stops holding the others back: a stopped LiDAR) only when nothing of
    it was received while the newest stamp received on any stream moved ``stale_after_s``
    on, and ``stale_after_s`` passed on ``clock`` since its last message. The first measure
    is in the stamps of messages actually received (the data's own time, sim time or not),
    so it does not depend on how fast the machine is: a stream whose messages wait in its
    queue is served in every executor round, one message per round like the others (an
    events executor serves the queues in arrival order, closer still), so the others cannot
    move far between two of its messages however far behind it drains (its own stamps may
    lag by seconds). A starved process cannot make a stream stale, nor can
    ROS time from a /clock that runs ahead of the queued data (not used here). The clock
    (steady) only delays staleness: a burst of one stream (seconds of stamps received at
    once), or a stream computed upstream from a fast replay (landmarks from a busy
    detector) that lags by more than stale_after_s of stamps, is not silent. A stream
    whose stamps run ahead of the others never holds them back, and it is not stale before
    the others pass its stamps. ``max_events`` bounds what is held.

    An event older than one already released is late: ``push`` returns it in ``late``
    instead of releasing it out of order. Ties release speed, observation, IMU, as
    iter_trip_events orders them, so a live run feeds the EventDriver what an offline run
    does. At the start nothing is released until every expected stream has spoken (or, by
    the same two measures counted from the first message, stale_after_s has passed): the
    first messages of two topics reach a subscriber in either order, and releasing the
    first would make the other late.
    """

    def __init__(self, window_s: float, max_events: int = 20_000, stale_after_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic,
                 expected_streams: Iterable[str] = (), stale_wall_s: float | None = None):
        """Hold events window_s of stamp time at least, at most max_events at once.

        Args:
            window_s: least stamp time an event waits behind the newest stamp, s.
            max_events: the oldest events are released beyond this many.
            stale_after_s: a stream silent for this long on the clock, and while the
                newest stamp received moved this far, stops holding events back, s.
            clock: steady seconds (monotonic); replaceable in tests.
            expected_streams: streams to wait for before the first release (at most
                stale_after_s after the first event).
            stale_wall_s: the clock's part of staleness, when it should differ from
                stale_after_s, s (longer: an upstream known to deliver every message,
                however slowly, is waited for longer before it counts as stopped).
        """
        self.window_s = window_s
        self.max_events = max_events
        self.stale_after_s = stale_after_s
        self.stale_wall_s = stale_after_s if stale_wall_s is None else stale_wall_s
        self.expected_streams = frozenset(expected_streams)
        self._started: float | None = None
        self._first_newest_s = -math.inf
        self._clock = clock
        self._heap: list[tuple[float, int, int, Any]] = []
        self._arrival = itertools.count()
        # Per stream: its newest stamp, the newest stamp of any stream when its last
        # message came, the clock then, and its last stamp interval (0 before two).
        self._streams: dict[str, tuple[float, float, float, float]] = {}
        self._newest_s = -math.inf
        self._released_s = -math.inf

    def __len__(self) -> int:
        return len(self._heap)

    @property
    def released_s(self) -> float:
        """Stamp of the last released event (-inf before the first)."""
        return self._released_s

    def push(self, stream: str, stamp_s: float, kind: EventKind, payload: Any
             ) -> tuple[ReadyEvents, list[Any]]:
        """Add an event of a stream; return (events now ready in order, late payloads)."""
        if stamp_s < self._released_s:
            return [], [payload]
        now = self._clock()
        newest_s = self._newest_s = max(self._newest_s, stamp_s)
        if self._started is None:
            self._started, self._first_newest_s = now, newest_s
        own_s, _, _, interval_s = self._streams.get(stream, (-math.inf, 0.0, 0.0, 0.0))
        if stamp_s > own_s:
            interval_s, own_s = (stamp_s - own_s if own_s > -math.inf else 0.0), stamp_s
        self._streams[stream] = (own_s, newest_s, now, interval_s)
        heapq.heappush(self._heap, (stamp_s, int(kind), next(self._arrival), payload))
        if (self._released_s == -math.inf and not self.expected_streams <= self._streams.keys()
                and not self._passed(now, self._started, self._first_newest_s)
                and len(self._heap) <= self.max_events):
            return [], []
        stale_s, wall_s = self.stale_after_s, self.stale_wall_s
        watermark = min((own for own, newest_then, seen, _ in self._streams.values()
                         if now - seen <= wall_s or newest_s - newest_then <= stale_s),
                        default=math.inf)  # not stale (see _passed), inline: per message
        return self._release(min(newest_s - self.window_s, watermark)), []

    def active_streams(self) -> set[str]:
        """Streams seen since the last clear that are not stale."""
        now = self._clock()
        return {stream for stream, (_, newest_then, seen, _) in self._streams.items()
                if not self._passed(now, seen, newest_then)}

    def _passed(self, now: float, seen: float, newest_then_s: float) -> bool:
        """Tell whether stale_wall_s has passed on the clock and stale_after_s in the stamps.

        On the clock since `seen`, and in the newest stamp received on any stream since it
        was `newest_then_s`.
        """
        return (now - seen > self.stale_wall_s
                and self._newest_s - newest_then_s > self.stale_after_s)

    def flush(self) -> ReadyEvents:
        """Release everything held."""
        return self._release(math.inf)

    def release_idle(self) -> ReadyEvents:
        """Release what no stream is still expected to overtake, when no input arrives.

        For the end of the data, where nothing else releases the tail: each stream holds
        back only events beyond its next expected stamp (its newest plus its last stamp
        interval, so streams that ended together release everything), until stale_wall_s
        passed on the clock since its last message. A stream that lags by more (messages
        still on their way: a reliable reader waiting for a lost sample to be sent again,
        an upstream node that is behind) keeps the later events until its messages come
        or it is stale; releasing them would make every one of its messages late.
        """
        now = self._clock()
        until_s = min((own + interval for own, _, seen, interval in self._streams.values()
                       if now - seen <= self.stale_wall_s), default=math.inf)
        return self._release(until_s + IDLE_STAMP_TOLERANCE_S)

    def clear(self) -> None:
        """Drop everything and forget the streams and stamps seen (after a reset)."""
        self._heap.clear()
        self._streams.clear()
        self._started = None
        self._first_newest_s = -math.inf
        self._newest_s = -math.inf
        self._released_s = -math.inf

    def _release(self, until_s: float) -> ReadyEvents:
        ready = []
        while self._heap and (self._heap[0][0] <= until_s or len(self._heap) > self.max_events):
            stamp_s, kind, _, payload = heapq.heappop(self._heap)
            self._released_s = stamp_s
            ready.append((stamp_s, EventKind(kind), payload))
        return ready
