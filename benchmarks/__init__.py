"""The benchmarks of `make bench` (`python -m benchmarks`): figures, never test assertions.

They live beside the package, not in it: they need a source checkout (the bundled bags, the
course logs in ../shared, filterpy from the bench extra) and start ROS nodes of their own.
"""
