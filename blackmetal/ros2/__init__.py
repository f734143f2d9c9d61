"""``blackmetal ros2``: the robot as a native ROS 2 node over Zenoh (rmw_zenoh or zenoh-bridge-ros2dds), no ROS installed.

A plain client of the robot's keys, beside the services: ``naming`` (keys,
tokens, attachments), ``messages`` (CDR through rosbags), ``adapter`` (the
pure translation), ``zenoh_edge`` and ``main``.
"""
