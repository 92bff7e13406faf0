"""Robotics I/O: ROS 2 bags in (image and pose topics paired into a flight) and out (depth, validity, labels,
status), rerun recordings, and the command-line glue that adds them to ``predict`` and ``view``."""
