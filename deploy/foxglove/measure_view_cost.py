"""What the Foxglove fleet view costs (#29): CPU of ``blackmetal foxglove --fleet`` idle and with one client on every pose.

    python deploy/foxglove/measure_view_cost.py 20 100 --windows 3 --seconds 10

Per fleet size: a router, ``sim --robots N``, ``gateway --fleet`` at 50 Hz,
``odometry --fleet`` and the view, all on loopback. CPU (utime + stime of the
view's process) over ``--windows`` windows of ``--seconds`` each, first with
no client connected, then with one WebSocket client (Foxglove's protocol, as
the app) subscribed to every ``/<id>/pose``; the poses it received per second
are printed too. Also the router, gateway and odometry, for scale. Figures,
not a test: the machine may be shared, so read min/median/max.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path

from websockets.sync.client import connect

from blackmetal.bench.rig import cpu_seconds
from blackmetal.bench.rig import service as _service
from blackmetal.runtime.ports import free_port


def _window(pids: dict[str, int], seconds: float, counter: list[int] | None = None) -> tuple[dict[str, float], float]:
    cpu0, n0, t0 = {n: cpu_seconds(p) for n, p in pids.items()}, (counter[0] if counter else 0), time.monotonic()
    time.sleep(seconds)
    cpu1, n1, t1 = {n: cpu_seconds(p) for n, p in pids.items()}, (counter[0] if counter else 0), time.monotonic()
    return {n: (cpu1[n] - cpu0[n]) / (t1 - t0) for n in pids}, (n1 - n0) / (t1 - t0)


def measure(robots: int, windows: int, seconds: float) -> dict[str, object]:
    with ExitStack() as stack, tempfile.TemporaryDirectory() as folder:
        zport = free_port()
        endpoint = ["-e", f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting"]
        procs = {"router": _service(stack, "router", ["router", "-l", f"tcp/127.0.0.1:{zport}"])}
        fleet = Path(folder) / "fleet.toml"
        procs["sim"] = _service(stack, "sim", ["sim", "--robots", str(robots), "--write-fleet", str(fleet), *endpoint])
        procs["gateway"] = _service(stack, "gateway", ["gateway", "--fleet", str(fleet), "--poll-hz", "50", *endpoint])
        procs["odometry"] = _service(stack, "odometry", ["odometry", "--fleet", str(fleet), *endpoint])
        procs["foxglove"] = _service(stack, "foxglove", ["foxglove", "--fleet", str(fleet), "--port", "0", *endpoint])
        url = procs["foxglove"].ready_info["url"]  # type: ignore[index]
        pids = {name: child.proc.pid for name, child in procs.items()}
        time.sleep(3.0)
        idle = [_window(pids, seconds)[0] for _ in range(windows)]

        received = [0]
        stop = threading.Event()
        ws = stack.enter_context(connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=30, max_size=None))
        channels: dict[str, int] = {}
        deadline = time.monotonic() + 30
        while len([t for t in channels if t.endswith("/pose") and "truth" not in t]) < robots and time.monotonic() < deadline:
            message = ws.recv(timeout=30)
            if isinstance(message, str):
                op = json.loads(message)
                if op["op"] == "advertise":
                    channels.update({c["topic"]: c["id"] for c in op["channels"]})
        poses = [cid for topic, cid in channels.items() if topic.endswith("/pose") and "truth" not in topic]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": c} for i, c in enumerate(poses)]}))

        def read() -> None:
            while not stop.is_set():
                try:
                    message = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
                except Exception:
                    return
                if isinstance(message, bytes) and message[:1] == b"\x01":
                    received[0] += 1

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        time.sleep(3.0)
        watched = [_window(pids, seconds, received) for _ in range(windows)]
        stop.set()
        reader.join(2)
    return {"robots": robots, "idle": idle, "watched": [w[0] for w in watched], "poses_per_s": [w[1] for w in watched]}


def _mmm(values: list[float]) -> str:
    return f"{min(values):.3f}/{statistics.median(values):.3f}/{max(values):.3f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sizes", nargs="*", type=int, default=[20, 100])
    parser.add_argument("--windows", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args(argv)
    for robots in args.sizes:
        run = measure(robots, args.windows, args.seconds)
        idle, watched = run["idle"], run["watched"]
        print(f"{robots} robots (cores, min/median/max of {args.windows} windows of {args.seconds:g} s):", flush=True)
        for name in ("foxglove", "router", "gateway", "odometry", "sim"):
            print(
                f"  {name:<9} idle {_mmm([w[name] for w in idle])}   one client on every pose {_mmm([w[name] for w in watched])}",  # type: ignore[index,union-attr]
                flush=True,
            )
        print(f"  poses received by the client per second: {_mmm(run['poses_per_s'])}", flush=True)  # type: ignore[arg-type]
    return 0


if __name__ == "__main__":
    sys.exit(main())
