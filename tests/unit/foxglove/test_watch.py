"""A view nobody watches costs almost nothing (#29): it encodes only what a client subscribes to, and follows only those keys.

Pure, at 20 robots: every robot's payloads handed to the fleet view while
no channel has a subscriber build and log nothing, and :class:`Watch`
needs no key; a subscription to ``/r5/pose`` needs ``fleet/r5/pose`` alone
and logs on that channel alone. Against real processes at 20 robots: the
view holds no subscriber on a robot's pose until a Foxglove client (the
official protocol, as the app speaks it) subscribes to ``/r5/pose``, then
follows it and sends the poses, and lets it go when the client unsubscribes.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for, zenoh_listen_args

from blackmetal.foxglove.channels import Kind
from blackmetal.foxglove.fleet_view import FleetView
from blackmetal.foxglove.watch import Watch
from blackmetal.schemas import ErrorReport, GatewayHealth, Keys, LinkHealth, Pose, RobotStatus, WheelImpulses, encode
from unit.foxglove.test_fleet import FleetClient
from unit.foxglove.test_live import protobuf_class

ROBOTS = [f"r{i}" for i in range(1, 21)]


class Counted:
    """A channel that counts what is logged into it; it has sinks while its topic is in ``watched``."""

    def __init__(self, topic: str, watched: set[str], logged: Counter[str]) -> None:
        self.topic, self.watched, self.logged = topic, watched, logged

    def has_sinks(self) -> bool:
        return self.topic in self.watched

    def log(self, msg: Any) -> None:
        self.logged[self.topic] += 1


def counted_fleet(watched: set[str], logged: Counter[str], clock: list[float]) -> FleetView:
    def channel(topic: str, kind: Kind, schema: dict[str, Any] | None) -> Counted:
        return Counted(topic, watched, logged)

    return FleetView([(rid, Keys(f"fleet/{rid}"), None, 100) for rid in ROBOTS], clock=lambda: clock[0], channel=channel)


def payloads(keys: Keys, stamp: float) -> dict[str, bytes]:
    health = GatewayHealth(stamp=stamp, control=LinkHealth("connected"), log=LinkHealth("connected"), poll_hz=50.0)
    return {
        keys.pose: encode(Pose(stamp=stamp, x=1.0, y=2.0, yaw=0.1)),
        keys.sim_truth: encode(Pose(stamp=stamp, x=1.0, y=2.0, yaw=0.1)),
        keys.impulses: encode(WheelImpulses(seq=1, stamp=stamp, left=200, right=-210, mono=stamp)),
        keys.status: encode(RobotStatus(stamp=stamp, state=1, state_name="READY", direction=1, direction_name="NORTH")),
        keys.health: encode(health),
        keys.errors: encode(ErrorReport(stamp=stamp, source="gateway", key=keys.cmd_vel, reason="test")),
    }


def feed_everything(view: FleetView, steps: int = 5) -> None:
    for step in range(steps):
        for rid in ROBOTS:
            handlers = view.handlers(rid)
            for key, payload in payloads(view.views[rid].keys, 100.0 + step * 0.02).items():
                handlers[key](payload)


def test_the_watch_needs_the_keys_of_watched_topics_only_and_forgets_a_client_that_leaves() -> None:
    watch = Watch({"a/pose": {"/pose", "/tf"}, "a/health": {"/health"}, "a/errors": {"/log"}})
    assert watch.needed() == set()
    assert watch.subscribe(1, "/tf") and not watch.subscribe(2, "/tf")
    assert watch.needed() == {"a/pose"}
    assert not watch.unsubscribe(1, "/tf") and watch.needed() == {"a/pose"}, "client 2 still watches /tf"
    assert not watch.unsubscribe(7, "/health"), "an unsubscription nobody made changes nothing"
    watch.subscribe(2, "/log")
    assert watch.client_gone(2) == ["/tf", "/log"] and watch.needed() == set()
    assert Watch(watch.feeds, record_all=True).needed() == {"a/pose", "a/health", "a/errors"}, "an MCAP file records every key"


def test_twenty_robots_nobody_watching_encode_nothing_and_one_watched_pose_encodes_that_pose_alone() -> None:
    watched: set[str] = set()
    logged: Counter[str] = Counter()
    clock = [0.0]
    view = counted_fleet(watched, logged, clock)
    watch = Watch(view.feeds())

    feed_everything(view)
    assert sum(logged.values()) == 0, logged
    assert watch.needed() == set(), "nothing watched: not one key followed"
    assert len(watch.feeds) == 8 * len(ROBOTS)

    watch.subscribe(1, "/r5/pose")
    watched.add("/r5/pose")
    assert watch.needed() == {"fleet/r5/pose"}
    feed_everything(view)
    assert logged == Counter({"/r5/pose": 5}), logged

    watch.subscribe(1, "/r5/robot_description")
    watched.add("/r5/robot_description")
    view.views["r5"].describe()
    assert logged["/r5/robot_description"] == 1 and watch.needed() == {"fleet/r5/pose"}, "the URDF follows no key"

    watch.subscribe(1, "/tf")
    watched.add("/tf")
    needed = {f"fleet/{rid}/{k}" for rid in ROBOTS for k in ("pose", "wheels/impulses", "nav/map_pose")}
    assert watch.needed() == needed, "the map frame too: published when it changes, it costs nothing"
    logged.clear()
    feed_everything(view, steps=1)
    # every robot: odom -> base_footprint from its pose with the URDF's two fixed joints (the first pose), base_link -> each
    # wheel from its impulses
    assert logged == Counter({"/tf": 5 * len(ROBOTS), "/r5/pose": 1}), logged

    assert watch.client_gone(1) and watch.needed() == set()


def test_the_summary_follows_health_only_while_watched_and_goes_out_at_most_once_a_second() -> None:
    watched: set[str] = {"/fleet/summary"}
    logged: Counter[str] = Counter()
    clock = [10.0]
    view = counted_fleet(watched, logged, clock)
    assert Watch(view.feeds(), record_all=False).feeds[Keys("fleet/r1").health] >= {"/fleet/summary", "/fleet/log"}
    for step in range(50):  # 20 robots' health for 2.5 s of the view's clock, 1 s apart each
        clock[0] = 10.0 + step * 0.05
        rid = ROBOTS[step % len(ROBOTS)]
        view.handlers(rid)[Keys(f"fleet/{rid}").health](payloads(Keys(f"fleet/{rid}"), clock[0])[Keys(f"fleet/{rid}").health])
    assert logged == Counter({"/fleet/summary": 3}), logged


@pytest.mark.integration
def test_twenty_robots_the_view_follows_a_pose_only_while_a_client_subscribes(children: list[Child], tmp_path: Path) -> None:
    port = free_port()
    fleet = tmp_path / "fleet.toml"
    sim = Child(["-m", "blackmetal", "sim", "--robots", str(len(ROBOTS)), "--write-fleet", str(fleet), *zenoh_listen_args(port)])
    children.append(sim)
    sim.ready()
    zargs = ["-e", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"]
    gateway = Child(["-m", "blackmetal.gateway", "--fleet", str(fleet), "--poll-hz", "20", *zargs])
    odometry = Child(["-m", "blackmetal.odometry_service", "--fleet", str(fleet), *zargs])
    view = Child(["-m", "blackmetal", "foxglove", "--fleet", str(fleet), "--port", "0", *zargs])
    children += [gateway, odometry, view]
    gateway.ready()
    odometry.ready()
    url = view.ready()["url"]
    with zenoh.open(client_config(port)) as session:
        # nobody but the view subscribes to a robot's pose or truth: a publisher of ours matches only its subscriber
        pose = session.declare_publisher("fleet/r5/pose")
        truth = session.declare_publisher("fleet/r7/sim/truth")
        wait_for(lambda: session.get("fleet/r5/pose", timeout=5), what="r5's pose from the odometry")
        client = FleetClient(url)
        try:
            client.wait(lambda: {"/r5/pose", "/r7/truth/pose", "/fleet/summary"} <= set(client.channels()), "the fleet's channels")
            client.pump(0.5)
            assert not pose.matching_status.matching and not truth.matching_status.matching, "no client subscribes: no key followed"
            assert not any(client.messages.values()), "no client subscribes: nothing sent"

            client.subscribe(1, "/r5/pose")
            wait_for(lambda: pose.matching_status.matching, what="the view to follow fleet/r5/pose")
            client.wait(lambda: len(client.messages[1]) >= 10, "/r5/pose messages")
            pose_class = protobuf_class(client.channels()["/r5/pose"])
            assert {pose_class.FromString(m).frame_id for m in client.messages[1]} == {"r5/odom"}
            assert not truth.matching_status.matching, "only what a client watches is followed"
            assert set(client.messages) == {1}

            client.ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [1]}))
            wait_for(lambda: not pose.matching_status.matching, what="the view to let fleet/r5/pose go")
            client.pump(0.3)
            seen = len(client.messages[1])
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                client.pump(0.05)
            assert len(client.messages[1]) == seen, "nothing sent once unsubscribed"
        finally:
            client.close()
    assert view.stop() == 0
