"""ekf_node says a gyro scale that is off in /diagnostics, as `gyro-ekf run` does.

The bag is a simulated 120-s trip (seed 3) whose gyro reads 1.01 times the true yaw rate.
Until the scale is known the bias takes in 1 % of every turn; the heading the LiDARs hold
measures it (core/gyro_scale.py), both say so with the same figure and both apply it at
the same scan (on this trip, its last).

In its own module, so its processes run in their own ROS domain next to nobody else's.
"""

from __future__ import annotations

import pytest

from ekf_harness import run_and_replay

pytestmark = pytest.mark.ros

SAID = "the gyro's scale is off: "


@pytest.fixture(scope='module')
def scaled_run(ros_processes, tmp_path_factory):
    """The bag through the detector and EKF nodes, and through `gyro-ekf run`."""
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip

    trip = simulate_trip(SimulationConfig(duration_s=120.0, gyro_scale_error=0.01), 3)
    return run_and_replay(ros_processes, trip, tmp_path_factory.mktemp('scale'))


def test_node_says_the_gyro_scale_as_the_offline_run_does(scaled_run):
    offline, (_, _, values), replay = scaled_run
    assert 'all acknowledged: True' in replay
    scale = offline['gyro_scale']
    assert scale['found'] and abs(scale['scale_error'] - 0.01) < 0.001, scale
    assert any(r.startswith(SAID) for r in offline['health']['reasons'])
    print(f"gyro scale: node {values['gyro_scale_error']} +- "
          f"{values['gyro_scale_error_sigma']}, offline {scale['scale_error']:.5f}")
    assert values['gyro_scale_off'] == 'true'
    # The same windows of the same data: the same figure, to the digits shown.
    assert values['gyro_scale_error'] == f"{scale['scale_error']:.5f}"
    assert values['gyro_scale_applied'] == str(scale['applied'])
    assert values['gyro_scale_error_in_use'] == f"{scale['in_use']:.5f}"
    assert values['verdict'] == 'degraded'
    assert any(r.startswith(SAID) for r in values['verdict_reasons'].split(' | '))
