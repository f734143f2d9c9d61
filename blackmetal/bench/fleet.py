"""``blackmetal bench --fleet``: one router, N robots behind one fleet gateway and one fleet odometry, measured together.

What is measured, in which window, and why the bench's own pose count is no
part of the fleet: docs/performance.md ("Fleets").
"""

from __future__ import annotations

import collections
import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from blackmetal.runtime.fleet import FleetRobot, load_fleet, write_fleet
from blackmetal.schemas import GatewayHealth, Keys, decode

from .command_path import RELEASE_SETTLE_S, command_latencies, estop_latencies, estop_publishers
from .peers import EXPRESS, RobotProcess, free_port
from .rig import cpu_window, latch_args, rss_mb, service, wait_polls
from .rig import session as client_session

#: Every fleet robot's poll rate (Hz): the issue's figure.
POLL_HZ = 50.0
#: The views count as started once both together use at most this much in a second (cores), or after SETTLE_MAX_S.
SETTLED_CORES = 0.05
SETTLE_MAX_S = 20.0


def _watch_foxglove(stack: ExitStack, url: str, robots: int) -> list[int]:
    """One Foxglove client (the app's protocol) subscribed to every robot's pose channel: ``[messages it got]``, counting."""
    import json
    import threading

    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    ws = stack.enter_context(connect(url, subprotocols=[Subprotocol("foxglove.sdk.v1")], open_timeout=30, max_size=None))
    channels: dict[str, int] = {}
    deadline = time.monotonic() + 30
    while len([t for t in channels if t.endswith("/pose")]) < robots and time.monotonic() < deadline:
        message = ws.recv(timeout=30)
        if isinstance(message, str) and json.loads(message)["op"] == "advertise":
            channels.update({c["topic"]: c["id"] for c in json.loads(message)["channels"]})
    poses = [cid for topic, cid in channels.items() if topic.endswith("/pose") and "truth" not in topic]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": c} for i, c in enumerate(poses)]}))
    received, stop = [0], threading.Event()

    def read() -> None:
        while not stop.is_set():
            try:
                message = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(message, bytes) and message[:1] == b"\x01":  # a message data frame
                received[0] += 1

    reader = threading.Thread(target=read, name="bench-foxglove-client", daemon=True)
    reader.start()
    stack.callback(reader.join, 2)
    stack.callback(stop.set)  # first: the stack unwinds last in, first out
    return received


def fleet_figure(robots: int, seconds: float, samples: int, views: bool = False) -> dict[str, Any]:
    """The figures of one fleet of ``robots`` (see the module docstring)."""
    import zenoh

    with ExitStack() as stack, tempfile.TemporaryDirectory(prefix="blackmetal-bench-fleet-") as folder:
        zport = free_port()
        endpoint = ["-e", f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting"]
        processes = {"router": service(stack, "router", ["router", "-l", f"tcp/127.0.0.1:{zport}"])}
        probe_robot = RobotProcess(stack)
        simulated: list[FleetRobot] = []
        if robots > 1:
            sim_file = Path(folder) / "simulated.toml"
            processes["sim"] = service(stack, "sim", ["sim", "--robots", str(robots - 1), "--write-fleet", str(sim_file), *endpoint])
            simulated = load_fleet(sim_file)
        probe = FleetRobot(robots, "probe", "127.0.0.1", probe_robot.control_port, probe_robot.log_port, "fleet/probe")
        fleet_file = Path(folder) / "fleet.toml"
        fleet_file.write_text(write_fleet([*simulated, probe]))
        processes["gateway"] = service(
            stack,
            "gateway",
            ["gateway", "--fleet", str(fleet_file), "--poll-hz", str(POLL_HZ), "--cmd-timeout", "0", *latch_args(stack), *endpoint],
        )
        processes["odometry"] = service(stack, "odometry", ["odometry", "--fleet", str(fleet_file), *endpoint])
        session = client_session(stack, zport)
        poses: collections.Counter[str] = collections.Counter()
        counting = session.declare_subscriber("fleet/*/pose", lambda sample: poses.update((str(sample.key_expr),)))
        wait_polls(probe_robot)
        deadline = time.monotonic() + 60.0
        while len(poses) < robots:
            if time.monotonic() > deadline:
                raise TimeoutError(f"only {len(poses)} of {robots} robots posed within 60 s")
            time.sleep(0.2)
        time.sleep(1.0)

        pids = {name: child.proc.pid for name, child in processes.items()}
        counts0, t0 = dict(poses), time.monotonic()
        cpu = cpu_window(pids, seconds)
        counts1, elapsed = dict(poses), time.monotonic() - t0
        rates = sorted((counts1.get(key, 0) - counts0.get(key, 0)) / elapsed for key in {*counts0, *counts1})
        rates += [0.0] * (robots - len(rates))
        rss = {name: rss_mb(pid) for name, pid in pids.items()}
        polls = _poll_rates(session)

        # poses still flow to a consumer (the router forwards them, as to a fleet view), but the bench's Python
        # count of 5,000 a second, on the machine's two cores with everything else, is not part of the fleet
        consumer = session.declare_subscriber("fleet/*/pose", zenoh.handlers.RingChannel(1))
        counting.undeclare()
        view_figures: dict[str, Any] = {}
        if views:
            view_figures = _views(stack, session, processes, fleet_file, endpoint, robots, seconds)
        probe_keys = Keys(probe.prefix)
        cmd = command_latencies(session.declare_publisher(probe_keys.cmd_vel, express=EXPRESS), probe_robot, samples)
        estop = estop_latencies(estop_publishers(session, probe_keys), probe_robot, samples, RELEASE_SETTLE_S)
        consumer.undeclare()
    services = ("router", "gateway", "odometry")
    return {
        "robots": robots,
        "seconds": elapsed,
        "cpu": cpu,
        "cpu_services": sum(cpu.get(name, 0.0) for name in services),
        "cpu_with_sim": sum(cpu.values()),
        "rss_mb": rss,
        "rss_services_mb": sum(rss.get(name, 0.0) for name in services),
        "pose_hz_min": rates[0],
        "pose_hz_median": statistics.median(rates),
        "poll_hz_min": min(polls, default=0.0),
        # every poll publishes one impulse sample, every pose one pose; health and status once a second each
        "messages_per_s": sum(polls) + sum(rates) + 2 * robots,
        "cmd_vel_ms": cmd,
        "estop_ms": estop,
        **({"views": view_figures} if views else {}),
    }


def _poll_rates(session: Any) -> list[float]:
    """Every fleet gateway's poll rate, as its robots' health reports say."""
    return [
        decode(GatewayHealth, r.ok.payload.to_bytes()).poll_hz for r in session.get("fleet/*/gateway/health", timeout=5) if r.ok is not None
    ]


def _views(stack: ExitStack, session: Any, processes: dict[str, Any], fleet_file: Path, endpoint: list[str], robots: int,
           seconds: float) -> dict[str, Any]:  # fmt: skip
    """The views' cost idle, then the whole host while a Foxglove client and an /odom subscriber watch every robot."""
    processes["ros2"] = service(stack, "ros2", ["ros2", "--fleet", str(fleet_file), *endpoint])
    processes["foxglove"] = service(stack, "foxglove", ["foxglove", "--fleet", str(fleet_file), "--port", "0", *endpoint])
    pids = {name: child.proc.pid for name, child in processes.items()}
    views = {name: pids[name] for name in ("ros2", "foxglove")}
    # idle means after the start: a view still declaring a few hundred robots on a saturated host is starting, not idle
    settle_until = time.monotonic() + SETTLE_MAX_S
    while sum(cpu_window(views, 1.0).values()) > SETTLED_CORES and time.monotonic() < settle_until:
        pass
    idle = cpu_window(pids, seconds)
    foxglove = _watch_foxglove(stack, processes["foxglove"].ready_info["url"], robots)
    odoms = [0]
    odom = session.declare_subscriber("0/*/odom/nav_msgs::msg::dds_::Odometry_/*", lambda _: odoms.__setitem__(0, odoms[0] + 1))
    stack.callback(odom.undeclare)
    time.sleep(3.0)
    got0, odom0, t0 = foxglove[0], odoms[0], time.monotonic()
    watched = cpu_window(pids, seconds)
    elapsed = time.monotonic() - t0
    polls = _poll_rates(session)
    return {
        "idle": {name: idle[name] for name in ("ros2", "foxglove")},
        "watched": watched,
        "host_watched": sum(watched.values()),
        "foxglove_poses_per_s": (foxglove[0] - got0) / elapsed,
        "odom_per_s": (odoms[0] - odom0) / elapsed,
        "poll_hz_min_watched": min(polls, default=0.0),
        "expected_per_s": robots * POLL_HZ,
    }


def fleet_table(runs: list[dict[str, Any]]) -> str:
    """One row per fleet size; memory per added robot against the smallest fleet of the same run."""
    first = runs[0]
    header = (
        "robots | CPU router+gateway+odometry (sim apart) | memory, per added robot | pose Hz min/median | "
        "messages/s | cmd_vel p50/p99 | e-stop p50/p99"
    )
    lines = [header, "-" * len(header)]
    for run in runs:
        added = run["robots"] - first["robots"]
        per_robot = f"{(run['rss_services_mb'] - first['rss_services_mb']) / added:.2f} MB" if added else "-"
        cpu = run["cpu"]
        lines.append(
            f"{run['robots']:>6} | {run['cpu_services']:.2f} cores (router {cpu['router']:.2f}, gateway {cpu['gateway']:.2f}, "
            f"odometry {cpu['odometry']:.2f}; sim {cpu.get('sim', 0.0):.2f}) | {run['rss_services_mb']:.0f} MB, {per_robot} | "
            f"{run['pose_hz_min']:.1f}/{run['pose_hz_median']:.1f} | {run['messages_per_s']:.0f} | "
            f"{run['cmd_vel_ms']['p50_ms']:.2f}/{run['cmd_vel_ms']['p99_ms']:.2f} ms | "
            f"{run['estop_ms']['p50_ms']:.2f}/{run['estop_ms']['p99_ms']:.2f} ms"
            + (f" ({run['estop_ms']['missing']} engages without their own EMG_STOP)" if run["estop_ms"].get("missing") else "")
        )
    if any("views" in run for run in runs):
        header = (
            "robots | idle ros2 / foxglove | watched: whole host (ros2, foxglove) | poses to Foxglove/s, /odom/s (of) | "
            "poll Hz min | cmd_vel p99 | e-stop p99 (while watched)"
        )
        lines += ["", header, "-" * len(header)]
        for run in runs:
            v = run.get("views")
            if not v:
                continue
            w = v["watched"]
            lines.append(
                f"{run['robots']:>6} | {v['idle']['ros2']:.3f} / {v['idle']['foxglove']:.3f} cores | {v['host_watched']:.2f} cores "
                f"(ros2 {w['ros2']:.2f}, foxglove {w['foxglove']:.2f}) | {v['foxglove_poses_per_s']:.0f}, {v['odom_per_s']:.0f} "
                f"({v['expected_per_s']:.0f}) | {v['poll_hz_min_watched']:.1f} | {run['cmd_vel_ms']['p99_ms']:.2f} ms | "
                f"{run['estop_ms']['p99_ms']:.2f} ms"
            )
    return "\n".join(lines)
