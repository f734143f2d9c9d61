"""The navigation service: goals to poses in the map or odometry frame, driven through the arbiter as the ``nav`` source."""
