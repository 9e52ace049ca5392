"""Pole detection on synthetic scans ray-cast against one pole and a wall."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyro_ekf.core.config import DetectorConfig
from gyro_ekf.core.detection import PoleDetections, detect_poles
from gyro_ekf.core.errors import CoreError

INCREMENT = math.radians(0.5)
ANGLES = -math.pi / 2 + INCREMENT * np.arange(361)
RADIUS = 0.05


def _cast(poles, wall_x=None, angles=ANGLES):
    """Ranges and intensities of a scan seeing circular poles and a wall x = wall_x."""
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    ranges = np.full(angles.shape, np.inf)
    intensities = np.zeros(angles.shape)
    for cx, cy in poles:
        along = directions @ np.array([cx, cy])
        miss2 = cx * cx + cy * cy - along * along
        hit = (miss2 <= RADIUS ** 2) & (along > 0)
        r = np.where(hit, along - np.sqrt(np.maximum(RADIUS ** 2 - miss2, 0.0)), np.inf)
        closer = r < ranges
        ranges = np.where(closer, r, ranges)
        intensities = np.where(closer, 1.0, intensities)
    if wall_x is not None:
        with np.errstate(divide='ignore'):
            r = np.where(directions[:, 0] > 1e-9, wall_x / directions[:, 0], np.inf)
        closer = r < ranges
        ranges = np.where(closer, r, ranges)
        intensities = np.where(closer, 0.0, intensities)
    return ranges, intensities


def _polar(range_m, bearing_rad):
    return np.array([range_m * math.cos(bearing_rad), range_m * math.sin(bearing_rad)])


@pytest.mark.parametrize('use_intensity', [True, False])
@pytest.mark.parametrize('range_m', [1.5, 3.0, 5.0])
def test_pole_on_a_beam_is_found_within_millimetres(range_m, use_intensity):
    # Centred on beam 200, so the beams (three or more at these ranges) sample the pole
    # symmetrically.
    centre = _polar(range_m, ANGLES[200])
    ranges, intensities = _cast([centre], wall_x=12.0)
    found = detect_poles(ranges, ANGLES, intensities if use_intensity else None,
                         DetectorConfig())
    assert len(found) == 1
    assert found.used_intensities is use_intensity
    np.testing.assert_allclose(found.points_sensor_m[0], centre, atol=0.003)
    assert found.ranges_m[0] == pytest.approx(range_m, abs=0.003)
    assert found.bearings_rad[0] == pytest.approx(ANGLES[200], abs=1e-3)


@pytest.mark.parametrize('use_intensity', [True, False])
def test_far_poles_hit_by_one_beam_are_placed_without_range_bias(use_intensity):
    # At 8-9 m a 10 cm pole spans 0.64-0.72 deg: under 0.5 deg beams mostly one beam hits
    # it, anywhere across it. Pushing that return back by R would put the centre 1 cm too
    # far on average; pi R / 4 leaves no bias.
    rng = np.random.default_rng(11)
    errors = []
    for _ in range(300):
        bearing = ANGLES[200] + rng.uniform(-0.5, 0.5) * INCREMENT
        centre = _polar(rng.uniform(8.0, 9.0), bearing)
        ranges, intensities = _cast([centre], wall_x=12.0)
        found = detect_poles(ranges, ANGLES, intensities if use_intensity else None,
                             DetectorConfig())
        if len(found) == 1 and found.beam_counts[0] == 1:
            errors.append(found.ranges_m[0] - np.hypot(*centre))
    errors = np.array(errors)
    assert errors.size > 100
    assert abs(errors.mean()) < 0.002
    assert np.abs(errors).max() <= (1.0 - math.pi / 4.0) * RADIUS + 1e-3


def test_pole_anywhere_is_found_within_beam_quantisation():
    rng = np.random.default_rng(7)
    for _ in range(50):
        range_m = rng.uniform(1.0, 10.0)
        centre = _polar(range_m, rng.uniform(-1.4, 1.4))
        ranges, intensities = _cast([centre], wall_x=12.0)
        for values in (intensities, None):
            found = detect_poles(ranges, ANGLES, values, DetectorConfig())
            assert len(found) == 1
            # Lateral error is bounded by half a beam spacing at that range.
            error = np.linalg.norm(found.points_sensor_m[0] - centre)
            assert error < 0.005 + 0.5 * INCREMENT * range_m


def test_single_beam_pole_at_long_range_counts_in_width_mode():
    centre = _polar(9.0, ANGLES[100] + 0.1 * INCREMENT)
    ranges, _ = _cast([centre], wall_x=14.0)
    assert np.isfinite(ranges).sum() > 0
    found = detect_poles(ranges, ANGLES, None, DetectorConfig())
    assert len(found) == 1
    assert found.beam_counts[0] <= 2
    assert DetectorConfig().min_width_m <= found.widths_m[0] <= DetectorConfig().max_width_m


def test_wall_is_not_a_pole():
    ranges, intensities = _cast([], wall_x=3.0)
    for values in (intensities, None):
        found = detect_poles(ranges, ANGLES, values, DetectorConfig())
        assert len(found) == 0
        assert found.cluster_count >= 1


def test_grazing_wall_beams_are_not_poles_in_width_mode():
    # A wall along the left side: far beams split into single-beam clusters at range jumps,
    # each narrow enough to pass the width test, but each has a closer neighbour.
    angles = ANGLES
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    with np.errstate(divide='ignore'):
        ranges = np.where(directions[:, 1] > 1e-9, 1.0 / directions[:, 1], np.inf)
    ranges[ranges > 40.0] = np.inf
    found = detect_poles(ranges, angles, None, DetectorConfig())
    assert len(found) == 0
    loose = detect_poles(ranges, angles, None, DetectorConfig(), require_foreground=False)
    assert len(loose) > 0


def test_reflective_wall_is_refused_by_its_chord():
    ranges, _ = _cast([], wall_x=3.0)
    ranges[np.abs(ANGLES) > math.radians(30.0)] = np.inf
    all_reflective = np.ones_like(ranges)
    found = detect_poles(ranges, ANGLES, all_reflective, DetectorConfig())
    assert len(found) == 0 and found.cluster_count == 1


def test_intensity_mode_uses_only_reflective_returns():
    # A pole touching the wall joins the wall's cluster; only its reflective returns count.
    centre = _polar(2.95, ANGLES[180])
    ranges, intensities = _cast([centre], wall_x=3.0)
    found = detect_poles(ranges, ANGLES, intensities, DetectorConfig())
    assert len(found) == 1
    np.testing.assert_allclose(found.points_sensor_m[0], centre, atol=0.003)
    assert found.last_beams[0] - found.first_beams[0] > 50  # the wall's cluster
    # Without intensities the same cluster is as wide as the wall: no pole.
    assert len(detect_poles(ranges, ANGLES, None, DetectorConfig())) == 0


def test_non_reflective_narrow_object_depends_on_mode():
    centre = _polar(4.0, ANGLES[150])
    ranges, _ = _cast([centre], wall_x=12.0)
    zeros = np.zeros_like(ranges)
    assert len(detect_poles(ranges, ANGLES, zeros, DetectorConfig())) == 0
    assert len(detect_poles(ranges, ANGLES, None, DetectorConfig())) == 1


@pytest.mark.parametrize('use_intensity', [True, False])
@pytest.mark.parametrize('range_m', [1.0, 2.0, 4.0])
def test_pole_cut_by_the_field_of_view_is_placed_from_its_inner_edge(range_m, use_intensity):
    # Centres from a quarter beam to 2.5 beams outside the first and last beams: part of
    # the pole is never sampled, so the centroid of its returns lies inward of the centre.
    step = float(ANGLES[1] - ANGLES[0])
    for beyond in (0.25, 1.0, 2.5):
        for bearing in (ANGLES[0] - beyond * step, ANGLES[-1] + beyond * step):
            centre = _polar(range_m, bearing)
            ranges, intensities = _cast([centre], wall_x=12.0)
            found = detect_poles(ranges, ANGLES, intensities if use_intensity else None,
                                 DetectorConfig(min_width_m=0.0))
            if not intensities.any():  # far and outside enough that no beam hits it
                assert len(found) == 0
                continue
            assert len(found) == 1, (beyond, bearing)
            assert found.first_beams[0] == 0 or found.last_beams[0] == ANGLES.size - 1
            # Half a beam of edge quantisation: r * step / 2 across the ray at most.
            error = np.linalg.norm(found.points_sensor_m[0] - centre)
            assert error < range_m * step / 2 + 0.003, (beyond, bearing, error)


def test_cut_pole_hidden_on_its_inner_side_is_not_reported():
    step = float(ANGLES[1] - ANGLES[0])
    far = _polar(3.0, ANGLES[0] - 0.5 * step)
    near = _polar(1.0, ANGLES[0] + 7 * step)
    alone, intensities = _cast([far])
    assert len(detect_poles(alone, ANGLES, intensities, DetectorConfig())) == 1
    # A closer pole right next to it hides its inner edge: only the near one is reported.
    ranges, intensities = _cast([far, near])
    assert np.isfinite(ranges[:2]).all() and ranges[1] > 2.0 and ranges[2] < 1.5
    found = detect_poles(ranges, ANGLES, intensities, DetectorConfig())
    assert len(found) == 1
    np.testing.assert_allclose(found.points_sensor_m[0], near, atol=0.003)


def test_cut_pole_with_beams_in_decreasing_angle_order():
    # A scan may run clockwise (negative angle increment): the edge logic must follow.
    angles = ANGLES[::-1].copy()
    step = float(angles[1] - angles[0])
    for bearing in (angles[0] - step, angles[-1] + step):   # beyond either end
        centre = _polar(2.0, bearing)
        ranges, intensities = _cast([centre], angles=angles)
        found = detect_poles(ranges, angles, intensities, DetectorConfig())
        assert len(found) == 1
        error = np.linalg.norm(found.points_sensor_m[0] - centre)
        assert error < 2.0 * abs(step) / 2 + 0.003, (bearing, error)


def test_pole_filling_the_whole_field_of_view_is_not_reported():
    angles = np.radians([-1.0, -0.5, 0.0, 0.5, 1.0])
    ranges, intensities = _cast([_polar(1.0, 0.0)], angles=angles)
    assert np.isfinite(ranges).all()
    assert len(detect_poles(ranges, angles, intensities, DetectorConfig())) == 0


def test_invalid_beams_split_clusters():
    ranges = np.full(361, 5.0)
    ranges[100:108] = 2.0           # an object in front
    ranges[104] = np.nan            # split in two by a NaN: 4 + 3 beams, both pole-wide
    ranges[200:203] = 60.0          # beyond max_range_m
    found = detect_poles(ranges, ANGLES, None, DetectorConfig())
    assert found.cluster_count == 5
    assert len(found) == 2


def test_empty_and_all_invalid_scans():
    for ranges in (np.full(361, np.inf), np.full(361, np.nan), np.zeros(361)):
        found = detect_poles(ranges, ANGLES, np.zeros(361), DetectorConfig())
        assert isinstance(found, PoleDetections)
        assert len(found) == 0 and found.cluster_count == 0
        assert found.points_sensor_m.shape == (0, 2)
    found = detect_poles(np.zeros(0), np.zeros(0), None, DetectorConfig())
    assert len(found) == 0


def test_float32_input_and_default_config():
    centre = _polar(3.0, ANGLES[200])
    ranges, intensities = _cast([centre], wall_x=12.0)
    found = detect_poles(ranges.astype(np.float32), ANGLES, intensities.astype(np.float32))
    assert len(found) == 1
    np.testing.assert_allclose(found.points_sensor_m[0], centre, atol=0.003)


def test_shape_mismatch_is_refused():
    with pytest.raises(CoreError, match='same length'):
        detect_poles(np.ones(10), np.ones(9), None)
    with pytest.raises(CoreError, match='intensities'):
        detect_poles(np.ones(10), np.ones(10), np.ones(3))


@pytest.mark.parametrize('with_intensity', [True, False])
def test_batched_detection_equals_scan_by_scan(with_intensity):
    from gyro_ekf.core.detection import detect_poles_in_scans
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    scans = simulate_trip(SimulationConfig(duration_s=20.0), seed=5).scans[0]
    ranges = scans.ranges_m.copy()
    ranges[3, :40] = np.inf          # a scan with a gap at its start ...
    ranges[4, -1] = ranges[5, 0]     # ... and scans whose edge beams could join up
    intensities = scans.intensities if with_intensity else None
    batched = detect_poles_in_scans(ranges, scans.angles_rad, intensities)
    assert len(batched) == ranges.shape[0]
    assert sum(len(found) for found in batched) > 100
    for k, found in enumerate(batched):
        single = detect_poles(ranges[k], scans.angles_rad,
                              None if intensities is None else intensities[k])
        for name in ('points_sensor_m', 'widths_m', 'beam_counts', 'first_beams',
                     'last_beams'):
            np.testing.assert_array_equal(getattr(found, name), getattr(single, name))
        assert found.cluster_count == single.cluster_count
