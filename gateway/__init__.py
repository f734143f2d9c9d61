"""The Black Metal gateway service: the only process that talks to the robot.

``connection`` (sans-I/O: safety, polling, reply pairing), ``safety`` and
``exchange`` (pure parts of it), ``service`` (the asyncio host that moves
bytes), ``zenoh_edge`` (declarations), ``settings`` and ``main``.
"""
