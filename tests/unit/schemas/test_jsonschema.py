"""The JSON Schemas (:mod:`blackmetal.schemas.jsonschema`): what a client in another language validates against.

``blackmetal schema`` writes them and recordings carry them (MCAP's
``jsonschema`` encoding, tests/unit/recording/test_reader.py). Each must be a
valid draft 2020-12 schema on its own, accept every message the codec
writes, refuse what the codec refuses, and say where the message travels.
"""

from __future__ import annotations

import json
import re
from typing import Any

import jsonschema
import pytest

from blackmetal.schemas import KEY_SPECS, MESSAGE_TYPES, encode, json_schemas
from unit.schemas.test_messages import EXAMPLES

SCHEMAS = json_schemas()


def validator(name: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator(SCHEMAS[name])


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_each_schema_is_a_self_contained_draft_2020_12_schema(name: str) -> None:
    schema = SCHEMAS[name]
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema" and schema["title"] == name
    refs = re.findall(r'"\$ref": "([^"]*)"', json.dumps(schema))
    assert refs and all(ref.startswith("#/$defs/") and ref.removeprefix("#/$defs/") in schema["$defs"] for ref in refs)


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_each_schema_accepts_what_the_codec_writes(name: str) -> None:
    errors = [error.message for error in validator(name).iter_errors(json.loads(encode(EXAMPLES[name])))]
    assert errors == []


@pytest.mark.parametrize(
    ("name", "payload"),
    [
        ("Twist", {"linear": {"X": 0.2}}),  # the typo the decoder refuses rather than read as a zero
        ("Twist", {"linear": {"x": "fast"}}),
        ("EStop", {}),
        ("EStop", {"engaged": 1}),
        ("WheelImpulses", {"seq": -1, "stamp": 1.0, "left": 0, "right": 0}),
        ("WheelImpulses", {"seq": 0, "stamp": 1.0, "left": 0.5, "right": 0}),
        ("SimFaults", {"dropout": 1.5}),
        ("SimFaults", {"delay": 61}),
        ("ErrorReport", {"stamp": 1.0, "source": "gateway", "key": "r1/cmd_vel"}),
        ("ParamsSet", {"values": {"max_speed": [0.5]}}),
    ],
)
def test_each_schema_refuses_what_the_codec_refuses(name: str, payload: dict[str, Any]) -> None:
    assert not validator(name).is_valid(payload)


def carried_on(name: str) -> list[str]:
    message_type = MESSAGE_TYPES[name]
    carried = [f"<prefix>/{spec.suffix}" for spec in KEY_SPECS if spec.message is message_type]
    return carried + [f"<prefix>/{spec.suffix} (the reply to a get)" for spec in KEY_SPECS if spec.reply is message_type]


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_each_schema_says_on_which_keys_its_message_travels(name: str) -> None:
    keys = carried_on(name)
    assert keys and SCHEMAS[name]["description"] == f"blackmetal message on {', '.join(keys)}"
