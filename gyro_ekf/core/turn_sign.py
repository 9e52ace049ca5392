"""A gyro or LiDAR upside down, a gyro or odometry in the wrong units or sign: named.

An IMU mounted upside down (its z axis down, against REP-145) reads the yaw rate with the
wrong sign; so do the beams of a LiDAR mounted upside down, whose bearings run clockwise.
A driver that publishes deg/s where REP-103 has rad/s reads 57.3 times the turn; an encoder
wired backwards, or in cm/s, reads -1 or 100 times the speed. Each loses the pose within
seconds, and the run said so only by its effects ("a bias beyond 10 deg/s", "the pose is
lost", "under 50 % associated"; a gyro flipped on a 120-s trip once ended 15 m off with the
verdict degraded), never the cause, which is one sign or factor to set.

The check needs neither the map nor the filter's pose. A LiDAR's scan is compared with the
first later one after the gyro turned ``MIN_TURN_RAD`` within ``MAX_INTERVAL_S`` (the 2016
log's LiDAR scans at 37 Hz, under 1 deg apart); until the LiDAR has ``MIN_VOTES`` votes, a
few pairs (``LATE_PAIRS``) are also tried ``LATE_PAIR_S`` apart while moving, for a gyro
that reads a fraction of each turn (or a platform that turns slowly). The gyro's turn
between the two is its integral less the bias the first stop learnt (not the filter's: one
a flipped gyro misled takes the turns for a bias of 40 deg/s). The first scan's poles are
moved by that turn divided by each of ``SCALES`` (what the gyro may read per radian turned:
1, -1, 57.3, 1/57.3 and their negatives), each set shifted by the path that fits the second
scan's detections best (``_score``), and scored by the squared distance of each detection
to the nearest moved pole (capped at ``GATE_M`` squared, so a pole seen in one scan only
costs the same under all). The pair votes for the scale that scores under half the next
best with at least two detections within half the gate: between the signs the poles move by
twice the turn times their range, tens of centimetres. The path fitted under the scale
voted for, forward in the body frame, is what the platform went by the LiDAR; against the
odometry's speed times the interval (over pairs that went ``MIN_PATH_M`` or more) it gives
the odometry's ``speed_ratio``: 0.95-1.03 on the course logs, -1 for an encoder wired
backwards.

A gyro whose z axis does not see the turns at all (an IMU mounted on its side reads them on
x or y, a dead axis reads nothing) never votes: every scale of a reading of nothing is
nothing. So each pair on time alone is also scored at every turn of ``UNSEEN_TURNS_RAD``
(-30 to +30 deg), and one whose scans turned ``MIN_TURN_RAD`` or more (scoring under half
of the gyro's own turn) where the gyro read under ``UNSEEN_SHARE`` of it counts as a turn
unseen (``_look_for_unseen_turn``). On the course logs none is (60 votes each); on simulated
trips with the z axis dead or on its side, 20-22 of the 40 pairs tried.

After ``MIN_VOTES`` votes, a LiDAR whose votes are for a negative scale in at least
``FOUND_SHARE`` of them turns the other way from the gyro, and one whose votes are for one
scale other than 1 or -1 as often finds the gyro in the wrong units. With two LiDARs or
more, the one that disagrees with the others is the one upside down; all of them against
the gyro, the gyro is. With one LiDAR, scan to scan cannot tell the two apart (a mirrored
world is as consistent as the real one); the map can, before the first turn misled the
filter: an upside-down gyro leaves the detections of the scans before the LiDAR's first
vote associated as usual (``associated``: 99.8 % on the 2016 log with its gyro negated), an
upside-down LiDAR's match the map nowhere (2 % on that log mirrored). Voting stops at
``MAX_VOTES`` per LiDAR, so a long run costs a few hundred scans' work.

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

LATE_PAIR_S = 0.4
"""A pair is tried on time alone once the gyro turned less than ``MIN_TURN_RAD`` in this."""

LATE_PAIRS = 40
"""Pairs tried on time alone per LiDAR, at most (each costs about 0.2 ms), and only while
it has fewer than ``MIN_VOTES`` votes."""

LATE_PAIR_SPEED_M_S = 0.05
"""Least odometry speed for a pair on time alone (standing still, nothing is told)."""

UNSEEN_TURNS_RAD = np.radians(np.arange(-30.0, 30.5, 1.0))
"""Turns a pair on time alone is also scored at, rad: where the scans turned, whatever the
gyro read (a gyro that reads none of the turns never votes on ``SCALES``)."""

UNSEEN_SHARE = 0.1
"""A pair's scans turned unseen when the gyro read under this share of their turn."""

MIN_PATH_M = 0.05
"""Least distance the LiDAR's scans show the platform went between two scans for the pair
to weigh the odometry's."""


DEG = 180.0 / math.pi

SCALES = (1.0, -1.0, DEG, -DEG, 1.0 / DEG, -1.0 / DEG)
"""What the gyro may read per radian turned: right, upside down, in deg/s where rad/s is
due (REP-103), a rad/s rate converted as if it were deg/s; each either way up."""


def _moved(points: FloatArray, mount: LidarMount, turns_rad: FloatArray) -> FloatArray:
    """Return first-scan points (sensor frame) where the second scan should see them.

    One set (h, n, 2) per turn of turns_rad (h,): the platform turned about its origin,
    the points static (the path between the scans is fitted in ``_score``).
    """
    c, s = math.cos(mount.yaw_rad), math.sin(mount.yaw_rad)
    # First scan: sensor frame to the first body frame.
    bx = mount.x_m + c * points[:, 0] - s * points[:, 1]
    by = mount.y_m + s * points[:, 0] + c * points[:, 1]
    # Into the second body frame, one row per turn.
    ct, st = np.cos(turns_rad)[:, None], np.sin(turns_rad)[:, None]
    bx, by = ct * bx + st * by - mount.x_m, -st * bx + ct * by - mount.y_m
    # Second body frame to the sensor frame.
    return np.stack([c * bx + s * by, -s * bx + c * by], axis=2)


def _score(moved: FloatArray, seen: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Score sets of moved poles (h, n, 2) against the detections seen (m, 2).

    Returns per set the sum of capped squared distances (h,), the detections within half
    the gate (h,), and the shift fitted (h, 2; sensor frame, m). Each set is shifted by the
    mean offset of the detections within the gate of one of its poles (twice): the
    sensor's own path between the scans is free, so a LiDAR whose frame is mirrored (its
    path mirrored too) is judged by its turn alone, and the path fitted says how far the
    platform went.
    """
    rows = np.arange(len(seen))
    shift = np.zeros((len(moved), 2))
    gate = GATE_M * GATE_M
    for _ in range(2):
        offsets = seen[None, :, None, :] - (moved + shift[:, None, :])[:, None, :, :]
        d2 = (offsets ** 2).sum(axis=3)  # (h, m, n)
        nearest = d2.argmin(axis=2)  # (h, m)
        best = np.take_along_axis(d2, nearest[:, :, None], axis=2)[:, :, 0]
        near = best < gate
        picked = offsets[np.arange(len(moved))[:, None], rows[None, :], nearest]  # (h, m, 2)
        count = near.sum(axis=1)
        shift += np.where(count[:, None] > 0, (picked * near[:, :, None]).sum(axis=1)
                          / np.maximum(count, 1)[:, None], 0.0)
    d2 = ((seen[None, :, None, :] - (moved + shift[:, None, :])[:, None, :, :]) ** 2
          ).sum(axis=3).min(axis=2)
    return np.minimum(d2, gate).sum(axis=1), (d2 < 0.25 * gate).sum(axis=1), shift


class TurnSignCheck:
    """Per LiDAR, votes on the gyro's reading per radian turned, and the odometry's path."""

    __slots__ = ('_last', '_votes', '_before', '_paths', '_late', '_unseen')

    def __init__(self) -> None:
        # Per LiDAR: (detections, matched) of its scans before its first vote.
        self._before: dict[Hashable, tuple[int, int]] = {}
        # Per LiDAR: (stamp s, points, the gyro's raw integral rad).
        self._last: dict[Hashable, tuple[float, FloatArray, float]] = {}
        # Per LiDAR: (name, votes per SCALES entry).
        self._votes: dict[Hashable, tuple[str, tuple[int, ...]]] = {}
        # Per LiDAR: (pairs, sum of odometry x LiDAR distance, sum of LiDAR distance^2).
        self._paths: dict[Hashable, tuple[int, float, float]] = {}
        # Per LiDAR: pairs tried on time alone (LATE_PAIRS at most).
        self._late: dict[Hashable, int] = {}
        # Per LiDAR: (name, pairs whose scans turned where the gyro read almost none, the
        # largest such turn rad).
        self._unseen: dict[Hashable, tuple[str, int, float]] = {}

    def scan(self, key: Hashable, name: str, stamp_s: float, points: FloatArray,
             mount: LidarMount, turned_rad: float, bias_rad_s: float, speed_m_s: float
             ) -> None:
        """Look at one scan.

        turned_rad: the gyro's raw integral (bias included) up to stamp_s; speed_m_s: the
        odometry's speed held; mount: the LiDAR's mount in use.
        """
        name_votes = self._votes.get(key)
        if name_votes is not None and sum(name_votes[1]) >= MAX_VOTES:
            return
        last = self._last.get(key)
        if last is None or len(last[1]) < 2 or not 0.0 < stamp_s - last[0] <= MAX_INTERVAL_S:
            self._last[key] = (stamp_s, points, turned_rad)  # the scan to compare with
            return
        dt = stamp_s - last[0]
        turn = turned_rad - last[2] - bias_rad_s * dt
        if len(points) < 2:
            return
        if abs(turn) < MIN_TURN_RAD:
            # A gyro that reads a fraction of the turn (or a platform that turns slowly)
            # never reaches it: a few pairs are tried on time alone, while moving.
            late = self._late.get(key, 0)
            if (dt < LATE_PAIR_S or late >= LATE_PAIRS or abs(speed_m_s) < LATE_PAIR_SPEED_M_S
                    or (name_votes is not None and sum(name_votes[1]) >= MIN_VOTES)):
                return
            self._late[key] = late + 1
        self._last[key] = (stamp_s, points, turned_rad)
        if abs(turn) < MIN_TURN_RAD:
            self._look_for_unseen_turn(key, name, last[1], points, mount, turn)
        scores, inliers, shifts = _score(_moved(last[1], mount, turn / np.array(SCALES)),
                                         points)
        order = np.argsort(scores)
        best, second = int(order[0]), int(order[1])
        if not (scores[best] < 0.5 * scores[second] and inliers[best] >= 2):
            return
        votes = list(name_votes[1] if name_votes else (0,) * len(SCALES))
        votes[best] += 1
        self._votes[key] = (name, tuple(votes))
        # The platform's path from the shift fitted with the turn voted for: the points
        # moved back by it, in the body frame (the mid-turn heading's share neglected).
        c, s = math.cos(mount.yaw_rad), math.sin(mount.yaw_rad)
        lidar_m = -(c * shifts[best, 0] - s * shifts[best, 1])
        if abs(lidar_m) >= MIN_PATH_M:
            pairs, cross, square = self._paths.get(key, (0, 0.0, 0.0))
            self._paths[key] = (pairs + 1, cross + speed_m_s * dt * lidar_m,
                                square + lidar_m * lidar_m)

    def _look_for_unseen_turn(self, key: Hashable, name: str, before: FloatArray,
                              points: FloatArray, mount: LidarMount, turn: float) -> None:
        """Count a pair on time alone whose scans turned where the gyro read almost none.

        Its scans scored at every turn of UNSEEN_TURNS_RAD (the path fitted at each): one
        of MIN_TURN_RAD or more that scores under half of the gyro's own turn, with two
        detections within half the gate, while the gyro read under UNSEEN_SHARE of it: a gyro
        whose z axis does not see the platform's turns (an IMU on its side, a dead axis).
        """
        scores, inliers, _ = _score(_moved(before, mount, np.append(UNSEEN_TURNS_RAD, turn)),
                                    points)
        best = int(np.argmin(scores[:-1]))
        seen = float(UNSEEN_TURNS_RAD[best])
        if (abs(seen) >= MIN_TURN_RAD and scores[best] < 0.5 * scores[-1]
                and inliers[best] >= 2 and abs(turn) < UNSEEN_SHARE * abs(seen)):
            _, count, largest = self._unseen.get(key, (name, 0, 0.0))
            self._unseen[key] = (name, count + 1, max(largest, abs(seen)))

    def associated(self, key: Hashable, detections: int, matched: int) -> None:
        """Count a scan's detections and those matched to the map, before its first vote."""
        if key not in self._votes:
            before = self._before.get(key, (0, 0))
            self._before[key] = (before[0] + detections, before[1] + matched)

    def save(self) -> tuple[dict, ...]:
        return (dict(self._last), dict(self._votes), dict(self._before), dict(self._paths),
                dict(self._late), dict(self._unseen))

    def restore(self, saved: tuple[dict, ...]) -> None:
        self._last, self._votes, self._before, self._paths, self._late, self._unseen = (
            dict(part) for part in saved)

    def report(self) -> list[dict[str, Any]]:
        """Return, per LiDAR that voted, its votes and what they find.

        votes; opposite: those for a gyro upside down (any scale); scale: the gyro's reading
        per radian most voted for, and scale_votes its votes; opposite_found, scale_found:
        beyond FOUND_SHARE of at least MIN_VOTES; the share of its detections matched before
        its first vote (None: none); the odometry's distance over the LiDAR's
        (speed_ratio, None before MIN_VOTES pairs) over speed_pairs pairs; and the pairs
        whose scans turned where the gyro read almost none (unseen_turns, the largest
        unseen_largest_deg; unseen_found: MIN_VOTES of them at least).
        """
        out = []
        entries = dict(self._votes)
        for key, (name, _, _) in self._unseen.items():
            entries.setdefault(key, (name, (0,) * len(SCALES)))
        for key, (name, counts) in entries.items():
            _, unseen, largest = self._unseen.get(key, (name, 0, 0.0))
            votes = sum(counts)
            against = sum(n for scale, n in zip(SCALES, counts) if scale < 0.0)
            top = max(range(len(SCALES)), key=counts.__getitem__)
            detections, matched = self._before.get(key, (0, 0))
            pairs, cross, square = self._paths.get(key, (0, 0.0, 0.0))
            out.append({'name': name, 'votes': votes, 'opposite': against,
                        'opposite_found': votes >= MIN_VOTES and against >= FOUND_SHARE * votes,
                        'scale': SCALES[top], 'scale_votes': counts[top],
                        'scale_found': (abs(SCALES[top]) != 1.0 and votes >= MIN_VOTES
                                        and counts[top] >= FOUND_SHARE * votes),
                        'detections_before_turns': detections,
                        'associated_before_turns': matched / detections if detections
                        else None,
                        'speed_ratio': float(cross / square) if pairs >= MIN_VOTES else None,
                        'speed_pairs': pairs, 'unseen_turns': unseen,
                        'unseen_largest_deg': math.degrees(largest),
                        'unseen_found': unseen >= MIN_VOTES})
        return out
