"""``blackmetal foxglove``: a live Foxglove view of the robot (WebSocket server from the ``foxglove-sdk`` package), optionally written to MCAP.

Clients (Foxglove, Lichtblick) may also drive: ``/cmd_vel`` as the command
source ``foxglove``, ``/estop``, and the services ``set_estop`` and
``reset_odometry``. In the services' shape: :mod:`.live` (what each channel
shows), :mod:`.diagnostics`, :mod:`.controls` (what clients may do, pure and
clock-injected), :mod:`.naming`, :mod:`.channels`, :mod:`.fleet_view`,
:mod:`.host` (the WebSocket server behind a thin front that also serves the
older subprotocol ``foxglove.websocket.v1``, and the MCAP file), :mod:`.zenoh_edge`
(declarations), :mod:`.main` (the command), :mod:`.settings`, and
:mod:`.fleet` (``--fleet FILE``: every robot of a fleet file in one view).
"""
