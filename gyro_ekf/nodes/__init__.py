"""rclpy nodes: thin adapters from messages to the core and back (rclpy lives only here)."""
