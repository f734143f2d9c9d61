"""``blackmetal ros2``: the robot as a native ROS 2 node over Zenoh (rmw_zenoh or zenoh-bridge-ros2dds), no ROS installed.

A plain client of the robot's keys, beside the services, in the services'
shape: :mod:`.core` (the translation, pure and clock-injected) with its
parts :mod:`.joints`, :mod:`.diagnostics`, :mod:`.calls` (the services
answered) and :mod:`.parameters`; :mod:`.host` (asyncio),
:mod:`.zenoh_edge` (declarations), :mod:`.main` (the command),
:mod:`.settings`, :mod:`.fleet` (``--fleet FILE``: one node per robot, one
process, one session); with :mod:`.naming` (keys, tokens, attachments, the
node's topics and services) and the codec: :mod:`.ros_types` (types and
their hashes through rosbags), :mod:`.messages` (CDR) and :mod:`.cdr`
(the hot paths by hand).
"""
