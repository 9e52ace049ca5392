"""Command-line tools: one `gyro-ekf` command with a subcommand each."""
