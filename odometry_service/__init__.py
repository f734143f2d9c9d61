"""The odometry service: wheel impulses in, a filtered, integrated pose out (docs/commands/odometry.md).

Pure pipeline (params, sample_order, glitches, integrator; batch, replay and calibration in numpy for logs),
then the service around it: core (pure, clock-injected), host (asyncio), zenoh_edge, main, settings.
"""
