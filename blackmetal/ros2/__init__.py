"""``blackmetal ros2``: the robot as a native ROS 2 node over Zenoh (rmw_zenoh or zenoh-bridge-ros2dds), no ROS installed.

A plain client of the robot's keys, in the services' shape (pure :mod:`.core`, :mod:`.host`, :mod:`.zenoh_edge`);
docs/ros2-adapter.md and docs/ros2.md say what it does.
"""
