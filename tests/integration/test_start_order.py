"""Start order: services wait for their router or hub, join it when it comes up, and ride out its restarts.

systemd and compose start units in parallel, and a router may restart at any
time: a service given an endpoint that does not answer yet says once which
endpoint it waits for, keeps trying (Zenoh's own connect retry), and starts
working when it comes up. The user tools still fail at once with one sentence.
"""

from __future__ import annotations

import json
import math
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for, zenoh_connect_args
from mcap.reader import make_reader

from blackmetal.schemas import Keys, Pose, decode

pytestmark = pytest.mark.integration

KEYS = Keys()
#: The issue's bound: each service joins within this long of its hub coming up.
JOIN_WITHIN_S = 2.0


def router(port: int) -> Child:
    hub = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}"])
    hub.ready()
    return hub


def port_open(port: int) -> bool:
    """Whether something listens on the loopback ``port`` (a plain TCP connect, closed at once)."""
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def get_pose(session: zenoh.Session, key: str) -> Pose | None:
    for reply in session.get(key, timeout=3):
        if reply.ok is not None:
            return decode(Pose, reply.ok.payload.to_bytes())
    return None


def alive(session: zenoh.Session) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get(f"{KEYS.prefix}/alive/**", timeout=3) if r.ok is not None}


def assert_the_robot_works(session: zenoh.Session) -> None:
    """Liveliness of the three services, poses that flow, and a cmd_vel that moves the true robot and its pose."""
    wait_for(lambda: alive(session) == {KEYS.alive_gateway, KEYS.alive_odometry, KEYS.alive_sim}, what="the three services' liveliness")
    poses: list[Pose] = []
    subscriber = session.declare_subscriber(KEYS.pose, lambda s: poses.append(decode(Pose, s.payload.to_bytes())))
    try:
        wait_for(lambda: len(poses) >= 10, what="poses flowing")
        start = wait_for(lambda: get_pose(session, KEYS.sim_truth), what="the simulator's truth")
        start_pose = poses[-1]
        for _ in range(12):
            session.put(KEYS.cmd_vel, json.dumps({"linear": {"x": 0.3}}))
            time.sleep(0.1)

        def moved() -> bool:
            truth = get_pose(session, KEYS.sim_truth)
            return truth is not None and math.hypot(truth.x - start.x, truth.y - start.y) > 0.15

        wait_for(moved, what="cmd_vel to move the simulated robot")
        wait_for(lambda: math.hypot(poses[-1].x - start_pose.x, poses[-1].y - start_pose.y) > 0.15, what="the pose to follow")
    finally:
        subscriber.undeclare()


def assert_the_ros2_node_works(session: zenoh.Session, odom_key: str) -> None:
    odoms: list[bytes] = []
    subscriber = session.declare_subscriber(odom_key, lambda s: odoms.append(s.payload.to_bytes()))
    try:
        wait_for(lambda: len(odoms) >= 5, what="the ROS 2 adapter's /odom")
    finally:
        subscriber.undeclare()
    tokens = [r for r in session.liveliness().get("@ros2_lv/0/**", timeout=3) if r.ok is not None]
    assert tokens, "the ROS 2 node's liveliness tokens"


def seen_at(children: dict[str, Child], pattern: str, timeout: float = 20.0) -> dict[str, float]:
    """When (time.monotonic) a line matching ``pattern`` first showed in each child's output."""
    regex = re.compile(pattern)
    found: dict[str, float] = {}
    deadline = time.monotonic() + timeout
    while len(found) < len(children):
        for name, child in children.items():
            if name not in found and any(regex.search(line) for line in list(child.lines)):
                found[name] = time.monotonic()
            assert child.poll() is None, f"{name} exited:\n{child.output()}"
        assert time.monotonic() < deadline, f"no {pattern!r} from {sorted(set(children) - set(found))} within {timeout:g} s"
        time.sleep(0.01)
    return found


def test_services_started_before_their_router_join_it_within_two_seconds(children: list[Child], tmp_path: Path) -> None:
    """Simulator, odometry, ROS 2 adapter, Foxglove view and recorder first, the gateway 3 s later, the router last."""
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    control_port, log_port = free_port(), free_port()
    zargs = zenoh_connect_args(zport)
    recording = tmp_path / "start.mcap"
    first = {
        "sim": Child(["-m", "blackmetal", "sim", "--control-port", str(control_port), "--log-port", str(log_port), *zargs]),
        "odometry": Child(["-m", "blackmetal", "odometry", *zargs]),
        "ros2": Child(["-m", "blackmetal", "ros2", *zargs]),
        "foxglove": Child(["-m", "blackmetal", "foxglove", "--port", "0", *zargs]),
        "record": Child(["-m", "blackmetal", "record", "-o", str(recording), *zargs]),
    }
    children.extend(first.values())
    started = time.monotonic()
    waiting = rf"waiting for {re.escape(endpoint)} \(router or hub\)"
    seen_at(first, waiting)
    time.sleep(max(0.0, started + 3.0 - time.monotonic()))
    gateway = Child(["-m", "blackmetal", "gateway", "--control-port", str(control_port), "--log-port", str(log_port), *zargs])
    children.append(gateway)
    services = {**first, "gateway": gateway}
    seen_at({"gateway": gateway}, waiting)
    for name, child in services.items():  # nothing is announced before it has joined
        assert child.ready_info is None and not any(" ready" in line for line in child.lines), f"{name}:\n{child.output()}"
        assert sum(bool(re.search(waiting, line)) for line in child.lines) == 1, child.output()  # said once
    hub = Child(["-m", "blackmetal", "router", "-l", endpoint])
    children.append(hub)
    up = wait_for(lambda: port_open(zport) and time.monotonic(), interval=0.002, what="the router's port to open")
    at = seen_at(services, rf"connected to {re.escape(endpoint)}")
    joined = {name: round(when - up, 3) for name, when in sorted(at.items())}
    print(f"joined after the router's port opened (s): {joined}")
    assert max(joined.values()) < JOIN_WITHIN_S, joined
    hub.ready()
    for child in services.values():
        child.ready()
    with zenoh.open(client_config(zport)) as session:
        assert_the_robot_works(session)
    assert first["record"].stop(signal.SIGINT) == 0
    with open(recording, "rb") as handle:
        topics = {channel.topic for _, channel, _ in make_reader(handle).iter_messages()}
    assert {KEYS.pose, KEYS.impulses} <= topics


def test_a_router_restarted_under_a_running_stack_leaves_every_service_working(children: list[Child], tmp_path: Path) -> None:
    zport = free_port()
    children.append(router(zport))
    control_port, log_port = free_port(), free_port()
    zargs = zenoh_connect_args(zport)
    recording = tmp_path / "restart.mcap"
    services = {
        "sim": Child(["-m", "blackmetal", "sim", "--control-port", str(control_port), "--log-port", str(log_port), *zargs]),
        "gateway": Child(["-m", "blackmetal", "gateway", "--control-port", str(control_port), "--log-port", str(log_port), *zargs]),
        "odometry": Child(["-m", "blackmetal", "odometry", *zargs]),
        "ros2": Child(["-m", "blackmetal", "ros2", *zargs]),
        "foxglove": Child(["-m", "blackmetal", "foxglove", "--port", "0", *zargs]),
        "record": Child(["-m", "blackmetal", "record", "-o", str(recording), *zargs]),
    }
    children.extend(services.values())
    for child in services.values():
        child.ready()
    odom_key = services["ros2"].ready()["keys"]["odom"]
    with zenoh.open(client_config(zport)) as session:
        assert_the_robot_works(session)
    for _ in range(2):  # killed outright, then started again on the same port: twice
        children[0].stop(signal.SIGKILL)
        time.sleep(1.0)  # every service notices the router gone and keeps trying
        children[0] = router(zport)
        restarted_ns = time.time_ns()
        with zenoh.open(client_config(zport)) as session:
            assert_the_robot_works(session)
            assert_the_ros2_node_works(session, odom_key)
        for name, child in services.items():
            assert child.poll() is None, f"{name} exited after the router restarted:\n{child.output()}"
    assert services["record"].stop(signal.SIGINT) == 0
    with open(recording, "rb") as handle:
        late = [m.log_time for _, channel, m in make_reader(handle).iter_messages() if channel.topic == KEYS.pose]
    assert late and max(late) > restarted_ns, "the recorder kept recording after the restart"


@pytest.mark.parametrize("service", ["gateway", "odometry", "sim", "ros2", "foxglove", "record"])
def test_a_service_waiting_for_its_router_says_so_once_and_stops_cleanly(service: str, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    extra = {"sim": ["--control-port", "0", "--log-port", "0"], "foxglove": ["--port", "0"], "record": ["-o", str(tmp_path / "r.mcap")]}
    child = Child(["-m", "blackmetal", service, *extra.get(service, []), "-e", endpoint])
    try:
        child.wait_line(rf"blackmetal {service}: waiting for {re.escape(endpoint)} \(router or hub\)")
        time.sleep(1.5)  # it keeps trying without a word more
        assert child.poll() is None
        stopping = time.monotonic()
        assert child.stop(signal.SIGINT) == 0
        assert time.monotonic() - stopping < 3.0
    finally:
        child.stop()
    out = child.output()
    assert out.count("waiting for") == 1 and " ready" not in out and "Traceback" not in out, out


def test_user_tools_still_fail_at_once_with_one_sentence() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    for args in (["watch"], ["estop", "on"], ["square"]):
        started = time.monotonic()
        result = subprocess.run(
            [sys.executable, "-m", "blackmetal", *args, "-e", endpoint], capture_output=True, text=True, timeout=60
        )  # fmt: skip
        assert time.monotonic() - started < 10.0  # interpreter start included; no waiting for the router
        assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
        assert result.stderr.count("\n") == 1 and f"cannot reach {endpoint}" in result.stderr, result.stderr
