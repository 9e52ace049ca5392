"""Topic, type and frame names shared by the bag layer and the nodes (plain strings).

Topic names are relative, so namespaces and remapping work on live nodes; bags store
them with a leading slash, as rosbag2 records them in the root namespace.
"""

IMU = 'imu'
IMU_CORRECTED = 'imu/corrected'
ODOM = 'odom'
SCAN = 'scan'
SCAN2 = 'scan2'
LANDMARKS = 'landmarks'
LANDMARK_MAP = 'landmark_map'
INITIAL_POSE = 'initialpose'
GROUND_TRUTH = 'ground_truth'
GYRO_BIAS = 'gyro_bias'
EKF_POSE = 'ekf/pose'
EKF_ODOMETRY = 'ekf/odometry'
EKF_BIAS = 'ekf/bias'
EKF_IMU = 'ekf/imu'
EKF_PATH = 'ekf/path'
EKF_MARKERS = 'ekf/markers'
LANDMARK_MARKERS = 'landmark_markers'
TF = '/tf'
TF_STATIC = '/tf_static'
EKF_MOUNTS = 'ekf/mounts'
DIAGNOSTICS = '/diagnostics'
CLOCK = '/clock'

UNKNOWN_AXIS_VARIANCE = 1e6
"""Angular-velocity variance, (rad/s)^2, marking an axis the IMU does not measure: the bag
writer writes it, the bag reader and the nodes read it (REP-145 keeps -1 at element 0 for
"no data at all", which would void the whole vector)."""

IMU_TYPE = 'sensor_msgs/msg/Imu'
ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
LASER_SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
POSE_ARRAY_TYPE = 'geometry_msgs/msg/PoseArray'
POSE_WITH_COVARIANCE_STAMPED_TYPE = 'geometry_msgs/msg/PoseWithCovarianceStamped'
VECTOR3_STAMPED_TYPE = 'geometry_msgs/msg/Vector3Stamped'

# REP-105 frames.
MAP_FRAME = 'map'
ODOM_FRAME = 'odom'
BASE_FRAME = 'base_link'
IMU_FRAME = 'imu_link'
LASER_FRAME = 'laser'
LASER2_FRAME = 'laser2'


def bag_topic(name: str) -> str:
    """Topic name as a bag records it (absolute)."""
    return name if name.startswith('/') else '/' + name
