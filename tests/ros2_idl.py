"""ROS 2 interface definitions as rosidl reads them: ``.msg`` / ``.srv`` / ``.action`` text to structures, the types an
action and a service imply, REP-2011's RIHS01 type hashes, and CDR driven by the structures.

Written from rosidl (https://github.com/ros2/rosidl, branch ``jazzy``): ``rosidl_adapter/msg`` for the ``.msg``
field grammar (``char`` is ``uint8``, ``byte`` is ``octet``), ``rosidl_parser/definition.py`` for the types an
``.action`` and a ``.srv`` imply (``<Action>_SendGoal`` with ``goal_id`` + ``goal``, ``<Action>_GetResult`` with
``status`` + ``result``, ``<Action>_FeedbackMessage``, every service's ``_Event`` message since Iron) and an empty
structure's ``structure_needs_at_least_one_member``, ``rosidl_generator_type_description/__init__.py`` for the
hash (the JSON of the type description without default values, sha256). The definitions are the genuine files
vendored in tests/ros2_interfaces/<distro>/ (its README says where from). CDR: XCDR1, little endian, each
primitive aligned to its size from the end of the 4-byte encapsulation header.
"""

from __future__ import annotations

import copy
import hashlib
import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

INTERFACES = Path(__file__).resolve().parent / "ros2_interfaces"
DISTROS = ("humble", "jazzy")
#: Distros whose vendored directory holds only what differs from Jazzy (their NavigateToPose.action).
LATER_DISTROS = ("kilted", "rolling")
HUMBLE_HASH = "TypeHashNotSupported"
CDR_LE = b"\x00\x01\x00\x00"

# ------------------------------------------------------------------ the interface definitions
#: .msg primitive -> (IDL type, struct format, size); rosidl_adapter's MSG_TYPE_TO_IDL.
PRIMITIVES: dict[str, tuple[str, str, int]] = {
    "bool": ("boolean", "?", 1),
    "byte": ("octet", "B", 1),
    "char": ("uint8", "B", 1),
    "int8": ("int8", "b", 1),
    "uint8": ("uint8", "B", 1),
    "int16": ("int16", "h", 2),
    "uint16": ("uint16", "H", 2),
    "int32": ("int32", "i", 4),
    "uint32": ("uint32", "I", 4),
    "int64": ("int64", "q", 8),
    "uint64": ("uint64", "Q", 8),
    "float32": ("float", "f", 4),
    "float64": ("double", "d", 8),
}
#: type_description_interfaces/msg/FieldType.msg's ids of the value types.
FIELD_TYPE_IDS = {
    "nested": 1,
    "int8": 2,
    "uint8": 3,
    "int16": 4,
    "uint16": 5,
    "int32": 6,
    "uint32": 7,
    "int64": 8,
    "uint64": 9,
    "float": 10,
    "double": 11,
    "boolean": 15,
    "octet": 16,
    "string": 17,
    "wstring": 18,
    "bounded_string": 21,
    "bounded_wstring": 22,
}
#: The id offset of arrays, bounded sequences and unbounded sequences (FieldType.msg).
COLLECTION_OFFSETS = {"single": 0, "array": 48, "bounded": 96, "sequence": 144}
EMPTY_MEMBER = "structure_needs_at_least_one_member"


@dataclass(frozen=True)
class FieldType:
    """One field's type: a primitive (.msg spelling), ``string`` / ``wstring`` (with a bound), or ``pkg/msg/Name``."""

    base: str
    collection: str = "single"  # single, array, bounded, sequence
    size: int = 0  # array length or sequence bound
    string_bound: int = 0

    @property
    def nested(self) -> bool:
        return "/" in self.base


@dataclass(frozen=True)
class Field:
    name: str
    type: FieldType
    default: str = ""


def _field_type(spelled: str, package: str) -> FieldType:
    collection, size = "single", 0
    match = re.fullmatch(r"(.+?)\[(<=)?(\d*)\]", spelled)
    if match:
        spelled = match.group(1)
        if match.group(2):
            collection, size = "bounded", int(match.group(3))
        elif match.group(3):
            collection, size = "array", int(match.group(3))
        else:
            collection = "sequence"
    string_bound = 0
    bounded = re.fullmatch(r"(w?string)<=(\d+)", spelled)
    if bounded:
        spelled, string_bound = bounded.group(1), int(bounded.group(2))
    if spelled in PRIMITIVES or spelled in ("string", "wstring"):
        base = spelled
    elif "/" in spelled:
        pkg, name = spelled.split("/")
        base = f"{pkg}/msg/{name}"
    else:
        base = f"{package}/msg/{spelled}"
    return FieldType(base, collection, size, string_bound)


def parse_fields(text: str, package: str) -> list[Field]:
    """The fields of one .msg section (constants and comments dropped); an empty one gets rosidl's placeholder."""
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        spelled, _, rest = line.partition(" ")
        rest = rest.strip()
        if "=" in rest:
            continue  # a constant: not part of the structure, nor of the type hash
        name, _, default = rest.partition(" ")
        fields.append(Field(name, _field_type(spelled, package), default.strip()))
    return fields or [Field(EMPTY_MEMBER, FieldType("uint8"))]


class Interfaces:
    """The structures of one distro's vendored definitions, with the types rosidl derives from a .srv and an .action."""

    def __init__(self, distro: str, extra: dict[str, str] | None = None) -> None:
        self.distro = distro
        self.root = INTERFACES / distro
        self.extra = dict(extra or {})  # "pkg/srv/Name" -> its text, for definitions not vendored
        self._structs: dict[str, list[Field]] = {}

    def _text(self, typename: str) -> str:
        if typename in self.extra:
            return self.extra[typename]
        package, kind, name = typename.split("/")
        path = self.root / package / kind / f"{name}.{kind}"
        if self.distro in LATER_DISTROS and not path.exists():
            path = INTERFACES / "jazzy" / package / kind / f"{name}.{kind}"  # the rest as Jazzy has it
        return path.read_text()

    def fields(self, typename: str) -> list[Field]:
        """The members of ``pkg/msg/Name``, ``pkg/srv/Name[_Request|_Response|_Event]``, ``pkg/action/Name[_Goal|...]`` or the service / action itself."""
        if typename not in self._structs:
            package, kind, name = typename.split("/")
            if kind == "msg":
                self._structs[typename] = parse_fields(self._text(typename), package)
            elif kind == "srv":
                service = re.sub(r"_(Request|Response|Event)$", "", name)
                self._add_service(package, "srv", service, *self._sections(f"{package}/srv/{service}", 2))
            else:
                self._add_action(
                    package, re.sub(r"_(Goal|Result|Feedback|SendGoal|GetResult|FeedbackMessage)(_Request|_Response|_Event)?$", "", name)
                )
            if typename not in self._structs:
                raise KeyError(typename)
        return self._structs[typename]

    def _sections(self, typename: str, count: int) -> list[str]:
        parts = re.split(r"^---\s*$", self._text(typename), flags=re.M)
        assert len(parts) == count, f"{typename}: {len(parts)} sections, not {count}"
        return parts

    def _add_service(self, package: str, kind: str, name: str, request: str | list[Field], response: str | list[Field]) -> None:
        base = f"{package}/{kind}/{name}"
        self._structs[f"{base}_Request"] = parse_fields(request, package) if isinstance(request, str) else request
        self._structs[f"{base}_Response"] = parse_fields(response, package) if isinstance(response, str) else response
        self._structs[base] = [
            Field("request_message", FieldType(f"{base}_Request")),
            Field("response_message", FieldType(f"{base}_Response")),
        ]
        if self.distro == "humble":
            return  # service events (and their type descriptions) came with Iron
        self._structs[f"{base}_Event"] = [
            Field("info", FieldType("service_msgs/msg/ServiceEventInfo")),
            Field("request", FieldType(f"{base}_Request", "bounded", 1)),
            Field("response", FieldType(f"{base}_Response", "bounded", 1)),
        ]
        self._structs[base].append(Field("event_message", FieldType(f"{base}_Event")))

    def _add_action(self, package: str, name: str) -> None:
        base = f"{package}/action/{name}"
        goal, result, feedback = self._sections(base, 3)
        self._structs[f"{base}_Goal"] = parse_fields(goal, package)
        self._structs[f"{base}_Result"] = parse_fields(result, package)
        self._structs[f"{base}_Feedback"] = parse_fields(feedback, package)
        uuid = FieldType("unique_identifier_msgs/msg/UUID")
        self._add_service(
            package,
            "action",
            f"{name}_SendGoal",
            [Field("goal_id", uuid), Field("goal", FieldType(f"{base}_Goal"))],
            [Field("accepted", FieldType("bool")), Field("stamp", FieldType("builtin_interfaces/msg/Time"))],
        )
        self._add_service(
            package,
            "action",
            f"{name}_GetResult",
            [Field("goal_id", uuid)],
            [Field("status", FieldType("int8")), Field("result", FieldType(f"{base}_Result"))],
        )
        self._structs[f"{base}_FeedbackMessage"] = [Field("goal_id", uuid), Field("feedback", FieldType(f"{base}_Feedback"))]
        self._structs[base] = [
            Field("goal", FieldType(f"{base}_Goal")),
            Field("result", FieldType(f"{base}_Result")),
            Field("feedback", FieldType(f"{base}_Feedback")),
            Field("send_goal_service", FieldType(f"{base}_SendGoal")),
            Field("get_result_service", FieldType(f"{base}_GetResult")),
            Field("feedback_message", FieldType(f"{base}_FeedbackMessage")),
        ]

    # -------------------------------------------------------------- REP-2011
    def _individual(self, typename: str) -> dict[str, Any]:
        described = []
        for f in self.fields(typename):
            t = f.type
            if t.nested:
                value = "nested"
            elif t.base in ("string", "wstring"):
                value = ("bounded_" if t.string_bound else "") + t.base
            else:
                value = PRIMITIVES[t.base][0]
            described.append(
                {
                    "name": f.name,
                    "type": {
                        "type_id": FIELD_TYPE_IDS[value] + COLLECTION_OFFSETS[t.collection],
                        "capacity": t.size,
                        "string_capacity": t.string_bound,
                        "nested_type_name": t.base if t.nested else "",
                    },
                    "default_value": f.default,
                }
            )
        return {"type_name": typename, "fields": described}

    def type_description(self, typename: str) -> dict[str, Any]:
        """``extract_full_type_description``: the type and every type it references, sorted by name."""
        references: set[str] = set()
        queue = [f.type.base for f in self.fields(typename) if f.type.nested]
        while queue:
            name = queue.pop()
            if name not in references:
                references.add(name)
                queue.extend(f.type.base for f in self.fields(name) if f.type.nested)
        return {
            "type_description": self._individual(typename),
            "referenced_type_descriptions": [self._individual(name) for name in sorted(references)],
        }

    def type_hash(self, typename: str) -> str:
        """RIHS01 of ``typename`` (``calculate_type_hash``), or ``TypeHashNotSupported`` on Humble."""
        if self.distro == "humble":
            return HUMBLE_HASH
        hashable = copy.deepcopy(self.type_description(typename))
        for described in [hashable["type_description"], *hashable["referenced_type_descriptions"]]:
            for f in described["fields"]:
                del f["default_value"]
        text = json.dumps(
            hashable,
            skipkeys=False,
            ensure_ascii=True,
            check_circular=True,
            allow_nan=False,
            indent=None,
            separators=(", ", ": "),
            sort_keys=False,
        )
        return "RIHS01_" + hashlib.sha256(text.encode()).hexdigest()

    # -------------------------------------------------------------- CDR
    def serialize(self, typename: str, value: dict[str, Any]) -> bytes:
        """``value`` (dicts for structures, missing fields zero) as CDR with its encapsulation header."""
        out = bytearray()
        self._write(out, typename, value or {})
        return CDR_LE + bytes(out)

    def deserialize(self, typename: str, data: bytes) -> dict[str, Any]:
        """CDR (with its encapsulation header, little endian) to dicts; raises ValueError on trailing or missing bytes."""
        if data[:4] != CDR_LE:
            raise ValueError(f"not little-endian CDR: header {data[:4].hex()}")
        body = data[4:]
        value, end = self._read(body, 0, typename)
        if len(body) - end >= 4:  # CDR pads a message to 4 bytes at most
            raise ValueError(f"{len(body) - end} bytes left after {typename}")
        return value

    def _write(self, out: bytearray, typename: str, value: dict[str, Any]) -> None:
        for f in self.fields(typename):
            item = value.get(f.name)
            t = f.type
            if t.collection == "single":
                self._write_one(out, t, item)
                continue
            items = list(item) if item is not None else []
            if t.collection == "array":
                items = items or [None] * t.size
                assert len(items) == t.size, f"{typename}.{f.name}: {len(items)} items, not {t.size}"
            else:
                assert t.collection == "sequence" or len(items) <= t.size, f"{typename}.{f.name}: over its bound"
                _align(out, 4)
                out += struct.pack("<I", len(items))
            for one in items:
                self._write_one(out, t, one)

    def _write_one(self, out: bytearray, t: FieldType, item: Any) -> None:
        if t.nested:
            self._write(out, t.base, item or {})
        elif t.base in ("string", "wstring"):
            encoded = str(item or "").encode()
            _align(out, 4)
            out += struct.pack("<I", len(encoded) + 1) + encoded + b"\x00"
        else:
            _, fmt, size = PRIMITIVES[t.base]
            _align(out, size)
            out += struct.pack("<" + fmt, item if item is not None else (False if fmt == "?" else 0))

    def _read(self, body: bytes, pos: int, typename: str) -> tuple[dict[str, Any], int]:
        value: dict[str, Any] = {}
        for f in self.fields(typename):
            t = f.type
            if t.collection == "single":
                value[f.name], pos = self._read_one(body, pos, t)
                continue
            if t.collection == "array":
                count = t.size
            else:
                pos += -pos % 4
                (count,) = struct.unpack_from("<I", body, pos)
                pos += 4
                if t.collection == "bounded" and count > t.size:
                    raise ValueError(f"{typename}.{f.name}: {count} items over its bound {t.size}")
            items = []
            for _ in range(count):
                one, pos = self._read_one(body, pos, t)
                items.append(one)
            value[f.name] = items
        return value, pos

    def _read_one(self, body: bytes, pos: int, t: FieldType) -> tuple[Any, int]:
        if t.nested:
            return self._read(body, pos, t.base)
        if t.base in ("string", "wstring"):
            pos += -pos % 4
            (length,) = struct.unpack_from("<I", body, pos)
            raw = body[pos + 4 : pos + 4 + length]
            if length == 0 or len(raw) != length or raw[-1] != 0:
                raise ValueError(f"a string of {length} bytes without its terminating NUL")
            return raw[:-1].decode(), pos + 4 + length
        _, fmt, size = PRIMITIVES[t.base]
        pos += -pos % size
        if pos + size > len(body):
            raise ValueError("the payload ends inside a field")
        return struct.unpack_from("<" + fmt, body, pos)[0], pos + size


def _align(out: bytearray, size: int) -> None:
    out += b"\x00" * (-len(out) % size)


def dds_type(typename: str) -> str:
    """``pkg/kind/Name`` as rmw_zenoh writes it in keys and tokens: ``pkg::kind::dds_::Name_``."""
    package, kind, name = typename.split("/")
    return f"{package}::{kind}::dds_::{name}_"
