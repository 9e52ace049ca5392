"""Mapped poles that stand elsewhere, found from the detections that lie near them.

A map is surveyed once; then a pole is moved or knocked, or was measured wrong. Its
detections fall outside the association gate of where the map has it, and the run said
only that fewer detections were associated: two poles of fourteen 0.1 or 0.3 m off, on the
stress suite's 120-s clean trips, read 84-86 % associated, degraded, and neither which pole
nor where it stands.

Each unmatched detection within ``recovery_max_distance_m`` of a mapped pole, in a scan
that matched that pole to no detection, is a look at where the pole may stand: its offset
from the mapped position, put in the map frame at the pose before the scan. A pole is found
to stand elsewhere when:

1. it has at least ``MIN_LOOKS`` such looks, and more than the detections matched to it
   (the 2016 log's pole 1, matched 5 306 times, has 39 looks 0.8 m off it: another
   object, seen when the pole is hidden);
2. they cluster: their RMS spread about their mean is under ``MAX_SPREAD`` of the mean's
   distance from the mapped position. The gate's misses of a pole where the map has it lie
   on every side of it and average out; a lost pose's offsets scatter;
3. their mean lies beyond ``SIGMAS`` standard errors of itself from the mapped position.

A reflector near a mapped pole is seen besides the pole (both in one scan), not instead of
it, so its detections are no looks. The figure is where the pole stands, which the map can
be set to; nothing in the filter changes (the pole's detections stay unmatched).

The looks are kept in an append-only list, so ``save`` and ``restore`` (on every event, by
``core/lagged.py``) are its length and a truncation; the sums per pole are added up from
the list when reported, from where the last report left off (a node reports at every
diagnostics tick) or, after a restore took looks back, from the start.
"""

from __future__ import annotations

from typing import Any

MIN_LOOKS = 20
"""Fewest looks at a pole before it can be found elsewhere."""

MAX_SPREAD = 0.5
"""Largest RMS spread of the looks about their mean, as a share of the mean's offset."""

SIGMAS = 6.0
"""Standard errors of the mean offset beyond which it is more than the looks' noise."""


class MapPoleWatch:
    """Looks at mapped poles from detections that missed them (module docstring)."""

    __slots__ = ('matched', '_looks', '_sums', '_summed')

    def __init__(self, poles: int = 0) -> None:
        # Detections matched to each pole: the driver counts them at each update.
        self.matched = [0] * poles
        self._looks: list[tuple[int, float, float]] = []  # (pole, dx m, dy m)
        # Per pole [n, sum dx, sum dy, sum dx^2 + dy^2] over the first _summed looks.
        self._sums: dict[int, list[float]] = {}
        self._summed = 0

    def look(self, pole: int, dx_m: float, dy_m: float) -> None:
        """Add a detection (dx_m, dy_m) off mapped pole ``pole``, in a scan that matched none."""
        self._looks.append((pole, dx_m, dy_m))

    @property
    def looks(self) -> int:
        """Looks so far, at every pole."""
        return len(self._looks)

    def save(self) -> tuple[int, tuple[int, ...]]:
        return len(self._looks), tuple(self.matched)

    def restore(self, saved: tuple[int, tuple[int, ...]]) -> None:
        saved, self.matched[:] = saved
        del self._looks[saved:]
        if self._summed > saved:
            self._sums, self._summed = {}, 0

    def report(self, poles_xy: list[list[float]]) -> list[dict[str, Any]]:
        """Return the poles found elsewhere, each with where its looks put it.

        poles_xy: the map's pole positions (m), as the looks' pole indices number them.
        """
        sums = self._sums
        for pole, dx, dy in self._looks[self._summed:]:
            total = sums.setdefault(pole, [0.0, 0.0, 0.0, 0.0])
            total[0] += 1.0
            total[1] += dx
            total[2] += dy
            total[3] += dx * dx + dy * dy
        self._summed = len(self._looks)
        found = []
        for pole, (n, sx, sy, sq) in sorted(sums.items()):
            if n < MIN_LOOKS or n <= self.matched[pole]:
                continue
            mx, my = sx / n, sy / n
            offset = (mx * mx + my * my) ** 0.5
            spread = max(0.0, sq / n - mx * mx - my * my) ** 0.5
            # Of the mean, per axis pooled: the spread over the root of the looks.
            standard_error = spread / n ** 0.5
            if spread < MAX_SPREAD * offset and offset > SIGMAS * standard_error:
                x, y = poles_xy[pole]
                found.append({'index': pole, 'map_xy_m': [x, y], 'looks': int(n),
                              'matched': self.matched[pole],
                              'offset_m': offset, 'spread_m': spread,
                              'seen_xy_m': [x + mx, y + my]})
        return found
