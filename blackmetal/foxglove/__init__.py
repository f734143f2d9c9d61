"""``blackmetal foxglove``: a live Foxglove view of the robot (WebSocket server from the ``foxglove-sdk`` package), optionally written to MCAP."""
