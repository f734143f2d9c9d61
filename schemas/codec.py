"""Tolerant decoding and canonical encoding of wire messages.

The decoder looks only at the bytes (``zenoh put`` sends no encoding header, a newline may trail); anything that is not
a valid message raises :class:`PayloadError` with a reason a person can act on.
"""

from __future__ import annotations

from typing import Any, TypeVar

import msgspec

from .errors import PayloadError

#: Largest payload we try to decode; anything larger is rejected unread.
MAX_PAYLOAD_BYTES = 64 * 1024
#: Length of the payload excerpt carried in error reports.
EXCERPT_CHARS = 80

T = TypeVar("T", bound=msgspec.Struct)

_encoder = msgspec.json.Encoder()
_decoders: dict[type, msgspec.json.Decoder[Any]] = {}


def excerpt(payload: bytes | bytearray | memoryview | str, limit: int = EXCERPT_CHARS) -> str:
    """A short printable excerpt of a payload, for error reports and logs."""
    if isinstance(payload, str):
        text = payload[: limit + 1]
    else:
        text = bytes(payload[: limit * 4 + 4]).decode("utf-8", errors="replace")
    text = text.encode("ascii", errors="backslashreplace").decode("ascii")
    text = "".join(ch if ch.isprintable() else f"\\x{ord(ch):02x}" for ch in text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _decoder(message_type: type[T]) -> msgspec.json.Decoder[T]:
    decoder = _decoders.get(message_type)
    if decoder is None:
        decoder = _decoders[message_type] = msgspec.json.Decoder(message_type)
    return decoder


def to_bytes(payload: Any) -> bytes:
    """Payload bytes from bytes-likes, str, or a Zenoh ``ZBytes`` (anything with ``to_bytes``)."""
    if isinstance(payload, bytes):
        return payload
    if isinstance(payload, (bytearray, memoryview)):
        return bytes(payload)
    if isinstance(payload, str):
        return payload.encode("utf-8")
    to_bytes_method = getattr(payload, "to_bytes", None)
    if callable(to_bytes_method):
        return bytes(to_bytes_method())
    raise TypeError(f"cannot read a payload from {type(payload).__name__}")


def payload_bytes(sample: Any) -> bytes:
    """A Zenoh sample's payload as bytes; empty if it cannot be read.

    Duck-typed (``sample.payload.to_bytes()``), so this layer needs no Zenoh; it never raises, because Zenoh callbacks
    call it on Zenoh's threads.
    """
    try:
        return bytes(sample.payload.to_bytes())
    except Exception:
        return b""


def decode(message_type: type[T], payload: Any, max_bytes: int = MAX_PAYLOAD_BYTES) -> T:
    """Decode one JSON message of ``message_type`` from ``payload``.

    Accepts surrounding whitespace and a UTF-8 byte-order mark; ignores any encoding header (callers pass only the
    payload). Raises PayloadError.
    """
    name = message_type.__name__
    data = to_bytes(payload)
    if len(data) > max_bytes:
        raise PayloadError(name, f"payload is {len(data)} bytes, larger than the {max_bytes}-byte limit", excerpt(data))
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    data = data.strip()
    if not data:
        raise PayloadError(name, "payload is empty; expected a JSON object")
    if data[:1] != b"{":
        raise PayloadError(name, "payload is not a JSON object (it must start with '{')", excerpt(data))
    try:
        return _decoder(message_type).decode(data)
    except msgspec.ValidationError as exc:
        raise PayloadError(name, _readable(str(exc)), excerpt(data)) from None
    except msgspec.DecodeError as exc:
        raise PayloadError(name, f"not valid JSON ({_readable(str(exc))})", excerpt(data)) from None


def _readable(text: str) -> str:
    """msgspec says '... - at `$.linear.x`'; keep it but make it read well."""
    return text.replace("Number out of range", "number out of range (not finite)")


def encode(message: msgspec.Struct) -> bytes:
    return _encoder.encode(message)
