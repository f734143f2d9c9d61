"""``blackmetal foxglove``: a live Foxglove view of the robot, optionally written to MCAP (docs/foxglove.md)."""
