"""The ROS types the node speaks (:mod:`blackmetal.ros2.ros_types`): the store rosbags is given, read as rosidl reads it.

The hashes of each type against ROS 2's own are held by test_core.py,
test_services.py and test_parameters.py; here, what makes them match.
"""

from __future__ import annotations

from typing import Any

import pytest

from blackmetal.ros2.ros_types import SERVICE_DEFINITIONS, TRIGGER, Frames, ParameterType, excerpt, type_store


@pytest.fixture(scope="module")
def store() -> Any:
    return type_store()


def test_every_service_is_registered_as_rosidl_describes_one(store: Any) -> None:
    types = store.types
    for service in SERVICE_DEFINITIONS:
        for part in ("", "_Request", "_Response", "_Event"):
            assert f"{service}{part}" in types, f"{service}{part}"
        assert store.hash_rihs01(service).startswith("RIHS01_")
    fields = [name for name, _ in store.fielddefs[f"{TRIGGER}_Request"][1]]
    assert fields == ["structure_needs_at_least_one_member"]  # an empty request has rosidl's placeholder


def test_no_field_is_left_as_rosbags_char_which_changes_the_hashes(store: Any) -> None:
    from rosbags.typesys.base import Nodetype

    def is_char(desc: Any) -> bool:
        kind, rest = desc
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return is_char(rest[0])
        return bool(kind == Nodetype.BASE and rest[0] == "char")

    fielddefs = store.fielddefs
    assert [(t, f) for t, (_, fields) in fielddefs.items() for f, desc in fields if is_char(desc)] == []
    info = dict(fielddefs["service_msgs/msg/ServiceEventInfo"][1])
    assert info["client_gid"][1][0][1][0] == "uint8"  # char[16] in the .msg, uint8[16] for rosidl


def test_each_store_is_fresh_so_the_changes_stay_in_it() -> None:
    from rosbags.typesys import Stores, get_typestore

    first, second = type_store(), type_store()
    assert first is not second
    assert "std_srvs/srv/SetBool" not in get_typestore(Stores.ROS2_JAZZY).types  # rosbags' own store is untouched


@pytest.mark.parametrize(
    ("kind", "expected"),
    [("bool", ParameterType.BOOL), ("integer", ParameterType.INTEGER), ("double", ParameterType.DOUBLE), ("string", ParameterType.STRING)],
)
def test_the_gateways_kinds_are_rcl_interfaces_types(kind: str, expected: ParameterType) -> None:
    assert ParameterType.of(kind) == expected
    assert ParameterType.of("list") == ParameterType.NOT_SET  # a kind it does not know is unset, never a wrong type


def test_an_excerpt_is_the_first_24_bytes_in_hex_and_says_when_there_is_more() -> None:
    assert excerpt(b"\x00\x01\xab") == "00 01 ab"
    assert excerpt(bytes(24)) == " ".join(["00"] * 24)
    assert excerpt(bytes(25)) == " ".join(["00"] * 24) + " ..."
    assert excerpt(b"") == ""


def test_the_frames_are_rep_105s() -> None:
    assert (Frames().odom, Frames().base) == ("odom", "base_footprint")
