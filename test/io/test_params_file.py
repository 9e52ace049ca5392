"""ROS 2 params YAML -> core configs."""

from __future__ import annotations

import dataclasses
import json
import math

from bag_edit import rewrite
import numpy as np
import pytest

from gyro_ekf.cli.main import main
from gyro_ekf.io.bag_reader import read_bag
from gyro_ekf.io.errors import ParamsFileError
from gyro_ekf.io.params_file import read_params_file, read_params_text
from gyro_ekf.core.config import DetectorConfig, EkfConfig, InputLimits, RunOptions

TEXT = """
/**:
  ros__parameters:
    gyro_noise_rad_s: 0.02
    use_sim_time: true
    initial_pose: {x_m: 1.0, y_m: 2.0, yaw_rad: 0.5}
    lidar:
      topics: [scan]
      scan: {frame_id: laser, x_m: 0.4, y_m: 0.0, yaw_rad: 0.0}
/robot/ekf_node:
  ros__parameters:
    gyro_noise_rad_s: 0.03
    gate_probability: 0.999
    use_stated_noise: false
landmark_detector_node:
  ros__parameters:
    max_width_m: 0.3
calibration_node:
  ros__parameters:
    window_length_s: 4
replayer:
  ros__parameters:
    gyro_noise_rad_s: 9.0
    rate: 2.0
"""


def test_node_sections_override_the_wildcard_and_other_nodes_are_ignored():
    params = read_params_text(TEXT, 'p.yaml')
    assert params.ekf.gyro_noise_rad_s == 0.03
    assert params.ekf.gate_probability == 0.999
    assert params.ekf.speed_noise_m_s == EkfConfig().speed_noise_m_s
    assert params.detector.max_width_m == 0.3
    assert params.calibration.window_length_s == 4.0
    assert params.options == RunOptions(use_stated_noise=False)
    assert params.explicit['options'] == ('use_stated_noise',)
    assert params.explicit['ekf'] == ('gate_probability', 'gyro_noise_rad_s')


def test_out_of_bounds_value_names_the_file_and_parameter(tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('/**:\n  ros__parameters:\n    gate_probability: 1.5\n')
    with pytest.raises(ParamsFileError, match=r"bad\.yaml.*'gate_probability' = 1\.5"):
        read_params_file(path)


def test_wrong_type_and_bad_layout_are_reported(tmp_path):
    with pytest.raises(ParamsFileError, match="p.yaml: parameter 'range_noise_m' must be"):
        read_params_text('/**:\n  ros__parameters:\n    range_noise_m: far\n', 'p.yaml')
    with pytest.raises(ParamsFileError, match="section 'ekf_node' has no 'ros__parameters'"):
        read_params_text('ekf_node:\n  gyro_noise_rad_s: 0.1\n', 'p.yaml')
    with pytest.raises(ParamsFileError, match='p.yaml: not valid YAML'):
        read_params_text('/**: [unclosed', 'p.yaml')
    with pytest.raises(ParamsFileError, match='missing.yaml: cannot read'):
        read_params_file(tmp_path / 'missing.yaml')


def test_a_bag_sidecar_is_a_valid_params_file_with_no_filter_values():
    sidecar = ('/**:\n  ros__parameters:\n    trip: {name: x, log_time_zero_ns: 1}\n'
               '    noise: {gyro_rad_s: 0.01}\n    true_gyro_bias_rad_s: [0.0, 0.0, 0.1]\n')
    params = read_params_text(sidecar, 's.yaml')
    assert params.ekf == EkfConfig()
    assert math.isclose(params.calibration.window_length_s, 5.0)


def test_a_bag_sidecars_own_entries_are_said_to_come_from_the_bag(caplog):
    # A stated figure written into the params file: the node takes it, `run` takes the
    # bag's (its sidecar's). Said in one line, with the parameter that sets the sigma.
    sidecar = ('/**:\n  ros__parameters:\n    trip: {name: x, log_time_zero_ns: 1}\n'
               '    noise: {gyro_rad_s: 0.01}\n    true_gyro_bias_rad_s: [0.0, 0.0, 0.1]\n')
    read_params_text(sidecar, 's.yaml')
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == [
        "s.yaml: noise.*, trip.*, true_gyro_bias_rad_s: a bag sidecar's own entries; run "
        "takes them from the bag's sidecar (BAG.params.yaml), not from --params-file (to set "
        "a sigma, write e.g. gyro_noise_rad_s with use_stated_noise: false); ignored"]


@pytest.mark.parametrize('line, message', [
    # NaN passes every bounds comparison, so it is refused by name before them.
    ('gyro_noise_rad_s: .nan', "'gyro_noise_rad_s' = nan is not finite"),
    ('speed_noise_m_s: .inf', "'speed_noise_m_s' = inf is not finite"),
    ('max_width_m: -.inf', "'max_width_m' = -inf is not finite"),
    ('calibration_bias_sigma_rad_s: .nan', "'calibration_bias_sigma_rad_s' = nan is not"),
    ('calibration_bias_sigma_rad_s: -0.1', "'calibration_bias_sigma_rad_s' = -0.1 is outside"),
])
def test_non_finite_values_are_refused_naming_file_and_key(tmp_path, line, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(f'/**:\n  ros__parameters:\n    {line}\n')
    with pytest.raises(ParamsFileError) as caught:
        read_params_file(path)
    assert str(caught.value).startswith(f'{path}: parameter ')
    assert message in str(caught.value)


@pytest.mark.parametrize('name', ['use_stated_noise', 'use_calibration'])
@pytest.mark.parametrize('value', ['-1.0', '1', 'yes please', '[]'])
def test_a_switch_that_is_not_true_or_false_is_refused(name, value):
    # Found by `make fuzz`: `use_calibration: -1.0` was taken (and read as true).
    with pytest.raises(ParamsFileError,
                       match=f"p.yaml: parameter '{name}' must be true or false, got"):
        read_params_text(f'/**:\n  ros__parameters:\n    {name}: {value}\n', 'p.yaml')
    options = read_params_text(f'/**:\n  ros__parameters:\n    {name}: true\n').options
    assert getattr(options, name) is True


def test_a_misspelt_name_is_warned_about_and_limits_are_read(caplog):
    # A typo left the parameter at its default with only a debug line; limits.* (which
    # the nodes take) were skipped by `run`.
    params = read_params_text(
        '/**:\n  ros__parameters:\n    gyro_noize_rad_s: 0.02\n    map_frame: world\n'
        '    limits.max_speed_m_s: 10.0\nekf_nod:\n  ros__parameters:\n'
        '    gyro_noise_rad_s: 0.5\nlandmark_detector_node:\n  ros__parameters:\n'
        '    detector.max_widht_m: 0.3\n', 'typo.yaml')
    warnings = [r.getMessage() for r in caplog.records if r.levelname == 'WARNING']
    assert warnings == [
        "typo.yaml: /**: 'gyro_noize_rad_s' is not a parameter (did you mean "
        "'gyro_noise_rad_s'?); ignored",
        "typo.yaml: section 'ekf_nod' is not one of the pipeline's nodes (did you mean "
        "'ekf_node'?); skipped",
        "typo.yaml: landmark_detector_node: 'detector.max_widht_m' is not a parameter (did "
        "you mean 'max_width_m'?); ignored"]
    assert params.ekf.gyro_noise_rad_s == EkfConfig().gyro_noise_rad_s
    assert params.limits.max_speed_m_s == 10.0


def test_a_file_with_no_pipeline_section_says_nothing_was_read(caplog):
    read_params_text('rosbag2_bagfile_information:\n  version: 5\n', 'metadata.yaml')
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == [
        'metadata.yaml: no section for /**, ekf_node, calibration_node, '
        'landmark_detector_node: nothing read']


# The start pose: read as the EKF node declares it, used by `run` as the node uses it.

def test_an_initial_pose_is_read_whole_and_checked_as_the_node_declares_it():
    assert read_params_text(TEXT).initial_pose == (1.0, 2.0, 0.5)
    assert read_params_text('/**:\n  ros__parameters:\n    gate_probability: 0.99\n'
                            ).initial_pose is None
    for body, message in [
            ('{x_m: 1.0, y_m: 2.0}', "'initial_pose.yaw_rad' is missing"),
            ('{x_m: 1.0, y_m: 2.0, yaw_deg: 30}',
             "'initial_pose.yaw_deg' is not one of .* \\(did you mean 'initial_pose.yaw_rad'"),
            ('{x_m: 1.0, y_m: two, yaw_rad: 0.0}', "'initial_pose.y_m' must be a number"),
            ('{x_m: .nan, y_m: 0.0, yaw_rad: 0.0}', "'initial_pose.x_m' = nan is not finite"),
            # Degrees where radians belong: the node's declared range refuses it too.
            ('{x_m: 0.0, y_m: 0.0, yaw_rad: 90}',
             "'initial_pose.yaw_rad' = 90 rad lies outside \\[-6.28319, 6.28319\\] rad")]:
        with pytest.raises(ParamsFileError, match=f'p.yaml: parameter {message}'):
            read_params_text(f'/**:\n  ros__parameters:\n    initial_pose: {body}\n', 'p.yaml')
    with pytest.raises(ParamsFileError, match="'lidar.scan2.yaw_rad' = 183 rad lies outside"):
        read_params_text('/**:\n  ros__parameters:\n    lidar:\n      topics: [scan2]\n'
                         '      scan2: {x_m: -0.4, y_m: 0.0, yaw_rad: 183.0}\n', 'p.yaml')


def test_a_unit_left_out_a_group_prefix_or_a_name_of_no_node_is_warned_about(caplog):
    # A group prefix was read by `run` (ekf.gyro_noise_rad_s, or nested under ekf:) while
    # the nodes, which declare every parameter bare, ignored it: one file, two filters. A
    # name no gyro_ekf node has was skipped with a debug line.
    params = read_params_text(
        '/**:\n  ros__parameters:\n    gyro_noise: 0.5\n    detector.gyro_noise_rad_s: 0.5\n'
        '    ekf:\n      speed_noise_m_s: 0.5\n    frame_prefix: robot\n', 'p.yaml')
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == [
        "p.yaml: /**: 'gyro_noise' is not a parameter (did you mean 'gyro_noise_rad_s'?); "
        "ignored",
        "p.yaml: /**: 'detector.gyro_noise_rad_s' is not a parameter (the nodes declare "
        "'gyro_noise_rad_s' bare, with no detector. before it); ignored",
        "p.yaml: /**: 'ekf.speed_noise_m_s' is not a parameter (the nodes declare "
        "'speed_noise_m_s' bare, with no ekf. before it); ignored",
        "p.yaml: /**: 'frame_prefix' is not a parameter of any gyro_ekf node; ignored"]
    assert params.ekf == EkfConfig()


def test_a_lidar_name_run_does_not_read_is_warned_about(caplog):
    # A mount in degrees, or a second LiDAR left out of lidar.topics: the bag's mount
    # stayed without a word (the node warns of both, by a name close to one it declares).
    params = read_params_text(
        '/**:\n  ros__parameters:\n    lidar:\n      topics: [scan]\n'
        '      scan: {x_m: 0.4, y_m: 0.0, yaw_rad: 0.0, yaw_deg: 180.0}\n'
        '      scan2: {x_m: -0.4, y_m: 0.0, yaw_rad: 3.1}\n', 'p.yaml')
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == [
        "p.yaml: 'lidar.scan.yaw_deg' is not a parameter (a LiDAR's are frame_id, x_m, y_m, "
        "yaw_rad, time_offset_s, range_offset_m, upside_down, yaw_sigma_rad: did you mean "
        "'yaw_rad'?); ignored",
        "p.yaml: lidar.scan2.x_m, lidar.scan2.y_m, lidar.scan2.yaw_rad: 'scan2' is not one of "
        "lidar.topics ['scan']; ignored"]
    assert list(params.lidars) == ['scan']


def test_the_nodes_live_side_names_are_skipped_quietly_and_path_length_is_read(caplog):
    params = read_params_text(
        '/**:\n  ros__parameters:\n    use_sim_time: true\n    reliable_inputs: true\n'
        'ekf_node:\n  ros__parameters:\n    map_frame: world\n    publish_every_n: 2\n'
        '    path_length: 50\ncalibration_node:\n  ros__parameters:\n    use_odom: false\n',
        'p.yaml')
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == []
    assert params.path_length == 50
    assert read_params_text(TEXT).path_length is None
    for value in ('0', '2.5', 'true', 'long'):
        with pytest.raises(ParamsFileError, match="p.yaml: parameter 'path_length' must be a "
                           'whole number of poses >= 1, got'):
            read_params_text(f'ekf_node:\n  ros__parameters:\n    path_length: {value}\n',
                             'p.yaml')


def _first_pose(out):
    return np.loadtxt(out / 'estimates.csv', delimiter=',', skiprows=1, max_rows=1)[1:4]


def test_run_starts_at_the_params_files_pose_unless_the_bag_states_one(tmp_path, caplog):
    # `run --params-file` used to skip initial_pose.* without a word, where ekf_node, given
    # the same file, starts there.
    stated = tmp_path / 'stated'
    assert main(['-q', 'simulate', '-o', str(stated), '--seed', '3', '--duration-s', '12'
                 ]) == 0
    without = rewrite(stated, tmp_path / 'without',
                      lambda items: [i for i in items if i[0] != '/initialpose'])
    trip = read_bag(stated).trip
    bag_pose = trip.initial_pose
    mine = bag_pose + np.array([0.5, -0.25, 0.1])
    params = tmp_path / 'robot.yaml'
    params.write_text('/**:\n  ros__parameters:\n    initial_pose: {x_m: %r, y_m: %r, '
                      'yaw_rad: %r}\n' % tuple(mine.tolist()))
    runs = {}
    for bag in (stated, without):
        caplog.clear()
        out = tmp_path / f'out_{bag.name}'
        assert main(['-q', 'run', str(bag), '-o', str(out), '--params-file', str(params),
                     '--no-plots', '--no-bag', '--no-progress']) == 0
        runs[bag.name] = (_first_pose(out), [r.getMessage() for r in caplog.records
                                             if r.levelname == 'WARNING'])
    # At rest the first estimate is the start pose (the simulated trip stands still first).
    pose, warnings = runs['without']
    np.testing.assert_allclose(pose, mine, atol=1e-6)
    assert not [w for w in warnings if 'initial_pose' in w]
    # The bag's /initialpose message wins, as in ekf_node once a replay publishes it: said.
    pose, warnings = runs['stated']
    np.testing.assert_allclose(pose, bag_pose, atol=1e-6)
    figures = (trip.name, *mine.tolist(), *bag_pose.tolist())
    assert [w for w in warnings if 'initial_pose' in w] == [
        "%s: the params file sets initial_pose (%g m, %g m, %g rad), but the bag's "
        '/initialpose message states (%g m, %g m, %g rad): the run starts there, as ekf_node '
        'does once a replay of the bag publishes it' % figures]


def test_a_sigma_the_stated_noise_replaces_is_named(tmp_path, caplog):
    bag = tmp_path / 'sim'
    assert main(['-q', 'simulate', '-o', str(bag), '--seed', '4', '--duration-s', '10']) == 0
    params = tmp_path / 'noise.yaml'
    params.write_text('ekf_node:\n  ros__parameters:\n    gyro_noise_rad_s: 1.0\n'
                      '    gate_probability: 0.99\n')
    runs = {}
    for extra in ((), ('--ignore-stated-noise',)):
        caplog.clear()
        out = tmp_path / f'out{len(extra)}'
        assert main(['-q', 'run', str(bag), '-o', str(out), '--params-file', str(params),
                     '--no-plots', '--no-bag', '--no-progress', *extra]) == 0
        summary = json.loads((out / 'summary.json').read_text())
        runs[extra] = (summary, [r.getMessage() for r in caplog.records
                                 if 'use_stated_noise' in r.getMessage()])
    summary, said = runs[()]
    used = summary['config']['ekf']['gyro_noise_rad_s']
    # The log's figure replaces the file's, and each IMU message's own variance both: the
    # messages' is the one filtered with, and the source says so.
    assert used != 1.0 and summary['config']['sources']['gyro_noise_rad_s'] == 'messages'
    assert said == [f'the params file sets gyro_noise_rad_s = 1, but the log states '
                    f'gyro_noise_rad_s = {used:g}, used while use_stated_noise is true; to '
                    "use the file's, set use_stated_noise: false in it (or run "
                    '--ignore-stated-noise)']
    summary, said = runs[('--ignore-stated-noise',)]
    assert summary['config']['ekf']['gyro_noise_rad_s'] == 1.0 and said == []
    # Still not the file's: the messages' own variances are (a helper found 0.5 and 1e-4
    # give the same bytes); said, with the switch that makes the file's count.
    assert summary['config']['sources']['gyro_noise_rad_s'] == 'messages'
    assert any('set use_message_covariance: false in it (or run --ignore-message-covariance)'
               in r.getMessage() and r.getMessage().startswith(
                   'the params file sets gyro_noise_rad_s = 1, but ')
               for r in caplog.records)


def test_a_lidar_time_offset_is_read_alone_or_with_the_mount_and_checked():
    head = '/**:\n  ros__parameters:\n    lidar:\n      topics: [scan, scan2]\n'
    params = read_params_text(
        head + '      scan: {time_offset_s: 0.03}\n'
        '      scan2: {x_m: 0.1, y_m: 0.0, yaw_rad: 3.14, time_offset_s: -0.005}\n')
    assert params.lidar_time_offsets == {'scan': 0.03, 'scan2': -0.005}
    # The offset alone leaves the bag's mount; with x, y and yaw, the mount is set too.
    assert list(params.lidars) == ['scan2']
    with pytest.raises(ParamsFileError, match=r"'lidar.scan.time_offset_s': \|1.5\| s exceeds"):
        read_params_text(head + '      scan: {time_offset_s: 1.5}\n'
                         '      scan2: {time_offset_s: 0}\n')
    with pytest.raises(ParamsFileError, match="'lidar.scan.time_offset_s' must be a number"):
        read_params_text(head + "      scan: {time_offset_s: '30 ms'}\n"
                         '      scan2: {time_offset_s: 0}\n')


def test_a_lidar_range_offset_is_read_checked_and_moves_its_poles():
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.params_file import with_lidar_mounts

    head = '/**:\n  ros__parameters:\n    lidar:\n      topics: [scan]\n'
    params = read_params_text(head + '      scan: {range_offset_m: 0.03}\n')
    assert params.lidar_range_offsets == {'scan': 0.03} and not params.lidars
    with pytest.raises(ParamsFileError, match=r"'lidar.scan.range_offset_m': \|2\| m exceeds"):
        read_params_text(head + '      scan: {range_offset_m: 2.0}\n')
    with pytest.raises(ParamsFileError, match="'lidar.scan.upside_down' must be true or "
                                              "false, got 'yes please'"):
        read_params_text(head + "      scan: {upside_down: 'yes please'}\n")
    # A LiDAR 3 cm long: its scans as recorded, its poles moved 3 cm toward it.
    trip = simulate_trip(SimulationConfig(duration_s=20.0), 0)
    scan = trip.scans[0]
    long = dataclasses.replace(trip, scans=(dataclasses.replace(
        scan, ranges_m=(scan.ranges_m + 0.03).astype(np.float32)),))
    given = with_lidar_mounts(long, params)
    assert given.scans[0].range_offset_m == 0.03
    assert given.scans[0].ranges_m is long.scans[0].ranges_m
    runs = [run_trip(t).result.updates for t in (trip, long, given)]
    exact, off, corrected = (np.hypot(*(u.point_map_m - trip.landmarks.xy_m[u.landmark]).T)
                             for u in runs)
    # The poles' centres a median 1.6 cm off on the exact trip (the detector's own error),
    # 2.9 cm when 3 cm long, and as the exact trip's with the offset given.
    assert np.median(off) > np.median(exact) + 0.01
    assert np.median(corrected) == pytest.approx(np.median(exact), abs=0.001)


def test_a_lidar_yaw_sigma_is_read_checked_and_widens_the_heading_reported():
    from gyro_ekf.analysis.offline import run_trip
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.params_file import with_lidar_mounts

    head = '/**:\n  ros__parameters:\n    lidar:\n      topics: [scan]\n'
    params = read_params_text(head + '      scan: {yaw_sigma_rad: 0.001}\n')
    assert params.lidar_yaw_sigmas == {'scan': 0.001} and not params.lidars
    with pytest.raises(ParamsFileError, match=r"'lidar.scan.yaw_sigma_rad': -0.001 rad is "
                                              r'negative \(a sigma\)'):
        read_params_text(head + '      scan: {yaw_sigma_rad: -0.001}\n')
    with pytest.raises(ParamsFileError, match=r"'lidar.scan.yaw_sigma_rad': \|1\| rad exceeds"):
        read_params_text(head + '      scan: {yaw_sigma_rad: 1.0}\n')
    # A null is neither 0 nor left out in silence (nor is an offset's).
    for key in ('yaw_sigma_rad', 'time_offset_s', 'range_offset_m'):
        with pytest.raises(ParamsFileError, match=rf"'lidar.scan.{key}' must be a number, "
                                                  'got null'):
            read_params_text(head + f'      scan: {{{key}: null}}\n')
    trip = simulate_trip(SimulationConfig(duration_s=20.0), 0)
    given = with_lidar_mounts(trip, params)
    assert given.scans[0].yaw_sigma_rad == 0.001 and trip.scans[0].yaw_sigma_rad == 0.0
    # The first LiDAR defines the body frame: the heading is known no better than its yaw.
    plain, widened = (run_trip(t).result for t in (trip, given))
    np.testing.assert_array_equal(widened.estimates.state, plain.estimates.state)
    last = widened.estimates.covariance[-1] - plain.estimates.covariance[-1]
    assert last[2, 2] >= 0.001 ** 2 - 1e-15
    last[2, 2] = 0.0
    np.testing.assert_array_equal(last, 0.0)
    assert widened.odometry.report()['heading_widened_deg'] >= math.degrees(0.001) - 1e-12
    # A heading known only to 0.29 deg (a hand-written sigma) is said; 0.057 deg is not.
    from gyro_ekf.analysis.summary import summarize
    loose = with_lidar_mounts(trip, read_params_text(head + '      scan: {yaw_sigma_rad: '
                                                            '0.005}\n'))
    said = 'the heading is known only to +-0.286 deg (1 sigma) at the end, more than 0.1 deg'
    reasons = [summarize(run_trip(t))['health']['reasons'] for t in (given, loose)]
    assert not any(said[:30] in r for r in reasons[0])
    assert any(r.startswith(said) and 'LiDAR scan defines the body frame' in r
               for r in reasons[1])


def test_a_lidar_time_offset_takes_each_scan_at_its_stamp_less_it():
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.params_file import with_lidar_mounts

    trip = simulate_trip(SimulationConfig(duration_s=5.0, second_lidar=True), 0)
    params = read_params_text('/**:\n  ros__parameters:\n    lidar:\n      topics: [scan2]\n'
                              '      scan2: {time_offset_s: 0.025}\n')
    moved = with_lidar_mounts(trip, params)
    (scan, scan2), (moved_scan, moved_scan2) = trip.scans, moved.scans
    assert np.array_equal(moved_scan.stamp_s, scan.stamp_s)
    assert np.allclose(moved_scan2.stamp_s, scan2.stamp_s - 0.025, rtol=0.0, atol=1e-12)
    assert moved_scan2.mount == scan2.mount and moved_scan2.topic == 'scan2'


def test_a_start_pose_the_bags_message_states_to_the_last_bits_is_no_disagreement(caplog):
    # A helper found "the params file sets initial_pose (0 m, 0 m, 1.5708 rad), but the
    # bag's /initialpose message states (0 m, 0 m, 1.5708 rad)": the yaw the message's
    # quaternion gives back differs from the file's in its last bits.
    from gyro_ekf.core.simulator import SimulationConfig, simulate_trip
    from gyro_ekf.io.params_file import with_initial_pose
    trip = dataclasses.replace(simulate_trip(SimulationConfig(duration_s=2.0, static_s=2.0)),
                               initial_pose=np.array([0.0, 0.0, math.pi / 2 + 1e-12]))
    params = read_params_text('/**:\n  ros__parameters:\n    initial_pose: {x_m: 0.0, '
                              'y_m: 0.0, yaw_rad: 1.5707963267948966}\n')
    assert with_initial_pose(trip, params, stated_by_message=True) is trip
    assert not [r for r in caplog.records if r.levelname == 'WARNING']
    moved = dataclasses.replace(params, initial_pose=(0.0, 0.0, 1.6))
    assert with_initial_pose(trip, moved, stated_by_message=True) is trip
    assert [r for r in caplog.records if 'initial_pose' in r.getMessage()]


def test_a_float_written_with_an_exponent_is_a_number_as_the_nodes_read_it():
    # PyYAML (YAML 1.1) read `1e-3` as text, and `run` refused "must be a number, got
    # '1e-3'" where the nodes (ROS's parser) took 0.001.
    params = read_params_text('/**:\n  ros__parameters:\n    gyro_noise_rad_s: 1e-3\n'
                              '    speed_noise_m_s: 1.0e-2\n    gate_probability: 9.5E-1\n'
                              '    range_noise_m: .5e-1\n    map_frame: 1e3x\n')
    assert (params.ekf.gyro_noise_rad_s, params.ekf.speed_noise_m_s,
            params.ekf.gate_probability, params.ekf.range_noise_m) == (0.001, 0.01, 0.95, 0.05)
    assert read_params_text('/**:\n  ros__parameters:\n    min_samples: 60\n'
                            ).calibration.min_samples == 60  # an integer stays one


def test_a_name_in_another_nodes_section_is_ignored_as_that_node_ignores_it(caplog):
    # `run` took every name from every pipeline section, so the section order chose
    # between the calibration node's window and one written under ekf_node (which no node
    # reads), and a gate under landmark_detector_node was used, which the nodes drop.
    params = read_params_text(
        'calibration_node: {ros__parameters: {window_length_s: 4.0}}\n'
        'ekf_node: {ros__parameters: {window_length_s: 3.0, max_width_m: 0.06}}\n'
        'landmark_detector_node: {ros__parameters: {gate_probability: 0.5, '
        'limits.max_speed_m_s: 9.0}}\n', 's.yaml')
    assert params.calibration.window_length_s == 4.0
    assert params.detector.max_width_m == DetectorConfig().max_width_m
    assert params.ekf.gate_probability == EkfConfig().gate_probability
    assert params.limits.max_speed_m_s == InputLimits().max_speed_m_s
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == [
        "s.yaml: ekf_node: 'window_length_s' is not a parameter of ekf_node (it is "
        "calibration_node's: set it in that section or /**); ignored",
        "s.yaml: ekf_node: 'max_width_m' is not a parameter of ekf_node (it is "
        "landmark_detector_node's: set it in that section or /**); ignored",
        "s.yaml: landmark_detector_node: 'gate_probability' is not a parameter of "
        "landmark_detector_node (it is ekf_node's: set it in that section or /**); ignored",
        "s.yaml: landmark_detector_node: 'limits.max_speed_m_s' is not a parameter of "
        "landmark_detector_node (it is ekf_node and calibration_node's: set it in that "
        "section or /**); ignored"]


@pytest.mark.parametrize('section', ['/*', '/robot1/**', '/**/ekf_*', '/robot1/ekf_node'])
def test_a_section_rclpy_matches_to_the_ekf_node_is_read(section):
    # `/*` and the like were skipped without a word whenever another section was there;
    # rclpy gives them to every node (or the one they match).
    params = read_params_text(f'"{section}":\n  ros__parameters:\n    gate_probability: 0.6\n'
                              'calibration_node:\n  ros__parameters:\n    min_samples: 60\n')
    assert params.ekf.gate_probability == 0.6 and params.calibration.min_samples == 60
