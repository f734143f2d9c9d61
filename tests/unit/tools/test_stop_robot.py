"""stop-robot: zero velocity then NORMAL_STOP, re-sent until the robot says OK; a robot out of reach is one sentence."""

from __future__ import annotations

import argparse
import socket
import threading
from pathlib import Path

import pytest

from blackmetal import wire
from blackmetal.tools.stop_robot import run, stop_robot


def _robot(answers: list[bytes]) -> tuple[socket.socket, list[bytes]]:
    """A listening socket that answers each request with the next of ``answers`` (in a thread: no process)."""
    server = socket.create_server(("127.0.0.1", 0))
    received: list[bytes] = []

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            for answer in answers:
                data = conn.recv(4096)
                if not data:
                    return
                received.append(data)
                conn.sendall(answer)
            conn.recv(4096)

    threading.Thread(target=serve, daemon=True).start()
    return server, received


def test_a_full_buffer_is_answered_by_sending_again() -> None:
    server, received = _robot([wire.encode_status("FULL_BUFFER"), wire.encode_status(), wire.encode_status()])
    with server:
        assert stop_robot("127.0.0.1", server.getsockname()[1], timeout=3.0) is None
    velocity = wire.encode_request(wire.set_velocity(left=0.0, right=0.0))
    assert received == [velocity, velocity, wire.encode_request(wire.simple(wire.CommandCode.NORMAL_STOP))]


def test_a_robot_out_of_reach_is_one_sentence(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.create_server(("127.0.0.1", 0)) as probe:
        port = probe.getsockname()[1]
    assert stop_robot("127.0.0.1", port, timeout=0.5).startswith(f"cannot connect to the robot's control port 127.0.0.1:{port}: ")  # type: ignore[union-attr]
    assert run(argparse.Namespace(settings=None, robot="127.0.0.1", control_port=port, timeout=0.5)) == 1
    assert capsys.readouterr().err.startswith("blackmetal stop-robot: cannot connect")


def test_a_bad_settings_file_is_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("robot = \n")
    assert run(argparse.Namespace(settings=str(bad), robot=None, control_port=None, timeout=0.5)) == 2
    assert capsys.readouterr().err.startswith("blackmetal stop-robot: ")
