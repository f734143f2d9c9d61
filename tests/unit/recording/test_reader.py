"""MCAP recordings: what the recorder writes, what ordinary MCAP readers see, and replay from them."""

from __future__ import annotations

import itertools
import json
import math
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, wait_for, zenoh_connect_args
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from blackmetal.recording.reader import _chunk_bytes, _record_table, read_mcap, topic_lines
from blackmetal.recording.writer import McapRecording
from blackmetal.schemas import Keys, Pose, WheelImpulses, decode, encode, make_pose


def read_all(path: Path) -> dict[str, list[tuple[object, object, object]]]:
    """topic -> [(schema, channel, message)] with the mcap package's seeking reader (needs a finished file)."""
    out: dict[str, list[tuple[object, object, object]]] = {}
    with open(path, "rb") as handle:
        for schema, channel, message in make_reader(handle).iter_messages():
            out.setdefault(channel.topic, []).append((schema, channel, message))
    return out


def test_fast_reader_equals_the_mcap_reader(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    rec = McapRecording(path, Keys())
    for i in range(500):
        rec.write("robot/wheels/impulses", encode(WheelImpulses(seq=i, stamp=1_795_000_000 + i / 100, left=i, right=-i)))
        rec.write("robot/pose", encode(make_pose(1_795_000_000 + i / 100, i, 0, 0)))
        if i % 97 == 0:
            rec.flush()
    rec.close()
    text, truncated = topic_lines(path, lambda t: t == "robot/wheels/impulses")
    assert truncated is None
    assert [line.strip() for line in text.splitlines() if line.strip()] == read_mcap(path).channels["robot/wheels/impulses"].payloads


def test_fast_reader_walks_many_chunks_whatever_the_payloads_hold(tmp_path: Path) -> None:
    """Enough chunks for the lock-step walk, one long chunk for its Python tail, and payloads full of
    bytes that look like record openings and lengths: exactly the payloads, in file order."""
    rng = random.Random(3)
    alphabet = bytes(b for b in range(256) if b not in b" \t\n\r\x0b\x0c")  # lines are split on whitespace below
    path = tmp_path / "r.mcap"
    rec = McapRecording(path, Keys())
    expected = []
    for i in range(3000):
        payload = bytes(rng.choice(b"\x03\x04\x05" + alphabet) for _ in range(rng.randint(1, 40)))
        rec.write("robot/wheels/impulses", payload)
        expected.append(payload)
        rec.write("robot/pose", bytes(rng.choice(alphabet) for _ in range(rng.randint(0, 30))))
        if i % 40 == 39 and i < 2000:  # 50 short chunks, then one of 1000 messages
            rec.flush()
    rec.close()
    text, truncated = topic_lines(path, lambda t: t == "robot/wheels/impulses")
    assert truncated is None
    assert [line for line in text.split(b"\n") if line] == expected
    # and the vectorised walk itself found every record (no fall-back to the record-by-record walk)
    with open(path, "rb") as handle:
        chunks = [_chunk_bytes(r) for r in StreamReader(handle, emit_chunks=True).records if isinstance(r, Chunk)]
    bounds = [0, *itertools.accumulate(len(c) for c in chunks)]
    table = _record_table(b"".join(chunks), bounds)
    assert table is not None and len(table[0]) == 2 * 3000 + 2 + 2  # messages, channels, schemas


def test_a_recording_cut_anywhere_replays_every_whole_sample_in_order(tmp_path: Path) -> None:
    """20 cuts at random bytes of a recording flushed every 50 samples (the recorder flushes every second): each cut file
    replays every sample of its whole chunks, in order, none rejected, none twice, and says where it was cut."""
    from blackmetal.odometry_service.replay import read_log, summary
    from blackmetal.tools.replay import key_matcher

    path = tmp_path / "whole.mcap"
    rec = McapRecording(path, Keys())
    stamp0 = 1_795_000_000.0
    for i in range(2000):
        rec.write(
            "robot/wheels/impulses", encode(WheelImpulses(seq=i, stamp=stamp0 + i / 50, left=400, right=420, mono=i / 50, source="g"))
        )
        rec.write("robot/pose", encode(make_pose(stamp0 + i / 50, i, 0, 0)))
        if i % 50 == 49:
            rec.flush()
    rec.close()
    data = path.read_bytes()
    with open(path, "rb") as handle:  # where each whole chunk ends, and the last impulse it holds
        ends = []
        for record in StreamReader(handle, emit_chunks=True).records:
            if isinstance(record, Chunk):
                ends.append(handle.tell())
    rng = random.Random(37)
    for cut in sorted(rng.randrange(ends[0] + 1, len(data)) for _ in range(20)):
        cut_file = tmp_path / f"cut-{cut}.mcap"
        cut_file.write_bytes(data[:cut])
        text, truncated = topic_lines(cut_file, key_matcher(None, "impulses"))
        whole_chunks = sum(1 for end in ends if end <= cut)
        result = read_log(text).replay()
        assert not result.rejected, (cut, summary(result), result.rejected[:2])
        seqs = [decode(WheelImpulses, line).seq for line in text.split(b"\n") if line.strip()]
        assert seqs == list(range(50 * whole_chunks)), (cut, seqs[:3], seqs[-3:])
        assert truncated is not None and truncated.startswith("cut at byte ") and f" of {cut}: the last " in truncated, truncated
        whole = int(truncated.split()[3])
        assert max(e for e in ends if e <= cut) <= whole <= cut, truncated  # after the last whole chunk, before the cut
        live = read_mcap(cut_file)  # the other reader agrees, and says the same
        assert len(live.channels["robot/wheels/impulses"].payloads) == len(seqs) and live.truncated is not None


# ------------------------------------------------------------------ the recorder as its own process, on a live robot
def drive(session: zenoh.Session, seconds: float, v: float = 0.25, w: float = 0.3) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        session.put("robot/cmd_vel", json.dumps({"linear": {"x": v}, "angular": {"z": w}}))
        time.sleep(0.1)


@pytest.mark.integration
def test_record_a_drive_then_replay_it(children: list[Child], tmp_path: Path) -> None:
    zport = free_port()
    start_robot(children, zport, gateway_args=("--poll-hz", "100"))
    full, killed = tmp_path / "drive.mcap", tmp_path / "killed.mcap"
    with zenoh.open(client_config(zport)) as session:
        seen: dict[str, list[bytes]] = {"robot/wheels/impulses": [], "robot/pose": []}
        for key, payloads in seen.items():
            session.declare_subscriber(key, lambda s, p=payloads: p.append(s.payload.to_bytes()))
        wait_for(lambda: [r for r in session.get("robot/odometry/reset", timeout=5) if r.ok is not None], what="an odometry reset")
        recorder = Child(["-m", "blackmetal", "record", "-o", str(full), *zenoh_connect_args(zport)])
        victim = Child(["-m", "blackmetal", "record", "-o", str(killed), *zenoh_connect_args(zport)])
        children.extend([recorder, victim])
        recorder.ready()
        victim.ready()
        time.sleep(0.5)  # both subscriptions in place
        drive(session, 4.0)
        victim.proc.kill()  # kill -9 after 4 s of the drive
        victim.proc.wait(10)
        drive(session, 1.0, v=0.0, w=0.0)
        time.sleep(1.0)  # the robot and the odometry stand still
        assert recorder.stop(signal.SIGINT) == 0
        recorder.wait_line(r"wrote .*drive\.mcap")
        time.sleep(0.3)

    found = read_all(full)
    for topic, schema_name in [
        ("robot/wheels/impulses", "WheelImpulses"),
        ("robot/pose", "Pose"),
        ("robot/status", "RobotStatus"),
        ("robot/gateway/health", "GatewayHealth"),
        ("robot/sim/truth", "Pose"),
    ]:
        assert topic in found, f"no {topic} channel; have {sorted(found)}"
        schema = found[topic][0][0]
        assert schema.name == schema_name and schema.encoding == "jsonschema"
        validator = jsonschema.Draft202012Validator(json.loads(schema.data))
        for _, _, message in found[topic]:
            validator.validate(json.loads(message.data))

    # nothing lost at 100 Hz: within the recorded span, the recorder has exactly what a plain subscriber saw
    for topic in ("robot/wheels/impulses", "robot/pose"):
        recorded = [m.data for _, _, m in found[topic]]
        first, last = seen[topic].index(recorded[0]), seen[topic].index(recorded[-1])
        assert recorded == seen[topic][first : last + 1], topic
        assert len(recorded) > 100  # seconds of samples (500 at 100 Hz on a quiet machine; the equality above is the check)

    # replay ends where the live odometry ended
    out = subprocess.run(
        [sys.executable, "-m", "blackmetal", "replay", str(full), "--compare"], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    replayed = decode(Pose, out.stdout.strip().splitlines()[-1].encode())
    live = decode(Pose, found["robot/pose"][-1][2].data)
    assert math.hypot(replayed.x - live.x, replayed.y - live.y) < 1e-3 and abs(math.remainder(replayed.yaw - live.yaw, math.tau)) < 1e-3
    assert math.hypot(live.x, live.y) > 0.5, "the robot did not move"
    assert "--compare:" in out.stderr and "largest difference" in out.stderr

    # JSON lines exported from the recording replay to the same poses
    jsonl = tmp_path / "drive.jsonl"
    a, b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    first = subprocess.run(
        [sys.executable, "-m", "blackmetal", "replay", str(full), "--export-jsonl", str(jsonl), "-o", str(a), "-q"],
        capture_output=True,
        timeout=120,
    )
    second = subprocess.run(
        [sys.executable, "-m", "blackmetal", "replay", str(jsonl), "-o", str(b), "-q"], capture_output=True, timeout=120
    )
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    pa = [decode(Pose, line) for line in a.read_bytes().splitlines()]
    pb = [decode(Pose, line) for line in b.read_bytes().splitlines()]
    assert len(pa) == len(pb) > 400
    assert max(max(abs(p.x - q.x), abs(p.y - q.y), abs(p.yaw - q.yaw)) for p, q in zip(pa, pb, strict=True)) < 1e-9

    # the killed recorder's file: ordinary streaming MCAP readers get everything but the last second
    times: list[int] = []
    # the file has no end; how the reader says so is its own business
    with open(killed, "rb") as handle, pytest.raises(Exception):  # noqa: B017
        for _, channel, message in NonSeekingReader(handle).iter_messages(log_time_order=False):
            if channel.topic == "robot/wheels/impulses":
                times.append(message.log_time)
    assert times and (times[-1] - times[0]) / 1e9 >= 2.5, f"only {(times[-1] - times[0]) / 1e9 if times else 0:.2f} s readable"


@pytest.mark.integration
def test_recorders_killed_at_random_moments_replay_with_nothing_rejected(children: list[Child], tmp_path: Path) -> None:
    """20 recorders, each killed with SIGKILL at a random moment of a drive: every file replays with no sample
    rejected and the same motion as the live poses it holds (``--compare``)."""
    import threading

    zport = free_port()
    start_robot(children, zport)
    rng = random.Random(20)
    files: list[Path] = []
    with zenoh.open(client_config(zport)) as session:
        stop = threading.Event()

        def keep_driving() -> None:
            k = 0
            while not stop.wait(0.1):
                k += 1
                session.put("robot/cmd_vel", json.dumps({"linear": {"x": 0.2}, "angular": {"z": 0.4 if (k // 30) % 2 else -0.3}}))

        driver = threading.Thread(target=keep_driving, daemon=True)
        driver.start()
        try:
            for round_ in range(5):  # four at a time, each killed at its own moment
                batch = [(tmp_path / f"killed-{round_}-{k}.mcap") for k in range(4)]
                victims = [Child(["-m", "blackmetal", "record", "-o", str(path), *zenoh_connect_args(zport)]) for path in batch]
                children.extend(victims)
                for victim in victims:
                    victim.ready()
                started = time.monotonic()
                for victim, at in sorted(zip(victims, [rng.uniform(1.2, 3.5) for _ in victims], strict=True), key=lambda p: p[1]):
                    time.sleep(max(started + at - time.monotonic(), 0.0))
                    victim.proc.kill()
                    victim.proc.wait(10)
                files += batch
        finally:
            stop.set()
            driver.join(5)
    replayed = 0
    for path in files:
        out = subprocess.run(
            [sys.executable, "-m", "blackmetal", "replay", str(path), "--compare"], capture_output=True, text=True, timeout=120
        )
        if out.returncode == 2 and "holds no usable impulse sample" in out.stderr:
            continue  # killed before its first chunk was closed (under a second): nothing to replay, and it says so
        assert out.returncode == 0, out.stderr
        summary_line = next(line for line in out.stderr.splitlines() if " samples, " in line)
        assert " 0 rejected" in summary_line, out.stderr
        largest = float(out.stderr.split("largest difference ")[1].split(" mm")[0])
        assert largest < 1.0, out.stderr
        replayed += 1
    print(f"{replayed} of {len(files)} killed recordings replayed, none with a rejected sample")
    assert replayed >= 15
