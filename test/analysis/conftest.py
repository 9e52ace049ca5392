"""A short simulated trip run offline once per session (shared by the analysis tests)."""

from __future__ import annotations

import pytest

from gyro_ekf.analysis.offline import run_trip
from gyro_ekf.core.simulator import SimulationConfig, simulate_trip


@pytest.fixture(scope='session')
def short_run():
    """OfflineRun of a seeded 30 s simulated trip (static start, ground truth)."""
    trip = simulate_trip(SimulationConfig(duration_s=30.0), seed=1)
    return run_trip(trip)
