"""MCAP recordings of the robot's keys: the writer the recorder and the Foxglove view share, and the reader replay and calibration use."""
