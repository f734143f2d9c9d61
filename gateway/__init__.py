"""The Black Metal gateway service: the only process that talks to the robot (docs/contributing.md)."""
