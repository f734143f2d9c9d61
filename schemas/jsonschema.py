"""JSON Schemas of every message, so clients in other languages can validate."""

from __future__ import annotations

from typing import Any

import msgspec

from .keys import KEY_SPECS, MESSAGE_TYPES


def json_schemas() -> dict[str, dict[str, Any]]:
    """One self-contained JSON Schema (draft 2020-12) per message type."""
    schemas: dict[str, dict[str, Any]] = {}
    for name, message_type in MESSAGE_TYPES.items():
        carried = [f"<prefix>/{spec.suffix}" for spec in KEY_SPECS if spec.message is message_type]
        answered = [f"<prefix>/{spec.suffix} (the reply to a get)" for spec in KEY_SPECS if spec.reply is message_type]
        schemas[name] = {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": name,
            "description": f"blackmetal message on {', '.join(carried + answered)}",
            **msgspec.json.schema(message_type),
        }
    return schemas
