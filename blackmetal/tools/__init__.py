"""The user tools: plain Zenoh clients of the robot's keys (and the Zenoh router from the wheel)."""
