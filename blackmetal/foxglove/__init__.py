"""``blackmetal foxglove``: a live Foxglove view of the robot (WebSocket server from the ``foxglove-sdk`` package), optionally written to MCAP.

In the services' shape, as far as a view without timers needs it:
:mod:`.core` (what each channel shows, from the robot's payloads),
:mod:`.host` (the WebSocket server and the MCAP file), :mod:`.zenoh_edge`
(declarations), :mod:`.main` (the command), :mod:`.settings`.
"""
