"""What a payload on ``<prefix>/estop`` means, failing safe: only ``{"engaged": false}`` releases.

Anything that plainly means "true" (``{"data": true}``, ``"engage"``, a trailing NUL) engages quietly; everything
else engages too, and is reported: a person who meant to stop the robot is never ignored on a technicality.
"""

from __future__ import annotations

from dataclasses import dataclass
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


@dataclass(frozen=True, slots=True)
class EStopInput:
    """A payload on ``<prefix>/estop`` (or ``estop/release``), read once where it enters (the Zenoh callback): whether
    the stop is engaged after it, what to report (None: nothing) and the payload's excerpt if a report may need it."""

    release_key: bool
    engaged: bool
    complaint: str | None = None
    snippet: str = ""


def read_estop(payload: Any, release_key: bool = False) -> EStopInput:
    try:
        if decode(EStop, payload).engaged:
            return EStopInput(release_key, True)
        return EStopInput(release_key, False, None, "" if release_key else excerpt(payload))
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
        return EStopInput(release_key, True)
    snippet = excerpt(data)
    if meaning is False:
        complaint = f"{snippet!r} is not a valid release, so the emergency stop is engaged: {RELEASE_HINT}"
    else:
        complaint = f"unreadable payload on estop engages the emergency stop ({strict_reason}); {RELEASE_HINT}"
    return EStopInput(release_key, True, complaint, snippet)
