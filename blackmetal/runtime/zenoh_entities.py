"""Small helpers shared by the edge and the flood guard: a sample's key chunk and payload, undeclaring quietly."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from blackmetal.schemas import payload_bytes

if TYPE_CHECKING:
    import zenoh


def chunk_and_payload(sample: "zenoh.Sample") -> tuple[str, bytes]:
    """``(last key chunk, payload)``: what a named input (``cmd_vel/<source>``, ``lock/<name>``) hands over."""
    return str(sample.key_expr).rpartition("/")[2], payload_bytes(sample)


def undeclare(entity: Any) -> None:
    import zenoh

    try:
        entity.undeclare()
    except zenoh.ZError:  # already undeclared by a closing session
        pass
