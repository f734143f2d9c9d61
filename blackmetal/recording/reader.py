"""Reading MCAP recordings back, front to back, so a file cut short by a kill yields its closed chunks."""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from blackmetal.schemas import ConfigError, require_extra


@dataclass
class Channel:
    """The messages of one key, byte for byte."""

    topic: str
    payloads: list[bytes] = field(default_factory=list)


@dataclass
class Recorded:
    path: Path
    channels: dict[str, Channel]
    truncated: str | None = None
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)


def is_mcap(path: str | Path) -> bool:
    try:
        with open(path, "rb") as handle:
            return handle.read(8) == b"\x89MCAP0\r\n"
    except OSError:
        return False


def _walk(path: Path, on_record: Callable[[Any], None], empty: Callable[[], bool], **options: Any) -> str | None:
    """Every record of ``path`` to ``on_record``, in file order (a cut-off end spoils nothing before it); where a
    cut-off or damaged end was cut, in words, or None. ConfigError if it fails while ``empty()``."""
    from mcap.stream_reader import StreamReader

    try:
        stream = open(path, "rb")  # noqa: SIM115 (closed by the with below)
    except OSError as exc:
        raise ConfigError(f"cannot read {path}: {exc.strerror}") from None
    whole = 0  # where the last whole record ends
    with stream:
        try:
            for record in StreamReader(stream, **options).records:
                whole = stream.tell()
                on_record(record)
        except Exception as exc:  # the mcap package raises several types for a cut-off or damaged file
            if empty():
                raise ConfigError(f"{path} is not a readable MCAP file: {exc}") from None
            try:
                size = path.stat().st_size
            except OSError:
                size = whole
            what = str(exc) or type(exc).__name__
            return f"cut at byte {whole} of {size}: the last {size - whole} bytes hold no whole record ({what})"
    return None


def read_mcap(path: str | Path, topics: Iterable[str] | None = None) -> Recorded:
    """Every message of the chosen topics (all by default), and the metadata records; a truncated end is noted, not fatal."""
    require_extra("reading MCAP", "record", "mcap")
    from mcap.records import Channel as ChannelRecord
    from mcap.records import Message, Metadata

    wanted = None if topics is None else set(topics)
    channels: dict[str, Channel] = {}
    metadata: list[tuple[str, dict[str, str]]] = []
    known: dict[int, Channel | None] = {}

    def on_record(record: Any) -> None:
        if isinstance(record, Message):
            out = known.get(record.channel_id)
            if out is not None:
                out.payloads.append(record.data)
        elif isinstance(record, ChannelRecord):
            if wanted is None or record.topic in wanted:
                out = channels.get(record.topic) or Channel(record.topic)
                channels[record.topic] = known[record.id] = out
            else:
                known[record.id] = None
        elif isinstance(record, Metadata):
            metadata.append((record.name, dict(record.metadata)))

    truncated = _walk(Path(path), on_record, lambda: not channels, validate_crcs=False)
    return Recorded(Path(path), channels, truncated, metadata)


_MESSAGE, _CHANNEL = 0x05, 0x04
#: Decompressed chunk bytes read in one vectorised pass (bounds the memory a long recording takes).
_BATCH = 32 << 20
_MESSAGE_HEADER = 22  # channel id u16, sequence u32, log time u64, publish time u64
_unpack_length = struct.Struct("<Q").unpack_from
_unpack_channel = struct.Struct("<HHI").unpack_from  # channel id, schema id, topic length


def _payloads(data: bytes, wanted: Callable[[str], bool], ids: set[int]) -> list[bytes]:
    """The payloads of wanted channels in one decompressed chunk (channel ids learnt on the way)."""
    payloads: list[bytes] = []
    offset, size = 0, len(data)
    while offset + 9 <= size:
        opcode = data[offset]
        body = offset + 9
        offset = body + _unpack_length(data, offset + 1)[0]
        if opcode == _MESSAGE:
            if data[body] | (data[body + 1] << 8) in ids:
                payloads.append(data[body + _MESSAGE_HEADER : offset])
        elif opcode == _CHANNEL:
            channel_id, _schema, topic_length = _unpack_channel(data, body)
            if wanted(data[body + 8 : body + 8 + topic_length].decode("utf-8", "replace")):
                ids.add(channel_id)
    return payloads


#: Chunks still being walked below this many, the rest go record by record in Python.
_LOCKSTEP_MIN = 16


def _record_table(data: bytes, bounds: list[int]) -> Any:
    """(starts, lengths) of the records of the chunks ``bounds[i]:bounds[i + 1]`` of ``data``, unsorted; None if a
    chunk's records do not end at its end. One numpy step per record depth across the chunks, the last few in Python."""
    import numpy as np

    length_at = np.ndarray((max(len(data) - 8, 0),), "<u8", data, 1, (1,))  # the u64 after each byte
    at = np.array(bounds[:-1], np.int64)
    end = np.array(bounds[1:], np.int64)
    live = at < end
    at, end = at[live], end[live]
    starts: list[Any] = []
    lengths: list[Any] = []
    while len(at) >= _LOCKSTEP_MIN:
        if np.any(at + 9 > end):
            return None
        length = length_at[at]
        if np.any(length > (end - at - 9).astype(np.uint64)):
            return None
        starts.append(at)
        lengths.append(length.astype(np.int64))
        at = at + 9 + lengths[-1]
        live = at < end
        at, end = at[live], end[live]
    rest_starts: list[int] = []
    rest_lengths: list[int] = []
    for position, stop in zip(at.tolist(), end.tolist(), strict=True):
        while position < stop:
            if position + 9 > stop:
                return None
            length = _unpack_length(data, position + 1)[0]
            if position + 9 + length > stop:
                return None
            rest_starts.append(position)
            rest_lengths.append(length)
            position += 9 + length
    starts.append(np.array(rest_starts, np.int64))
    lengths.append(np.array(rest_lengths, np.int64))
    return np.concatenate(starts), np.concatenate(lengths)


def _chunks_as_lines(chunks: list[bytes], wanted: Callable[[str], bool], ids: set[int]) -> bytes:
    """The wanted payloads of consecutive decompressed chunks as JSON lines, without a Python step per message."""
    import numpy as np

    data = b"".join(chunks)
    bounds = [0]
    for chunk in chunks:
        bounds.append(bounds[-1] + len(chunk))
    table = _record_table(data, bounds)
    if table is None:  # a damaged chunk: record by record, skipping what cannot be read
        return b"\n".join(b"\n".join(_payloads(chunk, wanted, ids)) for chunk in chunks)
    starts, lengths = table
    raw = np.frombuffer(data, np.uint8)
    opcodes = raw[starts]
    for start in np.sort(starts[opcodes == _CHANNEL]).tolist():
        channel_id, _schema, topic_length = _unpack_channel(data, start + 9)
        if wanted(data[start + 17 : start + 17 + topic_length].decode("utf-8", "replace")):
            ids.add(channel_id)
    is_message = (opcodes == _MESSAGE) & (lengths >= _MESSAGE_HEADER)
    messages, sizes = starts[is_message], lengths[is_message]
    channel_ids = raw[messages + 9].astype(np.uint16) | (raw[messages + 10].astype(np.uint16) << 8)
    chosen = np.isin(channel_ids, np.array(sorted(ids), np.uint16))
    messages, sizes = messages[chosen], sizes[chosen]
    order = np.argsort(messages)  # file order
    messages, sizes = messages[order], sizes[order]
    first = messages + 9 + _MESSAGE_HEADER
    last = messages + 9 + sizes
    # keep each payload and the header byte before it, which becomes the line's newline
    edges = np.empty(2 * len(first) + 2, np.int64)
    edges[0], edges[-1] = 0, len(data)
    edges[1:-1:2], edges[2:-1:2] = first - 1, last
    keep = np.repeat(np.arange(len(edges) - 1) % 2 == 1, np.diff(edges))
    lines = raw[keep]
    kept = last - first + 1
    lines[np.cumsum(kept) - kept] = ord("\n")
    return lines.tobytes()


def _chunk_bytes(chunk: Any) -> bytes:
    """A chunk's records, decompressed with the codecs the ``mcap`` package itself depends on."""
    if chunk.compression == "zstd":
        import zstandard

        return bytes(zstandard.decompress(chunk.data, chunk.uncompressed_size))
    if chunk.compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(chunk.data))
    if chunk.compression:
        raise ConfigError(f"unsupported MCAP chunk compression {chunk.compression!r}")
    return bytes(chunk.data)


def topic_lines(path: str | Path, wanted: Callable[[str], bool]) -> tuple[bytes, str | None]:
    """The payloads of the wanted topics as JSON lines for the numpy replay (no Python object per message: >= 1 M/s),
    and what a file cut short was missing at its end."""
    require_extra("reading MCAP", "record", "mcap")
    from mcap.records import Channel as ChannelRecord
    from mcap.records import Chunk, Message

    ids: set[int] = set()
    pieces: list[bytes] = []
    chunks: list[bytes] = []  # decompressed, not yet read: read together, up to _BATCH bytes
    pending = 0

    def flush() -> None:
        nonlocal pending
        pieces.append(_chunks_as_lines(chunks, wanted, ids))
        chunks.clear()
        pending = 0

    def on_record(record: Any) -> None:
        nonlocal pending
        if isinstance(record, Chunk):
            chunks.append(_chunk_bytes(record))
            pending += len(chunks[-1])
            if pending >= _BATCH:
                flush()
            return
        if chunks:  # keep file order with records outside chunks
            flush()
        if isinstance(record, ChannelRecord) and wanted(record.topic):
            ids.add(record.id)
        elif isinstance(record, Message) and record.channel_id in ids:
            pieces.append(b"\n" + record.data)

    truncated = _walk(Path(path), on_record, lambda: not pieces and not chunks, emit_chunks=True)
    if chunks:  # once: a cut-off end leaves them to this
        flush()
    return b"\n".join(pieces), truncated
