"""Keeps stamps far ahead of the inputs' common time out of a live filter.

A live node takes stamps from several publishers. One message stamped far ahead (a broken
clock, a hostile message) must not drag the filter forward: it would cost a prediction over
the whole gap, and every later message would then be "late". But a real gap, where every
input pauses and comes back later (a paused robot, a bag paused and resumed), must be
accepted. ``StampGate`` tells the two apart before the messages reach the merger:

- ``time_s`` is the newest stamp passed on, over all streams.
- A message stamped at most ``max_jump_s`` ahead of it passes at once (behind it is the
  merger's business: a late message, or stamps that restart).
- A message further ahead is held as a candidate of its stream. The candidates of a stream
  form a run while each comes after the previous one by at most ``max_jump_s``. A run
  becomes the new time (and is passed on) when
    * another stream's candidates agree with it (within ``max_jump_s``): every input jumped
      together, so the gap is real; or
    * it reaches ``confirm_after`` messages while no other stream passed a message since it
      began: the only input still talking keeps saying the new time.
- A message of the stream back near ``time_s`` ends its run: the held candidates were
  outliers, and are dropped (counted by the caller). A run that cannot be confirmed holds
  at most ``confirm_after`` messages; older ones are dropped.

Until the first run is confirmed (at the start, and after ``clear``) there is no time, so
every message is a candidate: a lone first message far from the others cannot set a time
that makes them all late (the node used to wedge on a first message 100 s ahead).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

from gyro_ekf.core.errors import CoreError

Passed = tuple[str, float, Any]
"""A message passed on or dropped: (stream, stamp_s, payload)."""

_NONE: list[Passed] = []
"""Nothing dropped (shared: callers only read it)."""


@dataclass(slots=True)
class _Run:
    """Held candidates of one stream and whether another stream passed since it began."""

    messages: list[Passed] = field(default_factory=list)
    arrivals: list[int] = field(default_factory=list)
    others_passed: bool = False


class StampGate:
    """Holds messages stamped far ahead until other inputs or a run of messages confirm them.

    Attributes:
        max_jump_s: largest step ahead of ``time_s`` passed at once, s.
        confirm_after: messages of a lone stream that confirm a jump.
        time_s: newest stamp passed on, s; None until a time is established.
    """

    def __init__(self, max_jump_s: float, confirm_after: int = 10):
        """Pass stamps up to max_jump_s ahead; confirm a jump after confirm_after messages.

        Raises:
            CoreError: max_jump_s is not a positive number, or confirm_after < 1.
        """
        if not (max_jump_s > 0.0 and math.isfinite(max_jump_s)):
            raise CoreError(f'max_jump_s must be a positive number, got {max_jump_s}')
        if confirm_after < 1:
            raise CoreError(f'confirm_after must be at least 1, got {confirm_after}')
        self.max_jump_s = max_jump_s
        self.confirm_after = confirm_after
        self.time_s: float | None = None
        self._runs: dict[str, _Run] = {}
        self._arrival = itertools.count()

    @property
    def held(self) -> int:
        """Count the candidates waiting: far ahead, not yet confirmed."""
        return sum(len(run.messages) for run in self._runs.values())

    def clear(self) -> None:
        """Forget the time and the candidates (after a reset): the next run sets the time."""
        self.time_s = None
        self._runs.clear()

    def offer(self, stream: str, stamp_s: float, payload: Any
              ) -> tuple[list[Passed], list[Passed]]:
        """Offer one message; return (messages passed on now, in stamp order; dropped ones).

        Raises:
            CoreError: stamp_s is not finite.
        """
        if not math.isfinite(stamp_s):
            raise CoreError(f'{stream} stamp {stamp_s} is not finite')
        message = (stream, stamp_s, payload)
        time_s = self.time_s
        if time_s is not None and stamp_s <= time_s + self.max_jump_s and not self._runs:
            # The common case, once per message at IMU rate: nothing held anywhere.
            if stamp_s > time_s:
                self.time_s = stamp_s
            return [message], _NONE
        if self.time_s is not None and stamp_s <= self.time_s + self.max_jump_s:
            # The stream is back near the common time: its candidates that the time has
            # reached meanwhile pass, the others were outliers.
            run = self._runs.pop(stream, _Run())
            limit = self.time_s + self.max_jump_s
            passed = sorted([m for m in run.messages if m[1] <= limit] + [message],
                            key=lambda m: m[1])
            for name, stamp, _ in passed:
                self._passed(name, stamp)
            return passed, [m for m in run.messages if m[1] > limit]
        run = self._runs.setdefault(stream, _Run())
        dropped: list[Passed] = []
        if run.messages and abs(stamp_s - run.messages[-1][1]) > self.max_jump_s:
            dropped = self._end_run(stream)  # not a run: the held ones were outliers
            run = self._runs.setdefault(stream, _Run())
        run.messages.append(message)
        run.arrivals.append(next(self._arrival))
        agreeing = [name for name, other in self._runs.items() if name != stream
                    and other.messages and abs(other.messages[-1][1] - stamp_s)
                    <= self.max_jump_s]
        if agreeing or (len(run.messages) >= self.confirm_after and not run.others_passed):
            return self._confirm([stream, *agreeing]), dropped
        if len(run.messages) > self.confirm_after:
            dropped.append(run.messages.pop(0))
            run.arrivals.pop(0)
        return [], dropped

    def _confirm(self, streams: list[str]) -> list[Passed]:
        held: list[tuple[float, int, Passed]] = []
        for name in streams:
            run = self._runs.pop(name)
            held += [(m[1], a, m) for m, a in zip(run.messages, run.arrivals)]
        self.time_s = max(stamp for stamp, _, _ in held)
        # Candidates of other streams that the new time reaches pass too.
        limit = self.time_s + self.max_jump_s
        for name in list(self._runs):
            run = self._runs[name]
            keep = [i for i, m in enumerate(run.messages) if m[1] > limit]
            held += [(m[1], a, m) for i, (m, a) in enumerate(zip(run.messages, run.arrivals))
                     if m[1] <= limit]
            run.messages = [run.messages[i] for i in keep]
            run.arrivals = [run.arrivals[i] for i in keep]
            if not run.messages:
                del self._runs[name]
        held.sort(key=lambda h: h[:2])  # stamp order; equal stamps in arrival order
        passed = [m for _, _, m in held]
        for name, stamp, _ in passed:
            self._passed(name, stamp)
        return passed

    def _passed(self, stream: str, stamp_s: float) -> None:
        self.time_s = stamp_s if self.time_s is None else max(self.time_s, stamp_s)
        for name, run in self._runs.items():
            if name != stream:
                run.others_passed = True

    def _end_run(self, stream: str) -> list[Passed]:
        run = self._runs.pop(stream, None)
        return [] if run is None else run.messages
