"""The key space (:mod:`blackmetal.schemas.keys`): every key built from the prefix, and the message each carries.

How each publication travels (telemetry dropped, commands never) is held,
with the edge that declares it, by tests/unit/runtime/test_edge.py; the key
tables of the README and of Concepts against this space by
tests/project/test_project.py.
"""

from __future__ import annotations

import pytest

from blackmetal.schemas import ConfigError, Keys
from blackmetal.schemas.keys import ANY_GATEWAY_ALIVE, KEY_SPECS, Delivery, Sources, delivery_of, validate_prefix
from blackmetal.schemas.messages import EStop, Lock, Twist

PREFIXES = ["robot", "fleet/a", "site-1/dock_2/r.7"]


@pytest.mark.parametrize("prefix", PREFIXES)
def test_every_key_is_the_prefix_and_its_suffix_and_carries_its_message(prefix: str) -> None:
    keys = Keys(prefix)
    for spec in KEY_SPECS:
        key = getattr(keys, spec.name)
        assert key == f"{prefix}/{spec.suffix}"
        concrete = key.replace("<source>", "nav").replace("<name>", "dock")  # a placeholder stands for any one name
        assert keys.message_for(concrete) is spec.message, spec.name
    assert sorted(Keys.__annotations__) == sorted(spec.name for spec in KEY_SPECS)  # every key is an attribute, no other
    assert len({spec.suffix for spec in KEY_SPECS}) == len(KEY_SPECS)


def test_the_default_prefix_is_robot() -> None:
    assert Keys().pose == "robot/pose" and repr(Keys()) == "Keys('robot')"


def test_keys_outside_the_prefix_or_the_space_carry_nothing_of_ours() -> None:
    keys = Keys("fleet/a")
    assert keys.message_for("fleet/b/pose") is None  # another robot's
    assert keys.message_for("fleet/apose") is None and keys.message_for("fleet/a") is None
    assert keys.message_for("fleet/a/cmd_vel/nav/extra") is None and keys.message_for("fleet/a/odometry") is None
    assert keys.message_for(keys.alive_gateway) is None  # a liveliness token carries no message
    assert Keys("fleet").message_for("fleet/a/pose") is None  # a longer prefix is not a key of the shorter one


def test_named_commands_locks_and_the_estop_have_their_keys() -> None:
    keys = Keys("r1")
    assert keys.cmd_vel_of(Sources.DEFAULT) == "r1/cmd_vel"  # the default source is plain cmd_vel
    assert keys.cmd_vel_of(Sources.NAV) == "r1/cmd_vel/nav" and keys.message_for(keys.cmd_vel_of("x")) is Twist
    assert keys.lock_of("dock") == "r1/lock/dock" and keys.message_for(keys.lock_of("dock")) is Lock
    assert (keys.estop_for(True), keys.estop_for(False)) == ("r1/estop", "r1/estop/release")  # a release needs the safety role
    assert keys.message_for(keys.estop_release) is EStop
    assert (keys.any_cmd_vel_source, keys.any_lock, keys.everything) == ("r1/cmd_vel/*", "r1/lock/*", "r1/**")


@pytest.mark.parametrize("prefix", PREFIXES)
def test_a_liveliness_token_gives_back_its_prefix(prefix: str) -> None:
    keys = Keys(prefix)
    assert keys.alive("gateway") == keys.alive_gateway and keys.alive("sim") == keys.alive_sim
    assert Keys.prefix_of_gateway_token(keys.alive_gateway) == prefix
    assert Keys.prefix_of_token(keys.alive_odometry, "odometry") == prefix
    assert ANY_GATEWAY_ALIVE == "**/alive/gateway"


@pytest.mark.parametrize(
    ("prefix", "reason"),
    [
        ("", "must be non-empty chunks separated by '/', e.g. 'robot' or 'fleet/a'"),
        ("fleet//a", "must be non-empty chunks separated by '/'"),
        ("/robot", "must be non-empty chunks separated by '/'"),
        ("robot/", "must be non-empty chunks separated by '/'"),
        ("fleet/*", "must not contain wildcards or the characters * $ ? # or a leading @"),
        ("**", "must not contain wildcards"),
        ("a$b", "must not contain wildcards"),
        ("a?b", "must not contain wildcards"),
        ("fleet/#1", "must not contain wildcards"),
        ("@admin", "or a leading @"),
        ("fleet/..", "must not have a '.' or '..' part: a key expression is not a path"),
        ("./robot", "must not have a '.' or '..' part"),
        ("my robot", "must be printable characters without spaces or control characters"),
        ("robot\n", "must be printable characters without spaces"),
    ],
)
def test_a_prefix_that_is_no_key_expression_is_refused_in_one_sentence(prefix: str, reason: str) -> None:
    with pytest.raises(ConfigError) as refused:
        validate_prefix(prefix)
    assert str(refused.value).startswith(f"prefix {prefix!r} ") and reason in str(refused.value)
    with pytest.raises(ConfigError):
        Keys(prefix)


@pytest.mark.parametrize("prefix", [*PREFIXES, "a.b", "ünïcode", "1"])
def test_a_plain_prefix_is_taken_as_given(prefix: str) -> None:
    assert validate_prefix(prefix) == prefix and Keys(prefix).prefix == prefix


def test_a_key_that_is_no_publication_has_no_delivery_and_says_so() -> None:
    keys = Keys("r1")
    for key in (keys.params_set, keys.odometry_reset, keys.alive_gateway, "r1/unknown"):
        with pytest.raises(ValueError, match=rf"^'{key}' is not a blackmetal publication key \(see schemas/keys.py KEY_SPECS\)$"):
            delivery_of(key, keys.prefix)


@pytest.mark.parametrize("prefix", ["site/cmd_vel", "lock"])
def test_the_delivery_of_telemetry_does_not_depend_on_the_prefix(prefix: str) -> None:
    assert delivery_of(Keys(prefix).pose, prefix) is Delivery.TELEMETRY
