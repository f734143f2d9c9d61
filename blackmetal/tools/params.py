"""``blackmetal params [NAME=VALUE ...]``: show the gateway's parameters, or set some on the running gateway.

Without arguments it prints every parameter with its value, bounds and
whether it is read-only. With ``NAME=VALUE`` pairs it sets each one on its
own through ``<prefix>/gateway/params/set`` (an operator's right in the
shipped secure router) and prints what became of each: set, or refused with
the gateway's reason. Exit 0 when every value was set, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json

from blackmetal.schemas import GatewayParams, Param, ParamsSetReply, ParamValue, decode, to_bytes

from .client import ToolError, add_client_arguments, connect, query, require_gateway, tool


def parse_assignment(text: str) -> tuple[str, ParamValue]:
    """``max_wheel_speed=0.3`` -> ("max_wheel_speed", 0.3): the value read as JSON (a number, true/false), else as text."""
    name, sep, raw = text.partition("=")
    if not sep or not name:
        raise ToolError(f"{text!r} is not NAME=VALUE, e.g. max_wheel_speed=0.3 (`blackmetal params` lists the names)")
    try:
        value = json.loads(raw)
    except ValueError:
        value = raw
    if not isinstance(value, bool | int | float | str):
        raise ToolError(f"{name}: a value is a number, true/false or text, got {raw!r}")
    return name, value


def render(params: list[Param]) -> str:
    """One line per parameter: name, value, and its bounds or 'read-only'."""
    width = max((len(p.name) for p in params), default=0)
    lines = []
    for p in params:
        limits = "read-only" if p.read_only else (f"{p.min:g} .. {p.max:g}" if p.min is not None and p.max is not None else "")
        lines.append(f"{p.name:<{width}}  {p.value!s:<12}  {limits:<14}  {p.description}".rstrip())
    return "\n".join(lines)


@tool("params")
def run(args: argparse.Namespace) -> int:
    assignments = [parse_assignment(text) for text in args.assignments]
    keys, settings, session = connect(args)
    with session:
        require_gateway(session, keys, settings, args.wait)
        if not assignments:
            if (table := query(session, keys.params, GatewayParams, timeout=args.wait)) is None:
                raise ToolError(f"the gateway on {keys.prefix} answered its health but not {keys.params}: is it older than this tool?")
            print(render(table.params))
            return 0
        payload = json.dumps({"values": dict(assignments)}).encode()
        replies = list(session.get(keys.params_set, payload=payload, timeout=args.wait))
        for reply in replies:
            if reply.err is not None:
                raise ToolError(f"the gateway refused the request: {to_bytes(reply.err.payload).decode(errors='replace')}")
            if reply.ok is not None:
                answer = decode(ParamsSetReply, to_bytes(reply.ok.payload))
                for result in answer.results:
                    print(f"{result.name}: {'set' if result.successful else 'refused: ' + result.reason}")
                return 0 if all(r.successful for r in answer.results) else 1
        raise ToolError(
            f"no answer on {keys.params_set} within {args.wait:g} s (Zenoh: {settings.where()}): setting parameters is an "
            "operator's right; does this user have it (BLACKMETAL_ZENOH_USER)?"
        )


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("assignments", nargs="*", metavar="NAME=VALUE", help="parameters to set, e.g. max_wheel_speed=0.3")
    add_client_arguments(parser)
