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


def _params_file_entries(text: str) -> dict[str, dict[str, str]]:
    """Node -> parameter -> the comment lines above it, joined (a params file's layout)."""
    entries: dict[str, dict[str, str]] = {}
    node, comment = None, []
    for line in text.splitlines():
        if re.fullmatch(r'[a-z_]+:', line):
            node, comment = line[:-1], []
            entries[node] = {}
        elif line.startswith('    # '):
            comment.append(line[len('    # '):])
        elif node is not None and re.match(r'    [a-z0-9_.]+: ', line):
            entries[node][line.split(':')[0].strip()] = ' '.join(comment)
            comment = []
    return entries


@pytest.mark.ros
def test_config_file_comments_and_values_are_the_declared_descriptions_and_defaults(ros_env):
    import rclpy

    from gyro_ekf.nodes.calibration_node import CalibrationNode
    from gyro_ekf.nodes.ekf_node import EkfNode
    from gyro_ekf.nodes.landmark_detector_node import LandmarkDetectorNode

    text = CONFIG.read_text()
    values = yaml.safe_load(text)
    comments = _params_file_entries(text)
    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args'])  # no file: the declared defaults
    try:
        for node_class in (CalibrationNode, LandmarkDetectorNode, EkfNode):
            node = node_class(context=context)
            try:
                name = node.get_name()
                declared = [n for n in node._parameters
                            if n not in ('use_sim_time', 'start_type_description_service')
                            and not n.startswith(('trip.', 'initial_pose.', 'lidar.',
                                                  'noise.'))]
                # Every parameter a user sets, in declaration order, and nothing else.
                assert list(comments[name]) == declared, name
                assert list(values[name]['ros__parameters']) == declared, name
                for parameter in declared:
                    default = node.get_parameter(parameter).value
                    value = values[name]['ros__parameters'][parameter]
                    assert value == default and type(value) is type(default), parameter
                    assert comments[name][parameter] == \
                        node.describe_parameter(parameter).description, parameter
            finally:
                node.destroy_node()
    finally:
        context.try_shutdown()


@pytest.mark.parametrize('node, config_name', [
    ('ekf_node', 'EkfConfig'), ('ekf_node', 'RunOptions'),
    ('landmark_detector_node', 'DetectorConfig'), ('calibration_node', 'CalibrationConfig')])
def test_config_file_holds_the_core_defaults(node, config_name):
    import dataclasses

    from gyro_ekf.core import config as core_config
    config_type = getattr(core_config, config_name)
    values = yaml.safe_load(CONFIG.read_text())[node]['ros__parameters']
    defaults = config_type()
    for field in dataclasses.fields(config_type):
        assert values[field.name] == getattr(defaults, field.name), field.name


@pytest.mark.parametrize('node', ['ekf_node', 'calibration_node'])
def test_config_file_holds_the_input_limits_the_node_checks(node):
    import importlib

    from gyro_ekf.core.config import InputLimits
    used = importlib.import_module(f'gyro_ekf.nodes.{node}').LIMITS_USED
    values = yaml.safe_load(CONFIG.read_text())[node]['ros__parameters']
    assert sorted(k for k in values if k.startswith('limits.')) == sorted(
        f'limits.{name}' for name in used)
    for name in used:
        assert values[f'limits.{name}'] == getattr(InputLimits(), name), name


@pytest.mark.ros
def test_the_config_file_is_what_the_generator_writes(ros_env):
    import subprocess
    import sys

    result = subprocess.run([sys.executable, str(REPO / 'tools' / 'parameters_doc.py'),
                             '--yaml', '-'], env=ros_env, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert 'path_length: 600\n' in result.stdout
    assert result.stdout == CONFIG.read_text(), 'config/gyro_ekf.yaml is stale: run `make docs`'


@pytest.mark.ros
def test_bag_sidecar_reaches_the_ekf_node(ros_env, sim_bag):
    import rclpy

    from gyro_ekf.io import read_sidecar
    from gyro_ekf.nodes.ekf_node import EkfNode, REMOVED_PARAMETERS
    from gyro_ekf.nodes.params import report_ignored

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
            # No entry of it passes for a parameter no node has (true_gyro_bias_rad_s, the
            # fingerprint trip.bag.*: no node declares them).
            assert params.true_gyro_bias_rad_s is not None and params.bag is not None
            assert report_ignored(node, REMOVED_PARAMETERS) == []
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()


@pytest.mark.ros
def test_the_params_file_readers_list_of_node_parameters_is_what_the_nodes_declare(ros_env):
    # `run` and the nodes tell a name some pipeline node declares from one none has by
    # io.params_file's list (ROS-free): held here to what each node really declares.
    import rclpy

    from gyro_ekf.io import params_file
    from gyro_ekf.nodes.calibration_node import CalibrationNode
    from gyro_ekf.nodes.ekf_node import EkfNode
    from gyro_ekf.nodes.landmark_detector_node import LandmarkDetectorNode

    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '-p', 'lidar.topics:=[scan]'])
    declared = {}
    try:
        for node_class in (CalibrationNode, LandmarkDetectorNode, EkfNode):
            node = node_class(context=context)
            try:
                declared[node.get_name()] = set(node._parameters)
            finally:
                node.destroy_node()
    finally:
        context.try_shutdown()
    assert set(declared) == set(params_file.PIPELINE_NODES)
    run_reads = set(params_file._KNOWN)
    for name, names in declared.items():
        assert all(params_file.is_gyro_ekf_parameter(n) for n in names), name
        own = {n for n in names - run_reads - set(params_file.ROS_PARAMETERS)
               if not n.startswith(('lidar.', 'initial_pose.', *params_file.SIDECAR_PREFIXES))
               and n != 'landmarks_file'}
        assert own == set(params_file.NODE_ONLY_PARAMETERS[name]), name
    # What `run` reads, a node declares: but for the bag's longest duration, run's alone.
    assert run_reads - set().union(*declared.values()) == {'limits.max_duration_s'}
    # And the node each name's section must be, for `run` to take it as that node does.
    for name, names in declared.items():
        for read in names & (run_reads | {'landmarks_file'}) | {
                n for n in names if n.startswith(('lidar.', 'initial_pose.'))}:
            assert name in params_file._declared_by(read), (name, read)
    for read in run_reads:
        for name in params_file._declared_by(read) or ():
            assert read in declared[name], (read, name)
    assert not params_file.is_gyro_ekf_parameter('frame_prefix')


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
    # A switch given as a number is refused, not read as a truth value (as offline).
    ('use_calibration:=1', r"'use_calibration' to '1' of type 'INTEGER', expecting type "
                           "'BOOL'"),
    # A LiDAR's time offset beyond its range, or NaN (which would reach the stamps).
    (('lidar.topics:=[scan]', 'lidar.scan.time_offset_s:=.nan'),
     r'lidar.scan.time_offset_s out of range'),
    (('lidar.topics:=[scan]', 'lidar.scan.time_offset_s:=2.0'),
     r'lidar.scan.time_offset_s out of range'),
])
def test_a_parameter_rclpy_refuses_is_one_line_and_exit_1(ros_env, param, match):
    import re
    import subprocess
    import sys

    given = [arg for value in ((param,) if isinstance(param, str) else param)
             for arg in ('-p', value)]
    result = subprocess.run([sys.executable, '-m', 'gyro_ekf.nodes.ekf_node', '--ros-args',
                             *given], env=ros_env, capture_output=True, text=True,
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


def _run_until_logged(ros_env, tmp_path, module: str, args: list[str], ready: str) -> str:
    """Start a node, wait until its log says ready, stop it; return its stderr."""
    import signal
    import subprocess
    import sys
    import time

    log = tmp_path / f'{module}.stderr'
    with open(log, 'w') as stderr:
        process = subprocess.Popen([sys.executable, '-m', f'gyro_ekf.nodes.{module}',
                                    '--ros-args', *args], env=ros_env, cwd=REPO,
                                   stdout=subprocess.DEVNULL, stderr=stderr)
        try:
            deadline = time.monotonic() + 120.0
            while ready not in log.read_text() and process.poll() is None:
                assert time.monotonic() < deadline, f'{module} never logged {ready!r}'
                time.sleep(0.05)  # polling its log file, not waiting for discovery
            assert process.poll() is None, f'{module} exited:\n{log.read_text()}'
        finally:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    return log.read_text()


@pytest.mark.ros
def test_a_former_parameter_is_warned_about_once_by_name_and_ignored(ros_env, tmp_path):
    from gyro_ekf.nodes.ekf_node import REMOVED_PARAMETERS

    old = tmp_path / 'old.yaml'
    old.write_text('/**:\n  ros__parameters:\n    reorder_window_s: 1.0\n'
                   '    limits.max_duration_s: 10.0\nekf_node:\n  ros__parameters:\n'
                   '    stale_input_s: 2.0\n    publish_every_n: 2\n')
    stderr = _run_until_logged(ros_env, tmp_path, 'ekf_node', [
        '--params-file', str(old), '-p', 'idle_flush_s:=0.2', '-p', 'reorder_window_s:=0.5'],
        'EKF ready')
    for name in ('reorder_window_s', 'limits.max_duration_s', 'stale_input_s',
                 'idle_flush_s'):
        warning = f"parameter '{name}' was removed after gyro_ekf 0.1.0 ("
        assert stderr.count(warning) == 1, (name, stderr)
        assert f'{REMOVED_PARAMETERS[name]}); ignored' in stderr
    # Parameters that remain are not reported, and nothing but these four is.
    assert stderr.count('was removed after') == 4, stderr
    assert 'publish_every_n' not in stderr
    assert 'Traceback' not in stderr


@pytest.mark.ros
def test_a_misspelt_parameter_is_warned_about_naming_the_one_meant(ros_env, tmp_path):
    # rclpy ignores a name nobody declares: the gyro noise stayed at its default unsaid.
    typo = tmp_path / 'typo.yaml'
    typo.write_text('/**:\n  ros__parameters:\n    gyro_noize_rad_s: 0.02\n'
                    '    window_length_s: 2.0\nekf_node:\n  ros__parameters:\n'
                    '    gate_probabilty: 0.9\n    publish_every_n: 2\n'
                    '    ekf:\n      speed_noise_m_s: 0.5\n    frame_prefix: robot\n'
                    '    lidar:\n      topics: [scan]\n      scan2: {x_m: -0.4}\n')
    stderr = _run_until_logged(ros_env, tmp_path, 'ekf_node', ['--params-file', str(typo)],
                               'EKF ready')
    assert stderr.count("parameter 'gyro_noize_rad_s' is not a parameter of this node "
                        "(did you mean 'gyro_noise_rad_s'?); ignored") == 1, stderr
    assert stderr.count("'gate_probabilty' is not a parameter of this node (did you "
                        "mean 'gate_probability'?)") == 1, stderr
    # Nested under a group, as `run` once read it: the node declares it bare.
    assert stderr.count("'ekf.speed_noise_m_s' is not a parameter of this node (did you "
                        "mean 'speed_noise_m_s'?)") == 1, stderr
    # A name another node declares (the calibration node's window) is no typo here; one
    # no gyro_ekf node has is said.
    assert stderr.count('is not a parameter of this node') == 3, stderr
    assert stderr.count("parameter 'frame_prefix' is not a parameter of any gyro_ekf node; "
                        'ignored') == 1, stderr
    # A LiDAR left out of lidar.topics: not "did you mean 'lidar.scan.x_m'?".
    assert stderr.count("parameter 'lidar.scan2.x_m': 'scan2' is not one of lidar.topics "
                        "['scan']; ignored") == 1, stderr
    assert 'window_length_s' not in stderr
    assert 'Traceback' not in stderr


@pytest.mark.ros
def test_a_sidecar_recording_what_convert_dropped_is_taken_without_a_warning(
        ros_env, tmp_path):
    # The record of what convert --skip-bad dropped: rclpy must parse it, the EKF node
    # declares it, and no name of it may pass for a misspelt parameter. The same for the
    # fingerprint of the bag (trip.bag.*), which the node does not declare.
    from gyro_ekf.core.validation import InputReport
    from gyro_ekf.io.sidecar import BagFingerprint, BagParams, sidecar_path, to_yaml

    dropped = InputReport(source='IMU_dataC.mat, Speed_dataC.mat', skip_bad=True)
    dropped.count('imu.angular_velocity.z', 'not finite', 20000, 10)
    dropped.count('speed.stamp_s', 'time went back', 300, 2)
    dropped.samples_dropped.update({'imu': 10, 'speed': 2})
    dropped.time_breaks['speed'] = 1
    sidecar = sidecar_path(tmp_path / 'bag')
    sidecar.write_text(to_yaml(BagParams(
        name='trip', log_time_zero_ns=1_700_000_000 * 10**9, converted=dropped,
        bag=BagFingerprint(26120, 1_700_000_000 * 10**9, 1_700_000_261 * 10**9))))
    assert 'dropped_when_converted' in sidecar.read_text()
    assert 'last_stamp_ns: 1700000261000000000' in sidecar.read_text()
    stderr = _run_until_logged(ros_env, tmp_path, 'ekf_node', ['--params-file', str(sidecar)],
                               'EKF ready')
    assert 'is not a parameter of this node' not in stderr, stderr
    assert 'was removed after' not in stderr, stderr
    assert '[FATAL]' not in stderr and 'Traceback' not in stderr, stderr


@pytest.mark.ros
def test_the_calibration_node_warns_about_its_former_parameters_too(ros_env, tmp_path):
    stderr = _run_until_logged(ros_env, tmp_path, 'calibration_node', [
        '-p', 'confirm_jump_after:=5', '-p', 'limits.max_coordinate_m:=10.0',
        '-p', 'limits.max_speed_m_s:=10.0'], 'collecting a')
    assert stderr.count("parameter 'confirm_jump_after' was removed") == 1, stderr
    assert stderr.count("parameter 'limits.max_coordinate_m' was removed") == 1, stderr
    assert stderr.count('was removed after') == 2, stderr


@pytest.mark.ros
@pytest.mark.parametrize('content, match', [
    (None, r'missing\.yaml: cannot read the landmarks file: No such file'),
    (b'\x89PNG\r\n\x1a\n\x00\x00', r'map\.yaml: binary data \(NUL byte at offset 8\)'),
    (b'landmarks: [[1.0, 2.0], [3.0]]\n', r'map\.yaml: landmark 1: expected two numbers x y'),
])
def test_a_bad_or_missing_landmarks_file_stops_the_node_with_one_line(
        ros_env, tmp_path, content, match):
    import subprocess
    import sys

    path = tmp_path / ('missing.yaml' if content is None else 'map.yaml')
    if content is not None:
        path.write_bytes(content)
    result = subprocess.run([sys.executable, '-m', 'gyro_ekf.nodes.ekf_node', '--ros-args',
                             '-p', f'landmarks_file:={path}'], env=ros_env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    fatal = [line for line in result.stderr.splitlines() if line.startswith('[FATAL]')]
    assert len(fatal) == 1 and re.search(match, fatal[0]), result.stderr
    assert str(path) in fatal[0]
    assert 'Traceback' not in result.stderr + result.stdout
