"""ROS-free estimation core: numpy and the standard library only."""
