"""McapRecording: channels, schemas and payloads as received, and the split into files.

The recorder: Zenoh's callbacks only queue; its own thread writes, flushes and finishes the file.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from blackmetal.recording.reader import read_mcap
from blackmetal.recording.writer import McapRecording, SessionRecorder
from blackmetal.schemas import Keys, WheelImpulses, decode, encode, json_schemas, make_pose

from .test_reader import read_all


def test_channels_schemas_and_bytes_as_received(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    rec = McapRecording(path, Keys())
    pose = encode(make_pose(1_795_000_000.5, 1.0, 2.0, 0.3))
    rec.write("robot/pose", pose, 1_795_000_001_000_000_000)
    rec.write("robot/pose", b"\x00not json", 1_795_000_002_000_000_000)  # evidence: kept byte for byte
    rec.write("robot/something/new", b'{"a": 1}', 1_795_000_003_000_000_000)
    rec.close()
    found = read_all(path)
    (s1, c1, m1), (_, _, m2) = found["robot/pose"]
    assert s1.name == "Pose" and s1.encoding == "jsonschema" and json.loads(s1.data) == json_schemas()["Pose"]
    assert c1.message_encoding == "json"
    assert m1.data == pose and m2.data == b"\x00not json"
    assert m1.log_time == 1_795_000_001_000_000_000 and m1.publish_time == 1_795_000_000_500_000_000  # its own stamp
    assert m2.publish_time == m2.log_time  # no stamp: the arrival time
    ((schema, channel, _),) = found["robot/something/new"]
    assert schema is None and channel.schema_id == 0


def test_split_size_rotates_into_readable_files(tmp_path: Path) -> None:
    rec = McapRecording(tmp_path / "r.mcap", Keys(), split_bytes=20_000)
    for i in range(3000):
        rec.write("robot/wheels/impulses", encode(WheelImpulses(seq=i, stamp=1_795_000_000 + i / 100, left=i, right=-i)))
        if i % 100 == 0:
            rec.flush()
    rec.close()
    assert len(rec.files) >= 3 and rec.files[1].name == "r-001.mcap"
    seqs = [decode(WheelImpulses, m.data).seq for f in rec.files for _, _, m in read_all(f)["robot/wheels/impulses"]]
    assert seqs == list(range(3000))


class Session:
    def __init__(self) -> None:
        self.callbacks: dict[str, Any] = {}

    def declare_subscriber(self, key: str, callback: Any) -> SimpleNamespace:
        self.callbacks[key] = callback
        return SimpleNamespace(undeclare=lambda: None)


def test_samples_and_notes_land_in_the_file(tmp_path: Path) -> None:
    session = Session()
    recording = McapRecording(tmp_path / "r.mcap", Keys())
    recorder = SessionRecorder(session, ["robot/**"], recording, flush_period=0.05)  # type: ignore[arg-type]
    pose = encode(make_pose(1_795_000_000.0, 1.0, 2.0, 0.0))
    for _ in range(3):
        session.callbacks["robot/**"](SimpleNamespace(key_expr="robot/pose", payload=SimpleNamespace(to_bytes=lambda: pose)))
    recorder.note("blackmetal.square", {"direction": "clockwise"})
    time.sleep(0.1)
    recorder.stop()
    assert recorder.error is None
    read = read_mcap(str(tmp_path / "r.mcap"), ["robot/pose"])
    assert read.channels["robot/pose"].payloads == [pose] * 3
    assert read.metadata[-1] == ("blackmetal.square", {"direction": "clockwise"})
