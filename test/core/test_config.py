"""core.config: the one place defaults, units, descriptions and bounds are written."""

from __future__ import annotations

import dataclasses
import math

import pytest

from gyro_ekf.core.config import (CalibrationConfig, DetectorConfig, EkfConfig, InputLimits,
                                  make_config, RunOptions)
from gyro_ekf.core.errors import CoreError
from gyro_ekf.io.params_file import PipelineParams, read_params_text

CONFIG_TYPES = (EkfConfig, CalibrationConfig, DetectorConfig, InputLimits, RunOptions)


@pytest.mark.parametrize('config_type', CONFIG_TYPES)
def test_every_field_has_a_description_a_unit_and_a_default_within_its_bounds(config_type):
    for spec in dataclasses.fields(config_type):
        meta = spec.metadata
        assert meta['description'].strip(), spec.name
        assert 'unit' in meta, spec.name
        if isinstance(spec.default, bool):
            assert meta['min'] is None and meta['max'] is None, spec.name
            continue
        assert meta['min'] is None or spec.default >= meta['min'], spec.name
        assert meta['max'] is None or spec.default <= meta['max'], spec.name


def test_the_run_options_are_the_nodes_switches_with_their_defaults():
    options = RunOptions()
    assert options.use_stated_noise is True
    assert options.use_message_covariance is True
    assert options.use_calibration is False
    assert options.calibration_bias_sigma_rad_s == pytest.approx(math.radians(0.05))


def test_a_params_file_without_options_gives_the_run_options_defaults():
    # The offline run reads its switches from here: no second copy of the defaults.
    assert read_params_text('/**:\n  ros__parameters:\n    gate_probability: 0.9\n'
                            ).options == RunOptions()
    assert PipelineParams().options == RunOptions()


@pytest.mark.parametrize('value', [1, 0, 1.0, -1.0, 'true', None, [True]])
def test_a_switch_accepts_only_true_or_false_naming_the_parameter(value):
    with pytest.raises(CoreError, match=r"^p\.yaml: parameter 'use_calibration' must be true "
                                        r'or false, got '):
        make_config(RunOptions, {'use_calibration': value}, source='p.yaml')


@pytest.mark.parametrize('value', [True, False])
def test_a_switch_takes_true_and_false(value):
    assert make_config(RunOptions, {'use_calibration': value}).use_calibration is value


@pytest.mark.parametrize('value', [True, False, '0.1'])
def test_a_number_does_not_accept_a_truth_value_or_text(value):
    with pytest.raises(CoreError, match=r"parameter 'calibration_bias_sigma_rad_s' must be a "
                                        'number'):
        make_config(RunOptions, {'calibration_bias_sigma_rad_s': value})


@pytest.mark.parametrize('value', [math.nan, math.inf])
def test_a_non_finite_number_is_refused_by_name(value):
    with pytest.raises(CoreError, match=r"parameter 'gyro_noise_rad_s' = (nan|inf) is not "
                                        'finite'):
        make_config(EkfConfig, {'gyro_noise_rad_s': value})


def test_out_of_bounds_and_unknown_names_are_refused_by_name():
    with pytest.raises(CoreError, match=r"'calibration_bias_sigma_rad_s' = 0\.0 is outside "
                                        r'\[1e-09, 1\.0\] rad/s'):
        make_config(RunOptions, {'calibration_bias_sigma_rad_s': 0.0})
    with pytest.raises(CoreError, match=r"unknown parameter 'use_stated' for RunOptions"):
        make_config(RunOptions, {'use_stated': True})


def test_an_integer_field_keeps_integers_and_a_float_field_takes_them():
    config = make_config(EkfConfig, {'health_min_detections': 7, 'gyro_noise_rad_s': 0})
    assert config.health_min_detections == 7 and isinstance(config.health_min_detections, int)
    assert config.gyro_noise_rad_s == 0.0 and isinstance(config.gyro_noise_rad_s, float)
