"""The shared Zenoh flags and their config (blackmetal.runtime.zenoh_setup): isolated by default, one sentence per mistake."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from blackmetal.runtime.zenoh_setup import (
    DEFAULT_ENDPOINT,
    SERVICE_RETRY,
    ZenohSettings,
    add_zenoh_arguments,
    check_endpoint,
    unavailable_error,
    unavailable_reason,
    unresolvable,
    zenoh_settings,
)
from blackmetal.schemas import ConfigError, ZenohUnavailable, ZenohUnreachable


def parsed(*argv: str) -> ZenohSettings:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    return zenoh_settings(parser.parse_args(argv))


def config_value(settings: ZenohSettings, key: str, wait: bool = False) -> object:
    return json.loads(settings.to_config(wait=wait).get_json(key))


@pytest.mark.parametrize("endpoint", ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "udp/robot.local:7447#iface=eth0", "unixsock-stream/x:y"])
def test_a_well_formed_endpoint_is_taken(endpoint: str) -> None:
    assert check_endpoint(endpoint) == endpoint


@pytest.mark.parametrize("endpoint", ["127.0.0.1:7447", "tcp/127.0.0.1", "/127.0.0.1:7447", "tcp/"])
def test_an_endpoint_without_protocol_host_and_port_is_refused_with_an_example(endpoint: str) -> None:
    with pytest.raises(ConfigError) as error:
        check_endpoint(endpoint)
    assert str(error.value) == (
        f"endpoint {endpoint!r} must look like PROTOCOL/HOST:PORT, for example tcp/127.0.0.1:7447 or tcp/[::1]:7447"
    )


@pytest.mark.parametrize(("endpoint", "port"), [("tcp/127.0.0.1:70000", "70000"), ("tcp/host:port", "port"), ("udp/h:-1", "-1")])
def test_a_port_out_of_range_is_named(endpoint: str, port: str) -> None:
    with pytest.raises(ConfigError) as error:
        check_endpoint(endpoint)
    assert str(error.value) == f"endpoint {endpoint!r} has an invalid port {port!r}: a port is a number from 1 to 65535"


def test_the_flags_are_checked_as_they_are_read() -> None:
    with pytest.raises(ConfigError, match=r"^Zenoh mode must be one of peer, client, router, got 'hub'$"):
        ZenohSettings(mode="hub")
    with pytest.raises(ConfigError, match="must look like PROTOCOL/HOST:PORT"):
        parsed("-l", "7447")


def test_the_flags_as_zenoh_python_spells_them() -> None:
    settings = parsed("-m", "peer", "-e", "tcp/a:1", "--connect", "tcp/b:2", "-l", "tcp/0.0.0.0:3", "-c", "z.json5", "--multicast-scouting")
    assert (settings.mode, settings.connect, settings.listen, settings.config) == (
        "peer",
        ["tcp/a:1", "tcp/b:2"],
        ["tcp/0.0.0.0:3"],
        "z.json5",
    )
    assert settings.multicast_scouting and settings.discovers and settings.given
    assert not parsed().given and not parsed("--no-multicast-scouting").discovers


def test_given_nothing_a_process_is_a_client_of_the_default_endpoint_and_meets_nobody_else() -> None:
    settings = parsed()
    assert settings.defaulted and settings.endpoints == [DEFAULT_ENDPOINT] and settings.where() == DEFAULT_ENDPOINT
    assert config_value(settings, "mode") == "client"
    assert config_value(settings, "connect/endpoints") == [DEFAULT_ENDPOINT]
    assert config_value(settings, "scouting/multicast/enabled") is False and config_value(settings, "scouting/gossip/enabled") is False


def test_a_process_that_listens_is_a_hub_and_connects_to_nothing_it_was_not_given() -> None:
    settings = parsed("-l", "tcp/127.0.0.1:7448")
    assert settings.is_hub and not settings.defaulted and settings.endpoints == []
    assert settings.where() == "listening on tcp/127.0.0.1:7448"
    assert config_value(settings, "listen/endpoints") == ["tcp/127.0.0.1:7448"]
    assert parsed("-m", "router").is_hub and parsed("-m", "router").endpoints == []


def test_discovery_is_asked_for_and_then_the_session_is_a_peer() -> None:
    settings = parsed("--multicast-scouting")
    assert settings.where() == "multicast scouting" and not settings.defaulted
    assert config_value(settings, "scouting/multicast/enabled") is True and config_value(settings, "scouting/gossip/enabled") is True
    assert config_value(parsed("--multicast-scouting", "--no-multicast-scouting"), "scouting/multicast/enabled") is False


def test_a_service_waits_for_its_endpoints_for_ever_and_retries_often() -> None:
    settings = parsed("-e", "tcp/10.0.0.1:7447")
    assert config_value(settings, "connect/timeout_ms", wait=True) == -1
    assert config_value(settings, "connect/exit_on_failure", wait=True) is False
    assert config_value(settings, "connect/retry", wait=True) == {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}
    assert "period_init_ms: 100" in SERVICE_RETRY


def test_a_config_file_decides_for_itself(tmp_path: Path) -> None:
    file = tmp_path / "zenoh.json5"
    file.write_text('{mode: "peer", connect: {endpoints: ["tcp/10.0.0.2:7447"], timeout_ms: 2000}}')
    settings = parsed("-c", str(file))
    assert not settings.defaulted and settings.where() == f"as {file} says"
    assert config_value(settings, "mode") == "peer" and config_value(settings, "connect/timeout_ms", wait=True) == 2000


def test_a_missing_or_invalid_config_file_is_one_sentence(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=rf"^Zenoh config file {tmp_path / 'none.json5'} does not exist$"):
        parsed("-c", str(tmp_path / "none.json5")).to_config()
    bad = tmp_path / "bad.json5"
    bad.write_text("{mode: ")
    with pytest.raises(ConfigError, match=rf"^Zenoh config file {bad} is invalid: "):
        parsed("-c", str(bad)).to_config()


def test_credentials_come_from_the_environment_and_both_are_needed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BLACKMETAL_ZENOH_USER", "robot")
    monkeypatch.delenv("BLACKMETAL_ZENOH_PASSWORD", raising=False)
    with pytest.raises(ConfigError, match=r"^BLACKMETAL_ZENOH_USER is set but BLACKMETAL_ZENOH_PASSWORD is not$"):
        ZenohSettings().to_config()
    monkeypatch.setenv("BLACKMETAL_ZENOH_PASSWORD", "secret")
    assert config_value(ZenohSettings(), "transport/auth/usrpwd/user") == "robot"


def test_host_names_that_do_not_resolve_are_named_and_addresses_are_never_asked() -> None:
    assert unresolvable(["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:7447"]) == []


def test_zenohs_failures_are_told_as_what_to_check(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("BLACKMETAL_ZENOH_USER", raising=False)
    client = parsed("-e", "tcp/10.0.0.1:7447")
    reason = unavailable_reason(client, "Unable to connect to any of [tcp/10.0.0.1:7447]! at /src/x.rs")
    assert reason == (
        "cannot reach tcp/10.0.0.1:7447: check that a router or `blackmetal up` runs there, that the address and port are right"
        " (-e tcp/HOST:PORT), and whether it asks for a user and password (set BLACKMETAL_ZENOH_USER and BLACKMETAL_ZENOH_PASSWORD)"
    )
    hub = parsed("-l", "tcp/127.0.0.1:7447")
    assert unavailable_reason(hub, "Can not create a new TCP listener: Address already in use").startswith(
        "cannot listen on tcp/127.0.0.1:7447: the port is in use by another process"
    )
    assert unavailable_reason(client, "Failed to lookup address") == "cannot resolve an address in tcp/10.0.0.1:7447: check the host name"
    assert unavailable_reason(client, "something else at /src/y.rs:12") == "cannot open a Zenoh session (tcp/10.0.0.1:7447): something else"
    assert type(unavailable_error(client, "Unable to connect")) is ZenohUnreachable
    assert type(unavailable_error(hub, "Address already in use")) is ZenohUnavailable
