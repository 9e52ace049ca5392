"""A stop the odometry calls still while the LiDARs see the platform turn in place.

At a stop (the odometry reads no speed, the gyro's spread is low) the filter applies
zero-rate updates: the gyro's rate there is taken for its bias (core/events.py). A platform
turning slowly on the spot reads no speed and a steady rate with the usual spread, so the
zero-rate logic cannot tell it from a still one, and the filter takes the turn for bias:
a 0.2 deg/s turn at a 10-s start left the verdict degraded for reasons that named
everything but the cause (innovations not white, stamp jitter, the bias "changed").

The LiDARs can tell. Every pole they follow through the stop turns back about the platform
as it turns (``calibration.pole_turn``, as ``gyro-ekf calibrate`` and the calibration node
check a static window). ``RestTurnWatch`` keeps each LiDAR's poles of the scans taken while
zero-rate updates were applied and judges each stop when it ends: a net turn beyond
``MAX_SCAN_TURN_RAD_S`` (0.02 deg/s) and 3 sigmas is reported, and the verdict names it
(core/health.py). It changes nothing in the filter: by the time a stop's scans can tell a
slow turn (a 5-s window resolves about 0.035 deg/s) its updates are in.

The driver does not know a LiDAR's beam step, so a pole's half-beam steps are counted at
``LIVE_BEAM_STEP_RAD`` (0.5 deg, as the calibration node does): a finer LiDAR is judged
more leniently than it could be, never more strictly.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyro_ekf.core.calibration import LIVE_BEAM_STEP_RAD, pole_turn
from gyro_ekf.core.models import sensor_to_map
from gyro_ekf.core.types import FloatArray, LidarMount

MAX_STOP_SCANS = 512
"""Scans kept per LiDAR and stop; beyond it every other one is let go (the stop is still
covered end to end, more thinly: the net turn rests on its first and last fifth)."""

MIN_STOP_SCANS = 10
"""Fewer scans of a stop than this say nothing of a turn (pole_turn needs five per pole)."""

MIN_STOP_S = 2.0
"""A stop's scans spanning less than this are not judged. A turn fast enough to show in a
short stop is the zero-rate logic's to see in the gyro's mean; the poles of a short stop
tell a rate only to some 0.2 deg/s, from ends of two or three scans whose scatter is itself
ill known (the real 2021 log: a 0.3-s stop of 13 scans read -0.69 +- 0.21 deg/s, its gyro
still)."""

_BODY = np.zeros(3)
"""The platform's own pose: sensor_to_map at it places points in the body frame."""


class RestTurnWatch:
    """Each stop's LiDAR scans, judged for a turn in place when the stop ends.

    Attributes:
        turns: the stops judged turning, as ``report`` gives them, oldest first.
    """

    def __init__(self) -> None:
        """Start with no stop and nothing found."""
        self.turns: list[dict[str, Any]] = []
        self._scans: dict[str, list[tuple[float, FloatArray, LidarMount]]] = {}
        # The open stop's last judgement per LiDAR: its scan list (the object), how many
        # scans and up to which stamp it held then, and the turn found (or None).
        self._judged: dict[str, tuple[list, int, float, dict[str, Any] | None]] = {}

    def add(self, sensor: str, stamp_s: float, points_sensor_m: FloatArray,
            mount: LidarMount) -> None:
        """Keep a scan's poles (sensor frame, its mount in use) taken during zero-rate updates."""
        scans = self._scans.setdefault(sensor, [])
        scans.append((stamp_s, points_sensor_m, mount))
        if len(scans) >= 2 * MAX_STOP_SCANS:
            # A new list, not the old one cut: a saved state still holds the old one.
            self._scans[sensor] = scans[::2]

    def close(self, stamp_s: float | None) -> None:
        """End the stop at ``stamp_s``: judge what each LiDAR saw, then forget it."""
        for sensor, scans in self._scans.items():
            turn = _judge(sensor, scans)
            if turn is not None:
                self.turns.append(turn if stamp_s is None else {**turn, 'end_s': stamp_s})
        self._scans, self._judged = {}, {}

    def report(self, stamp_s: float | None = None) -> list[dict[str, Any]]:
        """Return the stops judged turning and the stop under way if it turns (JSON-ready).

        Each: lidar (its name), start_s and end_s (the stop's scans; the stop under way's
        ends at ``stamp_s`` when given), rate_deg_s (the net turn rate its poles showed,
        counter-clockwise positive), sigma_deg_s, poles (followed through half the scans),
        scans. The stop under way is judged again only once its scans run ``MIN_STOP_S``
        past the last judgement (the EKF node asks at every diagnostics tick, and a long
        stop's 512-1024 scans took some 20 ms each time), so what it says of it may lag
        by as much.
        """
        found = list(self.turns)
        for sensor, scans in self._scans.items():
            if not scans:
                continue
            judged = self._judged.get(sensor)
            if (judged is None or judged[0] is not scans or len(scans) < judged[1]
                    or scans[-1][0] - judged[2] >= MIN_STOP_S):
                judged = self._judged[sensor] = (scans, len(scans), scans[-1][0],
                                                 _judge(sensor, scans))
            if judged[3] is not None:
                found.append(judged[3] if stamp_s is None else {**judged[3], 'end_s': stamp_s})
        return found

    def save(self) -> tuple:
        """Return the state in O(LiDARs): the lists are only appended to (or replaced)."""
        return ((self.turns, len(self.turns)),
                {name: (scans, len(scans)) for name, scans in self._scans.items()})

    def restore(self, saved: tuple) -> None:
        """Put back a state from ``save``."""
        (turns, n), scans = saved
        self.turns = turns[:n]
        # New lists: a judgement of the old ones is not theirs (report compares objects).
        self._scans = {name: entries[:n] for name, (entries, n) in scans.items()}


def _judge(sensor: str, scans: list[tuple[float, FloatArray, LidarMount]]
           ) -> dict[str, Any] | None:
    """Return what one LiDAR's scans of a stop say of a turn (``report``'s entry), or None."""
    if len(scans) < MIN_STOP_SCANS or scans[-1][0] - scans[0][0] < MIN_STOP_S:
        return None
    turn = pole_turn([scan[0] for scan in scans],
                     [sensor_to_map(_BODY, points, mount) for _, points, mount in scans],
                     LIVE_BEAM_STEP_RAD)
    if turn is None or not turn.turning:
        return None
    return {'lidar': sensor, 'start_s': scans[0][0], 'end_s': scans[-1][0],
            'rate_deg_s': math.degrees(turn.rate_rad_s),
            'sigma_deg_s': math.degrees(turn.sigma_rad_s),
            'poles': turn.poles, 'scans': turn.scans}
