"""A fleet across several hosts that survives a partition (issue #29, items 4 and 5).

docs/fleets.md's "Several hosts" recipe, its commands as written (the site router's address, the file
paths and ``--no-multicast-scouting`` filled in), on three hosts made of Linux network namespaces: the
site and fleet hosts a and b, each with one veth link to a fourth namespace, the LAN, which forwards
between them as a switch would (10.77.0.0/16, addresses that exist only inside the namespaces this
test makes). Host a runs a1 a2 a3, host b b1 b2 b3 (a router, a simulator, a gateway and an odometry
process each). At the site a probe (a Zenoh client of the site router) watches the gateways'
liveliness and the poses, and drives b1 and a2 at 10 Hz; on host b another probe subscribes to the
whole fleet (``fleet/**``) and records b1's and b2's true pose.

The cut is a pulled cable: in the LAN, two blackhole rules drop every packet from host b and every
packet to it, silently. Neither host is told anything, no reset, no unreachable network, no carrier
lost: their TCP connections stay established, only the Zenoh lease can tell, and b's attempts to
reconnect hang on TCP's retransmissions (1 s, 3 s, 7 s ...) as behind a real dead link. (``ip link
set down`` on b's end would be gentler: b's own kernel would refuse its reconnect attempts at once,
"network unreachable", and the site's end would lose its carrier; dropping in the site's or b's own
namespace, with a queue that drops all, would make the kernel resend every 0.5 s without backing off,
which a pulled cable does not.) The heal deletes the two rules.

Asserted, as the issue asks: every robot of a and b seen from the site; a command to b1 moves b1 alone;
across the cut and the heal, a's poses reach the site with no gap over 0.5 s; b1, driven from the site,
brakes within its command timeout + 0.3 s of the cut; the site marks b's robots lost within 3 s of the
cut and back within 3 s of the heal; no stale command moves b1 after the heal, a new one drives it;
nothing restarted, no Traceback anywhere. Beyond the issue's list: a2, driven from the site throughout,
never stops (commands to the other host never pause). The figures are printed (``-s``, or ``-rP``
under xdist).
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
from helpers import TIMEOUT, Child, wait_for

from blackmetal.runtime.harness import ServiceProcess

ROOT = Path(__file__).resolve().parents[3]
SECTION = "## Several hosts"
#: The site router's address in the recipe, replaced by its address on the LAN.
SITE_PLACEHOLDER = "tcp/site-router.local:7447"
HOSTS = ("a", "b")
ROBOTS = {host: [f"{host}{k}" for k in (1, 2, 3)] for host in HOSTS}
#: The issue's limits.
MAX_GAP_S = 0.5
BRAKE_MARGIN_S = 0.3
MAX_LOST_S = 3.0
MAX_BACK_S = 3.0
#: How long everything runs undisturbed before the cut (the gaps between poses then are the machine's, not the cut's).
STEADY_S = 3.0
#: How long the cut lasts at least: the lease runs out (2 s) and the gap is measured well after. Longer cuts (4 to 12 s)
#: occasionally meet a limit of Zenoh 1.10, the old TCP link's 10 s linger delaying the rejoin: measured and documented
#: in docs/fleets.md ("When it comes back"), not asserted here.
CUT_AT_LEAST_S = 4.0
DRIVE = json.dumps({"linear": {"x": 0.3}})
SLOW = json.dumps({"linear": {"x": 0.05}})

#: A Zenoh client in one namespace, driven line by line on stdin; replies are one JSON line each, marked "@@ ".
#: It records the arrival time (time.monotonic(): the same clock in every namespace) of every sample on its
#: recorded keys, with the pose's x and v, and the liveliness of every gateway.
PROBE = r"""
import json, sys, threading, time, zenoh
from blackmetal.runtime.harness import announce_ready
spec = json.loads(sys.argv[1])
conf = zenoh.Config.from_json5(json.dumps({
    "mode": "client", "connect": {"endpoints": [spec["endpoint"]]},
    "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}}))
lock = threading.Lock()
series = {key: [] for key in spec["record"]}
counts = {}
events = []
alive = set()
def on_sample(sample):
    t = time.monotonic()
    key = str(sample.key_expr)
    with lock:
        counts[key] = counts.get(key, 0) + 1
    if key in series:
        pose = json.loads(sample.payload.to_bytes())
        with lock:
            series[key].append((t, pose["x"], pose["v"], pose["stamp"]))
def on_alive(sample):
    t = time.monotonic()
    key = str(sample.key_expr)
    put = sample.kind == zenoh.SampleKind.PUT
    with lock:
        events.append((t, "PUT" if put else "DELETE", key))
        (alive.add if put else alive.discard)(key)
session = zenoh.open(conf)
subscribers = [session.declare_subscriber(spec["broad"], on_sample)] if spec.get("broad") else [
    session.declare_subscriber(key, on_sample) for key in spec["record"]]
subscribers.append(session.liveliness().declare_subscriber("fleet/*/alive/gateway", on_alive, history=True))
drivers = {}
def drive(key, payload, period, stop):
    publisher = session.declare_publisher(key)
    while True:
        publisher.put(payload)
        if stop.wait(period):
            break
    publisher.undeclare()
announce_ready("probe")
for line in sys.stdin:
    cmd = json.loads(line)
    op = cmd["op"]
    with lock:
        if op == "state":
            reply = {"alive": sorted(alive), "events": list(events), "counts": dict(counts)}
        elif op == "series":
            reply = {"series": [p for p in series[cmd["key"]] if p[0] >= cmd.get("since", 0.0)]}
        elif op == "last":
            reply = {"last": series[cmd["key"]][-1] if series[cmd["key"]] else None}
        else:
            reply = None
    if op == "drive":
        stop = threading.Event()
        thread = threading.Thread(target=drive, args=(cmd["key"], cmd["payload"], 1.0 / cmd["hz"], stop), daemon=True)
        drivers[cmd["key"]] = (stop, thread)
        thread.start()
        reply = {"t": time.monotonic()}
    elif op == "halt":
        stop, thread = drivers.pop(cmd["key"])
        stop.set()
        thread.join(5)
        reply = {"t": time.monotonic()}
    elif op == "quit":
        break
    print("@@ " + json.dumps(reply), flush=True)
for stop, thread in drivers.values():
    stop.set()
    thread.join(5)
session.close()
"""


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)
    if check and result.returncode != 0:
        raise AssertionError(f"ip {' '.join(args)}: {result.stderr.strip()}")
    return result


class Net:
    """The hosts' namespaces (``ns["site"]``, ``ns["a"]``, ``ns["b"]``) and the LAN between them (``ns["lan"]``).

    Each host has one veth link to the LAN namespace, which forwards between them as a switch would:
    the site at 10.77.0.1, host a at 10.77.1.2, host b at 10.77.2.2, each LAN end at .254 of its subnet.
    """

    SITE_ADDR = "10.77.0.1"
    #: The priority of the LAN's rules that cut a host off (before its main routing table, 32766).
    CUT_PREF = 100

    def __init__(self, tag: str) -> None:
        self.ns = {role: f"bmmh{tag}{role}" for role in ("lan", "site", *HOSTS)}
        self.roles = ("site", *HOSTS)
        self.subnet = {role: f"10.77.{index}" for index, role in enumerate(self.roles)}
        self.lan_end = {role: f"bm{tag}l{role[0]}" for role in self.roles}  # in the LAN's namespace
        self.host_end = {role: f"bm{tag}{role[0]}l" for role in self.roles}  # in the host's namespace

    def launcher(self, role: str) -> list[str]:
        return ["ip", "netns", "exec", self.ns[role]]

    def cut(self, host: str) -> None:
        """Every packet from ``host`` and to it vanishes in the LAN, as behind a pulled cable (the module's docstring)."""
        lan = self.ns["lan"]
        _ip("-n", lan, "rule", "add", "pref", str(self.CUT_PREF), "iif", self.lan_end[host], "blackhole")
        _ip("-n", lan, "rule", "add", "pref", str(self.CUT_PREF + 1), "to", f"{self.subnet[host]}.0/24", "blackhole")

    def heal(self) -> None:
        for pref in (self.CUT_PREF, self.CUT_PREF + 1):
            _ip("-n", self.ns["lan"], "rule", "del", "pref", str(pref), check=False)


@pytest.fixture
def net() -> Iterator[Net]:
    """Namespaces site, a, b and their LAN; every namespace and link removed afterwards, even on failure."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("hosts as network namespaces need root and iproute2's ip")
    net = Net(uuid.uuid4().hex[:5])
    made: list[str] = []
    try:
        for ns in net.ns.values():
            result = _ip("netns", "add", ns, check=False)
            if result.returncode != 0:
                pytest.skip(f"network namespaces cannot be made here: {result.stderr.strip()}")
            made.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        lan = net.ns["lan"]
        forward = "open('/proc/sys/net/ipv4/ip_forward', 'w').write('1')"  # in the LAN's namespace only
        forwarding = subprocess.run([*net.launcher("lan"), sys.executable, "-c", forward], capture_output=True, text=True, timeout=20)
        assert forwarding.returncode == 0, forwarding.stderr
        for role in net.roles:
            host, subnet = net.ns[role], net.subnet[role]
            _ip("link", "add", net.lan_end[role], "netns", lan, "type", "veth", "peer", "name", net.host_end[role], "netns", host)
            _ip("-n", lan, "addr", "add", f"{subnet}.254/24", "dev", net.lan_end[role])
            _ip("-n", host, "addr", "add", f"{subnet}.{1 if role == 'site' else 2}/24", "dev", net.host_end[role])
            _ip("-n", lan, "link", "set", net.lan_end[role], "up")
            _ip("-n", host, "link", "set", net.host_end[role], "up")
            _ip("-n", host, "route", "add", "10.77.0.0/16", "via", f"{subnet}.254")
        yield net
    finally:
        for role in net.roles:
            _ip("-n", net.ns["lan"], "link", "del", net.lan_end[role], check=False)  # both ends go with it
        for ns in made:
            _ip("netns", "del", ns, check=False)


class Probe(ServiceProcess):
    """The PROBE script in one namespace; :meth:`ask` sends one command and returns its reply."""

    def __init__(self, net: Net, role: str, endpoint: str, record: list[str], broad: str | None = None) -> None:
        spec = json.dumps({"endpoint": endpoint, "record": record, "broad": broad})
        super().__init__(f"probe-{role}", ["-c", PROBE, spec], launcher=net.launcher(role), interactive=True)

    def ask(self, op: str, **args: Any) -> dict[str, Any]:
        line = self.request(json.dumps({"op": op, **args}), timeout=TIMEOUT)
        deadline = time.monotonic() + TIMEOUT
        while not line.startswith("@@ "):  # anything else the process printed
            assert self._replies is not None and time.monotonic() < deadline, f"{self.name} did not answer {op}:\n{self.output()}"
            line = self._replies.get(timeout=TIMEOUT)
        reply: dict[str, Any] = json.loads(line[3:])
        return reply

    def alive(self) -> set[str]:
        return {key.split("/")[1] for key in self.ask("state")["alive"]}

    def events(self, kind: str, since: float) -> dict[str, float]:
        """The first liveliness event of ``kind`` after ``since``, per robot id."""
        first: dict[str, float] = {}
        for t, what, key in self.ask("state")["events"]:
            if what == kind and t >= since:
                first.setdefault(key.split("/")[1], t)
        return first

    def last(self, key: str) -> tuple[float, float, float, float] | None:
        """The latest sample on a recorded key: (arrival time, x, v, stamp)."""
        last = self.ask("last", key=key)["last"]
        return None if last is None else (last[0], last[1], last[2], last[3])

    def series(self, key: str, since: float = 0.0) -> list[tuple[float, float, float, float]]:
        return [(t, x, v, stamp) for t, x, v, stamp in self.ask("series", key=key, since=since)["series"]]


def recipe() -> tuple[list[list[str]], str, list[list[str]]]:
    """docs/fleets.md's several-hosts recipe: the site's commands, host a's fleet file, a fleet host's commands."""
    text = (ROOT / "docs" / "fleets.md").read_text()
    text = text[text.index(SECTION) :]

    def block(lang: str, nth: int) -> str:
        at = -1
        for _ in range(nth + 1):
            at = text.index(f"```{lang}\n", at + 1)
        start = at + len(f"```{lang}\n")
        return text[start : text.index("```", start)]

    def commands(script: str) -> list[list[str]]:
        found = []
        for line in script.splitlines():
            argv = shlex.split(line, comments=True)
            if argv and argv[-1] == "&":
                argv.pop()
            if argv:
                assert argv[0] == "blackmetal", f"not a blackmetal command in the recipe: {line}"
                found.append(argv)
        return found

    return commands(block("sh", 0)), block("toml", 0), commands(block("sh", 1))


def filled(argv: list[str], tmp_path: Path, host: str | None, site: str | None) -> list[str]:
    """A recipe command as ``python -m blackmetal ...``: paths made absolute, host a's fleet file as ``host``'s, the site's address."""
    out = ["-m", "blackmetal"]
    for word in argv[1:]:
        if word.startswith("deploy/"):
            word = str(ROOT / word)
        elif word == "a.toml" and host is not None:
            word = str(tmp_path / f"{host}.toml")
        elif word == SITE_PLACEHOLDER and site is not None:
            word = f"tcp/{site}:7447"
        out.append(word)
    return [*out, "--no-multicast-scouting"]


def max_gap(times: list[float], start: float, end: float) -> tuple[float, float]:
    """The longest time without a sample in [start, end], and when it began."""
    inside = [start, *(t for t in times if start < t < end), end]
    return max((b - a, a) for a, b in pairwise(inside))


def test_the_routers_configs_hold_the_figures_the_docs_give() -> None:
    """The lease, keep-alive, reconnect and open timeout docs/fleets.md explains, as Zenoh reads the shipped files."""
    import zenoh

    def get(conf: zenoh.Config, key: str) -> Any:
        return json.loads(conf.get_json(key))

    site = zenoh.Config.from_file(str(ROOT / "deploy" / "zenoh" / "site-router.json5"))
    host = zenoh.Config.from_file(str(ROOT / "deploy" / "zenoh" / "fleet-host-router.json5"))
    for conf in (site, host):
        assert get(conf, "mode") == "router"
        assert (get(conf, "transport/link/tx/lease"), get(conf, "transport/link/tx/keep_alive")) == (2000, 8)
        assert get(conf, "scouting/multicast/enabled") is False
    assert get(site, "listen/endpoints") == ["tcp/[::]:7447"]
    assert get(host, "listen/endpoints") == ["tcp/127.0.0.1:7447"] and get(host, "connect/endpoints") == [SITE_PLACEHOLDER]
    assert get(host, "connect/retry") == {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2.0}
    assert (get(host, "connect/timeout_ms"), get(host, "connect/exit_on_failure")) == (-1, False)
    assert get(host, "transport/unicast/open_timeout") == 1500


@pytest.mark.integration  # about 15 s; slow too, as every integration test (conftest.py)
def test_a_fleet_on_two_hosts_survives_a_host_cut_off_and_back(net: Net, children: list[Child], tmp_path: Path) -> None:
    site_cmds, a_toml, host_cmds = recipe()
    assert [c[:2] for c in site_cmds] == [["blackmetal", "router"], ["blackmetal", "robots"], ["blackmetal", "teleop"]], site_cmds
    assert [c[:2] for c in host_cmds] == [
        ["blackmetal", "router"],
        ["blackmetal", "sim"],
        ["blackmetal", "gateway"],
        ["blackmetal", "odometry"],
    ]
    assert SITE_PLACEHOLDER in host_cmds[0] and a_toml.count("[[robot]]") == 3
    for host in HOSTS:
        (tmp_path / f"{host}.toml").write_text(a_toml.replace('id = "a', f'id = "{host}'))

    # the site router, then each host's router and fleet, as the recipe says
    router = Child(filled(site_cmds[0], tmp_path, None, None), launcher=net.launcher("site"))
    children.append(router)
    router.ready()
    gateways: dict[str, dict[str, Any]] = {}
    for host in HOSTS:
        started = []
        for argv in host_cmds:
            child = Child(filled(argv, tmp_path, host, net.SITE_ADDR), launcher=net.launcher(host))
            children.append(child)
            started.append(child)
        for child, argv in zip(started, host_cmds, strict=True):
            info = child.ready()
            if argv[1] == "gateway":
                gateways[host] = info
    cmd_timeout = float(gateways["b"]["cmd_timeout"])

    site = Probe(net, "site", "tcp/127.0.0.1:7447", ["fleet/a1/pose", "fleet/b1/pose", "fleet/b2/pose", "fleet/a2/sim/truth"])
    on_b = Probe(net, "b", "tcp/127.0.0.1:7447", ["fleet/b1/sim/truth", "fleet/b2/sim/truth"], broad="fleet/**")
    probes = [site, on_b]
    try:
        for probe in probes:
            probe.wait_ready(TIMEOUT)

        # 1. every robot of a and b seen from the site: by liveliness, and by the recipe's `blackmetal robots`
        everyone = {*ROBOTS["a"], *ROBOTS["b"]}
        wait_for(lambda: site.alive() == everyone, timeout=30, what="the six gateways alive at the site")
        listed = subprocess.run([*net.launcher("site"), sys.executable, *filled(site_cmds[1], tmp_path, None, None)],
                                capture_output=True, text=True, timeout=60)  # fmt: skip
        assert listed.returncode == 0 and listed.stdout.split() == sorted(f"fleet/{r}" for r in everyone), listed.stdout + listed.stderr
        for key in ("fleet/a1/pose", "fleet/b1/pose", "fleet/b2/pose"):
            wait_for(lambda key=key: site.last(key) is not None, what=f"{key} at the site")
        for key in ("fleet/b1/sim/truth", "fleet/b2/sim/truth"):
            wait_for(lambda key=key: on_b.last(key) is not None, what=f"{key} on host b")

        # 2. a command from the site to b1 moves b1 alone
        site.ask("drive", key="fleet/b1/cmd_vel", payload=DRIVE, hz=10)
        wait_for(lambda: (p := on_b.last("fleet/b1/sim/truth")) is not None and p[2] > 0.25 and p[1] > 0.2, what="b1 driving")
        wait_for(lambda: (p := site.last("fleet/b1/pose")) is not None and p[1] > 0.2, what="b1's pose moving at the site")
        for key in ("fleet/a1/pose", "fleet/b2/pose"):
            still = site.last(key)
            assert still is not None and abs(still[1]) < 1e-9 and still[2] == 0.0, f"{key} moved: {still}"
        b2 = on_b.last("fleet/b2/sim/truth")
        assert b2 is not None and abs(b2[1]) < 1e-9 and b2[2] == 0.0, b2

        # meanwhile the site drives a2 too, slowly: commands to the other host must not stall either
        site.ask("drive", key="fleet/a2/cmd_vel", payload=SLOW, hz=10)
        wait_for(lambda: (p := site.last("fleet/a2/sim/truth")) is not None and p[2] > 0.04, what="a2 driving")

        # a while as it is, to compare: the largest gap between a1's poses at the site with every link up
        t_steady = time.monotonic()
        wait_for(lambda: time.monotonic() > t_steady + STEADY_S, timeout=STEADY_S + 1, interval=0.1)

        # 3.-5. b's link cut while b1 is driven from the site and host b subscribes to the whole fleet
        t_cut = time.monotonic()
        net.cut("b")
        try:
            lost = wait_for(lambda: set(ROBOTS["b"]) <= set(e := site.events("DELETE", t_cut)) and e, timeout=15,
                            what="b's robots lost at the site")  # fmt: skip
            stopped = wait_for(lambda: next((p for p in on_b.series("fleet/b1/sim/truth", t_cut) if p[2] == 0.0), None),
                               timeout=10, what="b1 braking on host b")  # fmt: skip
            assert site.alive() == set(ROBOTS["a"]), site.ask("state")["events"]
            wait_for(lambda: time.monotonic() > t_cut + CUT_AT_LEAST_S, timeout=CUT_AT_LEAST_S + 1, interval=0.1)
            site.ask("halt", key="fleet/b1/cmd_vel")  # the stream the cut interrupted ends while b is away
        finally:
            t_heal = time.monotonic()
            net.heal()
        back = wait_for(lambda: set(ROBOTS["b"]) <= set(e := site.events("PUT", t_heal)) and e, timeout=15,
                        what="b's robots back at the site")  # fmt: skip
        wait_for(lambda: site.alive() == everyone, what="all six alive again")
        t_back = max(back.values())
        # the site keeps receiving a's poses for a while after b's return
        wait_for(lambda: time.monotonic() > t_back + 1.0, timeout=5, interval=0.1)

        # 6. nothing sent while b was away moves b1 once it is back; a new command from the site does
        idle = on_b.series("fleet/b1/sim/truth", stopped[0])
        assert idle and all(p[2] == 0.0 for p in idle), [p for p in idle if p[2] != 0.0][:5]
        a2 = site.series("fleet/a2/sim/truth", t_cut)
        a2_stopped = [round(p[0] - t_cut, 3) for p in a2 if p[0] <= t_back + 1.0 and p[2] == 0.0]
        site.ask("halt", key="fleet/a2/cmd_vel")
        x_before = on_b.last("fleet/b1/sim/truth")
        assert x_before is not None
        site.ask("drive", key="fleet/b1/cmd_vel", payload=DRIVE, hz=10)
        wait_for(lambda: (p := on_b.last("fleet/b1/sim/truth")) is not None and p[1] > x_before[1] + 0.1, what="b1 driving again")
        wait_for(lambda: (p := site.last("fleet/b1/pose")) is not None and p[1] > x_before[1] + 0.1, what="b1's new pose at the site")
        site.ask("halt", key="fleet/b1/cmd_vel")

        a_poses = site.series("fleet/a1/pose", t_steady)
        gap_steady, _ = max_gap([p[0] for p in a_poses], t_steady, t_cut)
        gap_cut, _ = max_gap([p[0] for p in a_poses], t_cut - 0.5, t_heal)
        gap_all, gap_at = max_gap([p[0] for p in a_poses], t_cut - 0.5, t_back + 1.0)
        # the same poses by their stamps (taken on host a): a gap there too is host a's (or the machine's) stall, not the network's
        around = [p[3] for p in a_poses if gap_at - 0.5 <= p[0] <= gap_at + gap_all + 0.5]
        stamped = max((b - a for a, b in pairwise(around)), default=0.0)
        brake = stopped[0] - t_cut
        lost_s = max(lost[r] for r in ROBOTS["b"]) - t_cut
        back_s = t_back - t_heal
        print(
            f"\nseveral hosts (cut {t_heal - t_cut:.1f} s): a1's poses at the site, largest gap {gap_all * 1000:.0f} ms "
            f"({gap_cut * 1000:.0f} ms during the cut, {gap_steady * 1000:.0f} ms in the {STEADY_S:g} s before it; it began {gap_at - t_cut:+.2f} s after the cut, the poses' stamps "
            f"{stamped * 1000:.0f} ms apart there); b1 stopped {brake:.3f} s after the cut (cmd_timeout {cmd_timeout:g} s); "
            f"b1-b3 lost at the site {lost_s:.3f} s after the cut, back {back_s:.3f} s after the heal; a2 never stopped: {not a2_stopped}"
        )
        assert gap_all <= MAX_GAP_S, f"a's poses stalled {gap_all:.3f} s at the site"
        assert brake <= cmd_timeout + BRAKE_MARGIN_S, f"b1 stopped {brake:.3f} s after the cut"
        assert not a2_stopped, f"a2, driven from the site, stopped at {a2_stopped[:5]} s after the cut: its commands stalled"
        assert lost_s <= MAX_LOST_S, f"b's robots were marked lost {lost_s:.3f} s after the cut"
        assert back_s <= MAX_BACK_S, f"b's robots were back {back_s:.3f} s after the heal"
        assert not site.events("DELETE", 0.0).keys() & set(ROBOTS["a"]), "a robot of host a was marked lost"

        # nothing restarted, nothing crashed
        for child in [*children, *probes]:
            assert child.poll() is None, f"{child.name} exited with {child.poll()}:\n{child.output()}"
    finally:
        for probe in probes:
            if probe.poll() is None and probe.proc.stdin is not None:
                try:
                    probe.proc.stdin.write(json.dumps({"op": "quit"}) + "\n")  # it closes its session and exits
                    probe.proc.stdin.flush()
                except OSError:
                    pass
                try:
                    probe.wait(10)
                except subprocess.TimeoutExpired:
                    pass
            probe.stop()
    for child in [*children, *probes]:
        assert "Traceback" not in child.output(), f"{child.name}:\n{child.output()}"
