"""ament_python packaging: `colcon build` on a Jazzy install, `pip install .` elsewhere."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'gyro_ekf'

NODES = ('calibration_node', 'landmark_detector_node', 'ekf_node')

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, PACKAGE + '.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    python_requires='>=3.10',
    # ROS message packages and rclpy come from the ROS install (package.xml) or, without
    # ROS, from the 'ros' extra; everything else is plain PyPI.
    install_requires=[
        'setuptools',
        'numpy>=1.24',
        'scipy>=1.10',
        'PyYAML>=6',
        'rosbags==0.11.9',
        # The bundled bags are zstd-compressed; pinning the codec keeps `make bags` bit-exact.
        'backports.zstd==1.8.0; python_version < "3.14"',
        # lz4-compressed MCAP chunks (io/mcap_chunks.py); rosbags brings it today, but an
        # import of ours is declared by us.
        'lz4>=4',
        'matplotlib>=3.6',
        'tqdm>=4.60',
    ],
    extras_require={
        'ros': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces'],
        'test': ['pytest', 'mcap>=1.2', 'mcap-ros2-support>=0.5', 'flake8', 'pydocstyle',
                 'filterpy',
                 'colcon-core', 'colcon-ros', 'colcon-python-setup-py',
                 'colcon-test-result', 'colcon-common-extensions'],
        'bench': ['filterpy'],
    },
    # The Fast DDS writer profile of the node processes (nodes/runtime.py).
    package_data={PACKAGE + '.nodes': ['fastdds_writer.xml']},
    zip_safe=True,
    maintainer='gyro_ekf developers',
    maintainer_email='dev@gyro-ekf.local',
    description='Gyro bias calibration and pose/bias EKF with LiDAR landmarks, for ROS 2 Jazzy.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'gyro-ekf = gyro_ekf.cli.main:main',
        ] + [f'{node} = {PACKAGE}.nodes.{node}:main' for node in NODES],
    },
)
