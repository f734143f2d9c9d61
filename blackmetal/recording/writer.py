"""MCAP recordings of the robot's keys, written with the ``mcap`` package: evidence first.

Payloads go in byte for byte, invalid ones included; known messages get their JSON Schema. Chunks are
closed at least once a second, so a killed recorder loses at most the last second (docs/commands/recording.md).
The recorder writes on a thread of its own: the Zenoh callbacks only queue.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import msgspec

from blackmetal.schemas import ConfigError, Keys, json_schemas, payload_bytes, require_extra

if TYPE_CHECKING:
    import zenoh

#: Zstandard-compressed chunks of at most this many bytes (closed earlier by flush()).
CHUNK_BYTES = 1 << 20
DRAIN_PERIOD_S = 0.02


class _Stamped(msgspec.Struct):
    stamp: float


_stamp_decoder = msgspec.json.Decoder(_Stamped)


def publish_time_ns(payload: bytes, log_time_ns: int) -> int:
    """The message's own stamp (Unix seconds) in ns, or the log time if it has none or is not valid JSON."""
    try:
        stamp = _stamp_decoder.decode(payload).stamp
    except (msgspec.DecodeError, msgspec.ValidationError):
        return log_time_ns
    return int(stamp * 1e9) if 0.0 < stamp < 1e10 else log_time_ns


@dataclass
class McapRecording:
    """Writes samples of the robot's keys to one MCAP file, or a numbered series when split."""

    path: Path
    keys: Keys
    split_bytes: int | None = None
    files: list[Path] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)  # messages per key
    total_bytes: int = 0

    def __post_init__(self) -> None:
        require_extra("blackmetal record", "record", "mcap")
        self._schemas = {name: json.dumps(schema).encode() for name, schema in json_schemas().items()}
        self._stream: IO[bytes] | None = None
        self._writer: Any = None
        self._channels: dict[str, int] = {}
        self._open()

    def _open(self) -> None:
        from mcap.writer import CompressionType, IndexType, Writer

        path = self.path.with_name(f"{self.path.stem}-{len(self.files):03d}{self.path.suffix}") if self.files else self.path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._stream = open(path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise ConfigError(f"cannot write the recording {path}: {exc.strerror}") from None
        self.files.append(path)
        # Chunk indexes only: readers seek by chunk; per-message indexes would double the work of every streaming read.
        index = IndexType.ALL & ~IndexType.MESSAGE
        self._writer = Writer(self._stream, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD, index_types=index)
        self._writer.start(profile="", library="blackmetal")  # not a ROS profile: JSON channels
        self._writer.add_metadata("blackmetal", {"prefix": self.keys.prefix, "part": str(len(self.files))})
        self._channels = {}

    def _channel(self, key: str) -> int:
        channel = self._channels.get(key)
        if channel is None:
            message = self.keys.message_for(key)  # keys without a message get no schema
            schema_id = 0
            if message is not None:
                schema = self._schemas[message.__name__]
                schema_id = self._writer.register_schema(name=message.__name__, encoding="jsonschema", data=schema)
            channel = self._channels[key] = self._writer.register_channel(topic=key, message_encoding="json", schema_id=schema_id)
        return channel

    def write(self, key: str, payload: bytes, log_time_ns: int | None = None) -> None:
        """One sample as received; never raises for what the payload holds."""
        log_time = time.time_ns() if log_time_ns is None else log_time_ns
        channel = self._channel(key)
        self.stats[key] = sequence = self.stats.get(key, 0) + 1
        self.total_bytes += len(payload)
        self._writer.add_message(
            channel_id=channel, log_time=log_time, data=payload, publish_time=publish_time_ns(payload, log_time), sequence=sequence
        )
        if self.split_bytes and self._stream is not None and self._stream.tell() >= self.split_bytes:
            self.close()
            self._open()

    def metadata(self, name: str, data: dict[str, str]) -> None:
        """A named metadata record: ``blackmetal square`` marks each run's span this way."""
        self._writer.add_metadata(name, data)

    def flush(self) -> None:
        """Close the chunk in progress and write it out: what is written survives a kill from now on."""
        self._writer.flush()

    def close(self) -> None:
        """Finish the file properly (summary, indexes): Ctrl-C and SIGTERM end here."""
        if self._writer is not None:
            self._writer.finish()
            self._writer = None
        if self._stream is not None:
            self._stream.close()
            self._stream = None

    def progress(self, elapsed: float) -> str:
        per_key = ", ".join(f"{key.removeprefix(self.keys.prefix + '/')} {n}" for key, n in sorted(self.stats.items()))
        return f"recording {self.files[-1].name}: {elapsed:.0f} s, {self.total_bytes / 1e6:.2f} MB | {per_key or 'waiting for messages'}"


class SessionRecorder:
    """Subscribes to ``keyexprs`` on ``session`` and writes every sample to ``recording`` until stopped."""

    def __init__(self, session: "zenoh.Session", keyexprs: list[str], recording: McapRecording, flush_period: float = 1.0) -> None:
        self.recording = recording
        self.flush_period = flush_period
        self.error: BaseException | None = None
        self._queue: deque[tuple[str, bytes, int]] = deque()
        self._notes: deque[tuple[str, dict[str, str]]] = deque()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()
        self._subscribers: list[Any] = [session.declare_subscriber(k, self._on_sample) for k in keyexprs]

    def _on_sample(self, sample: "zenoh.Sample") -> None:
        arrival = time.time_ns()
        self._queue.append((str(sample.key_expr), payload_bytes(sample), arrival))

    def note(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record (e.g. where a run starts and ends), written by the writer thread."""
        self._notes.append((name, data))

    def _drain(self) -> None:
        queue, write = self._queue, self.recording.write
        while queue:
            key, payload, arrival = queue.popleft()
            write(key, payload, arrival)
        while self._notes:
            self.recording.metadata(*self._notes.popleft())

    def _run(self) -> None:
        next_flush = time.monotonic() + self.flush_period
        try:
            while not self._stop.wait(DRAIN_PERIOD_S):
                self._drain()
                if time.monotonic() >= next_flush:
                    self.recording.flush()
                    next_flush = time.monotonic() + self.flush_period
        except BaseException as exc:  # a full disk: reported by stop()
            self.error = exc

    def stop(self) -> None:
        """Undeclare, write what is queued, finish the file. Idempotent."""
        for subscriber in self._subscribers:
            with suppress(Exception):
                subscriber.undeclare()
        self._subscribers = []
        self._stop.set()
        self._thread.join()
        if self.error is None:
            self._drain()
        self.recording.close()
