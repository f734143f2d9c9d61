"""``blackmetal foxglove``: a live Foxglove view of the robot: pose, transform, path, truth, wheels, status, health, errors.

Open Foxglove (app or desktop) or Lichtblick, "Open connection", Foxglove
WebSocket, and the URL this prints; then import the layout shipped in
``deploy/foxglove/blackmetal.layout.json``. Clients may drive: ``/cmd_vel``
(geometry_msgs/msg/Twist, as the command source ``foxglove``), ``/estop``
(std_msgs/msg/Bool) and the services ``set_estop``, ``reset_odometry`` and
``cancel_goal``, all JSON; the 3D panel's publish tools send goals (``/goal_pose``, to
``<prefix>/nav/goal``) and pose estimates (``/initialpose``, to
``<prefix>/nav/set_pose``), the answers shown on ``/log``. ``--mcap FILE`` writes the view's channels to an MCAP file as they
are sent. ``--fleet FILE``: every robot of a fleet file in one view, each
under ``/<id>/`` (/r3/odometry, /r3/cmd_vel, /r3/set_estop; frames r3/odom,
r3/base_link), with /fleet/summary.
"""

from __future__ import annotations

import asyncio
from typing import Any

from blackmetal.runtime.entry import ServiceCommand, say
from blackmetal.schemas import Keys, require_extra

from .controls import Controls
from .fleet import FLEET, Wiring, serve_views
from .front import SUBPROTOCOLS
from .host import FoxgloveHost
from .live import LiveView
from .naming import COMMAND_SOURCE, Service, nav_takes, takes
from .params import Parameters
from .settings import FoxgloveSettings
from .watch import Watch

#: The one robot's id where the parts name robots (its names carry no namespace).
ONE_ROBOT = ""


async def serve(settings: FoxgloveSettings, stop: asyncio.Event) -> None:
    """Start the server (and the MCAP file), open the Zenoh session, show the robot and take its clients' commands until ``stop``, close everything."""
    require_extra("blackmetal foxglove", "foxglove", "foxglove")
    keys = Keys(settings.prefix)
    host = FoxgloveHost(settings)
    try:
        await host.start()  # the port is taken before Zenoh opens: a port in use is one sentence, at once
        view = LiveView(keys, path_length=settings.path_length)
        controls = Controls(keys, host, call_timeout=settings.call_timeout)
        params = Parameters({ONE_ROBOT: (keys, "")}, host, call_timeout=settings.call_timeout)
        wiring = Wiring(host, {ONE_ROBOT: view}, {ONE_ROBOT: controls}, Watch(view.feeds(), record_all=bool(settings.mcap)))
        host.attach(controls, params, wiring)

        def announce(address: str) -> dict[str, Any]:
            wiring.ask_params(ONE_ROBOT)
            say(
                f"blackmetal foxglove: {keys.prefix} on {address}",
                f"  open in Foxglove: Open connection > Foxglove WebSocket > {address}",
                f"  or https://app.foxglove.dev/?ds=foxglove-websocket&ds.url={address}",
                f"  clients publish {takes()} (as the command source {COMMAND_SOURCE!r})",
                f"  goals from the 3D panel: {nav_takes()}",
                f"  services: {', '.join(s.value for s in Service)}; subprotocols {', '.join(SUBPROTOCOLS)}",
                f"  the gateway's parameters ({keys.params}), the URDF on {view.description_topic}",
            )
            return {"prefix": keys.prefix, "services": [s.value for s in Service]}

        await serve_views(settings, stop, host, wiring, announce)
    finally:
        host.close()


COMMAND = ServiceCommand("foxglove", FoxgloveSettings, __doc__, serve, FLEET)
build_parser, run, main = COMMAND.build_parser, COMMAND.run, COMMAND.main
