"""Whether the gyro and each LiDAR turn the same way: an upside-down sensor, found and named.

An IMU mounted upside down (its z axis down, against REP-145) reads the yaw rate with the
wrong sign; so do the beams of a LiDAR mounted upside down, whose bearings run clockwise.
Either way the filter turns one way while the poles move the other: the pose is lost at the
first turn, and the run said so only by its effects ("a bias beyond 10 deg/s", "the pose is
lost", "under 50 % associated"; a gyro flipped on a 120-s trip once ended 15 m off with the
verdict degraded), never the cause, which is one sign to set.

The check needs neither the map nor the filter's pose. A LiDAR's scan is compared with the
first later one after the platform turned ``MIN_TURN_RAD`` within ``MAX_INTERVAL_S`` (the
2016 log's LiDAR scans at 37 Hz, under 1 deg apart). Between the two the platform turned
by dpsi, the gyro's integral less the bias the first stop learnt (not the filter's: one a
flipped gyro misled takes the turns for a bias of 40 deg/s), and moved by the odometry's
speed over the interval. The poles of the first scan are moved twice, by dpsi and by
-dpsi, and each detection of the second scores its squared distance to the nearest moved
pole (capped at ``GATE_M`` squared, so a pole seen in one scan only costs the same under
both; the sensor's own path is fitted to the detections within the gate, ``_score``). The
pair votes for the sign that scores under half the other with at least two detections
within half the gate: between the two signs the poles move by twice dpsi times their
range, tens of centimetres.

After ``MIN_VOTES`` votes, a LiDAR whose votes say -dpsi in at least ``FOUND_SHARE`` of them
turns the other way from the gyro. With two LiDARs or more, the one that disagrees with the
others is the one upside down; all of them against the gyro, the gyro is. With one LiDAR,
scan to scan cannot tell the two apart (a mirrored world is as consistent as the real one);
the map can, before the first turn misled the filter: an upside-down gyro leaves the
detections of the scans before the LiDAR's first vote associated as usual (``associated``:
99.8 % on the 2016 log with its gyro negated), an upside-down LiDAR's match the map nowhere
(2 % on that log mirrored). Voting stops at ``MAX_VOTES`` per LiDAR, so a long run costs a
few hundred scans' work.

The state is per LiDAR the last scan's points and a few counts, replaced, never changed in
place, so ``save`` and ``restore`` (on every event, by ``core/lagged.py``) cost O(LiDARs).
"""

from __future__ import annotations

import math
from typing import Any, Hashable

import numpy as np

from gyro_ekf.core.types import FloatArray, LidarMount

MIN_TURN_RAD = math.radians(2.0)
"""Least turn between two scans that votes (smaller, the two signs differ by little)."""

MAX_INTERVAL_S = 0.5
"""Longest time between two scans that votes (longer, the odometry's path is a guess)."""

GATE_M = 0.5
"""Cap of a detection's distance to the nearest moved pole, m (less than poles' spacing)."""

MIN_VOTES = 10
"""Votes before a LiDAR is judged."""

FOUND_SHARE = 0.8
"""Share of the votes for -dpsi at which the LiDAR turns the other way from the gyro."""

MAX_VOTES = 60
"""Votes after which a LiDAR is no longer looked at."""


def _moved(points: FloatArray, mount: LidarMount, turn_rad: float, distance_m: float
           ) -> FloatArray:
    """Return first-scan points (sensor frame) where the second scan should see them.

    The platform turned by turn_rad and went distance_m along its heading half-way through
    the turn; the points are static.
    """
    c, s = math.cos(mount.yaw_rad), math.sin(mount.yaw_rad)
    # First scan: sensor frame to the first body frame.
    bx = mount.x_m + c * points[:, 0] - s * points[:, 1]
    by = mount.y_m + s * points[:, 0] + c * points[:, 1]
    # Into the second body frame.
    half = 0.5 * turn_rad
    bx = bx - distance_m * math.cos(half)
    by = by - distance_m * math.sin(half)
    ct, st = math.cos(turn_rad), math.sin(turn_rad)
    bx, by = ct * bx + st * by, -st * bx + ct * by
    # Second body frame to the sensor frame.
    bx, by = bx - mount.x_m, by - mount.y_m
    return np.column_stack([c * bx + s * by, -s * bx + c * by])


def _score(moved: FloatArray, seen: FloatArray) -> tuple[float, int]:
    """Return (sum of capped squared distances, detections within half the gate).

    The moved poles are shifted first by the mean offset of the detections within the gate
    of one (twice): the sensor's own path between the scans is free, so a LiDAR whose
    frame is mirrored (its path mirrored too) is judged by its turn alone.
    """
    for _ in range(2):
        offsets = seen[:, None, :] - moved[None, :, :]
        d2 = (offsets ** 2).sum(axis=2)
        nearest = d2.argmin(axis=1)
        best = d2[np.arange(len(seen)), nearest]
        near = best < GATE_M * GATE_M
        if not near.any():
            break
        moved = moved + offsets[np.arange(len(seen)), nearest][near].mean(axis=0)
    d2 = ((seen[:, None, :] - moved[None, :, :]) ** 2).sum(axis=2).min(axis=1)
    return float(np.minimum(d2, GATE_M * GATE_M).sum()), int((d2 < 0.25 * GATE_M ** 2).sum())


class TurnSignCheck:
    """Votes, per LiDAR, on the sign of the gyro's turn its scans show (module docstring)."""

    __slots__ = ('_last', '_votes', '_before')

    def __init__(self) -> None:
        # Per LiDAR: (detections, matched) of its scans before its first vote.
        self._before: dict[Hashable, tuple[int, int]] = {}
        # Per LiDAR: (stamp s, points, the gyro's raw integral rad).
        self._last: dict[Hashable, tuple[float, FloatArray, float]] = {}
        # Per LiDAR: (name, votes, votes for -dpsi).
        self._votes: dict[Hashable, tuple[str, int, int]] = {}

    def scan(self, key: Hashable, name: str, stamp_s: float, points: FloatArray,
             mount: LidarMount, turned_rad: float, bias_rad_s: float, speed_m_s: float
             ) -> None:
        """Look at one scan.

        turned_rad: the gyro's raw integral (bias included) up to stamp_s; speed_m_s: the
        odometry's speed held; mount: the LiDAR's mount in use.
        """
        name_votes = self._votes.get(key)
        if name_votes is not None and name_votes[1] >= MAX_VOTES:
            return
        last = self._last.get(key)
        if last is None or len(last[1]) < 2 or not 0.0 < stamp_s - last[0] <= MAX_INTERVAL_S:
            self._last[key] = (stamp_s, points, turned_rad)  # the scan to compare with
            return
        dt = stamp_s - last[0]
        turn = turned_rad - last[2] - bias_rad_s * dt
        if abs(turn) < MIN_TURN_RAD or len(points) < 2:
            return
        self._last[key] = (stamp_s, points, turned_rad)
        distance = speed_m_s * dt
        same, same_in = _score(_moved(last[1], mount, turn, distance), points)
        other, other_in = _score(_moved(last[1], mount, -turn, distance), points)
        if same < 0.5 * other and same_in >= 2:
            opposite = 0
        elif other < 0.5 * same and other_in >= 2:
            opposite = 1
        else:
            return
        _, votes, against = name_votes or (name, 0, 0)
        self._votes[key] = (name, votes + 1, against + opposite)

    def associated(self, key: Hashable, detections: int, matched: int) -> None:
        """Count a scan's detections and those matched to the map, before its first vote."""
        if key not in self._votes:
            before = self._before.get(key, (0, 0))
            self._before[key] = (before[0] + detections, before[1] + matched)

    def save(self) -> tuple[dict, dict, dict]:
        return dict(self._last), dict(self._votes), dict(self._before)

    def restore(self, saved: tuple[dict, dict, dict]) -> None:
        self._last, self._votes, self._before = (dict(part) for part in saved)

    def report(self) -> list[dict[str, Any]]:
        """Return, per LiDAR that voted, its votes, those for -dpsi, and the verdict.

        With the share of its detections matched before its first vote (None: none).
        """
        out = []
        for key, (name, votes, against) in self._votes.items():
            detections, matched = self._before.get(key, (0, 0))
            out.append({'name': name, 'votes': votes, 'opposite': against,
                        'opposite_found': votes >= MIN_VOTES and against >= FOUND_SHARE * votes,
                        'detections_before_turns': detections,
                        'associated_before_turns': matched / detections if detections
                        else None})
        return out
