"""Simulated trips for the tests: two-LiDAR trips with one mis-mounted, and one-off runs.

Not a test module: test files import it (pytest puts this folder on sys.path through the
conftest beside it).
"""

from __future__ import annotations

import dataclasses
import math

from gyro_ekf.analysis.offline import OfflineRun, run_trip
from gyro_ekf.analysis.summary import summarize
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
from gyro_ekf.core.types import Trip
from gyro_ekf.core.validation import validate_trip

FRONT_DROPOUT_S = (20.0, 30.0)
"""The front LiDAR gives no scan in this span: the rear one alone could drag the pose."""


def two_lidar_trip(seed: int, duration_s: float = 60.0, rear_yaw_error_deg: float = 0.0,
                   front_dropout_s: tuple[float, float] | None = FRONT_DROPOUT_S) -> Trip:
    """A trip with the simulator's front LiDAR and a rear one whose stated yaw is off.

    The rear LiDAR is simulated on the same seed (the path and poles depend only on the
    seed), facing backwards 0.3 m behind base_link; its stated mount then gets
    ``rear_yaw_error_deg`` added, so its detections disagree with the map as a LiDAR
    mounted that far off its stated yaw does.
    """
    config = SimulationConfig(duration_s=duration_s, static_s=0.0)
    trip = simulate_trip(config, seed)
    rear = simulate_trip(dataclasses.replace(config, lidar_x_m=-0.3, lidar_yaw_rad=math.pi),
                         seed).scans[0]
    stated = dataclasses.replace(rear.mount,
                                 yaw_rad=rear.mount.yaw_rad + math.radians(rear_yaw_error_deg))
    rear = dataclasses.replace(rear, topic='scan2', frame_id='laser2', mount=stated)
    front = trip.scans[0]
    if front_dropout_s is not None:
        keep = (front.stamp_s < front_dropout_s[0]) | (front.stamp_s >= front_dropout_s[1])
        front = dataclasses.replace(
            front, stamp_s=front.stamp_s[keep], ranges_m=front.ranges_m[keep],
            intensities=None if front.intensities is None else front.intensities[keep])
    return dataclasses.replace(trip, scans=(front, rear))


def simulated_run(duration_s: float, seed: int = 3, **changes
                  ) -> tuple[SimulationConfig, Trip, OfflineRun, dict]:
    """Simulate a trip with `changes` to the default config, run it as `gyro-ekf run` does.

    Returns the config, the validated trip, the run and its summary.json content.
    """
    config = dataclasses.replace(SimulationConfig(duration_s=duration_s), **changes)
    trip = simulate_trip(config, seed)
    trip, report = validate_trip(trip, trip.name)
    run = run_trip(trip)
    return config, trip, run, summarize(run, report)
