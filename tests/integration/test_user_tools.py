"""The way a person meets the project: ``blackmetal up`` and the tools teleop, watch and square."""

from __future__ import annotations

import json
import math
import os
import pty
import re
import signal
import socket
import subprocess
import sys
import termios
import time
from collections.abc import Iterator

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for

from blackmetal.schemas import GatewayHealth, GatewayParams, Pose, decode

pytestmark = pytest.mark.integration


class Up(Child):
    def __init__(self, *extra: str) -> None:
        self.zport = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.zport}"
        super().__init__(["-m", "blackmetal", "up", "-l", self.endpoint, "--no-multicast-scouting", *extra])
        info = self.ready(timeout=60)
        self.control_port = int(info["control_port"])
        self.children: dict[str, int] = info["children"]


@pytest.fixture(scope="module")
def up() -> Iterator[Up]:
    demo = Up("--ros2")
    yield demo
    demo.stop()


def get(session: zenoh.Session, key: str, message_type: type, payload: bytes | None = None):  # type: ignore[no-untyped-def]
    for reply in session.get(key, payload=payload, timeout=5):
        if reply.ok is not None:
            return decode(message_type, reply.ok.payload.to_bytes())
    return None


def tool(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackmetal", *args], capture_output=True, text=True, timeout=timeout)


def test_up_prints_a_command_line_that_drives_the_robot(up: Up) -> None:
    line = up.wait_line(r"^\s*python3 -c .*").group(0).strip()  # the ready announcement can overtake the printed lines
    with zenoh.open(client_config(up.zport)) as session:
        before = wait_for(lambda: get(session, "robot/pose", Pose), what="a pose")
        result = subprocess.run(line.replace("python3", sys.executable, 1), shell=True, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr
        pose = wait_for(lambda: (p := get(session, "robot/pose", Pose)) is not None and p.v == 0.0 and p, what="a stop")
        moved = math.hypot(pose.x - before.x, pose.y - before.y)
        assert moved > 0.3  # 3 s at 0.2 m/s on an arc
        assert abs(math.remainder(pose.yaw - before.yaw, math.tau)) > 0.5
    wait_for(lambda: re.search(r"link connected/connected \| poll \d+ Hz", up.output()), what="the live status line")
    assert re.search(r"\| default drives \|", up.output()), up.output()[-2000:]  # who drove: plain cmd_vel is the source default


def test_the_readmes_python_example_drives_prints_the_pose_and_leaves_the_robot_drivable(up: Up, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = re.search(r"From Python:\n\n```python\n(.*?)```", text, re.S).group(1)  # type: ignore[union-attr]
    assert "tcp/127.0.0.1:7447" in block
    script = tmp_path / "example.py"
    script.write_text(block.replace("tcp/127.0.0.1:7447", up.endpoint))  # verbatim but for the test's own port
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert re.fullmatch(r"x=[-0-9.]+ m  y=[-0-9.]+ m  yaw=[-0-9.]+ rad\n", result.stdout), result.stdout  # one line: the pose
    with zenoh.open(client_config(up.zport)) as session:
        health = wait_for(lambda: get(session, "robot/gateway/health", GatewayHealth), what="health")
        assert not health.estop  # the next command the README suggests still drives


def test_watch_shows_pose_status_health_and_errors(up: Up) -> None:
    with zenoh.open(client_config(up.zport)) as session:
        session.put("robot/cmd_vel", b"not json")  # something to show under errors
        result = tool("watch", "-e", up.endpoint, "--no-multicast-scouting", "--duration", "3")
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "pose    x=" in out and "truth   x=" in out
    assert "status  READY (1), direction NORTH" in out
    assert "health  control connected" in out and "poll" in out


def test_square_reports_a_closure_that_agrees_with_the_truth(up: Up) -> None:
    result = tool(
        "square",
        "-e",
        up.endpoint,
        "--no-multicast-scouting",
        "--size",
        "0.5",
        "--speed",
        "0.3",
        "--turn-rate",
        "1.2",
        "--json",
        timeout=240,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "odometry closure" in result.stdout and "truth    closure" in result.stdout
    (run,) = json.loads(result.stdout.strip().splitlines()[-1])
    odo, truth = run["odometry"], run["truth"]
    assert math.hypot(odo["dx_m"] - truth["dx_m"], odo["dy_m"] - truth["dy_m"]) < 0.02
    assert abs(math.remainder(odo["dyaw_rad"] - truth["dyaw_rad"], math.tau)) < 0.03
    assert truth["distance_m"] < 0.05  # it really drove a closed square


def test_teleop_in_a_terminal(up: Up) -> None:
    master, slave = pty.openpty()
    before_attrs = termios.tcgetattr(slave)
    proc = subprocess.Popen(
        [sys.executable, "-m", "blackmetal", "teleop", "-e", up.endpoint, "--no-multicast-scouting"],
        stdin=slave, stdout=slave, stderr=slave, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    screen = bytearray()

    def read_screen() -> str:
        import select

        while select.select([master], [], [], 0)[0]:
            try:
                screen.extend(os.read(master, 65536))
            except OSError:
                break
        return screen.decode(errors="replace")

    def hold(key: bytes, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:  # a held key repeats, as a terminal does
            os.write(master, key)
            time.sleep(0.03)
            read_screen()

    try:
        with zenoh.open(client_config(up.zport)) as session:
            wait_for(lambda: "arrows/WASD drive" in read_screen(), what="teleop's help line")
            start = get(session, "robot/sim/truth", Pose)
            hold(b"\x1b[A", 1.5)  # up arrow: forward
            forward = wait_for(
                lambda: (p := get(session, "robot/sim/truth", Pose)) is not None and p.v == 0.0 and p, what="a stop after release"
            )
            heading = (math.cos(start.yaw), math.sin(start.yaw))
            assert (forward.x - start.x) * heading[0] + (forward.y - start.y) * heading[1] > 0.15
            hold(b"a", 1.0)  # turn left
            turned = wait_for(lambda: (p := get(session, "robot/sim/truth", Pose)) is not None and p.w == 0.0 and p, what="a stop")
            assert math.remainder(turned.yaw - forward.yaw, math.tau) > 0.3
            os.write(master, b"e")
            wait_for(lambda: (h := get(session, "robot/gateway/health", GatewayHealth)) is not None and h.estop, what="e-stop engaged")
            os.write(master, b"e")
            wait_for(lambda: (h := get(session, "robot/gateway/health", GatewayHealth)) is not None and not h.estop, what="e-stop released")
            assert "pose x=" in read_screen()
            os.write(master, b"q")
            assert proc.wait(20) == 0
        assert termios.tcgetattr(slave) == before_attrs  # the terminal is restored
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        os.close(master)
        os.close(slave)


def test_tools_fail_clearly_when_nothing_answers() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    for name in ("watch", "square", "robots"):  # nothing listens there at all
        result = tool(name, "-e", endpoint, "--wait", "1", timeout=60)
        assert result.returncode == 1 and "Traceback" not in result.stderr
        assert result.stderr.count("\n") == 1 and f"cannot reach {endpoint}" in result.stderr
    for bad in ("127.0.0.1:7447", "tcp/127.0.0.1"):  # an endpoint without its protocol, or without a port
        result = tool("watch", "-e", bad, timeout=60)
        assert result.returncode == 2 and "must look like PROTOCOL/HOST:PORT" in result.stderr and "Traceback" not in result.stderr
    router = Child(["-m", "blackmetal", "router", "-l", endpoint])  # a router runs, but no robot behind it
    try:
        router.ready()
        for name in ("watch", "square"):
            result = tool(name, "-e", endpoint, "--no-multicast-scouting", "--wait", "1", timeout=60)
            assert result.returncode == 1
            assert "no gateway answered" in result.stderr and "Traceback" not in result.stderr
    finally:
        router.stop()
    master, slave = pty.openpty()
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "blackmetal", "teleop", "-e", endpoint, "--no-multicast-scouting", "--wait", "1"],
            stdin=slave, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 1 and "cannot reach" in proc.stderr
    finally:
        os.close(master)
        os.close(slave)
    result = subprocess.run(
        [sys.executable, "-m", "blackmetal", "teleop"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2 and "needs a terminal" in result.stderr


def test_up_stops_everything_on_ctrl_c_within_three_seconds() -> None:
    demo = Up()
    try:
        with socket.create_connection(("127.0.0.1", demo.control_port), timeout=5):
            pass  # the simulator is there
        start = time.monotonic()
        assert demo.stop(signal.SIGINT) == 0
        assert time.monotonic() - start < 3.0
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", demo.control_port), timeout=2).close()
    finally:
        demo.stop()


def test_up_reports_a_child_that_dies() -> None:
    demo = Up()
    try:
        pids = [demo.children["odometry"]]
        for pid in pids:
            os.kill(pid, signal.SIGKILL)
        assert demo.wait(20) == 1
        _, found, tail = demo.output().partition("odometry exited with code -9; its last lines:\n")  # no backtracking regex
        assert found and "odometry ready" in tail, demo.output()
    finally:
        demo.stop()


def test_estop_on_and_off_are_confirmed_by_the_gateway(up: Up) -> None:
    try:
        on = tool("estop", "on", "-e", up.endpoint, timeout=60)
        assert on.returncode == 0 and "ENGAGED" in on.stdout and "confirmed" in on.stdout, on.stderr
        with zenoh.open(client_config(up.zport)) as session:
            health = get(session, "robot/gateway/health", GatewayHealth)
            assert health is not None and health.estop
    finally:
        off = tool("estop", "off", "-e", up.endpoint, timeout=60)
    assert off.returncode == 0 and "released" in off.stdout, off.stderr


def test_up_with_ros2_serves_odom_and_takes_the_estop_from_ros(up: Up) -> None:
    from blackmetal.ros2.messages import RosCodec

    assert "ros2" in up.children
    up.wait_line(r"ROS 2: node /blackmetal \(rmw_zenoh\)")
    codec = RosCodec()
    estop_key = f"0/estop/std_msgs::msg::dds_::Bool_/{codec.type_hash('std_msgs/msg/Bool')}"
    odom_key = f"0/odom/nav_msgs::msg::dds_::Odometry_/{codec.type_hash('nav_msgs/msg/Odometry')}"
    with zenoh.open(client_config(up.zport)) as session:
        odoms: list[bytes] = []
        session.declare_subscriber(odom_key, lambda s: odoms.append(s.payload.to_bytes()))
        wait_for(lambda: len(odoms) >= 3, what="/odom from blackmetal up --ros2")

        def estop_is(engaged: bool) -> bool:
            session.put(estop_key, codec.encode("std_msgs/msg/Bool", data=engaged))
            health = get(session, "robot/gateway/health", GatewayHealth)
            return health is not None and health.estop is engaged

        try:
            wait_for(lambda: estop_is(True), what="the ROS /estop to engage the gateway's stop", interval=0.2)
        finally:
            wait_for(lambda: estop_is(False), what="the ROS /estop to release it", interval=0.2)


def test_small_things_a_new_user_meets(tmp_path) -> None:  # type: ignore[no-untyped-def]
    version = tool("--version")
    assert version.returncode == 0 and version.stdout.startswith("blackmetal ")
    typo = tool("gateway", "--pol-hz", "5")
    assert typo.returncode == 2 and "usage: blackmetal gateway" in typo.stderr and "--pol-hz" in typo.stderr
    assert "``" not in tool("replay", "--help").stdout  # no raw reST in help texts
    empty = tmp_path / "empty.jsonl"
    empty.write_text("")
    replay = tool("replay", str(empty))
    assert replay.returncode == 2 and "no usable impulse sample" in replay.stderr and replay.stdout == ""
    try:
        import matplotlib  # noqa: F401
    except ImportError:  # --plot without matplotlib fails before driving anything, not after the whole route
        plot = tool("square", "--plot", str(tmp_path / "p.png"), "-e", f"tcp/127.0.0.1:{free_port()}", timeout=60)
        assert plot.returncode == 1 and "pip install 'blackmetal[plot]'" in plot.stderr


def test_up_settings_file_gives_each_service_its_own_keys(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The gateway.toml of the docs (its addresses made loopback) goes to the gateway alone; sections go to one service."""
    gateway_toml = tmp_path / "gateway.toml"
    gateway_toml.write_text(
        f'robot = "127.0.0.1"\npoll_hz = 100\ncmd_timeout = 0.25\nconnect = ["tcp/127.0.0.1:{free_port()}"]\nmode = "client"\n'
        "[odometry]\nfilter_alpha = 0.2\n[sim]\nwatchdog = 8\n"
    )
    demo = Up("--settings", str(gateway_toml))
    try:
        demo.wait_line(r"gateway\.toml: robot, connect, mode left to up's own options")
        demo.wait_line(r"commands time out after 0\.25 s: publish at 10 Hz or more")  # the gateway's own timeout
        with zenoh.open(client_config(demo.zport)) as session:
            # the gateway took the file's rate (how fast a loaded machine then polls is the bench's figure)
            params = wait_for(lambda: get(session, "robot/gateway/params", GatewayParams), what="the gateway's parameters")
            assert {p.name: p.value for p in params.params}["poll_hz"] == 100
            assert get(session, "robot/pose", Pose) is not None  # the odometry took its own keys, not the gateway's
    finally:
        demo.stop()
    bad = tmp_path / "bad.toml"
    bad.write_text("poll_hz = 100\nbogus = 1\n[sim]\nnot_a_sim_setting = 2\n[gateway]\nfilter_alpha = 0.2\n")
    result = tool("up", "--settings", str(bad), "-l", f"tcp/127.0.0.1:{free_port()}", timeout=60)
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert "['bogus', 'gateway.filter_alpha', 'sim.not_a_sim_setting']" in result.stderr, result.stderr


def test_robots_returns_once_the_robots_present_have_answered_not_after_its_whole_wait(up: Up) -> None:
    start = time.monotonic()
    listed = tool("robots", "-e", up.endpoint, "--no-multicast-scouting", "--wait", "20")
    took = time.monotonic() - start
    assert listed.returncode == 0 and listed.stdout.split() == ["robot"], listed.stdout + listed.stderr
    assert took < 10, f"{took:.1f} s: it waited for its --wait 20 although the one robot had answered"


def test_up_with_a_robot_that_cannot_be_reached_says_why_in_its_status_line() -> None:
    """`blackmetal up --robot HOST` whose robot refuses connections: the status line names the failure, not just 'down'."""
    closed = free_port()  # nothing listens there
    up = Child(["-m", "blackmetal", "up", "--robot", "127.0.0.1", "--control-port", str(closed), "--log-port", str(free_port()),
                "-l", f"tcp/127.0.0.1:{free_port()}", "--no-multicast-scouting"])  # fmt: skip
    try:
        up.ready(timeout=60)
        up.wait_line(rf"^link (down|connecting)/\w+ \| cannot connect to 127\.0\.0\.1:{closed}: connection refused")
    finally:
        up.stop()


def test_a_robot_that_cannot_be_reached_is_said_in_health_and_in_a_watch_started_later() -> None:
    """A gateway whose robot refuses connections: health says why, and `watch` started later shows the report it missed."""
    closed = free_port()  # nothing listens there
    zport = free_port()
    gateway = Child(["-m", "blackmetal", "gateway", "--control-port", str(closed), "--log-port", str(free_port()),
                     "-l", f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting"])  # fmt: skip
    try:
        gateway.ready()
        with zenoh.open(client_config(zport)) as session:
            health = wait_for(lambda: (h := get(session, "robot/gateway/health", GatewayHealth)) is not None and h.control.reason and h,
                              what="health naming the failure")  # fmt: skip
            assert health.control.state != "connected"
            assert f"127.0.0.1:{closed}" in health.control.reason and "refused" in health.control.reason.lower()
        time.sleep(1.5)  # the failure was reported well before this watch starts
        watched = tool("watch", "--duration", "1", "-e", f"tcp/127.0.0.1:{zport}", timeout=60)
        assert watched.returncode == 0, watched.stderr
        assert re.search(rf"control (down|connecting): cannot connect to .*127\.0\.0\.1:{closed}", watched.stdout), watched.stdout
        assert re.search(rf"robot:.*control link: cannot connect to .*{closed}", watched.stdout), watched.stdout
    finally:
        gateway.stop()
