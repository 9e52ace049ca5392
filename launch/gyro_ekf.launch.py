"""Launch calibration_node, landmark_detector_node and ekf_node (ROS 2 Jazzy).

    ros2 launch gyro_ekf gyro_ekf.launch.py bag_params:=/path/BAG.params.yaml use_sim_time:=true
    ros2 bag play BAG --clock      # in another terminal

`bag_params` is the params sidecar written beside a bag (LiDAR mounts, initial pose, stated
noise); leave it empty on a robot and set those parameters in your own file instead.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    config = os.path.join(get_package_share_directory('gyro_ekf'), 'config', 'gyro_ekf.yaml')
    files = [config]
    bag_params = LaunchConfiguration('bag_params').perform(context)
    if bag_params:
        files.append(bag_params)
    sim_time = LaunchConfiguration('use_sim_time').perform(context) == 'true'
    parameters = files + [{'use_sim_time': sim_time}]
    return [
        Node(package='gyro_ekf', executable='calibration_node', parameters=parameters),
        Node(package='gyro_ekf', executable='landmark_detector_node', parameters=parameters),
        Node(package='gyro_ekf', executable='ekf_node', parameters=parameters + [
            {'use_calibration': LaunchConfiguration('use_calibration').perform(context) ==
             'true'}]),
    ]


def generate_launch_description():
    """Declare the arguments and the three nodes."""
    return LaunchDescription([
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='use /clock (true with ros2 bag play --clock)'),
        DeclareLaunchArgument('bag_params', default_value='',
                              description='params sidecar of the bag being played'),
        DeclareLaunchArgument('use_calibration', default_value='true',
                              description='seed the EKF bias from calibration_node'),
        OpaqueFunction(function=_nodes),
    ])
