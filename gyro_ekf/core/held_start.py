"""A start pose given exactly, held until the platform moves, while the map agrees with it.

A trip whose start pose is stated with no uncertainty (P0 of the pose 0: every course log
and simulated trip, by the course's convention) starts at that pose, and until the odometry
reads a speed or the gyro a turn the platform has not left it. The filter then has nothing
to estimate but the bias: ``core/events.py`` neither moves the pose nor lets it grow
uncertain (``GyroBiasEkf.hold_still``: no position random walk, no heading integrated
from a gyro that only shows its noise and bias), and the zero-rate updates learn the bias.
Landmark looks are still associated and applied, but with P of the pose 0 they move
nothing; their innovations judge the start pose.

Why: standing still, each LiDAR sees the same poles through the same beams, so its
detection errors repeat scan after scan. A filter whose pose is uncertain at rest is
dragged by them (1-7 mm and up to 0.1 deg on simulated trips) while its covariance grows
with the random walk the moving filter needs; the NEES of a static start was then a draw
of those fixed errors, far below or above its band.

The start pose is only held while the map agrees with it. Each LiDAR's first look at each
pole at the held pose gives a NIS (the pose exact, S is the sensor and map noise alone);
their sum over k poles is chi-square with 2k dof. Once the LiDARs have looked (every known
LiDAR has seen ``min_poles`` poles, or ``decide_after_s`` passed) and no LiDAR's sum stays
within the ``significance`` quantile, the start pose is wrong (the real 2016 log's
conventional heading is 0.45 deg off what its poles say) and the hold ends: the filter
goes on as from any start, the walk and the looks correcting the pose. A LiDAR that
disagrees while another agrees is a mount problem, which the health monitor and the start
check (``core/odometry_online.py``) handle; the pose stays held.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Mapping
from typing import Any, Hashable

from gyro_ekf.core.health import chi_square_tail


@dataclass(slots=True)
class HeldStart:
    """Whether the start pose is held, and each LiDAR's judgement of it.

    Attributes:
        held: the pose is held now.
        since_s: stamp of the first look at the held pose, s (None before it).
        released_s: stamp the hold ended at, s (None while held or never held).
        reason: why it ended ('moved', 'turned', 'map disagrees', ...).
        looks: LiDAR -> (NIS sum, poles looked at, their landmark indexes).
    """

    held: bool
    significance: float = 1e-4
    min_poles: int = 3
    decide_after_s: float = 0.5
    since_s: float | None = None
    released_s: float | None = None
    reason: str = ''
    looks: dict[Hashable, tuple[float, int, frozenset[int]]] = field(default_factory=dict)

    def copy(self) -> HeldStart:
        """Return an independent duplicate (for the driver's save and restore)."""
        return HeldStart(self.held, self.significance, self.min_poles, self.decide_after_s,
                         self.since_s, self.released_s, self.reason,
                         dict(self.looks))

    def release(self, stamp_s: float | None, reason: str) -> None:
        """End the hold (no-op when not held)."""
        if self.held:
            self.held = False
            self.released_s = stamp_s
            self.reason = reason

    def look(self, key: Hashable, landmark: int, nis: float, stamp_s: float) -> None:
        """Add a LiDAR's look at a pole from the held pose (only its first look counts)."""
        if not self.held:
            return
        if self.since_s is None:
            self.since_s = stamp_s
        total, count, seen = self.looks.get(key, (0.0, 0, frozenset()))
        if landmark in seen:
            return
        self.looks[key] = (total + nis, count + 1, seen | {landmark})

    def judge(self, stamp_s: float, expected: int) -> None:
        """End the hold when every LiDAR that has looked disagrees with the held pose.

        expected: how many LiDARs the trip has (each is waited for, up to decide_after_s).
        """
        if not self.held or self.since_s is None:
            return
        judged = [(total, count) for total, count, _ in self.looks.values()
                  if count >= self.min_poles]
        if not judged:
            return
        if len(judged) < expected and stamp_s - self.since_s < self.decide_after_s:
            return  # another LiDAR may yet vouch for the pose
        if all(chi_square_tail(total, 2 * count) < self.significance
               for total, count in judged):
            self.release(stamp_s, 'the map disagrees with the start pose')

    def report(self, names: Mapping[Hashable, str] | None = None) -> dict[str, Any]:
        """JSON-ready figures for summary.json and /diagnostics (names: LiDAR -> its name)."""
        names = names or {}
        return {'held': self.held, 'first_look_s': self.since_s,
                'released_s': self.released_s, 'reason': self.reason,
                'lidars': {names.get(key, str(key)): {
                    'nis_sum': total, 'poles': count,
                    'chance_if_exact': chi_square_tail(total, 2 * count)}
                    for key, (total, count, _) in self.looks.items() if count}}
