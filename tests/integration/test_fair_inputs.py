"""The input edge tried as an attacker would: floods of one commander and storms of the e-stop against the gateway process.

The robot is tests/rogue_robot.py (it logs every command with its arrival
time); the attackers are separate processes publishing as fast as Python
can. Priorities must hold, teleop must never time out under a flood of a
lower source, and a storm of e-stop samples must end on its last state at
once, with nothing moving after a final ON.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest
from helpers import FLOODER, wait_for
from rogue_robot import Behaviour

from integration.test_safety_e2e import EMG_STOP, KEYS, VELOCITY, Rig

pytestmark = pytest.mark.integration

#: Toggles the e-stop as fast as it can for argv[2] seconds, then one final ON; prints the final put's monotonic time.
STORM = """
import sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    publisher = session.declare_publisher("robot/estop")
    end, n = time.monotonic() + float(sys.argv[2]), 0
    while time.monotonic() < end:
        publisher.put(b'{"engaged": true}')
        publisher.put(b'{"engaged": false}')
        n += 2
    final = time.monotonic()
    publisher.put(b'{"engaged": true}')
    time.sleep(0.5)
    print(f"{final} {n}", flush=True)
"""


#: Puts on argv[3] distinct names under argv[2] (``robot/lock`` or ``robot/cmd_vel``), from index argv[4], within 10 s.
NAMES = """
import sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
conf.insert_json5("scouting/multicast/enabled", "false")
payload = b'{"locked": true}' if sys.argv[2].endswith("lock") else b'{"linear":{"x":0.5}}'
with zenoh.open(conf) as session:
    end = time.monotonic() + 10
    first = int(sys.argv[4])
    for i in range(first, first + int(sys.argv[3])):
        session.put("%s/n%d" % (sys.argv[2], i), payload)
        if time.monotonic() > end:
            break
    time.sleep(0.5)
    print(i - first + 1, flush=True)
"""


@pytest.fixture
def rig() -> Iterator[Rig]:
    # releases on estop count here (--unsafe-release-on-estop), so that one key carries the storm's ONs and OFFs in order
    made = Rig(Behaviour(), "--unsafe-release-on-estop")
    yield made
    made.close()


def _stop(processes: list[subprocess.Popen[str]]) -> None:
    for process in processes:
        if process.poll() is None:
            process.kill()
        process.wait(10)


def test_teleop_keeps_control_while_two_processes_flood_nav(rig: Rig) -> None:
    teleop = b'{"linear":{"x":0.05}}'  # nav floods 0.10-0.15 m/s: anything above 0.05 at the robot is nav's
    rig.put(KEYS.cmd_vel_of("teleop"), teleop)
    wait_for(lambda: rig.robot.speed == (0.05, 0.05), what="teleop driving")
    flooders = [
        subprocess.Popen([sys.executable, "-c", FLOODER, str(rig.zport), KEYS.cmd_vel_of("nav"), "5", str(n)], text=True) for n in range(2)
    ]
    stop = threading.Event()
    ages: list[float] = []

    def drive_teleop() -> None:
        while not stop.wait(0.05):  # 20 Hz, as a joystick node
            rig.session.put(KEYS.cmd_vel_of("teleop"), teleop)

    driver = threading.Thread(target=drive_teleop, daemon=True)
    driver.start()
    start = time.monotonic()
    try:
        time.sleep(1.0)  # the flood is on
        while time.monotonic() - start < 4.5:
            health = rig.health()
            assert health.active_source == "teleop", health
            ages.append(health.sources["teleop"].age or 0.0)
            time.sleep(0.2)
        nav = rig.health().sources["nav"]
    finally:
        stop.set()
        driver.join(5)
        _stop(flooders)
    sent = rig.robot.commands(VELOCITY, since=start)
    print(f"teleop's age under the flood: max {max(ages):.3f} s; nav dropped {nav.dropped}, superseded {nav.superseded}")
    # the flood was real, and counted against nav (what Zenoh's ring drops while nav floods is not counted: under load, few)
    assert nav.dropped + nav.superseded > 200
    assert all(wheels is not None and max(abs(w) for w in wheels) <= 0.05 + 1e-9 for _, wheels in sent), sent[:10]
    assert max(ages) < 0.5  # teleop never timed out


def test_an_estop_storm_ends_on_its_final_on_at_once_and_nothing_moves_after_it(rig: Rig) -> None:
    stop = threading.Event()

    def drive() -> None:
        while not stop.wait(0.005):  # 200 Hz
            rig.session.put(KEYS.cmd_vel, b'{"linear":{"x":0.3}}')

    driver = threading.Thread(target=drive, daemon=True)
    driver.start()
    try:
        wait_for(lambda: rig.robot.speed == (0.3, 0.3), what="the robot driving")
        storm = subprocess.run([sys.executable, "-c", STORM, str(rig.zport), "2"], capture_output=True, text=True, timeout=60)
        final_text, toggles = storm.stdout.split()
        final = float(final_text)
        time.sleep(1.0)  # the 200 Hz stream goes on after the final ON
    finally:
        stop.set()
        driver.join(5)
    moving = [t for t, w in rig.robot.commands(VELOCITY) if w is not None and any(w)]
    last_stop = rig.robot.commands(EMG_STOP)[-1][0]  # the EMG_STOP that left the robot stopped (the final ON's, or one
    # of the storm's ONs that the final ON found still engaged)
    print(
        f"{toggles} e-stop samples in 2 s; last moving command {1000 * (moving[-1] - final):+.1f} ms from the final ON, "
        f"the last EMG_STOP {1000 * (last_stop - final):+.1f} ms"
    )
    # the robot got its EMG_STOP within 100 ms of the final ON on a quiet machine (-5 to +17 ms measured), 176 ms once
    # with two other workers on the two cores; before the fix it came 1.1-1.9 s late, behind the storm's backlog
    assert last_stop - final <= 0.3
    assert moving[-1] < last_stop  # and nothing moved after it, with 200 commands a second still coming for 1 s
    assert rig.health().estop


@pytest.fixture
def locked_rig() -> Iterator[Rig]:
    made = Rig(Behaviour(), "--lock", "pause:200")
    yield made
    made.close()


def test_names_a_client_invents_create_no_state_and_a_bounded_number_of_reports(locked_rig: Rig) -> None:
    rig = locked_rig
    # warm-up, a whole round of other names: the allocator's and Zenoh's buffers reach what a flood takes (on a loaded
    # machine a backlog takes more), so what the measured round adds is per-name state, which there must be none of
    for family in ("robot/lock", "robot/cmd_vel"):
        subprocess.run(
            [sys.executable, "-c", NAMES, str(rig.zport), family, "100000", "500000"], check=True, timeout=60, capture_output=True
        )
    time.sleep(2.5)  # the warm-up's flood is over
    rss_before = rig.rss_mb()
    for family in ("robot/lock", "robot/cmd_vel"):
        reports_before = len(rig.errors)
        names = subprocess.Popen(
            [sys.executable, "-c", NAMES, str(rig.zport), family, "100000", "10000"], stdout=subprocess.PIPE, text=True
        )
        latencies = []
        try:
            while names.poll() is None:
                latencies.append(rig.estop_latency())
                rig.release()
                time.sleep(0.3)
            sent = int(names.stdout.read() if names.stdout else 0)
        finally:
            _stop([names])
        time.sleep(2.5)  # the reporter's last summaries
        reports = len(rig.errors) - reports_before
        print(f"{family}/<100k names>: {sent} sent, {reports} error reports, e-stop {[round(x * 1e3, 1) for x in latencies]} ms")
        assert sent >= 20_000  # the attack was real
        assert reports <= 200
        assert latencies and max(latencies) <= 0.1
    time.sleep(1.0)
    rss_after = rig.rss_mb()
    print(f"RSS {rss_before:.1f} -> {rss_after:.1f} MB")
    # 200 000 invented names: the per-name tables this replaced grew 4.3-5.1 MB per 100 000 and never shrank. The
    # gateway's RSS itself moves by +-6 MB between two quiet moments (Zenoh's and the allocator's buffers after a
    # flood: -5.9, +4.9 and +0.1 MB in three runs of this test), so the bound here catches state of 60 bytes a name
    # and more; tests/unit/runtime/test_reports_limits.py holds the reporter's tables to their bound exactly.
    assert rss_after - rss_before <= 10.0
