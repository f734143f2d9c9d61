"""``blackmetal ros2``: the robot as a native ROS 2 node over Zenoh, no ROS installed (docs/ros2-adapter.md, docs/ros2.md)."""
