"""The launch file and the parameters: what can be checked without a Jazzy install."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / 'launch' / 'gyro_ekf.launch.py'
CONFIG = REPO / 'config' / 'gyro_ekf.yaml'


def _console_scripts() -> set[str]:
    tree = ast.parse((REPO / 'setup.py').read_text())
    nodes = next(node.value for node in ast.walk(tree) if isinstance(node, ast.Assign)
                 and any(getattr(t, 'id', '') == 'NODES' for t in node.targets))
    return set(ast.literal_eval(nodes))


def test_launch_file_compiles_and_names_installed_executables():
    source = LAUNCH.read_text()
    compile(source, str(LAUNCH), 'exec')
    named = set(re.findall(r"executable='([a-z_]+)'", source))
    assert named == {'calibration_node', 'landmark_detector_node', 'ekf_node'}
    assert named <= _console_scripts()
    for executable in named:
        assert (REPO / 'gyro_ekf' / 'nodes' / f'{executable}.py').exists()


@pytest.mark.ros
def test_config_file_sets_only_declared_parameters_with_descriptions(ros_env):
    import rclpy

    from gyro_ekf.nodes.calibration_node import CalibrationNode
    from gyro_ekf.nodes.ekf_node import EkfNode
    from gyro_ekf.nodes.landmark_detector_node import LandmarkDetectorNode

    document = yaml.safe_load(CONFIG.read_text())
    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file', str(CONFIG)])
    try:
        for node_class in (CalibrationNode, LandmarkDetectorNode, EkfNode):
            node = node_class(context=context)
            try:
                values = document[node.get_name()]['ros__parameters']
                for name, value in values.items():
                    assert node.has_parameter(name), f'{node.get_name()}: {name} undeclared'
                    assert node.get_parameter(name).value == value
                    assert node.describe_parameter(name).description
            finally:
                node.destroy_node()
    finally:
        context.try_shutdown()


@pytest.mark.parametrize('node, config_name', [
    ('ekf_node', 'EkfConfig'), ('landmark_detector_node', 'DetectorConfig'),
    ('calibration_node', 'CalibrationConfig')])
def test_config_file_holds_the_core_defaults(node, config_name):
    import dataclasses

    from gyro_ekf.core import config as core_config
    config_type = getattr(core_config, config_name)
    values = yaml.safe_load(CONFIG.read_text())[node]['ros__parameters']
    defaults = config_type()
    for field in dataclasses.fields(config_type):
        assert values.get(field.name) == getattr(defaults, field.name), field.name


@pytest.mark.parametrize('node', ['ekf_node', 'calibration_node'])
def test_config_file_holds_the_input_limits_defaults(node):
    import dataclasses

    from gyro_ekf.core.config import InputLimits
    values = yaml.safe_load(CONFIG.read_text())[node]['ros__parameters']
    for field in dataclasses.fields(InputLimits):
        assert values.get(f'limits.{field.name}') == field.default, field.name


@pytest.mark.ros
def test_bag_sidecar_reaches_the_ekf_node(ros_env, sim_bag):
    import rclpy

    from gyro_ekf.io import read_sidecar
    from gyro_ekf.nodes.ekf_node import EkfNode

    params = read_sidecar(sim_bag)
    context = rclpy.Context()
    rclpy.init(context=context,
               args=['--ros-args', '--params-file', f'{sim_bag}.params.yaml'])
    try:
        node = EkfNode(context=context)
        try:
            assert node.driver.ekf.x[:3].tolist() == pytest.approx(params.initial_pose.tolist())
            frame, mount = params.lidars['scan']
            assert node._sidecar.mount_for_frame(frame) == mount
            assert node.config.gyro_noise_rad_s == params.noise.gyro_rad_s
            # A simulator's map is exact: a stated 0 must win over the default.
            assert params.noise.landmark_m == 0.0
            assert node.config.landmark_sigma_m == 0.0
            assert node._origin.zero_ns == params.log_time_zero_ns
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()


@pytest.mark.ros
@pytest.mark.parametrize('args, match', [
    (['-p', 'lidar.topics:=[scan]', '-p', 'lidar.scan.x_m:=.nan'], 'lidar.scan .*not finite'),
    (['-p', 'lidar.topics:=[scan]', '-p', 'lidar.scan.y_m:=50.0'], 'lidar.scan .*exceeds'),
    (['-p', 'initial_pose.x_m:=.inf'], 'initial_pose: .*not finite'),
])
def test_a_mount_or_start_pose_out_of_its_limits_is_a_configuration_error(ros_env, args,
                                                                          match):
    import rclpy

    from gyro_ekf.errors import GyroEkfError
    from gyro_ekf.nodes.ekf_node import EkfNode

    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', *args])
    try:
        with pytest.raises(GyroEkfError, match=match):
            EkfNode(context=context)
    finally:
        context.try_shutdown()


@pytest.mark.ros
@pytest.mark.parametrize('param, match', [
    ('path_length:=0', r'path_length out of range'),
    ('publish_tf:=7', r"'publish_tf' to '7' of type 'INTEGER', expecting type 'BOOL'"),
])
def test_a_parameter_rclpy_refuses_is_one_line_and_exit_1(ros_env, param, match):
    import re
    import subprocess
    import sys

    result = subprocess.run([sys.executable, '-m', 'gyro_ekf.nodes.ekf_node', '--ros-args',
                             '-p', param], env=ros_env, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 1
    assert re.search(match, result.stderr)
    assert 'Traceback' not in result.stderr + result.stdout
    assert [line for line in result.stderr.splitlines() if line.startswith('[FATAL]')]


@pytest.mark.ros
def test_the_parameters_doc_is_what_the_nodes_declare(ros_env):
    import subprocess
    import sys

    # ros_env: the tool claims a domain of its own; the env keeps it on loopback anyway.
    result = subprocess.run([sys.executable, str(REPO / 'tools' / 'parameters_doc.py')],
                            env=ros_env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert '| `path_length` | `600` |' in result.stdout
    assert result.stdout == (REPO / 'docs' / 'parameters.md').read_text(), (
        'docs/parameters.md is stale: run `make docs`')
