"""The command path's figures: a command or an e-stop put on Zenoh -> its bytes at the robot's socket.

The robot is the bench's mini robot in its own process, stamping arrivals with the kernel's receive time.
"""

from __future__ import annotations

import random
import statistics
import time
from collections.abc import Callable
from contextlib import ExitStack
from typing import TYPE_CHECKING

from blackmetal.schemas import Keys

from . import peers
from .peers import COMMAND_GAP_S, EXPRESS, RobotProcess, free_port, percentiles
from .rig import KEYS, client_service, peer, robot_and_gateway, rss_mb, session, wait_polls
from .runner import Figure, Plan, Result, Row, at_most, latency_rows, met, noisy, over, rounds, spreads

if TYPE_CHECKING:
    import zenoh


def _json_twist(speed: float) -> bytes:
    return b'{"linear":{"x":%.6f}}' % speed


def cmd_latency(samples: int, via_ros2: bool = False, ros2_in_line: bool = False) -> dict[str, float]:
    """``cmd_vel`` put -> command bytes at the robot's socket (the kernel's receive stamp, Unix time).

    ``via_ros2``: a CDR Twist on rmw_zenoh's ``/cmd_vel`` through ``blackmetal ros2``, its publisher a client of the
    gateway (-> adapter -> gateway), or with ``ros2_in_line`` of the adapter (-> gateway: one more hop).
    """
    with ExitStack() as stack:
        robot, zport, _ = robot_and_gateway(stack)
        adapter_port = free_port() if ros2_in_line else None
        adapter = client_service(stack, "ros2", zport, adapter_port) if via_ros2 else None
        client = session(stack, adapter_port or zport)
        key, payload = KEYS.cmd_vel, _json_twist
        if adapter is not None:
            from blackmetal.ros2.messages import RosCodec

            codec = RosCodec()
            key, payload = adapter.wait_ready()["keys"]["cmd_vel"], lambda speed: codec.encode_twist(speed, 0.0)
        pub = client.declare_publisher(key, express=EXPRESS)
        wait_polls(robot)
        return command_latencies(pub, robot, samples, payload)


def forwarder_latency(samples: int) -> dict[str, float]:
    """``cmd_vel`` put -> bytes at the robot's socket through the minimal forwarder instead of the gateway."""
    with ExitStack() as stack:
        robot = RobotProcess(stack)
        zport = free_port()
        peer(stack, "forwarder", [str(zport), str(robot.control_port)])
        pub = session(stack, zport).declare_publisher(KEYS.cmd_vel, express=EXPRESS)
        return command_latencies(pub, robot, samples)


def command_latencies(
    pub: "zenoh.Publisher", robot: RobotProcess, samples: int, payload: Callable[[float], bytes] = _json_twist
) -> dict[str, float]:
    """Commands put on ``pub`` (30 of warm-up, then ``samples``), each a distinct speed: put -> arrival at the robot's socket."""
    time.sleep(0.3)
    sent: dict[float, float] = {}
    for i in range(samples + 30):
        speed = round(0.0005 * (1 + i), 6) * (1 if i % 2 else -1)
        data = payload(speed)
        start = time.time()
        pub.put(data)
        if i >= 30:  # warm-up
            sent[speed] = start
        time.sleep(random.uniform(*COMMAND_GAP_S))
    time.sleep(0.3)
    arrivals = {float(k): v for k, v in robot.dump()["arrivals"]}
    return percentiles([arrivals[s] - t for s, t in sent.items() if s in arrivals])


#: The engage and release publishers of one robot's e-stop.
EStop = tuple["zenoh.Publisher", "zenoh.Publisher"]


def estop_publishers(client: "zenoh.Session", keys: Keys = KEYS) -> EStop:
    return client.declare_publisher(keys.estop, express=EXPRESS), client.declare_publisher(keys.estop_release, express=EXPRESS)


def _estop_rig(stack: ExitStack) -> tuple[RobotProcess, int, EStop]:
    """A mini robot, its gateway on a free port, and the e-stop's publishers, once the gateway polls."""
    robot, zport, _ = robot_and_gateway(stack)
    estop = estop_publishers(session(stack, zport))
    wait_polls(robot)
    return robot, zport, estop


def _engage_release(estop: EStop, count: int, gap: tuple[float, float], settle: float = 0.0) -> list[float]:
    """``count`` engages, each released a random ``gap`` later, then ``settle``: when each engage was put (Unix time)."""
    engage, release = estop
    starts = []
    for _ in range(count):
        time.sleep(random.uniform(*gap))
        starts.append(time.time())
        engage.put(b'{"engaged": true}')
        time.sleep(random.uniform(*gap))
        release.put(b'{"engaged": false}')
        time.sleep(settle)
    return starts


def estop_latency(samples: int) -> dict[str, float]:
    """``{"engaged": true}`` put on estop -> EMG_STOP bytes at the robot's socket (kernel receive stamp)."""
    with ExitStack() as stack:
        robot, _, estop = _estop_rig(stack)
        return estop_latencies(estop, robot, samples)


#: After a release, before the next engage, where the gateway's loop is busy (a fleet): the gateway keeps only the
#: newest e-stop state, so an engage that finds the release still waiting merges with it and needs no new EMG_STOP.
RELEASE_SETTLE_S = 0.03


def estop_latencies(estop: EStop, robot: RobotProcess, samples: int, settle: float = 0.0) -> dict[str, float]:
    """Engage then release, 10 of warm-up, then ``samples``: put -> EMG_STOP at the robot's socket.

    ``settle``: a pause after each release (RELEASE_SETTLE_S for a fleet). ``missing``: engages without their own EMG_STOP.
    """
    time.sleep(0.3)
    first = len(robot.dump()["emg_stops"])
    starts = _engage_release(estop, samples + 10, COMMAND_GAP_S, settle)
    time.sleep(0.3)
    stops = sorted(robot.dump()["emg_stops"][first:])
    # an engage's EMG_STOP arrives before the next engage; one without is counted, never paired with another's stop
    ends = [*starts[1:], float("inf")]
    latencies, missing = [], 0
    for start, end in list(zip(starts, ends, strict=True))[10:]:  # after the warm-up
        arrival = next((stop for stop in stops if start <= stop < end), None)
        if arrival is None:
            missing += 1
        else:
            latencies.append(arrival - start)
    return {**percentiles(latencies), "missing": missing}


def estop_under_flood(samples: int, flooders: int = 3) -> dict[str, float]:
    """The e-stop's latency while ``flooders`` processes flood ``cmd_vel/nav`` at full speed (an attacker, or a runaway planner)."""
    with ExitStack() as stack:
        robot, zport, estop = _estop_rig(stack)
        for _ in range(flooders):
            peer(stack, "flooder", [str(zport), KEYS.cmd_vel_of("nav"), str(4.0 + samples * 0.05)])
        time.sleep(1.0)  # the flood is on: the gateway's nav input has changed over to its ring buffer
        starts = _engage_release(estop, samples, (0.02, 0.04))
        time.sleep(0.5)
        stops = robot.dump()["emg_stops"]
    latencies = []
    for start in starts:  # the first EMG_STOP at or after each engage
        after = [stop for stop in stops if stop >= start]
        latencies.append(min(after) - start if after else float("inf"))
    return {**percentiles(latencies), "flooders": flooders, "lost": sum(1 for x in latencies if x == float("inf"))}


def flood(rate_hz: float, seconds: float) -> dict[str, float]:
    """``cmd_vel`` at ``rate_hz`` for ``seconds``: gateway memory, and how soon the last command reaches the robot."""
    with ExitStack() as stack:
        robot, zport, gw = robot_and_gateway(stack)
        pub = session(stack, zport).declare_publisher(KEYS.cmd_vel, express=EXPRESS)
        wait_polls(robot)
        time.sleep(0.3)
        rss_before = rss_mb(gw.proc.pid)
        count = int(rate_hz * seconds)
        start = time.monotonic()
        for i in range(count):
            while time.monotonic() < start + i / rate_hz:
                pass
            pub.put(_json_twist(0.1 + 0.3 * (i % 1000) / 1000))
        last_value = round(0.1 + 0.3 * ((count - 1) % 1000) / 1000, 6)
        final = -0.123456
        t_final = time.time()
        pub.put(_json_twist(final))
        deadline = time.monotonic() + 5
        arrivals: dict[float, float] = {}
        while time.monotonic() < deadline:
            arrivals = {float(k): v for k, v in robot.dump()["arrivals"]}
            if final in arrivals:
                break
            time.sleep(0.02)
        achieved = count / (time.monotonic() - start)
        rss_after = rss_mb(gw.proc.pid)
        commands = robot.dump()["commands"]
    return {
        "asked_hz": rate_hz,
        "sent_hz": achieved,
        "sent": count + 1,
        "commands_at_robot": commands,
        "rss_before_mb": rss_before,
        "rss_after_mb": rss_after,
        "rss_growth_mb": rss_after - rss_before,
        "last_command_latency_ms": (arrivals[final] - t_final) * 1e3 if final in arrivals else float("nan"),
        "last_flood_value_seen": float(last_value in arrivals),
    }


def _cmd_vel_path(plan: Plan, gateway: bool) -> Result:
    """Round by round: one Zenoh hop, the minimal forwarder and (with ``gateway``) the gateway, each right after the other."""
    measured = rounds(
        plan,
        hop=lambda: peers.zenoh_hop(plan.samples),
        forwarder=lambda: forwarder_latency(plan.samples),
        **({"gateway": lambda: cmd_latency(plan.samples)} if gateway else {}),
    )
    hop, fwd = measured["hop"], measured["forwarder"]
    out = {
        "zenoh_hop_ms": spreads(hop),
        "forwarder_to_robot_ms": {**spreads(fwd), "p50_over_hop": over(fwd, hop), "noisy": noisy(fwd["p50"]) or noisy(hop["p50"])},
    }
    if gateway:
        cmd = measured["gateway"]
        out["cmd_vel_to_robot_ms"] = {
            **spreads(cmd),
            "p50_over_hop": over(cmd, hop),
            "noisy": noisy(cmd["p50"]) or noisy(hop["p50"]),
            "p50_over_forwarder": over(cmd, fwd),
            "p99_over_forwarder": over(cmd, fwd, "p99"),
        }
    return out


def _forwarder_rows(f: Result) -> list[Row]:
    fwd, hop = f["forwarder_to_robot_ms"], f["zenoh_hop_ms"]
    p99_ratio = fwd["p99"]["median"] / hop["p99"]["median"]
    return latency_rows("minimal forwarder -> robot socket {p}", fwd, "1 Zenoh hop", hop,
                        f"{fwd['p50_over_hop']:.2f}x (report: the floor of a Python gateway)" + (" NOISY" if fwd["noisy"] else ""),
                        f"{p99_ratio:.2f}x (report)")  # fmt: skip


def _cmd_vel_rows(f: Result) -> list[Row]:
    cmd, hop, fwd = f["cmd_vel_to_robot_ms"], f["zenoh_hop_ms"], f["forwarder_to_robot_ms"]
    p99_ratio = cmd["p99"]["median"] / hop["p99"]["median"]
    return [
        *_forwarder_rows(f),
        *latency_rows("cmd_vel -> robot socket {p}", cmd, "1 Zenoh hop", hop, at_most(cmd["p50_over_hop"], 1.5, cmd["noisy"]),
                      f"{p99_ratio:.2f}x (<= 2x{met(p99_ratio <= 2.0)}; <= 1 ms{met(cmd['p99']['median'] <= 1.0)})"),
        *latency_rows("cmd_vel -> robot socket {p}, against the forwarder", cmd, "forwarder", fwd,
                      at_most(cmd["p50_over_forwarder"], 1.2), at_most(cmd["p99_over_forwarder"], 1.5)),
    ]  # fmt: skip


def _ros2_cmd_vel(plan: Plan, out: Result) -> Result:
    cmd_p50, hop_p50 = out["cmd_vel_to_robot_ms"]["p50"]["median"], out["zenoh_hop_ms"]["p50"]["median"]
    measured = rounds(
        plan,
        ros2_cmd_vel_to_robot_ms=lambda: cmd_latency(plan.samples, via_ros2=True, ros2_in_line=True),
        ros2_routed_cmd_vel_to_robot_ms=lambda: cmd_latency(plan.samples, via_ros2=True, ros2_in_line=False),
    )
    return {
        name: {
            **spreads(ros),
            "p50_over_cmd_vel": statistics.median(ros["p50"]) / cmd_p50,
            "extra_hops": (statistics.median(ros["p50"]) - cmd_p50) / hop_p50,
        }
        for name, ros in measured.items()
    }


def _ros2_cmd_vel_rows(f: Result) -> list[Row]:
    cmd, ros, routed = f["cmd_vel_to_robot_ms"], f["ros2_cmd_vel_to_robot_ms"], f["ros2_routed_cmd_vel_to_robot_ms"]
    return [
        *latency_rows("ROS /cmd_vel -> robot {p} (ros2 in line)", ros, "cmd_vel {p}", cmd,
                      f"{ros['p50_over_cmd_vel']:.2f}x; +{ros['extra_hops']:.2f} Zenoh hops (<= 1 more hop{met(ros['extra_hops'] <= 1.0)})"),
        latency_rows("ROS /cmd_vel -> robot {p}, routed via the gateway", routed, "cmd_vel {p}", cmd,
                     f"{routed['p50_over_cmd_vel']:.2f}x; +{routed['extra_hops']:.2f} Zenoh hops (report: two more transits by construction)")[0],
    ]  # fmt: skip


def _estop(plan: Plan, out: Result) -> Result:
    estop = rounds(plan, estop=lambda: estop_latency(plan.samples // 2))["estop"]
    ratio = statistics.median(estop["p50"]) / out["cmd_vel_to_robot_ms"]["p50"]["median"]
    return {"estop_to_robot_ms": {**spreads(estop), "p50_over_cmd_vel": ratio}}


def _estop_rows(f: Result) -> list[Row]:
    estop = f["estop_to_robot_ms"]
    return latency_rows(
        "e-stop -> EMG_STOP at robot {p}", estop, "cmd_vel {p}", f["cmd_vel_to_robot_ms"], at_most(estop["p50_over_cmd_vel"], 1.0)
    )


def _estop_flood_row(e: Result) -> Row:
    return (f"e-stop under {e['flooders']} full-speed flooders, p50 / p99 / max", f"{e['p50_ms']:.2f} / {e['p99_ms']:.2f} / {e['max_ms']:.2f} ms",
            "the e-stop without a flood (above)", f"max <= 100 ms{met(e['max_ms'] <= 100.0)}; {e['n']} samples, {e['lost']} without EMG_STOP")  # fmt: skip


def _flood_row(fl: Result) -> Row:
    return (f"cmd_vel flood {fl['sent_hz'] / 1e3:.1f} kHz", f"RSS {fl['rss_before_mb']:.1f} -> {fl['rss_after_mb']:.1f} MB; last command after {fl['last_command_latency_ms']:.2f} ms",
            "memory before the flood", f"{fl['rss_growth_mb']:+.1f} MB; {fl['commands_at_robot']} of {fl['sent']} puts sent on (latest wins)")  # fmt: skip


FORWARDER = Figure("forwarder", "minimal forwarder latency", "latency: minimal forwarder -> robot socket, against one Zenoh hop ...",
                   ("zenoh_hop_ms", "forwarder_to_robot_ms"), lambda plan, out: _cmd_vel_path(plan, gateway=False), _forwarder_rows,
                   within="cmd_vel")  # fmt: skip
CMD_VEL = Figure("cmd_vel", "cmd_vel latency", "latency: cmd_vel -> robot socket, against one Zenoh hop and the minimal forwarder ...",
                 ("zenoh_hop_ms", "forwarder_to_robot_ms", "cmd_vel_to_robot_ms"), lambda plan, out: _cmd_vel_path(plan, gateway=True),
                 _cmd_vel_rows)  # fmt: skip
ROS2_CMD_VEL = Figure("ros2_cmd_vel", "ROS 2 /cmd_vel latency",
                      "latency: ROS 2 /cmd_vel through blackmetal ros2 -> robot socket, against cmd_vel and one Zenoh hop ...",
                      ("ros2_cmd_vel_to_robot_ms", "ros2_routed_cmd_vel_to_robot_ms"), _ros2_cmd_vel, _ros2_cmd_vel_rows,
                      extra="ros2", needs=("cmd_vel",))  # fmt: skip
ESTOP = Figure("estop", "e-stop latency", "latency: e-stop -> EMG_STOP at the robot socket, against cmd_vel ...",
               ("estop_to_robot_ms",), _estop, _estop_rows, needs=("cmd_vel",))  # fmt: skip
ESTOP_FLOOD = Figure("estop_flood", "e-stop under a flood", "latency: e-stop while three processes flood cmd_vel/nav at full speed ...",
                     ("estop_under_flood_ms",), lambda plan, out: {"estop_under_flood_ms": estop_under_flood(plan.pick(10, 100))},
                     lambda f: [_estop_flood_row(f["estop_under_flood_ms"])])  # fmt: skip
FLOOD = Figure("flood", "cmd_vel flood", "cmd_vel flood ...", ("flood",),
               lambda plan, out: {"flood": flood(5000.0, plan.pick(0.3, 5.0))}, lambda f: [_flood_row(f["flood"])])  # fmt: skip
