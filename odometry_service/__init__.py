"""The odometry service: wheel impulses in, a filtered, integrated pose out.

The pipeline, pure: :mod:`.params`, :mod:`.sample_order` (which samples are
integrated, and why an epoch starts), :mod:`.glitches` (spikes, dropouts,
low-pass), :mod:`.integrator` (the streaming odometry); :mod:`.batch`,
:mod:`.replay` and :mod:`.calibration` (the same in numpy, for logs). The
service: :mod:`.core` (pure, clock-injected), :mod:`.host` (asyncio),
:mod:`.zenoh_edge` (declarations), :mod:`.main` (the command), :mod:`.settings`.
"""
