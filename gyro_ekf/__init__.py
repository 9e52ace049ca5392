"""gyro_ekf: gyro bias calibration and a pose/bias EKF for ROS 2 Jazzy."""
