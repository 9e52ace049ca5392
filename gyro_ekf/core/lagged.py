"""Estimates at the IMU rate while observations arrive late: keep a short history and replay.

A LiDAR at 10 Hz delivers its poles up to a scan period (plus detection time) after the
IMU samples with the same stamps. Strict stamp order (``StreamMerger`` over every input)
holds each IMU sample until the slowest stream has caught up, so every pose is 50 ms late
on average. ``LaggedObservations`` instead lets the fast inputs (speed, IMU) through as
they come and keeps, for the last ``history_s`` of stamp time, every event it applied with
the filter as it was before that event. An observation stamped before the filter's last
event is put back where it belongs: the filter returns to the state saved before the first
later event, takes the observation, and the later events are applied again. An
observation stamped ahead of the filter waits until a speed or IMU event passes it.

The filter ends in exactly the state strict ordering gives (the same arithmetic in the
same order, see ``EventDriver``) for every observation that arrives within the history;
only the estimates already handed out before a late observation arrived were predictions
without it. A change made to the filter from outside (a new pose, a seeded bias, a new map)
cannot be replayed: call ``forget_history`` after it, so no replay undoes it.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gyro_ekf.core.errors import CoreError
from gyro_ekf.core.event_records import Estimate, EventKind
from gyro_ekf.core.events import EventDriver
from gyro_ekf.core.types import FloatArray, LidarMount


class ObservationFate:
    """What ``LaggedObservations.observation`` did with an observation (plain strings)."""

    APPLIED = 'applied'
    HELD = 'held'
    REPLAYED = 'replayed'
    TOO_LATE = 'too_late'


@dataclass(slots=True)
class LagStats:
    """Counts of the late-observation handling.

    Attributes:
        replays: late observations put back into the history.
        replayed_events: events applied again because of them.
        too_late: observations older than the history, dropped.
        refused: held observations the filter refused (CoreError), dropped.
    """

    replays: int = 0
    replayed_events: int = 0
    too_late: int = 0
    refused: int = 0


class LaggedObservations:
    """Drives an EventDriver with in-order inputs and observations that may come late.

    Attributes:
        driver: the driven filter (its state is rewound and replayed by this class).
        history_s: stamp time of history kept; older observations are dropped.
        stats: replay counts.
    """

    def __init__(self, driver: EventDriver, history_s: float, max_held: int = 10_000,
                 on_refused: Callable[[float, CoreError], None] | None = None):
        """Wrap a driver; keep history_s seconds (stamp time) of applied events.

        Args:
            driver: the filter to drive.
            history_s: stamp time of history kept, s.
            max_held: most observations held ahead of the inputs; beyond it the oldest is
                applied at once (inputs that stopped must not grow the queue forever).
            on_refused: told (stamp, error) of a held observation the filter refuses while
                a speed or IMU sample releases it (that sample is still applied).

        Raises:
            CoreError: history_s is negative or not finite, or max_held < 1.
        """
        if not (history_s >= 0.0 and math.isfinite(history_s)):
            raise CoreError(f'history_s must be a finite number >= 0, got {history_s}')
        if max_held < 1:
            raise CoreError(f'max_held must be at least 1, got {max_held}')
        self.driver = driver
        self.history_s = history_s
        self.max_held = max_held
        self.on_refused = on_refused
        self.stats = LagStats()
        # (stamp_s, kind, arrival) keys, and per event (kind, payload, state before it).
        self._keys: list[tuple[float, int, int]] = []
        self._events: list[tuple[EventKind, Any, Any]] = []
        self._pending: list[tuple[float, int, Any]] = []
        self._arrival = itertools.count()

    def reset(self) -> None:
        """Forget the history and the held observations (after a driver reset)."""
        self.forget_history()
        self._pending.clear()
        self.stats = LagStats()

    def forget_history(self) -> None:
        """Forget what could be replayed (after the filter was changed from outside).

        Observations older than the filter's last event then count as too late.
        """
        del self._keys[:-1]
        del self._events[:-1]
        if self._events:
            # The newest key still bounds what is late, but its saved state predates the
            # change and must never be restored.
            kind, value, _ = self._events[-1]
            self._events[-1] = (kind, value, None)

    @property
    def held(self) -> int:
        """Observations waiting for the inputs to pass their stamp."""
        return len(self._pending)

    def on_speed(self, stamp_s: float, speed_m_s: float, variance: float | None = None
                 ) -> None:
        """Apply a speed sample (inputs come in stamp order) after the observations before it."""
        self._release_before(stamp_s, EventKind.SPEED)
        self._apply(stamp_s, EventKind.SPEED, (speed_m_s, variance))

    def on_imu(self, stamp_s: float, yaw_rate_rad_s: float, variance: float | None = None
               ) -> Estimate:
        """Apply an IMU sample after the observations up to its stamp; return the estimate."""
        self._release_before(stamp_s, EventKind.IMU)
        self._apply(stamp_s, EventKind.IMU, (yaw_rate_rad_s, variance))
        return self.driver.estimate()

    def observation(self, stamp_s: float, points_sensor_m: FloatArray,
                    mount: LidarMount) -> str:
        """Take pole detections of any age; return an ObservationFate value.

        Raises:
            TimeWentBackwardsError: never for a late observation (it is replayed or dropped);
                only as EventDriver raises it for its own inputs.
        """
        payload = (points_sensor_m, mount)
        key = (stamp_s, int(EventKind.OBSERVATION), next(self._arrival))
        if not self._keys or key > self._keys[-1]:
            heapq.heappush(self._pending, (stamp_s, key[2], payload))
            if len(self._pending) > self.max_held:
                self._apply_held(*heapq.heappop(self._pending))
            return ObservationFate.HELD
        position = bisect.bisect_right(self._keys, key)
        if key < self._keys[0] or self._events[position][2] is None:
            self.stats.too_late += 1
            return ObservationFate.TOO_LATE
        now = self.driver.save()
        keys, events = list(self._keys), list(self._events)
        later = list(zip(keys[position:], events[position:]))
        del self._keys[position:]
        del self._events[position:]
        try:
            self.driver.restore(events[position][2])
            self._apply_keyed(stamp_s, EventKind.OBSERVATION, payload, key[2])
            for (event_stamp, _, arrival), (kind, value, _) in later:
                self._apply_keyed(event_stamp, kind, value, arrival)
        except CoreError:
            # The filter refused the late observation (or a later scan after it): put
            # everything back as it was, as if the observation had never come.
            self._keys[:], self._events[:] = keys, events
            self.driver.restore(now)
            raise
        self.stats.replays += 1
        self.stats.replayed_events += len(later)
        return ObservationFate.REPLAYED

    def flush(self) -> None:
        """Apply every held observation now (the inputs stopped: end of data)."""
        while self._pending:
            self._apply_held(*heapq.heappop(self._pending))

    def _release_before(self, stamp_s: float, kind: EventKind) -> None:
        # Observations sort after speed and before IMU samples of the same stamp.
        while self._pending and (self._pending[0][0] < stamp_s or (
                self._pending[0][0] == stamp_s and kind is EventKind.IMU)):
            self._apply_held(*heapq.heappop(self._pending))

    def _apply_held(self, stamp_s: float, arrival: int, payload: Any) -> None:
        # A refused observation must not take the speed or IMU sample that released it down.
        try:
            self._apply_keyed(stamp_s, EventKind.OBSERVATION, payload, arrival)
        except CoreError as err:
            self.stats.refused += 1
            if self.on_refused is not None:
                self.on_refused(stamp_s, err)

    def _apply(self, stamp_s: float, kind: EventKind, value: Any) -> None:
        self._apply_keyed(stamp_s, kind, value, next(self._arrival))

    def _apply_keyed(self, stamp_s: float, kind: EventKind, value: Any, arrival: int) -> None:
        saved = self.driver.save()
        if kind is EventKind.IMU:
            self.driver.step_imu(stamp_s, *value)
        elif kind is EventKind.SPEED:
            self.driver.on_speed(stamp_s, *value)
        else:
            self.driver.on_detections(stamp_s, value[0], value[1])
        self._keys.append((stamp_s, int(kind), arrival))
        self._events.append((kind, value, saved))
        self._forget_before(stamp_s - self.history_s)

    def _forget_before(self, oldest_s: float) -> None:
        drop = bisect.bisect_left(self._keys, (oldest_s, -1, -1))
        # Keep at least the newest event: it bounds what counts as late.
        drop = min(drop, len(self._keys) - 1)
        if drop > 0:
            del self._keys[:drop]
            del self._events[:drop]
