"""Helpers of the io tests: small synthetic course logs and a synthetic trip.

The synthetic logs are written with scipy.io.savemat in the layout of each vintage (see
../shared/data/mtrn4010/README.md), small enough to build per test, and let the error tests
corrupt one field at a time. Real logs come only through the `shared_data` fixture.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

import numpy as np
import scipy.io

from gyro_ekf.core.types import (
    GroundTruth, ImuSeries, LandmarkMap, LidarMount, NoiseFigures, ScanSeries, SpeedSeries,
    Trip)

T0_COUNTS = 25_435_735
"""First stamp of the synthetic logs, counts of 0.1 ms (as in the real 2016 log)."""
POLE_LOG_DEG = 135.0
"""Bearing of the synthetic pole in the 2016 convention (0 = right): 45 deg left of ahead."""
POLE_RANGE_CM = 512
SIM_POLE_DEG = -30.0
"""Bearing of the synthetic pole in the simulated logs (ROS convention)."""


def _counts(n: int, step: int, offset: int = 0) -> np.ndarray:
    return (T0_COUNTS + offset + step * np.arange(n)).astype(np.uint32)


def sick_scans(m: int) -> np.ndarray:
    """SICK words (361, m): no return everywhere but a reflective pole at POLE_LOG_DEG."""
    words = np.full((361, m), 8191, dtype=np.uint16)
    beam = int(POLE_LOG_DEG / 0.5)
    words[beam - 1:beam + 2, :] = POLE_RANGE_CM | (5 << 13)
    words[10, :] = 250  # a plain return, intensity 0
    return words


def write_2016(folder: Path, n: int = 120, m: int = 12,
               change: Callable[[dict[str, Any]], None] | None = None) -> list[Path]:
    """Write a 2016 trio into `folder`; `change` may edit the variables before saving."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    data = rng.normal(0.0, 0.01, (9, n)).astype(np.float32)
    data[2] -= 1.0
    variables = {
        'IMU': {'times': _counts(n, 50), 'DATAf': data, 'N': n},
        'Vel': {'times': _counts(n, 50), 'speeds': np.linspace(0, 1, n).astype(np.float32),
                'N': n},
        'dataL': {'times': _counts(m, 270, offset=40), 'Scans': sick_scans(m), 'N': m,
                  'angles': np.deg2rad(np.arange(361) * 0.5).astype(np.float32)},
    }
    if change is not None:
        change(variables)
    paths = []
    for name, file_name in (('IMU', 'IMU_dataC.mat'), ('Vel', 'Speed_dataC.mat'),
                            ('dataL', 'Laser__2C.mat')):
        scipy.io.savemat(folder / file_name, {name: variables[name]})
        paths.append(folder / file_name)
    return paths


def write_map(path: Path) -> Path:
    """Write a MapMTRN4010.mat-style map of three landmarks."""
    path.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(path, {'Map': {'x': np.array([1.0, 2.0, 3.0], dtype=np.float32),
                                    'y': np.array([4.0, 5.0, 6.5], dtype=np.float32),
                                    'n': 3}})
    return path


def write_2021(folder: Path, with_map: bool = True, samples: int = 100, m: int = 10,
               change: Callable[[dict[str, Any]], None] | None = None) -> Path:
    """Write a 2021 event table (and, by default, its map beside it) into `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    n = samples + m
    kinds = np.zeros(n, dtype=bool)
    kinds[np.linspace(3, n - 1, m).astype(int)] = True
    z = np.zeros((3, n), dtype=np.int32)
    z[0] = np.arange(n) * 7          # mm/s
    z[1] = np.arange(n) % 50 - 25    # 0.01 deg/s
    z[2] = -1
    z[2, kinds] = np.arange(1, m + 1)
    variables = {'A': {'t': (99_960 + 50 * np.arange(n)).astype(np.uint32), 'Z': z,
                       'scans': sick_scans(m), 'L': n}}
    if change is not None:
        change(variables)
    path = folder / 'Measurements_AAS01.mat'
    scipy.io.savemat(path, variables)
    if with_map:
        write_map(folder / 'MapMTRN4010.mat')
    return path


def _sim_table(samples: int, m: int) -> np.ndarray:
    n = samples + m
    kinds = np.full(n, 2, dtype=np.uint32)
    scan_events = np.linspace(0, n - 1, m).astype(int)
    kinds[scan_events] = 1
    index = np.zeros(n, dtype=np.uint32)
    index[kinds == 1] = np.arange(1, m + 1)
    index[kinds == 2] = np.arange(1, samples + 1)
    return np.vstack([(100 * np.arange(n)).astype(np.uint32), index, kinds])


def _sim_poses(m: int) -> np.ndarray:
    return np.vstack([np.linspace(1, 2, m), np.linspace(3, 4, m),
                      np.linspace(0.1, 0.5, m)]).astype(np.float32)


def write_2022(path: Path, samples: int = 100, m: int = 8,
               change: Callable[[dict[str, Any]], None] | None = None) -> Path:
    """Write a data019b-style simulated log; a pole at SIM_POLE_DEG in every scan."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2)
    scans = np.full((321, m), 16000, dtype=np.uint16)
    beam = int(round((SIM_POLE_DEG + 80.0) / 0.5))
    scans[beam, :] = 733
    data = {
        'table': _sim_table(samples, m),
        'vw': np.vstack([rng.uniform(0, 1, samples), rng.normal(0, 0.1, samples)]
                        ).astype(np.float32),
        'scans': scans,
        'verify': {'poseL': _sim_poses(m)},
        'pose0': np.array([1.0, 3.0, 0.1], dtype=np.float32),
        'LidarCfg': {'Lx': 0.4, 'Ly': 0, 'Alpha': 90,
                     'info': "LiDAR's pose in UGV's CF=[Lx;Ly;Alpha], in [m,m,deg]"},
        'Landmarks': np.array([[5.0, 6.0], [7.0, 8.0]], dtype=np.float32),
        'Walls': np.array([[0, 0, np.nan, 15], [0, 10, np.nan, 0]], dtype=np.float32),
        'etc': {'ns': np.array([0.08, 0.017453292, 2, 0.005235988], dtype=np.float32)},
    }
    if change is not None:
        change(data)
    scipy.io.savemat(path, {'data': data})
    return path


def write_2023(path: Path, samples: int = 100, m: int = 8,
               change: Callable[[dict[str, Any]], None] | None = None) -> Path:
    """Write a DataUsr_006k-style two-LiDAR log; a pole at SIM_POLE_DEG in `scans2`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    first = np.full((301, m), 1000, dtype=np.uint16)
    first[0, :] = 0
    second = np.zeros((301, m), dtype=np.uint16)
    beam = int(round((SIM_POLE_DEG + 75.0) / 0.5))
    second[beam, :] = 421 | (3 << 14)
    lidar = {'Lx': 0.4, 'Ly': 0, 'Alpha': 0, 'FoV': np.array([-75.0, 75.0, 0.5])}
    data = {
        'table': _sim_table(samples, m),
        'vw': np.vstack([rng.uniform(0, 1, samples), rng.normal(0, 0.1, samples)]
                        ).astype(np.float32),
        'scans': first, 'scans2': second,
        'verify': {'poseL': _sim_poses(m)},
        'pose0': np.array([1.0, 3.0, 0.1], dtype=np.float32),
        'LidarsCfg': {'Lidar1': lidar, 'Lidar2': dict(lidar, Alpha=math.pi)},
        'Context': {'Landmarks': np.array([[5.0, 6.0, 7.0], [7.0, 8.0, 9.0]],
                                          dtype=np.float32),
                    'Walls': np.array([[0, 0], [0, 10]], dtype=np.float32)},
    }
    if change is not None:
        change(data)
    scipy.io.savemat(path, {'data': data})
    return path


def make_trip(seed: int = 0, n: int = 400, m: int = 30) -> Trip:
    """Build a trip by hand using every Trip feature (3-axis gyro, accel, two LiDARs, ...)."""
    rng = np.random.default_rng(seed)
    imu_s = np.cumsum(rng.uniform(0.004, 0.006, n))
    speed_s = np.cumsum(rng.uniform(0.009, 0.011, n // 2))
    scan_s = np.cumsum(rng.uniform(0.05, 0.3, m))
    ranges = rng.uniform(0.1, 30.0, (m, 181)).astype(np.float32)
    ranges[rng.random((m, 181)) < 0.1] = np.inf
    second = rng.uniform(0.1, 10.0, (m, 91)).astype(np.float32)
    return Trip(
        name=f'synthetic{seed}',
        imu=ImuSeries(stamp_s=imu_s, angular_velocity_rad_s=rng.normal(0, 0.3, (n, 3)),
                      axes_known=(True, True, True),
                      linear_acceleration_m_s2=rng.normal(0, 1, (n, 3))),
        speed=SpeedSeries(stamp_s=speed_s, speed_m_s=rng.uniform(-1, 2, speed_s.size)),
        scans=(
            ScanSeries(stamp_s=scan_s, ranges_m=ranges,
                       intensities=rng.integers(0, 8, (m, 181)).astype(np.float32),
                       angle_min_rad=-math.pi / 2, angle_increment_rad=math.pi / 180,
                       range_min_m=0.05, range_max_m=40.0, mount=LidarMount(0.3, -0.1, 0.2)),
            ScanSeries(stamp_s=scan_s + 0.01, ranges_m=second, intensities=None,
                       angle_min_rad=-0.75, angle_increment_rad=1.5 / 90, range_min_m=0.0,
                       range_max_m=12.0, mount=LidarMount(-0.2, 0.0, math.pi),
                       topic='scan2', frame_id='laser2')),
        landmarks=LandmarkMap(rng.uniform(-20, 20, (7, 2))),
        initial_pose=np.array([1.5, -2.5, 0.7]),
        ground_truth=GroundTruth(stamp_s=scan_s, pose=np.column_stack([
            rng.normal(0, 5, m), rng.normal(0, 5, m), rng.uniform(-3.1, 3.1, m)])),
        true_gyro_bias_rad_s=np.array([0.001, -0.002, 0.003]),
        noise=NoiseFigures(gyro_rad_s=0.02, speed_m_s=0.05, range_m=None, bearing_rad=0.01,
                           landmark_m=0.0),
        walls=None,
        static_duration_s=1.25)


def leftovers(folder: Path) -> list[str]:
    """Names in `folder`, hidden temporaries included (for 'nothing left behind' checks)."""
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []
