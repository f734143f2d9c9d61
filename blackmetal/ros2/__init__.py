"""``blackmetal ros2``: the robot as a native ROS 2 node over Zenoh (rmw_zenoh or zenoh-bridge-ros2dds), no ROS installed.

A plain client of the robot's keys, beside the services, in the services'
shape: :mod:`.core` (the translation, the pending service calls and the
diagnostics, pure and clock-injected), :mod:`.host` (asyncio),
:mod:`.zenoh_edge` (declarations), :mod:`.main` (the command),
:mod:`.settings`, :mod:`.fleet` (``--fleet FILE``: one node per robot, one
process, one session); with :mod:`.naming` (keys, tokens, attachments, the node's
topics and services) and :mod:`.messages` (CDR and type hashes through
rosbags).
"""
