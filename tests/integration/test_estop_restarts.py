"""The e-stop latch survives ``kill -9`` of real gateways: standalone, under ``up``, in a fleet of 10, as systemd starts it.

After each restart the e-stop is still engaged (health says since when and by which key), nothing moves on
``cmd_vel``, and a release on ``estop/release`` drives again. A state file made unreadable, corrupt or absent
starts the gateway engaged with its one sentence. These gateways run with the defaults a deployment has (the
suite's ``--unsafe-start-released`` is switched off here).
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from helpers import Child, SimProcess, client_config, free_port, wait_for, zenoh_connect_args, zenoh_listen_args

from blackmetal.gateway.latch import latch_path
from blackmetal.schemas import GatewayHealth, Pose, decode

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
AS_DEPLOYED = {"BLACKMETAL_UNSAFE_START_RELEASED": "false"}


def health(session: zenoh.Session, prefix: str = "robot") -> GatewayHealth | None:
    for reply in session.get(f"{prefix}/gateway/health", timeout=3):
        if reply.ok is not None:
            return decode(GatewayHealth, reply.ok.payload.to_bytes())
    return None


def truth(session: zenoh.Session, prefix: str = "robot") -> Pose | None:
    for reply in session.get(f"{prefix}/sim/truth", timeout=3):
        if reply.ok is not None:
            return decode(Pose, reply.ok.payload.to_bytes())
    return None


def estop_tool(endpoint: str, state: str, prefix: str = "robot") -> None:
    done = subprocess.run(
        [sys.executable, "-m", "blackmetal", "estop", state, "--prefix", prefix, "-e", endpoint, "--no-multicast-scouting", "--timeout", "10"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr


def held_then_released(session: zenoh.Session, endpoint: str, prefix: str = "robot", killed_at: float = 0.0) -> None:
    """After a restart: engaged as before the kill, nothing moves for 1 s of cmd_vel, and a release drives again."""
    wait_for(lambda: (h := health(session, prefix)) is not None and h.stamp > killed_at and h.control.state == "connected",
             timeout=30, what="the restarted gateway connected")  # fmt: skip
    h = health(session, prefix)
    assert h is not None and h.estop and h.estop_by == f"{prefix}/estop", h
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        session.put(f"{prefix}/cmd_vel", json.dumps({"linear": {"x": 0.3}}))
        time.sleep(0.1)
    still = truth(session, prefix)
    assert still is not None and still.v == 0.0, "the robot moved while the e-stop was engaged"
    estop_tool(endpoint, "off", prefix)
    h = health(session, prefix)
    assert h is not None and not h.estop and h.estop_by == f"{prefix}/estop/release"

    def drives() -> bool:
        session.put(f"{prefix}/cmd_vel", json.dumps({"linear": {"x": 0.2}}))
        return (p := truth(session, prefix)) is not None and p.v > 0.1

    wait_for(drives, timeout=10, interval=0.1, what="the robot driving after the release")


def test_a_standalone_gateway_killed_and_started_again_is_still_engaged(children: list[Child], tmp_path: Path) -> None:
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    sim = SimProcess(*zenoh_listen_args(zport))
    children.append(sim)
    argv = ["-m", "blackmetal", "gateway", "--control-port", str(sim.control_port), "--log-port", str(sim.log_port),
            "--state-dir", str(tmp_path / "state"), *zenoh_connect_args(zport)]  # fmt: skip
    first = Child(argv, env=AS_DEPLOYED)
    children.append(first)
    first.ready()
    first.wait_line(r"the e-stop is engaged at start: no saved e-stop state at .*robot\.json")  # a first start
    with zenoh.open(client_config(zport)) as session:
        estop_tool(endpoint, "off")
        estop_tool(endpoint, "on")
        engaged = health(session)
        assert engaged is not None and engaged.estop
        first.proc.send_signal(signal.SIGKILL)
        first.proc.wait(10)
        killed_at = time.time()
        second = Child(argv, env=AS_DEPLOYED)
        children.append(second)
        second.ready()
        held_then_released(session, endpoint, killed_at=killed_at)
        h = health(session)
        assert h is not None and h.source != engaged.source  # another run of the gateway
    saved = json.loads(latch_path(str(tmp_path / "state"), "robot").read_text())
    assert saved["engaged"] is False and saved["by"] == "robot/estop/release"


@pytest.mark.parametrize("damage", ["absent", "corrupt", "unreadable"])
def test_a_state_that_cannot_be_trusted_starts_the_gateway_engaged_with_its_sentence(
    children: list[Child], tmp_path: Path, damage: str
) -> None:
    zport = free_port()
    sim = SimProcess(*zenoh_listen_args(zport))
    children.append(sim)
    state = tmp_path / "state"
    path = latch_path(str(state), "robot")
    path.parent.mkdir(parents=True)
    if damage == "corrupt":
        path.write_text('{"prefix": "robot", "engaged": fal')
    elif damage == "unreadable":
        path.mkdir()  # as root, a folder in its place is what cannot be read
    gateway = Child(["-m", "blackmetal", "gateway", "--control-port", str(sim.control_port), "--log-port", str(sim.log_port),
                     "--state-dir", str(state), *zenoh_connect_args(zport)], env=AS_DEPLOYED)  # fmt: skip
    children.append(gateway)
    gateway.ready()
    words = {"absent": "no saved e-stop state at", "corrupt": "is corrupt", "unreadable": "cannot be read"}[damage]
    line = gateway.wait_line(rf"the e-stop is engaged at start: .*{words}")
    assert str(path) in line.string and "blackmetal estop off" in line.string and "Traceback" not in gateway.output()
    with zenoh.open(client_config(zport)) as session:
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="the gateway connected")
        h = health(session)
        assert h is not None and h.estop and h.estop_by is not None and words in h.estop_by
        session.put("robot/cmd_vel", json.dumps({"linear": {"x": 0.3}}))
        time.sleep(0.5)
        assert (p := truth(session)) is not None and p.v == 0.0


def test_under_up_a_killed_gateway_comes_back_engaged(children: list[Child]) -> None:
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    up = Child(["-m", "blackmetal", "up", "-l", endpoint, "--no-multicast-scouting"])
    children.append(up)
    info = up.ready(timeout=60)
    with zenoh.open(client_config(zport)) as session:
        wait_for(lambda: (h := health(session)) is not None and not h.estop and h.control.state == "connected",
                 what="up's simulated robot, released at first")  # fmt: skip
        estop_tool(endpoint, "on")
        os.kill(info["children"]["gateway"], signal.SIGKILL)
        killed_at = time.time()
        up.wait_line(r"gateway started again \(pid \d+\)")
        held_then_released(session, endpoint, killed_at=killed_at)


def _running(pid: int) -> bool:
    """Alive and not a zombie (a child whose parent died may wait to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def test_a_killed_up_leaves_no_process_behind(children: list[Child]) -> None:
    """``kill -9`` of ``up``: its gateway, odometry and simulator (in their own session, out of Ctrl-C's reach) end too."""
    zport = free_port()
    up = Child(["-m", "blackmetal", "up", "-l", f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting"])
    children.append(up)
    pids = list(up.ready(timeout=60)["children"].values())
    assert pids and all(_running(pid) for pid in pids)
    os.kill(up.proc.pid, signal.SIGKILL)
    wait_for(lambda: not any(_running(pid) for pid in pids), timeout=20, what="up's children gone after up was killed")


def test_in_a_fleet_of_ten_a_killed_gateway_comes_back_with_each_robots_latch(children: list[Child]) -> None:
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    up = Child(["-m", "blackmetal", "up", "--robots", "10", "-l", endpoint, "--no-multicast-scouting"])
    children.append(up)
    info = up.ready(timeout=90)
    prefixes = info["prefixes"]
    with zenoh.open(client_config(zport)) as session:
        wait_for(lambda: all((h := health(session, p)) is not None and h.control.state == "connected" for p in prefixes),
                 timeout=60, what="ten robots connected")  # fmt: skip
        estop_tool(endpoint, "on", "fleet/r3")
        os.kill(info["children"]["gateway"], signal.SIGKILL)
        killed_at = time.time()
        up.wait_line(r"gateway started again \(pid \d+\)")
        wait_for(lambda: all((h := health(session, p)) is not None and h.stamp > killed_at for p in prefixes),
                 timeout=60, what="every robot's restarted gateway")  # fmt: skip
        assert [p for p in prefixes if (h := health(session, p)) is not None and h.estop] == ["fleet/r3"]
        held_then_released(session, endpoint, "fleet/r3", killed_at=killed_at)


def test_the_systemd_units_command_line_keeps_the_latch_across_a_kill(children: list[Child], tmp_path: Path) -> None:
    """ExecStart as the shipped unit writes it (paths moved into tmp_path): a first start engaged, then the latch kept."""
    unit = (ROOT / "deploy" / "systemd" / "blackmetal-gateway.service").read_text()
    assert "StateDirectory=blackmetal" in unit
    (line,) = [ln for ln in unit.splitlines() if ln.startswith("ExecStart=")]
    argv = shlex.split(line.removeprefix("ExecStart="))
    assert argv[:2] == ["/opt/blackmetal/venv/bin/blackmetal", "gateway"] and argv[argv.index("--state-dir") + 1] == "/var/lib/blackmetal"
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    sim = SimProcess(*zenoh_listen_args(zport))
    children.append(sim)
    settings = tmp_path / "gateway.toml"  # what /etc/blackmetal/gateway.toml holds for this robot
    settings.write_text(f'robot = "127.0.0.1"\ncontrol_port = {sim.control_port}\nlog_port = {sim.log_port}\n')
    zenoh_conf = tmp_path / "gateway.json5"  # deploy/zenoh/gateway.json5 with the router's address
    zenoh_conf.write_text((ROOT / "deploy" / "zenoh" / "gateway.json5").read_text().replace("tcp/router.local:7447", endpoint))
    command = ["-m", "blackmetal", *argv[1:]]
    command[command.index("--settings") + 1] = str(settings)
    command[command.index("-c") + 1] = str(zenoh_conf)
    command[command.index("--state-dir") + 1] = str(tmp_path / "var-lib-blackmetal")
    first = Child(command, env=AS_DEPLOYED)
    children.append(first)
    first.ready()
    first.wait_line("the e-stop is engaged at start: no saved e-stop state")
    with zenoh.open(client_config(zport)) as session:
        estop_tool(endpoint, "off")
        estop_tool(endpoint, "on")
        first.proc.send_signal(signal.SIGKILL)
        first.proc.wait(10)
        killed_at = time.time()
        second = Child(command, env=AS_DEPLOYED)  # Restart=on-failure
        children.append(second)
        second.ready()
        held_then_released(session, endpoint, killed_at=killed_at)
