"""ROS 2 params YAML -> core configs."""

from __future__ import annotations

import math

import pytest

from gyro_ekf.io.errors import ParamsFileError
from gyro_ekf.io.params_file import read_params_file, read_params_text
from gyro_ekf.core.config import EkfConfig, RunOptions

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
    detector:
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


@pytest.mark.parametrize('line, message', [
    # NaN passes every bounds comparison, so it is refused by name before them.
    ('gyro_noise_rad_s: .nan', "'ekf.gyro_noise_rad_s' = nan is not finite"),
    ('ekf: {speed_noise_m_s: .inf}', "'ekf.speed_noise_m_s' = inf is not finite"),
    ('detector: {max_width_m: -.inf}', "'detector.max_width_m' = -inf is not finite"),
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
        "you mean 'detector.max_width_m'?); ignored"]
    assert params.ekf.gyro_noise_rad_s == EkfConfig().gyro_noise_rad_s
    assert params.limits.max_speed_m_s == 10.0


def test_a_file_with_no_pipeline_section_says_nothing_was_read(caplog):
    read_params_text('rosbag2_bagfile_information:\n  version: 5\n', 'metadata.yaml')
    assert [r.getMessage() for r in caplog.records if r.levelname == 'WARNING'] == [
        'metadata.yaml: no section for /**, ekf_node, calibration_node, '
        'landmark_detector_node: nothing read']
