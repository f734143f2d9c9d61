"""The benchmark's peers: a minimal robot and a Zenoh echo, each in its own process.

The minimal robot answers at once and stamps arrivals, so simulator costs and the GIL stay out of the gateway's figures.
"""

from __future__ import annotations

import json
import os
import queue
import random
import selectors
import socket
import struct
import sys
import threading
import time
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

from blackmetal import wire
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.ports import free_port
from blackmetal.wire import CommandCode, Request, RequestDecoder

from .children import spawn

if TYPE_CHECKING:
    import zenoh

#: Linux's SO_TIMESTAMPNS (not exported by Python's socket module): kernel receive time stamps.
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)

#: Publish bench messages without batching (what a latency-minded client does).
EXPRESS = os.environ.get("BLACKMETAL_BENCH_EXPRESS", "1") == "1"


def _zenoh_conf(listen: int | None = None, connect: int | None = None) -> "zenoh.Config":
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{listen}"] if listen else []))
    if connect:
        conf.insert_json5("mode", '"client"')  # a client of exactly that process, as blackmetal's tools are
        conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{connect}"]))
    return conf


def _serve(sel: selectors.BaseSelector, state: dict[str, Any], lock: threading.Lock) -> None:
    """The robot's thread: status for every command, zeros for polls, a log report per second; arrivals kernel-stamped."""
    decoders: dict[socket.socket, RequestDecoder] = {}
    log_clients: list[socket.socket] = []
    next_log = time.monotonic()
    while True:
        for key, _ in sel.select(0.05):
            kind, port = key.data
            sock: socket.socket = key.fileobj  # type: ignore[assignment]
            if kind == "accept":
                conn, _ = sock.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                conn.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)  # the kernel stamps arrivals
                if port == "control":
                    decoders[conn] = RequestDecoder()
                    sel.register(conn, selectors.EVENT_READ, ("control", None))
                else:
                    log_clients.append(conn)
                continue
            try:
                data, ancillary, _, _ = sock.recvmsg(65536, socket.CMSG_SPACE(16))
            except OSError:
                data, ancillary = b"", []
            now = time.time()
            for level, kind_, payload in ancillary:
                if level == socket.SOL_SOCKET and kind_ == SO_TIMESTAMPNS and len(payload) >= 16:
                    seconds, nanos = struct.unpack("qq", payload[:16])
                    now = seconds + nanos * 1e-9  # when the bytes reached the socket, not when we woke up
            if not data:
                sel.unregister(sock)
                decoders.pop(sock, None)
                sock.close()
                continue
            out = bytearray()
            for request in decoders[sock].feed(data):
                if not isinstance(request, Request):
                    continue
                out += wire.encode_status()
                with lock:
                    if request.command is CommandCode.SET_LR_WHEEL_VELOCITY:
                        state["commands"] += 1
                        state["arrivals"][float(request.right or 0.0)] = now
                    elif request.command is CommandCode.EMG_STOP:
                        state["emg_stops"].append(now)
                    elif request.command is CommandCode.GET_LR_WHEEL_VELOCITY:
                        state["polls"].append(now)
                        out += wire.encode_wheel_speeds(left=0, right=0)
            try:
                sock.sendall(out)
            except OSError:
                pass
        if time.monotonic() >= next_log:
            next_log += 1.0
            for client in list(log_clients):
                try:
                    client.sendall(wire.encode_log_report(1, 1))
                except OSError:
                    log_clients.remove(client)


def robot_main() -> None:
    """Child process: a robot that answers at once; announces its ports, dumps what arrived as JSON on 'dump', ends on SIGINT or EOF.

    ``arrivals`` maps each command's right wheel speed to its arrival; every time is Unix time, the kernel's receive stamp.
    """
    state: dict[str, Any] = {"arrivals": {}, "polls": [], "commands": 0, "emg_stops": []}
    lock = threading.Lock()
    sel = selectors.DefaultSelector()
    ports = {}
    for kind in ("control", "log"):
        server = socket.create_server(("127.0.0.1", 0))  # SO_REUSEADDR, as a robot's server socket
        server.setblocking(False)
        ports[kind] = server.getsockname()[1]
        sel.register(server, selectors.EVENT_READ, ("accept", kind))
    threading.Thread(target=_serve, args=(sel, state, lock), daemon=True).start()
    announce_ready("mini-robot", **ports)
    for line in sys.stdin:
        if line.strip() == "dump":
            with lock:
                print(json.dumps({**state, "arrivals": list(state["arrivals"].items())}), flush=True)


class RobotProcess:
    """A MiniRobot in its own process, so its thread never competes with the client for the GIL; stopped with ``stack``."""

    def __init__(self, stack: ExitStack) -> None:
        self.child = spawn("mini-robot", ["-m", "blackmetal.bench", "robot"], interactive=True)
        stack.callback(self.child.stop, timeout=3)
        ports = self.child.wait_ready()
        self.control_port, self.log_port = ports["control"], ports["log"]

    def dump(self) -> dict[str, Any]:
        return json.loads(self.child.request("dump"))


def percentiles(samples: list[float]) -> dict[str, float]:
    """p50, p99 and max of ``samples`` (s) in ms, and their number."""
    if not samples:
        raise TimeoutError("not one sample arrived in the measuring window")
    ordered = sorted(samples)
    pick = lambda q: ordered[min(len(ordered) - 1, int(q * len(ordered)))]  # noqa: E731
    return {"p50_ms": pick(0.5) * 1e3, "p99_ms": pick(0.99) * 1e3, "max_ms": ordered[-1] * 1e3, "n": len(ordered)}


def echo_main(port: int) -> None:
    """Child process: answer every ping with a pong, from the main thread (not the callback)."""
    import zenoh

    inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    with zenoh.open(_zenoh_conf(listen=port)) as session:
        pub = session.declare_publisher("bench/pong", express=EXPRESS)
        session.declare_subscriber("bench/ping", lambda s: inbox.put(s.payload.to_bytes()))
        announce_ready("echo")
        while True:
            payload = inbox.get()
            if payload == b"quit":
                return
            pub.put(payload)


def flooder_main(port: int, key: str, seconds: float) -> None:
    """Child process: put a moving command on ``key`` in a tight loop for ``seconds`` (an attacker's flood)."""
    import zenoh

    with zenoh.open(_zenoh_conf(connect=port)) as session:
        pub = session.declare_publisher(key)
        announce_ready("flooder")
        end = time.monotonic() + seconds
        sent = 0
        while time.monotonic() < end:
            for _ in range(100):
                pub.put(b'{"linear":{"x":0.5}}')
            sent += 100
        print(json.dumps({"sent": sent}), flush=True)


#: Pause between latency samples, the same for a figure and its baseline: an idle machine
#: wakes up slower (measured here: 0.8 ms at 20 ms pauses against 0.55 ms at 5 ms).
COMMAND_GAP_S = (0.004, 0.012)


def zenoh_hop(samples: int = 300, gap: tuple[float, float] = COMMAND_GAP_S) -> dict[str, float]:
    """Half the ping-pong round trip between this process and a plain echo process."""
    import zenoh

    port = free_port()
    child = spawn("echo", ["-m", "blackmetal.bench", "echo", str(port)])
    try:
        child.wait_ready()
        got = threading.Event()
        with zenoh.open(_zenoh_conf(connect=port)) as session:
            session.declare_subscriber("bench/pong", lambda s: got.set())
            ping = session.declare_publisher("bench/ping", express=EXPRESS)
            hops: list[float] = []
            for i in range(samples + 50):
                got.clear()
                start = time.monotonic()
                ping.put(b"%d" % i)
                if not got.wait(2.0):
                    continue
                if i >= 50:
                    hops.append((time.monotonic() - start) / 2)
                time.sleep(random.uniform(*gap))
            session.put("bench/ping", b"quit")
    finally:
        child.stop(timeout=3)
    hop = percentiles(hops)
    return {**hop, "rtt_p50_ms": 2 * hop["p50_ms"], "rtt_p99_ms": 2 * hop["p99_ms"]}
