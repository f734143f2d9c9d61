"""The odometry service: wheel impulses in, a filtered, integrated pose out (docs/commands/odometry.md)."""
