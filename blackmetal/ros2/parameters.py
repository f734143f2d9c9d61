"""The node's ROS 2 parameters: the gateway's table, as rclcpp's parameter services show it. Pure.

The node keeps no parameter of its own (docs/ros2.md "ros2 param"): reads are answered from the gateway's table,
sets go to the gateway as one ParamsSet, each change goes out on ``/parameter_events``. rclcpp's rules kept here:
``list_parameters`` by prefix and depth with ``.`` as the separator, in name order (``NodeParameters::list_parameters``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from blackmetal.schemas import GatewayParams, Param, ParamValue

from .ros_types import ParameterType, RosValue

SEPARATOR = "."


def list_names(names: Sequence[str], prefixes: Sequence[str], depth: int) -> tuple[list[str], list[str]]:
    """``list_parameters`` as rclcpp answers it: the names under ``prefixes`` (all when none) at most ``depth`` parts
    deeper (0: any depth), and the prefixes of the names listed."""

    def deep_enough(rest: str) -> bool:
        return depth == 0 or rest.count(SEPARATOR) < depth

    out: list[str] = []
    found: list[str] = []
    for name in sorted(names):  # rclcpp keeps its parameters in a std::map: in name order
        wanted = (not prefixes and deep_enough(name)) or any(
            name == prefix or (name.startswith(prefix + SEPARATOR) and deep_enough(name[len(prefix) :])) for prefix in prefixes
        )
        if not wanted:
            continue
        out.append(name)
        if SEPARATOR in name:
            prefix = name.rsplit(SEPARATOR, 1)[0]
            if prefix not in found:
                found.append(prefix)
    return out, found


def ros_value(param: Param) -> RosValue:
    """The table's value as the ROS type the table names (a double stays a float when its value is whole)."""
    if param.type == "double" and isinstance(param.value, int) and not isinstance(param.value, bool):
        return float(param.value)
    return param.value


@dataclass(slots=True)
class NodeParameters:
    """The gateway's parameter table as the node shows it."""

    table: dict[str, Param] = field(default_factory=dict)
    known: bool = False  # a table has arrived: until then every name is unknown

    def on_table(self, table: GatewayParams) -> tuple[list[tuple[str, RosValue]], list[tuple[str, RosValue]]]:
        """Take the gateway's table; (new, changed) parameters as ``/parameter_events`` names them."""
        new: list[tuple[str, RosValue]] = []
        changed: list[tuple[str, RosValue]] = []
        for param in table.params:
            old = self.table.get(param.name)
            if old is None:
                new.append((param.name, ros_value(param)))
            elif old.value != param.value or old.type != param.type:
                changed.append((param.name, ros_value(param)))
            self.table[param.name] = param
        self.known = True
        return new, changed

    def _check(self, name: str, value: RosValue) -> tuple[ParamValue | None, str | None]:
        if isinstance(value, ParameterType):
            if value is ParameterType.NOT_SET:
                return None, f"{name} cannot be unset: the gateway's parameters are declared and always have a value"
            return None, f"{name}: {value.name.lower()} values are refused: the gateway's parameters are bool, integer, double or string"
        param = self.table.get(name)
        if param is None:
            return value, None  # the gateway judges names it has and has not (it may have changed since our table)
        if param.type == "double" and isinstance(value, int) and not isinstance(value, bool):
            return float(value), None
        if isinstance(value, float) and not math.isfinite(value):
            return None, f"{name} must be a finite number, got {value!r}"
        return value, None

    def plan(self, parameters: Sequence[tuple[str, RosValue]], atomically: bool = False) -> tuple[dict[str, ParamValue], dict[int, str]]:
        """(what goes to the gateway, the refusals decided here by position in the call): what this side refuses never
        reaches the gateway; ``atomically``: checked against the table too, one refusal refuses them all."""
        values: dict[str, ParamValue] = {}
        refused: dict[int, str] = {}
        for i, (name, value) in enumerate(parameters):
            checked, reason = self._check(name, value)
            if reason is not None or checked is None:
                refused[i] = reason or f"{name} refused"
            else:
                values.pop(name, None)  # a name given twice: the last value wins, as rclcpp sets them in order
                values[name] = checked
        if atomically:
            reasons = [*refused.values(), *(r for name, value in values.items() if (r := self.refusal(name, value)) is not None)]
            if reasons:
                return {}, {i: "; ".join(reasons) for i in range(len(parameters))}
        return values, refused

    def refusal(self, name: str, value: ParamValue) -> str | None:
        """Why the gateway would refuse ``name = value`` by its table (read-only, unknown, wrong kind, out of range)."""
        param = self.table.get(name)
        if param is None:
            return (
                f"no parameter {name!r}: the gateway's parameters are {', '.join(self.table)}"
                if self.known
                else ("the gateway's parameters are not known yet (no answer on <prefix>/gateway/params): is the gateway running?")
            )
        if param.read_only:
            return f"{name} is read-only on a running gateway: set it in the gateway's settings and restart it"
        expected = {"bool": (bool,), "integer": (int,), "double": (int, float), "string": (str,)}.get(param.type, ())
        if not isinstance(value, expected) or (param.type != "bool" and isinstance(value, bool)):
            return f"{name} takes a {param.type}, got {value!r}"
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            low = -math.inf if param.min is None else param.min
            high = math.inf if param.max is None else param.max
            if not low <= value <= high:
                return f"{name} must be within {low:g}..{high:g}, got {value!r}"
        return None
