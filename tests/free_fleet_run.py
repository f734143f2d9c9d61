"""free_fleet's robot adapter calls (tests/free_fleet_client.py) with free_fleet's own pinned packages, in their virtualenv.

free_fleet's README installs ``eclipse-zenoh==1.5.0`` and ``pycdr2``; this script runs with exactly those
(tests/integration/test_open_rmf_edges.py makes the virtualenv and never mixes it with ours), so the
Zenoh version a real fleet adapter has is the one that talks to the robot. Standard library, zenoh and
pycdr2 only. ``python free_fleet_run.py ROUTER_PORT ROBOT X Y YAW``: a client of the router, as
docs/open-rmf.md configures free_fleet, it finds the robot, sends one goal to (X, Y, YAW) on the map and
reads it back, then sends one far goal and stops it (RMF's stop: a cancel-all), and prints one JSON line.
"""

import json
import sys
import time
from importlib.metadata import version
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import zenoh
from free_fleet_client import FreeFleetRobot, GoalStatus


def main() -> None:
    port, name = int(sys.argv[1]), sys.argv[2]
    x, y, yaw = (float(v) for v in sys.argv[3:6])
    config = zenoh.Config.from_json5(
        json.dumps({"mode": "client", "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}, "scouting": {"multicast": {"enabled": False}}})
    )
    out: dict = {"zenoh": version("eclipse-zenoh"), "pycdr2": version("pycdr2")}
    with zenoh.open(config) as session:
        robot = FreeFleetRobot(session, name, service_call_timeout_sec=1.0)
        try:
            out["pose"], out["found_after_s"] = robot.initialize()
            accepted, call = robot.navigate(x, y, yaw)
            out["accepted"], out["accepted_in_s"] = accepted, call.elapsed
            deadline, status = time.monotonic() + 60, None
            while time.monotonic() < deadline:
                done, status = robot.is_navigation_done()
                if done:
                    break
                time.sleep(0.1)
            out["status"] = None if status is None else GoalStatus(status).name
            out["end_pose"] = robot.get_pose()
            accepted, _ = robot.navigate(x + 3.0, y, yaw)
            time.sleep(1.5)
            out["far_accepted"], out["cancel_codes"] = accepted, robot.stop()
            out["feedback_count"], out["battery_soc"], out["errors"] = robot.feedback_count, robot.battery_soc, robot.errors
        finally:
            robot.close()
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
