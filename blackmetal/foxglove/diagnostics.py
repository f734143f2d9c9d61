"""The gateway's health as ROS ``diagnostic_msgs/msg/DiagnosticArray`` (JSON) for Foxglove's Diagnostics panels.

The levels and words are the shared table's (:mod:`blackmetal.runtime.diagnostics`), as on ROS 2 ``/diagnostics``.
"""

from __future__ import annotations

from typing import Any

from blackmetal.runtime.diagnostics import COMMANDS_REFUSED, ESTOP_ENGAGED, REPLIES_LOST_EVER, Level, Status, link_level
from blackmetal.schemas import GatewayHealth, LinkHealth, stamp_parts

from .channels import HEADER, array, message_schema, obj, typed

_STRING = typed("string")
#: ROS's diagnostic_msgs/msg/DiagnosticArray as JSON, the shape the Diagnostics panels read.
DIAGNOSTICS_SCHEMA = message_schema(
    "diagnostic_msgs/msg/DiagnosticArray",
    "the gateway's health as ROS diagnostics, from <prefix>/gateway/health",
    {
        "header": HEADER,
        "status": array(
            obj(
                level=typed("integer", description="0 OK, 1 WARN, 2 ERROR, 3 STALE"),
                name=_STRING,
                message=_STRING,
                hardware_id=_STRING,
                values=array(obj(key=_STRING, value=_STRING)),
            )
        ),
    },
)


def _status(name: str, level: Level, message: str, hardware_id: str, **values: Any) -> Status:
    return Status(level, name, message, hardware_id, tuple((key, "" if value is None else str(value)) for key, value in values.items()))


def _fields(health: GatewayHealth, *names: str) -> dict[str, Any]:
    return {name: getattr(health, name) for name in names}


def _link(name: str, link: LinkHealth, hardware_id: str) -> Status:
    return _status(name, link_level(link.state), link.state, hardware_id, connected_since=link.connected_since, reconnects=link.reconnects)


def diagnostic_json(status: Status) -> dict[str, Any]:
    values = [{"key": key, "value": value} for key, value in status.values]
    return {"level": int(status.level), "name": status.name, "message": status.message, "hardware_id": status.hardware_id, "values": values}


def diagnostics(health: GatewayHealth, hardware_id: str) -> dict[str, Any]:
    """The gateway's health as a diagnostic_msgs/msg/DiagnosticArray (JSON): e-stop, links, commands, robot exchange."""
    sec, nsec = stamp_parts(health.stamp)
    driver = health.active_source or "nobody"
    if health.conflict_with:
        level, message = COMMANDS_REFUSED.check(other=health.conflict_with)
        command = _status("gateway: commands", level, message, hardware_id)
    else:
        command = _status(
            "gateway: commands",
            Level.OK,
            f"driven by {driver}",
            hardware_id,
            **_fields(health, "active_source", "cmd_timeout_active", "commands_sent", "rejected_inputs"),
            **{f"source {name}": f"priority {s.priority}, age {s.age}, dropped {s.dropped}" for name, s in health.sources.items()},
            **{f"lock {name}": engaged for name, engaged in health.locks.items()},
        )
    lost = health.lost_replies + health.malformed_replies
    statuses = [
        _status(
            "gateway: e-stop",
            ESTOP_ENGAGED.level if health.estop else Level.OK,
            health.estop_text(),
            hardware_id,
            **_fields(health, "estop", "estop_since", "estop_by"),
        ),
        _link("gateway: control link", health.control, hardware_id),
        _link("gateway: log link", health.log, hardware_id),
        command,
        _status(
            "gateway: robot exchange",
            REPLIES_LOST_EVER if lost else Level.OK,
            f"{health.poll_hz:g} Hz polls, rtt {health.last_rtt_ms} ms",
            hardware_id,
            **_fields(health, "polls", "replies", "lost_replies", "malformed_replies", "full_buffer", "wheel_speeds"),
        ),
    ]
    status = [diagnostic_json(s) for s in statuses]
    return {"header": {"stamp": {"sec": sec, "nsec": nsec}, "frame_id": ""}, "status": status}
