"""What a payload on ``<prefix>/estop`` means, failing safe: only a valid release releases.

``{"engaged": false}`` (whitespace around it allowed) is the one release.
Any payload whose meaning is "true" engages without complaint, whatever its
shape: ``{"engaged": true, "reason": ".."}``, ``{"engaged": 1}``,
``{"engaged": "true"}``, ``true``, ``{"data": true}`` (a ROS bridge's
``std_msgs/Bool``), ``{"Engaged": true}``, a trailing NUL from a C client.
Everything else engages too, and is reported, because a person who meant
to stop the robot must never be ignored on a technicality.
"""

from __future__ import annotations

from typing import Any

import msgspec

from blackmetal.schemas import MAX_PAYLOAD_BYTES, EStop, PayloadError, decode, excerpt, to_bytes

_any = msgspec.json.Decoder(Any)
_TRUE_WORDS = frozenset({"true", "1", "on", "yes", "engage", "engaged", "stop"})
_FALSE_WORDS = frozenset({"false", "0", "off", "no", "release", "released"})
_FIELDS = ("engaged", "data", "value", "estop", "stop")

RELEASE_HINT = 'only {"engaged": false} releases the emergency stop'


def _meaning(value: Any) -> bool | None:
    """True/False for values that plainly mean it; None for anything else."""
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in _TRUE_WORDS | _FALSE_WORDS:
        return value.strip().lower() in _TRUE_WORDS
    if isinstance(value, dict):
        lowered = {str(k).lower(): v for k, v in value.items()}
        for name in _FIELDS:
            if name in lowered:
                return _meaning(lowered[name])
    return None


def read_estop(payload: Any) -> tuple[bool, str | None]:
    """``(engage, complaint)``: whether the stop is engaged after this payload, and what to report (None = nothing)."""
    try:
        return decode(EStop, payload).engaged, None
    except PayloadError as exc:
        strict_reason = str(exc)
    data = to_bytes(payload)
    meaning = None
    if len(data) <= MAX_PAYLOAD_BYTES:
        try:
            meaning = _meaning(_any.decode(data.strip(b" \t\r\n\x00")))
        except (msgspec.DecodeError, ValueError, RecursionError):
            pass  # unreadable: engages below, and is reported
    if meaning is True:
        return True, None
    if meaning is False:
        return True, f"{excerpt(data)!r} is not a valid release, so the emergency stop is engaged: {RELEASE_HINT}"
    return True, f"unreadable payload on estop engages the emergency stop ({strict_reason}); {RELEASE_HINT}"
