"""``blackmetal foxglove``: a live Foxglove view of the robot (WebSocket server from the ``foxglove-sdk`` package), optionally written to MCAP.

What it shows and takes: docs/foxglove.md. :mod:`.main` is the command, :mod:`.fleet` its ``--fleet``.
"""
