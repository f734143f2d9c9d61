"""The Black Metal robot's wire protocol, sans I/O: both roles, for the gateway and the simulator.

The gateway uses the client role (:func:`encode_request`, :class:`ReplyDecoder`); the simulator the server role
(:class:`RequestDecoder`, the ``encode_*`` replies). What the robot speaks (control port 665, log port 664):

* a request is one JSON object, no terminator:
  ``{"UserID":1,"Command":3,"RightWheelSpeed":0.250000,"LeftWheelSpeed":0.250000}``;
* every command gets ``{"status":"RECIEVE_OK"}`` (sic) or ``{"status":"FULL_BUFFER"}`` (command dropped);
* commands 6 and 8 then get a JSON-like data reply a JSON parser rejects, ``{"LeftWheelSpeed"=150 "RightWheelSpeed"=-148}``
  (a space or a comma between the pairs): integer impulses (per second for speeds), the right encoder mirrored;
* the log port pushes ``{"state":S,"direction":D}`` about once a second.

Framing is by braces (no message nests one): garbage is skipped and reported as :class:`Malformed`, a run without a
closing brace is dropped past ``max_frame`` so the buffer stays bounded; ``feed`` never raises.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass
from dataclasses import fields as fields_of
from enum import IntEnum
from typing import Any, Generic, TypeVar

import msgspec

from blackmetal.schemas import BlackmetalError


class ProtocolError(BlackmetalError):
    """A command the robot must never see, or a value the wire cannot carry."""


#: The only user id the robot's software is known to use.
USER_ID = 1
#: Largest wheel speed (m/s) that may go on the wire; the robot's own limit is 0.8.
WIRE_SPEED_LIMIT = 1.0
#: Integer fields on the wire are 32-bit on the robot.
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
#: Longest message we wait for before declaring the bytes garbage.
DEFAULT_MAX_FRAME = 512

STATUS_OK = "RECIEVE_OK"  # sic: the robot's own spelling
STATUS_FULL_BUFFER = "FULL_BUFFER"


class CommandCode(IntEnum):
    """Command codes of the control port."""

    EMPTY = 0
    EMG_STOP = 1
    NORMAL_STOP = 2
    SET_LR_WHEEL_VELOCITY = 3
    SET_LR_WHEEL_POSITION = 4
    NOT_IMPLEMENTED_5 = 5
    GET_LR_WHEEL_VELOCITY = 6
    PREPARE_WHEEL_CONTROLLER = 7
    GET_LR_WHEEL_POSITION = 8


#: Commands that get a data reply after their status reply.
DATA_COMMANDS = frozenset({CommandCode.GET_LR_WHEEL_VELOCITY, CommandCode.GET_LR_WHEEL_POSITION})


@dataclass(frozen=True, slots=True)
class Request:
    """One command to the robot. ``left``/``right`` (keyword-only, as every wheel pair): wheel speeds (m/s) for
    SET_LR_WHEEL_VELOCITY, impulse counts for SET_LR_WHEEL_POSITION, else None; :func:`encode_request` writes them
    right then left, as the robot wants."""

    command: CommandCode
    _: KW_ONLY
    left: float | int | None = None
    right: float | int | None = None
    user_id: int = USER_ID


def set_velocity(*, left: float, right: float) -> Request:
    return Request(CommandCode.SET_LR_WHEEL_VELOCITY, left=float(left), right=float(right))


def simple(command: CommandCode) -> Request:
    """A command without payload fields (everything but 3 and 4)."""
    return Request(CommandCode(command))


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _is_int32(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and INT32_MIN <= value <= INT32_MAX


def _wire_speed(name: str, value: object) -> str:
    if not isinstance(value, (int, float)) or not _is_number(value):
        raise ProtocolError(f"{name} must be a finite number, got {value!r}")
    if abs(value) > WIRE_SPEED_LIMIT:
        raise ProtocolError(f"{name} {value!r} m/s is beyond the wire limit of {WIRE_SPEED_LIMIT} m/s")
    text = f"{value:.6f}"
    return "0.000000" if text == "-0.000000" else text


def _wire_int(name: str, value: object) -> str:
    if not _is_int32(value):
        raise ProtocolError(f"{name} must be a 32-bit integer, got {value!r}")
    return str(value)


#: The wheel fields of commands 3 and 4, in the robot's right-then-left order: how a value is checked, written and read.
_WHEEL_FIELDS: dict[CommandCode, tuple[str, str, Callable[[str, object], str], Callable[[object], bool], type, str]] = {
    CommandCode.SET_LR_WHEEL_VELOCITY: ("RightWheelSpeed", "LeftWheelSpeed", _wire_speed, _is_number, float, "finite"),
    CommandCode.SET_LR_WHEEL_POSITION: ("RightWheelPosition", "LeftWheelPosition", _wire_int, _is_int32, int, "integer"),
}


def encode_request(request: Request) -> bytes:
    """The exact bytes the robot expects for ``request`` (one JSON object, no newline).

    Raises ProtocolError for anything the robot must never see: non-finite or out-of-range speeds, non-integer
    positions, unknown commands.
    """
    command = request.command if type(request.command) is CommandCode else CommandCode(request.command)
    text = f'{{"UserID":{_wire_int("UserID", request.user_id)},"Command":{int(command)}'
    wheels = _WHEEL_FIELDS.get(command)
    if wheels is not None:
        right, left, write = wheels[:3]
        text += f',"{right}":{write(right, request.right)},"{left}":{write(left, request.left)}'
    return (text + "}").encode("ascii")


@dataclass(frozen=True, slots=True)
class StatusReply:
    """The robot's answer to every command."""

    status: str

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK

    @property
    def full_buffer(self) -> bool:
        return self.status == STATUS_FULL_BUFFER


@dataclass(frozen=True, slots=True, kw_only=True)
class SpeedReading:
    """Data reply to GET_LR_WHEEL_VELOCITY: impulses per second, right mirrored."""

    left: int
    right: int


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionReading:
    """Data reply to GET_LR_WHEEL_POSITION: cumulative impulses, right mirrored."""

    left: int
    right: int


@dataclass(frozen=True, slots=True)
class LogReport:
    """Log-port state report."""

    state: int
    direction: int


@dataclass(frozen=True, slots=True)
class Malformed:
    """Bytes that are not a valid message: why, and a short excerpt."""

    reason: str
    raw: bytes


Reply = StatusReply | SpeedReading | PositionReading | LogReport
M = TypeVar("M")


def encode_status(status: str = STATUS_OK) -> bytes:
    return f'{{"status":"{status}"}}'.encode("ascii")


def encode_wheel_speeds(*, left: int, right: int, separator: str = " ") -> bytes:
    """The robot's JSON-like speed reply; ``separator`` is " " or "," (both occur)."""
    return _encode_pair("LeftWheelSpeed", left, "RightWheelSpeed", right, separator)


def encode_wheel_positions(*, left: int, right: int, separator: str = " ") -> bytes:
    return _encode_pair("LeftWheelPosition", left, "RightWheelPosition", right, separator)


def _encode_pair(left_name: str, left: int, right_name: str, right: int, separator: str) -> bytes:
    if separator not in (" ", ","):
        raise ProtocolError(f"separator must be ' ' or ',', got {separator!r}")
    return (f'{{"{left_name}"={_wire_int(left_name, left)}{separator}"{right_name}"={_wire_int(right_name, right)}}}').encode("ascii")


def encode_log_report(state: int, direction: int) -> bytes:
    return f'{{"state":{_wire_int("state", state)},"direction":{_wire_int("direction", direction)}}}'.encode("ascii")


_PAIR = re.compile(rb'\s*"([A-Za-z_]{1,32})"\s*[:=]\s*(?:"([A-Za-z_]{0,32})"|(-?\d{1,10}))\s*(,?)')


def _parse_pairs(frame: bytes) -> dict[str, str | int] | None:
    """Parse the robot's JSON-like ``{"k"=v "k2":v2}`` body; None if it is not that."""
    body = frame[1:-1]
    fields: dict[str, str | int] = {}
    pos = 0
    end = len(body)
    while pos < end:
        match = _PAIR.match(body, pos)
        if match is None or match.end() == pos:
            return None
        key = match.group(1).decode("ascii")
        if key in fields:
            return None
        string, number = match.group(2), match.group(3)
        fields[key] = string.decode("ascii") if string is not None else int(number)
        pos = match.end()
    return fields


#: The robot's key/value replies besides the status: their two keys, in the order of the reply's fields.
_PAIR_REPLIES: dict[tuple[str, str], type[SpeedReading | PositionReading | LogReport]] = {
    ("LeftWheelSpeed", "RightWheelSpeed"): SpeedReading,
    ("LeftWheelPosition", "RightWheelPosition"): PositionReading,
    ("state", "direction"): LogReport,
}


#: The wheel-speed reply as the robot and the simulator write it, read in one match (a fleet gateway reads 5 000 a
#: second): what it matches, :func:`_parse_pairs` reads the same way (a test holds them equal); the rest goes there. Its
#: whitespace runs are possessive (``\s*+``): no run gives back what it took, so a frame it fails on is given up in one
#: pass (a frame of 500 spaces took 500 us with two plain runs side by side, against 4 us in the field parser).
_SPEED_REPLY = re.compile(rb'\{\s*+"LeftWheelSpeed"\s*+[:=]\s*+(-?\d{1,10})\s*+(?:,\s*+)?"RightWheelSpeed"\s*+[:=]\s*+(-?\d{1,10})\s*+,?\}')
#: The status replies the robot writes (every command is answered by one), by their exact bytes; others are parsed.
_STATUS_FRAMES: dict[bytes, StatusReply] = {encode_status(word): StatusReply(word) for word in (STATUS_OK, STATUS_FULL_BUFFER)}


def parse_reply(frame: bytes) -> Reply | Malformed:
    """Turn one ``{...}`` frame from the robot into a reply, or Malformed."""
    known = _STATUS_FRAMES.get(frame)
    if known is not None:
        return known
    speeds = _SPEED_REPLY.fullmatch(frame)
    if speeds is not None:
        left, right = int(speeds.group(1)), int(speeds.group(2))
        if INT32_MIN <= left <= INT32_MAX and INT32_MIN <= right <= INT32_MAX:
            return SpeedReading(left=left, right=right)
    return _parse_reply(frame)


def _parse_reply(frame: bytes) -> Reply | Malformed:
    """:func:`parse_reply`, field by field (the reference the fast paths are tested against)."""
    fields = _parse_pairs(frame)
    if fields is None:
        return Malformed("not a robot reply (unreadable key/value pairs)", frame)
    if set(fields) == {"status"}:
        status = fields["status"]
        if isinstance(status, str) and status:
            return StatusReply(status)
        return Malformed("status reply without a status word", frame)
    keys = next((keys for keys in _PAIR_REPLIES if set(keys) == set(fields)), None)
    if keys is None:
        return Malformed(f"unknown reply fields {sorted(fields)}", frame)
    kind = _PAIR_REPLIES[keys]
    values = [value for value in (fields[key] for key in keys) if isinstance(value, int)]
    if len(values) != len(keys):
        return Malformed(f"{kind.__name__} values must be integers", frame)
    if not all(INT32_MIN <= value <= INT32_MAX for value in values):
        return Malformed(f"{kind.__name__} values beyond 32 bits", frame)
    return kind(**{f.name: value for f, value in zip(fields_of(kind), values, strict=True)})


class _FramedDecoder(Generic[M]):
    """Cuts a byte stream into ``{...}`` frames (everything else is garbage) and parses each; ``feed`` never raises.

    ``garbage_bytes`` and ``malformed`` count what was skipped.
    """

    _parse: Callable[[bytes], M | Malformed]

    def __init__(self, max_frame: int = DEFAULT_MAX_FRAME) -> None:
        self._buf = bytearray()
        self.max_frame = max_frame
        self.garbage_bytes = 0
        self.malformed = 0

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[M | Malformed]:
        """Every complete frame of ``data`` parsed and every run of garbage as a :class:`Malformed`, in stream order.

        The work is per frame, not per byte: a frame is the last ``{`` before the next ``}``, and all that lies before
        it is one run of garbage, whatever its length (a flood of ``{`` costs one report per read).
        """
        out: list[M | Malformed] = []
        buf = self._buf
        buf += data
        pos = 0
        size = len(buf)
        while pos < size:
            end = buf.find(b"}", pos)
            start = buf.rfind(b"{", pos, end if end >= 0 else size)
            if start < 0:  # no opening brace before the next closing one (or at all): garbage up to the next '{'
                stop = buf.find(b"{", end + 1) if end >= 0 else -1
                stop = size if stop < 0 else stop
                self._garbage(buf, pos, stop, "bytes outside any {...} message", out)
                pos = stop
                continue
            if start > pos:
                cut = buf.find(b"{", pos, start) >= 0
                self._garbage(buf, pos, start, "message cut off by a new '{'" if cut else "bytes outside any {...} message", out)
            if end < 0:
                if size - start > self.max_frame:
                    self._garbage(buf, start, size, f"no closing '}}' within {self.max_frame} bytes", out)
                    pos = size
                else:
                    pos = start
                break
            item = self._parse(bytes(buf[start : end + 1]))
            if isinstance(item, Malformed):
                self.malformed += 1
            out.append(item)
            pos = end + 1
        del buf[:pos]
        return out

    def _garbage(self, buf: bytearray, start: int, end: int, reason: str, out: list[M | Malformed]) -> None:
        chunk = bytes(buf[start:end])
        if not chunk.strip():
            return  # whitespace between messages is harmless
        self.garbage_bytes += len(chunk)
        self.malformed += 1
        out.append(Malformed(reason, chunk[:DEFAULT_MAX_FRAME]))

    def reset(self) -> None:
        """Forget any partial message (after a reconnect)."""
        self._buf.clear()


class ReplyDecoder(_FramedDecoder[Reply]):
    """Client role: feed bytes from the control or log port, get replies (a :class:`Malformed` where garbage was skipped)."""

    _parse = staticmethod(parse_reply)


_request_decoder = msgspec.json.Decoder(dict[str, Any])


def parse_request(frame: bytes) -> Request | Malformed:
    """Turn one ``{...}`` frame from a client into a Request, or Malformed."""
    known = _SIMPLE_FRAMES.get(frame)
    if known is not None:
        return known
    return _parse_request(frame)


def _parse_request(frame: bytes) -> Request | Malformed:
    """:func:`parse_request`, field by field (the reference the cache of known frames is tested against)."""
    try:
        fields = _request_decoder.decode(frame)
    except msgspec.DecodeError:
        return Malformed("request is not a JSON object", frame)
    user_id = fields.get("UserID")
    code = fields.get("Command")
    if not isinstance(user_id, int) or isinstance(user_id, bool):
        return Malformed("request without an integer UserID", frame)
    if not isinstance(code, int) or isinstance(code, bool) or not 0 <= code <= 8:
        return Malformed("request without a Command code 0-8", frame)
    command = CommandCode(code)
    wheels = _WHEEL_FIELDS.get(command)
    if wheels is None:
        return Request(command, user_id=user_id)
    right_name, left_name, _, valid, kind, what = wheels
    right, left = fields.get(right_name), fields.get(left_name)
    if not (valid(right) and valid(left)):
        return Malformed(f"{command.name} needs {what} {right_name} and {left_name}", frame)
    return Request(command, left=kind(left), right=kind(right), user_id=user_id)


#: The requests without wheel values, by the exact bytes the gateway writes (the simulator reads a fleet's 5 000 polls a
#: second): a Request is frozen, so one object serves every time; any other frame is parsed.
_SIMPLE_FRAMES: dict[bytes, Request] = {
    encode_request(simple(code)): simple(code)
    for code in CommandCode
    if code not in (CommandCode.SET_LR_WHEEL_VELOCITY, CommandCode.SET_LR_WHEEL_POSITION)
}


class RequestDecoder(_FramedDecoder[Request]):
    """Server role (the simulator): feed bytes from a client, get requests."""

    _parse = staticmethod(parse_request)
