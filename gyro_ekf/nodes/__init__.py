"""rclpy nodes: thin adapters from messages to the core and back (rclpy lives only here)."""

# The node executables' processes: one BLAS thread, before numpy loads (see the module).
import gyro_ekf.blas_threads  # noqa: F401
