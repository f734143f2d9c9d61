"""``blackmetal gateway`` / ``python -m blackmetal.gateway``: the robot's Zenoh gateway."""

from __future__ import annotations

import asyncio

from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.entry import ServiceCommand, freeze_start_up, say
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session

from .fleet import FLEET, build
from .settings import GatewaySettings, when_killed

#: A short GIL switch interval lets Zenoh's threads hand a command over without waiting out the default 5 ms slice.
SWITCH_INTERVAL_S = 0.0005


async def serve(settings: GatewaySettings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the service until ``stop``, close everything."""
    with await open_service_session(settings.zenoh, stop, "gateway") as session:
        refuse_taken(session, "gateway", [settings.prefix])
        edge, service = build(session, settings)
        say(
            f"blackmetal gateway ready: robot {settings.robot}:{settings.control_port} (log {settings.log_port}), "
            f"prefix {settings.prefix}, polling at {settings.poll_hz:g} Hz",
            f"  {when_killed(settings.robot)}",
            f"  e-stop state kept in {service.latch.where}",
            service.start_sentence and f"  {service.start_sentence}",
        )
        announce_ready("gateway", prefix=settings.prefix, cmd_timeout=settings.cmd_timeout)
        freeze_start_up()
        try:
            await service.run(stop)
        finally:
            edge.close()


COMMAND = ServiceCommand("gateway", GatewaySettings, __doc__, serve, FLEET, switch_interval=SWITCH_INTERVAL_S)
build_parser, run, main = COMMAND.build_parser, COMMAND.run, COMMAND.main
