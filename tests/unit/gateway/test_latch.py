"""The e-stop latch outlives the gateway: kept on disk, read before the first command, released only once saved.

Fast: the store, the start rules and the core's two-phase release on a fake clock, and the host's order (the
EMG_STOP bytes leave before the save) over the in-memory robot. The kills of real gateways (standalone, under
``up``, in a fleet, as the systemd unit starts it) are in tests/integration/test_estop_restarts.py.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import pytest
from helpers import MemoryLatchStore, RecordingOutput

from blackmetal import wire
from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.host import GatewayHost
from blackmetal.gateway.latch import AT_START, FileLatchStore, Latch, Untrusted, latch_path, start_latch
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.schemas import ErrorReport, GatewayHealth
from blackmetal.sim.memory import MemoryConnector
from blackmetal.sim.physics import SimRobot
from blackmetal.sim.server import SimServer
from blackmetal.transport import ByteStream
from blackmetal.wire import CommandCode
from unit.gateway.test_core import WALL0, Bench

ENGAGE = b'{"engaged": true}'
RELEASE = b'{"engaged": false}'


def store(tmp_path: Path, prefix: str = "robot") -> FileLatchStore:
    return FileLatchStore(latch_path(str(tmp_path), prefix), prefix)


# ---------------------------------------------------------------------- the store and the start rules


def test_a_saved_latch_reads_back_and_a_fleet_prefix_gets_a_file_of_its_own(tmp_path: Path) -> None:
    one, other = store(tmp_path, "fleet/r3"), store(tmp_path, "fleet/r30")
    assert one.path != other.path and one.path.parent == tmp_path / "estop"
    assert one.save(Latch(True, 1.5, "fleet/r3/estop")) is None
    assert one.load() == Latch(True, 1.5, "fleet/r3/estop")
    assert json.loads(one.path.read_text()) == {"prefix": "fleet/r3", "engaged": True, "since": 1.5, "by": "fleet/r3/estop"}
    assert isinstance(other.load(), Untrusted) and list(one.path.parent.iterdir()) == [one.path]  # no temporary file left


def test_no_saved_state_starts_engaged_and_says_why_in_one_sentence(tmp_path: Path) -> None:
    latch, sentence = start_latch(store(tmp_path), WALL0)
    assert latch.engaged and latch.by.startswith(AT_START)
    assert sentence is not None and "\n" not in sentence
    assert "no saved e-stop state at" in sentence and "blackmetal estop off" in sentence
    assert store(tmp_path).load() == latch  # saved at once: the next start finds it engaged too


def test_unsafe_start_released_releases_only_a_missing_state(tmp_path: Path) -> None:
    latch, sentence = start_latch(store(tmp_path), WALL0, missing_released=True)
    assert not latch.engaged and sentence is None
    store(tmp_path).path.write_text("{not json")
    latch, sentence = start_latch(store(tmp_path), WALL0, missing_released=True)
    assert latch.engaged and sentence is not None and "is corrupt" in sentence


@pytest.mark.parametrize("damage", ["corrupt", "empty", "another prefix", "unreadable", "unwritable"])
def test_a_state_that_cannot_be_trusted_or_kept_starts_engaged(tmp_path: Path, damage: str) -> None:
    state_dir = tmp_path / "state"
    kept = store(state_dir)
    kept.save(Latch(False, 1.0, "robot/estop/release"))
    if damage == "corrupt":
        kept.path.write_bytes(b'{"prefix": "robot", "engaged": "maybe"}')
    elif damage == "empty":
        kept.path.write_bytes(b"")
    elif damage == "another prefix":
        kept.path.write_text(json.dumps({"prefix": "fleet/r1", "engaged": False, "since": 1.0, "by": "x"}))
    elif damage == "unreadable":  # root reads any file: a folder in its place cannot be read by anyone
        kept.path.unlink()
        kept.path.mkdir()
    else:  # the state folder is a file: nothing can be saved under it
        state_dir = tmp_path / "a-file"
        state_dir.write_text("")
        kept = store(state_dir)
    latch, sentence = start_latch(kept, WALL0, missing_released=True)
    assert latch.engaged, damage
    assert sentence is not None and sentence.count("\n") == 0 and str(kept.path) in sentence, sentence
    print(f"{damage}: {sentence}")


# ---------------------------------------------------------------------- the core: engage at once, release once saved


def test_an_engage_is_saved_once_with_its_key_and_time_and_health_says_so() -> None:
    bench = Bench()
    bench.connect()
    bench.run(0.5)
    bench.conn.on_estop(read_estop(ENGAGE), bench.t)
    bench.settle()
    bench.conn.on_estop(read_estop(ENGAGE), bench.t + 0.1)  # an engage repeated (as tools do until confirmed) changes nothing kept
    bench.settle()
    assert bench.latch.saves == [Latch(True, WALL0 + 0.5, "robot/estop")]
    health = bench.conn.health(bench.t)
    assert health.estop and health.estop_since == WALL0 + 0.5 and health.estop_by == "robot/estop"
    assert health.estop_text().startswith("ENGAGED since ") and health.estop_text().endswith(" by robot/estop")


def test_a_release_takes_effect_only_once_saved() -> None:
    bench = Bench()
    bench.connect()
    bench.conn.on_estop(read_estop(ENGAGE), bench.t)
    bench.settle()
    bench.conn.on_estop(read_estop(RELEASE, release_key=True), bench.t)
    assert bench.conn.governor.estop  # not before the host saved it
    latch = bench.conn.take_latch()
    assert latch is not None and not latch.engaged and latch.by == "robot/estop/release"
    bench.conn.latch_saved(latch, None, bench.t)
    assert not bench.conn.governor.estop and bench.conn.health(bench.t).estop_by == "robot/estop/release"


def test_a_release_that_cannot_be_saved_is_refused_and_the_stop_stays() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.latch.failing = "the e-stop state cannot be saved to /x (Read-only file system): check ..."
    bench.connect()
    bench.conn.on_estop(read_estop(ENGAGE), bench.t)
    bench.settle()
    bench.conn.on_estop(read_estop(RELEASE, release_key=True), bench.t)
    bench.settle()
    bench.cmd(b'{"linear":{"x":0.2}}')
    assert bench.conn.governor.estop and not bench.robot.moving
    reasons = [e.reason for e in bench.of(ErrorReport)]
    assert any(r.startswith("the e-stop is engaged, but the e-stop state cannot be saved") for r in reasons), reasons
    assert any(r.startswith("the release is refused, the e-stop stays engaged: the e-stop state cannot be saved") for r in reasons)


def test_a_gateway_that_starts_engaged_sends_emg_stop_before_anything_that_moves() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.conn = bench.conn.__class__(bench.conn.settings, 0.0, lambda: WALL0 + bench.t, latch=Latch(True, 5.0, "robot/estop"))
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.3}}')
    bench.run(0.5)
    commands = [r.command for _, r in bench.requests if r.command is not CommandCode.GET_LR_WHEEL_VELOCITY]
    assert commands[:2] == [CommandCode.PREPARE_WHEEL_CONTROLLER, CommandCode.EMG_STOP], commands
    assert all(r.left == 0 and r.right == 0 for _, r in bench.requests if r.command is CommandCode.SET_LR_WHEEL_VELOCITY)
    assert not bench.robot.moving and bench.conn.health(bench.t).estop_since == 5.0


# ---------------------------------------------------------------------- the host: bytes first, then the disk


class Journal:
    """What happened, in order: bytes written to the robot's control stream, and saves of the latch."""

    def __init__(self) -> None:
        self.entries: list[tuple[str, Any]] = []


class JournalStore(MemoryLatchStore):
    def __init__(self, journal: Journal) -> None:
        super().__init__()
        self.journal = journal

    def save(self, latch: Latch) -> str | None:
        self.journal.entries.append(("save", latch.engaged))
        return super().save(latch)


class JournalConnector(MemoryConnector):
    def __init__(self, server: SimServer, journal: Journal) -> None:
        super().__init__(server)
        self.journal = journal

    async def open(self, port: str) -> ByteStream:
        stream = await super().open(port)
        journal, write, write_now = self.journal, stream.write, stream.write_now

        def logged_write(data: bytes) -> None:
            journal.entries.append(("bytes", [r.command for r in wire.RequestDecoder().feed(data)]))  # type: ignore[union-attr]
            write(data)

        def logged_write_now(data: bytes) -> int:
            journal.entries.append(("bytes", [r.command for r in wire.RequestDecoder().feed(data)]))  # type: ignore[union-attr]
            return write_now(data)

        stream.write, stream.write_now = logged_write, logged_write_now  # type: ignore[method-assign]
        return stream


def test_the_host_writes_the_emg_stop_before_it_saves_the_latch_and_shows_it_in_health(run_loop: Any) -> None:
    async def main() -> None:
        journal = Journal()
        server = SimServer(SimRobot(now=time.monotonic(), seed=1), "127.0.0.1", 0, 0)
        output = RecordingOutput()
        host = GatewayHost(GatewaySettings(cmd_timeout=0.0), JournalConnector(server, journal), output, JournalStore(journal))
        stop = asyncio.Event()
        task = asyncio.create_task(host.run(stop))
        try:
            deadline = time.monotonic() + 20
            while not host.control.connected:
                assert time.monotonic() < deadline
                await asyncio.sleep(0.01)
            host.driver.take(host.core.on_estop, read_estop(ENGAGE))
            while not any(h.estop for h in output.of(GatewayHealth)):
                assert time.monotonic() < deadline
                await asyncio.sleep(0.01)
            save = journal.entries.index(("save", True))
            emg = next(k for k, (kind, what) in enumerate(journal.entries) if kind == "bytes" and CommandCode.EMG_STOP in what)
            assert emg < save
            before = len(journal.entries)
            host.driver.take(host.core.on_estop, read_estop(RELEASE, release_key=True))
            assert ("save", False) in journal.entries[before:] and not host.health().estop
        finally:
            stop.set()
            await asyncio.wait_for(task, 5)
            await server.close()

    run_loop(main())
