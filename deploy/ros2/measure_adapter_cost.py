"""What the ROS 2 fleet adapter costs (#29): CPU of ``blackmetal ros2 --fleet`` idle and with one subscriber on every /odom.

    python deploy/ros2/measure_adapter_cost.py 20 100 --windows 3 --seconds 10

Per fleet size: a router, ``sim --robots N``, ``gateway --fleet`` at 50 Hz,
``odometry --fleet`` and ``ros2 --fleet``, all on loopback. CPU (utime +
stime of each process) over ``--windows`` windows of ``--seconds`` each,
first with no ROS subscriber anywhere, then with one Zenoh subscriber on
every robot's ``/odom`` key (what an rmw_zenoh subscription declares; Zenoh's
matching status is what the adapter follows). The ``/odom`` samples it
received per second are printed too. Figures, not a test: the machine may be
shared, so read min/median/max.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import zenoh

from blackmetal.bench.figures import _service, cpu_seconds
from blackmetal.runtime.ports import free_port


def _window(pids: dict[str, int], seconds: float, counter: list[int]) -> tuple[dict[str, float], float]:
    cpu0, n0, t0 = {n: cpu_seconds(p) for n, p in pids.items()}, counter[0], time.monotonic()
    time.sleep(seconds)
    cpu1, n1, t1 = {n: cpu_seconds(p) for n, p in pids.items()}, counter[0], time.monotonic()
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
        procs["ros2"] = _service(stack, "ros2", ["ros2", "--fleet", str(fleet), *endpoint])
        pids = {name: child.proc.pid for name, child in procs.items()}
        time.sleep(3.0)
        received = [0]
        idle = [_window(pids, seconds, received)[0] for _ in range(windows)]
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{zport}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        session = stack.enter_context(zenoh.open(conf))

        def on_odom(sample: zenoh.Sample) -> None:
            received[0] += 1

        session.declare_subscriber("0/*/odom/nav_msgs::msg::dds_::Odometry_/*", on_odom)
        time.sleep(3.0)
        watched = [_window(pids, seconds, received) for _ in range(windows)]
    return {"robots": robots, "idle": idle, "watched": [w[0] for w in watched], "odom_per_s": [w[1] for w in watched]}


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
        for name in ("ros2", "router", "gateway", "odometry", "sim"):
            print(
                f"  {name:<9} idle {_mmm([w[name] for w in idle])}   one subscriber on every /odom {_mmm([w[name] for w in watched])}",  # type: ignore[index,union-attr]
                flush=True,
            )
        print(f"  /odom samples received per second: {_mmm(run['odom_per_s'])}", flush=True)  # type: ignore[arg-type]
    return 0


if __name__ == "__main__":
    sys.exit(main())
