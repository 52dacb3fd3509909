"""MCAP files of palpate messages: writing, reading, summaries, recovery and tick grouping.

Layout of a palpate log:
- one channel per topic (per topic and message type, should a topic ever carry two types), message
  encoding ``msgpack``: a message's data is exactly the palpate payload that travelled on the bus;
- one schema per message type: name = the wire type (``ContactSet``), encoding ``jsonschema``, data =
  a JSON Schema generated from the message's FieldSpecs, with the schema version, units and array
  dtypes and shapes (``x-palpate-*`` keys);
- log_time = publish_time = the message's ``stamp_ns`` (simulated time), sequence = publish order
  within the message's publisher;
- header profile ``palpate``, library ``palpate-<version> mcap-python-<version>``: nothing in a
  file depends on wall-clock time, so the same run gives the same bytes.
"""

from __future__ import annotations

import io
import json
import os
import struct
import zlib
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import IO, Any, NamedTuple

import msgpack
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import McapReader, make_reader
from mcap.records import Channel, Chunk, Footer, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary
from mcap.writer import CompressionType, IndexType, Writer

import palpate
from palpate.errors import MalformedMessageError, MessageError, RecordError
from palpate.messages import codec, topics
from palpate.messages.base import REGISTRY
from palpate.messages.schemas import Clock, LockstepAck
from palpate.paths import same_file, why_not

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
PROFILE = "palpate"
#: Topics the runtime itself uses; the recorder always keeps them, since they delimit ticks.
INTERNAL_TOPICS = (topics.CLOCK, topics.LOCKSTEP_ACK, topics.GRAPH_CONTROL)
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}

try:
    _MCAP_VERSION = version("mcap")
except PackageNotFoundError:  # pragma: no cover - the venv always has it
    _MCAP_VERSION = "unknown"
LIBRARY = f"palpate-{palpate.__version__} mcap-python-{_MCAP_VERSION}"

# What a truncated or damaged file can raise while being read record by record.
READ_ERRORS = (
    McapError,
    struct.error,
    ValueError,
    RuntimeError,
    EOFError,
    OverflowError,  # a damaged length field
    MemoryError,
    zstandard.ZstdError,
    zlib.error,
    KeyError,  # a chunk's message or channel names an id the summary does not define
    OSError,  # a seek to a damaged offset (a chunk index's, or before the start of a tiny file)
)
#: The bytes every MCAP file starts and ends with.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Bytes of a footer record (opcode, length, summary start, summary offset start, summary CRC).
FOOTER_BYTES = 1 + 8 + 8 + 8 + 4


_WHOLE_UNPACK_BYTES = 16_384


class PayloadInfo(NamedTuple):
    """What the recorder needs from a payload's header: its type, schema version and stamp."""

    type: str
    version: int
    stamp_ns: int


def peek(payload: bytes | memoryview) -> PayloadInfo:
    """Read type, version and ``stamp_ns`` from a payload's msgpack header, without decoding arrays.

    Raises MalformedMessageError when the bytes are not a palpate envelope.
    """
    view = memoryview(payload)
    if len(view) <= _WHOLE_UNPACK_BYTES:  # faster than an incremental unpacker for small payloads
        try:
            envelope = msgpack.unpackb(view, raw=False)
        except (ValueError, TypeError, msgpack.UnpackException) as exc:
            raise MalformedMessageError(codec.header_error(exc, view)) from exc
        if not isinstance(envelope, list) or len(envelope) != 2:
            raise MalformedMessageError("payload is not a 2-item msgpack array [header, blob]")
        return _info(envelope[0])
    size = 2048
    while True:
        unpacker = msgpack.Unpacker(raw=False, max_buffer_size=max(len(view), 1) + 16)
        unpacker.feed(view[:size])
        try:
            if unpacker.read_array_header() != 2:
                raise MalformedMessageError("payload is not a 2-item msgpack array [header, blob]")
            header = unpacker.unpack()
            break
        except msgpack.OutOfData:
            if size >= len(view):
                raise MalformedMessageError("payload ends inside its header") from None
            size *= 8
        except MessageError:
            raise
        except (ValueError, TypeError, msgpack.UnpackException) as exc:
            raise MalformedMessageError(codec.header_error(exc, view)) from exc
    return _info(header)


def _info(header: Any) -> PayloadInfo:
    if not isinstance(header, dict):
        raise MalformedMessageError("payload header is not a map")
    fields = header.get("fields")
    type_name, schema_version = header.get("type"), header.get("version")
    stamp = fields.get("stamp_ns") if isinstance(fields, dict) else None
    if not isinstance(type_name, str) or not isinstance(schema_version, int) or not isinstance(stamp, int):
        raise MalformedMessageError("payload header lacks a string 'type', an int 'version' or an int 'stamp_ns'")
    if stamp < 0:
        raise MalformedMessageError(f"negative stamp_ns {stamp} cannot be an MCAP log time")
    return PayloadInfo(type_name, schema_version, stamp)


def schema_document(type_name: str, schema_version: int) -> dict[str, Any]:
    """A JSON Schema of a message type's fields (units, dtypes, shapes), generated from its FieldSpecs."""
    doc: dict[str, Any] = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": type_name,
        "type": "object",
        "x-palpate-type": type_name,
        "x-palpate-version": schema_version,
        "x-palpate-encoding": (
            "msgpack [header {type, version, fields}, blob]; an array field is {dtype, shape, offset, nbytes} "
            "into blob (C order, 8-byte aligned); see docs/messages.md (palpate/messages/codec.py)"
        ),
    }
    cls = REGISTRY.get(type_name)
    if cls is None or schema_version != cls.VERSION:
        doc["description"] = "message type unknown to the recording build"
        return doc
    doc["description"] = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
    json_types = {"int": "integer", "float": "number", "str": "string", "bool": "boolean"}
    properties: dict[str, Any] = {}
    for name, spec in cls.field_specs().items():
        prop: dict[str, Any] = {"description": spec.doc}
        if spec.unit:
            prop["x-unit"] = spec.unit
        if spec.kind == "array":
            prop.update({"type": "object", "x-dtype": spec.dtype, "x-shape": list(spec.shape or ())})
            prop["x-finite"] = spec.finite
        elif spec.kind == "str_list":
            prop.update({"type": "array", "items": {"type": "string"}})
            if spec.shape:
                prop["x-shape"] = list(spec.shape)
        else:
            prop["type"] = json_types[spec.kind]
            if spec.kind == "float":
                prop["x-finite"] = spec.finite
        properties[name] = prop
    doc["properties"] = properties
    doc["required"] = list(properties)
    doc["additionalProperties"] = False  # a message holds its fields, no more and no less (docs/messages.md)
    return doc


def schema_bytes(type_name: str, schema_version: int) -> bytes:
    return json.dumps(schema_document(type_name, schema_version), sort_keys=True, separators=(",", ":")).encode()


class LogWriter:
    """Writes palpate payloads into an MCAP file, one channel per (topic, type).

    Chunks close when they reach `chunk_size` bytes or when `flush()` is called; `flush()` also pushes
    the bytes to the operating system, so a process killed afterwards loses nothing written before.
    """

    def __init__(
        self, path: str | Path, *, compression: str = "zstd", chunk_size: int = 1 << 20, profile: str = PROFILE
    ):
        if compression not in COMPRESSIONS:
            raise RecordError(f"unknown compression {compression!r}; choose one of {sorted(COMPRESSIONS)}")
        self.path = Path(path)
        try:
            self._file: IO[bytes] = self.path.open("wb")
        except OSError as exc:
            raise RecordError(f"cannot write log {str(path)!r}: {exc.strerror}") from exc
        self._writer = Writer(
            self._file,
            chunk_size=chunk_size,
            compression=COMPRESSIONS[compression],
            # per-message indexes cost more than they save with the recorder's small chunks
            index_types=IndexType.CHUNK | IndexType.ATTACHMENT | IndexType.METADATA,
            # the data section's CRC (in DataEnd) covers what the chunks' CRCs do not: their frames and the
            # records between them, such as the launch's metadata (``check_complete``)
            enable_data_crcs=True,
        )
        self._writer.start(profile=profile, library=LIBRARY)
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self.messages = 0
        self.closed = False

    def channel(
        self,
        topic: str,
        schema_name: str,
        schema_data: bytes,
        *,
        encoding: str = SCHEMA_ENCODING,
        message_encoding: str = MESSAGE_ENCODING,
    ) -> int:
        """The channel id of `topic` with the given schema, registering both on first use.

        An empty `schema_name` means a channel without schema (schema id 0).
        """
        key = (topic, schema_name)
        channel_id = self._channels.get(key)
        if channel_id is None:
            schema_id = 0
            if schema_name:
                schema_key = (schema_name, encoding, schema_data)
                schema_id = self._schemas.get(schema_key, 0)
                if not schema_id:
                    schema_id = self._writer.register_schema(schema_name, encoding, schema_data)
                    self._schemas[schema_key] = schema_id
            channel_id = self._channels[key] = self._writer.register_channel(topic, message_encoding, schema_id)
        return channel_id

    @property
    def topics(self) -> set[str]:
        """The topics of the channels registered so far (``write`` registers a channel with its first message)."""
        return {topic for topic, _ in self._channels}

    def write(self, topic: str, payload: bytes, info: PayloadInfo, sequence: int = 0) -> None:
        """Append one payload on `topic`; log and publish time are its stamp."""
        channel_id = self._channels.get((topic, info.type))
        if channel_id is None:
            channel_id = self.channel(topic, info.type, schema_bytes(info.type, info.version))
        self._writer.add_message(channel_id, info.stamp_ns, payload, info.stamp_ns, sequence & 0xFFFFFFFF)
        self.messages += 1

    def add(self, channel_id: int, log_time_ns: int, data: bytes, sequence: int = 0) -> None:
        """Append already encoded `data` on a channel from `channel()`; log and publish time are `log_time_ns`."""
        self._writer.add_message(channel_id, log_time_ns, data, log_time_ns, sequence & 0xFFFFFFFF)
        self.messages += 1

    def write_logged(
        self, message: LoggedMessage, schema: Schema | None, message_encoding: str = MESSAGE_ENCODING
    ) -> None:
        """Append a message read from another log, keeping its schema, encoding, times and sequence."""
        name, data, encoding = (schema.name, schema.data, schema.encoding) if schema is not None else ("", b"", "")
        channel_id = self.channel(message.topic, name, data, encoding=encoding, message_encoding=message_encoding)
        self._writer.add_message(channel_id, message.log_time, message.data, message.publish_time, message.sequence)
        self.messages += 1

    def metadata(self, name: str, values: Mapping[str, str]) -> None:
        """Write a metadata record `name` holding the string pairs `values` (what made the log)."""
        self._writer.add_metadata(name, dict(values))

    def flush(self) -> None:
        """Close the chunk in progress (if it has messages) and push everything to the OS."""
        self._writer.flush()

    def close(self) -> None:
        """Write the summary and footer, and close the file."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LoggedMessage(NamedTuple):
    """One message of a log: topic, message type (schema name), payload bytes, times and sequence."""

    topic: str
    type: str
    data: bytes
    log_time: int
    publish_time: int
    sequence: int


def _open(path: str | Path) -> IO[bytes]:
    try:
        return Path(path).open("rb")
    except OSError as exc:
        raise RecordError(f"cannot open log {str(path)!r}: {exc.strerror}") from exc


def check_complete(stream: IO[bytes], path: str | Path, *, data_crc: bool = False) -> None:
    """RecordError naming what is wrong unless `stream` starts and ends with MCAP's magic bytes, its summary
    matches its footer's CRC and (``data_crc``) its data section matches the CRC its DataEnd record holds."""
    try:
        head = stream.read(len(MCAP_MAGIC))
        size = stream.seek(0, os.SEEK_END)
    except OSError as exc:  # /proc/self/mem opens but cannot be read
        raise RecordError(f"cannot read log {str(path)!r}: {exc.strerror}") from exc
    if size == 0:
        raise RecordError(f"{path} is empty (0 bytes): not an MCAP log")
    if head != MCAP_MAGIC:
        raise RecordError(f"{path} is not an MCAP log (it does not start with MCAP's magic bytes)")
    stream.seek(max(0, size - len(MCAP_MAGIC)))
    if size < 2 * len(MCAP_MAGIC) + FOOTER_BYTES or stream.read() != MCAP_MAGIC:
        if (extra := _bytes_after_end(stream, size)) is not None:
            raise RecordError(
                f"{path} holds {extra} bytes after the end of its log (appended to?); "
                f"`palpate bag recover {path}` writes the log without them"
            )
        raise RecordError(
            f"{path} ends before the log's footer: its recorder was killed or is still writing it; "
            f"`palpate bag recover {path}` writes what it holds into a complete log"
        )
    _check_summary(stream, size, path)
    if data_crc:
        _check_data_crc(stream, size, path)
    stream.seek(0)


#: How far from its end a file is searched for the end of a log that something was appended to.
APPENDED_SEARCH_BYTES = 1 << 16
#: MCAP's footer record opcode.
FOOTER_OPCODE = 0x02


def _bytes_after_end(stream: IO[bytes], size: int) -> int | None:
    """How many bytes follow a footer and end magic within the file's last APPENDED_SEARCH_BYTES (None: none)."""
    start = max(0, size - APPENDED_SEARCH_BYTES)
    stream.seek(start)
    tail = stream.read()
    at = tail.rfind(MCAP_MAGIC)
    while at >= FOOTER_BYTES:
        if tail[at - FOOTER_BYTES] == FOOTER_OPCODE and start + at > len(MCAP_MAGIC):
            return size - (start + at + len(MCAP_MAGIC))
        at = tail.rfind(MCAP_MAGIC, 0, at)
    return None


def _check_summary(stream: IO[bytes], size: int, path: str | Path) -> None:
    """RecordError when the footer's summary CRC does not match the summary: a damaged channel or schema
    record there, or a log with another appended (the footer then belongs to the second, its summary
    offset to the first)."""
    footer_at = size - len(MCAP_MAGIC) - FOOTER_BYTES
    stream.seek(footer_at)
    footer = stream.read(FOOTER_BYTES)
    opcode, _, summary_start, _, crc = struct.unpack("<BQQQI", footer)
    if opcode != FOOTER_OPCODE or summary_start == 0 or crc == 0:
        return  # not a footer (the reader names it), or a log without a summary or its CRC
    damaged = (
        f"{path}: its summary does not match the CRC its footer holds (damaged, or another log appended to it); "
        f"`palpate bag recover {path}` rewrites what its chunks hold"
    )
    if summary_start > footer_at:
        raise RecordError(damaged)
    stream.seek(summary_start)
    covered = stream.read(footer_at - summary_start) + footer[: FOOTER_BYTES - 4]
    if zlib.crc32(covered) != crc:
        raise RecordError(damaged)


#: Bytes of MCAP's DataEnd record (opcode, length, data section CRC).
DATA_END_BYTES = 1 + 8 + 4
#: Files (device, inode, size, modification time) whose data section matched its CRC in this process.
_DATA_CRC_MATCHED: set[tuple[int, int, int, int]] = set()


def _check_data_crc(stream: IO[bytes], size: int, path: str | Path) -> None:
    """RecordError when the data section (from the start magic to its DataEnd record) does not match the CRC
    DataEnd holds: damage the chunks' own CRCs do not see, in a chunk's frame (its length) or in a record
    between chunks (the launch's metadata). A log whose writer computed none (CRC 0) passes."""
    st = os.fstat(stream.fileno())
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    if key in _DATA_CRC_MATCHED:
        return
    footer_at = size - len(MCAP_MAGIC) - FOOTER_BYTES
    stream.seek(footer_at)
    footer = stream.read(1 + 8 + 8)
    if len(footer) != 17 or footer[0] != FOOTER_OPCODE:
        return  # not a footer: the reader names what is wrong
    (summary_start,) = struct.unpack("<Q", footer[9:])
    data_end_at = (summary_start or footer_at) - DATA_END_BYTES
    if not len(MCAP_MAGIC) <= data_end_at <= footer_at - DATA_END_BYTES:
        return  # a summary offset outside the file: the reader names it
    stream.seek(data_end_at)
    data_end = stream.read(DATA_END_BYTES)
    if len(data_end) != DATA_END_BYTES:
        return
    opcode, length, expected = struct.unpack("<BQI", data_end)
    if opcode != Opcode.DATA_END or length != 4 or expected == 0:
        return
    stream.seek(0)
    crc, left = 0, data_end_at
    while left > 0:
        block = stream.read(min(left, 1 << 20))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    if crc != expected:
        raise RecordError(
            f"{path}: its data section does not match the CRC its DataEnd record holds (a chunk, a chunk's frame "
            f"or a record between chunks such as the launch's metadata); the file is damaged: `palpate bag recover "
            f"{path}` keeps every intact chunk"
        )
    _DATA_CRC_MATCHED.add(key)


def _data_crc_matches(path: str | Path) -> bool:
    """Whether the data section of the log at `path` (whose end and summary are intact) matches its CRC."""
    with _open(path) as stream:
        try:
            _check_data_crc(stream, os.fstat(stream.fileno()).st_size, path)
        except RecordError:
            return False
    return True


def _unreadable(path: str | Path, exc: BaseException) -> RecordError:
    what = f"{type(exc).__name__}: {exc}"
    if isinstance(exc, KeyError):
        what = f"a record names channel or schema id {exc}, which the log's summary does not define"
    return RecordError(
        f"{path}: cannot read the MCAP log ({what}); the file is damaged: "
        f"`palpate bag recover {path}` keeps every intact chunk"
    )


@contextmanager
def _reader(path: str | Path, *, validate_crcs: bool = False, data_crc: bool = False) -> Iterator[McapReader]:
    """A reader of the finished log at `path`: RecordError naming what is wrong for a file that is not
    one (``check_complete``) or that turns out damaged while it is read (``_unreadable``)."""
    with _open(path) as stream:
        check_complete(stream, path, data_crc=data_crc)
        try:
            yield make_reader(stream, validate_crcs=validate_crcs)
        except READ_ERRORS as exc:
            raise _unreadable(path, exc) from exc


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[LoggedMessage]:
    """Messages of a finished log in file order (the recorder's canonical order), optionally of `topics`.
    The data section's CRC and every chunk's are checked, and the messages read are counted against the
    summary's statistics: a damaged log is a RecordError, never altered or missing data (a lost or repeated
    chunk index, altered metadata)."""
    wanted = None if topics is None else list(topics)
    read = 0
    with _reader(path, validate_crcs=True, data_crc=True) as reader:
        for schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=False):
            read += 1
            yield LoggedMessage(
                channel.topic,
                schema.name if schema is not None else "",
                message.data,
                message.log_time,
                message.publish_time,
                message.sequence,
            )
        expected = _counted(reader.get_summary(), wanted)
    if expected is not None and read != expected:
        of = "" if wanted is None else f" of the topics read ({', '.join(sorted(wanted))})"
        raise RecordError(
            f"{path}: its summary counts {expected} messages{of}, its chunks hold {read}; the file is damaged: "
            f"`palpate bag recover {path}` rewrites what it holds"
        )


def _counted(summary: Summary | None, topics: list[str] | None) -> int | None:
    """How many messages (of `topics`, or all) the summary's statistics count; None when it does not say."""
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    if topics is None:
        return stats.message_count
    if not stats.channel_message_counts and stats.message_count:
        return None  # a writer that counts no channel
    ids = {i for i, channel in summary.channels.items() if channel.topic in topics}
    return sum(n for i, n in stats.channel_message_counts.items() if i in ids)


@dataclass
class LogSummary:
    """Per-topic counts and types, and the time span of a log."""

    topics: dict[str, int] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    messages: int = 0

    def as_json(self) -> dict[str, Any]:
        return {
            "topics": dict(sorted(self.topics.items())),
            "types": dict(sorted(self.types.items())),
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "messages": self.messages,
        }


def summarize(path: str | Path) -> LogSummary:
    """Counts per topic, types and time span, from the log's summary section (no message is read)."""
    summary = _summary(path)
    if summary is None or summary.statistics is None:
        return _summarize_by_scan(path)
    out = LogSummary()
    stats = summary.statistics
    for channel_id, channel in summary.channels.items():
        count = stats.channel_message_counts.get(channel_id, 0)
        out.topics[channel.topic] = out.topics.get(channel.topic, 0) + count
        schema = summary.schemas.get(channel.schema_id)
        name = schema.name if schema is not None else ""
        previous = out.types.get(channel.topic)
        out.types[channel.topic] = name if previous in (None, name) else f"{previous}|{name}"
    out.messages = stats.message_count
    out.start_ns, out.end_ns = (stats.message_start_time, stats.message_end_time) if stats.message_count else (0, 0)
    return out


def _summarize_by_scan(path: str | Path) -> LogSummary:
    out = LogSummary()
    for message in read_messages(path):
        out.topics[message.topic] = out.topics.get(message.topic, 0) + 1
        out.types.setdefault(message.topic, message.type)
        out.start_ns = message.log_time if out.messages == 0 else min(out.start_ns, message.log_time)
        out.end_ns = max(out.end_ns, message.log_time)
        out.messages += 1
    return out


#: The metadata record in which `palpate launch --record` says what it ran: launch file, arguments, seed.
LAUNCH_METADATA = "palpate.launch"


def launch_info(path: str | Path, *, verify: bool = False) -> dict[str, str]:
    """The launch file, arguments and seed a log was recorded from (``LAUNCH_METADATA``); {} when the log
    does not say (recorded by ``palpate record``, or by another tool). ``verify``: RecordError unless the
    data section, which holds the record, matches its CRC (a full read of the file)."""
    with _reader(path, data_crc=verify) as reader:
        for record in reader.iter_metadata():
            if record.name == LAUNCH_METADATA:
                return dict(record.metadata)
    return {}


def launch_values(info: Mapping[str, str]) -> dict[str, Any]:
    """``launch_info``'s strings with the arguments and the parameters set (``--set``) as JSON values and
    the seed as an int, where they parse; other values stay the strings stored."""
    out: dict[str, Any] = dict(info)
    for key in ("args", "params"):
        if key in out:
            with suppress(ValueError):
                out[key] = json.loads(out[key])
    if str(out.get("seed", "")).isdigit():
        out["seed"] = int(out["seed"])
    return out


def topic_types(path: str | Path) -> dict[str, str]:
    """Topic -> message type of every channel of a finished log."""
    return summarize(path).types


def topic_encodings(path: str | Path) -> dict[str, str]:
    """Topic -> the message encoding its channel records (palpate writes MESSAGE_ENCODING)."""
    summary = _summary(path)
    return {} if summary is None else {c.topic: c.message_encoding for c in summary.channels.values()}


def topic_versions(path: str | Path) -> dict[str, int]:
    """Topic -> the message version its channel's schema records (``x-palpate-version``), where one does."""
    summary = _summary(path)
    if summary is None:
        return {}
    versions = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        try:
            recorded = json.loads(schema.data).get("x-palpate-version") if schema is not None else None
        except (ValueError, AttributeError):  # not palpate's JSON Schema
            recorded = None
        if isinstance(recorded, int):
            versions[channel.topic] = recorded
    return versions


def version_problem(path: str | Path, topic_types: Mapping[str, str]) -> str:
    """Of ``topic_types`` (topic -> type name), the first topic recorded in another version of its type than
    this build's, in words ("topic 'x' carries T version 2; this build speaks T version 1 only"); "" when
    there is none (a type this build does not know is not judged)."""
    versions = topic_versions(path)
    for topic, type_name in topic_types.items():
        cls = REGISTRY.get(type_name)
        if cls is not None and versions.get(topic, cls.VERSION) != cls.VERSION:
            return (
                f"topic {topic!r} carries {type_name} version {versions[topic]}; this build speaks {type_name} "
                f"version {cls.VERSION} only"
            )
    return ""


def _summary(path: str | Path) -> Summary | None:
    with _reader(path) as reader:
        return reader.get_summary()


# --- recovery and copying ------------------------------------------------------------------------


@dataclass
class RecoverReport:
    """What `recover` found: messages kept, whether the input ended early, and why."""

    messages: int = 0
    chunks: int = 0
    truncated: bool = False
    reason: str = ""
    last_log_time: int | None = None
    #: Chunks whose records were framed intact but whose data was damaged (CRC or decompression): skipped.
    damaged_chunks: int = 0
    damage: str = ""
    #: The log's footer was read: it ended as its writer closed it.
    complete: bool = False
    #: Messages skipped because the channel they were recorded on was defined in a damaged chunk only.
    orphaned: int = 0
    #: Bytes after the log's end (its footer and magic) that were left out: something appended to it.
    trailing: int = 0
    #: Messages the log's summary counts (None: no readable summary).
    expected: int | None = None
    #: The data section did not match its CRC: a record between the chunks (the launch's metadata) may be altered.
    data_crc_mismatch: bool = False
    #: The file ends inside the log's closing magic bytes (after its footer).
    magic_cut: bool = False
    #: Every chunk was read where the log's (intact) summary indexes it, not by scanning the file.
    indexed: bool = False

    def lost(self) -> int | None:
        """Messages the summary counts that were not recovered (None: no summary to count them)."""
        return None if self.expected is None else max(0, self.expected - self.messages)


def _why(exc: BaseException) -> str:
    if isinstance(exc, struct.error):  # its class is called `error`: say what it means here
        return f"a record shorter than its fields: cut off or damaged ({exc})"
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def iter_records_tolerant(
    path: str | Path, report: RecoverReport
) -> Iterator[Schema | Channel | McapMessage | Metadata]:
    """Schema, channel, message and metadata records of a possibly truncated or damaged log, front to back.

    Uses the library's streaming (non-seeking) reader; a chunk is used only when it is complete and
    its CRC matches. A chunk whose data is damaged but whose record is framed intact is skipped
    (`report.damaged_chunks`); reading stops at the first damaged frame or missing byte, and `report`
    says why.
    """
    with _open(path) as stream:
        # chunks are checked one by one below; the data section's CRC would end the records at DataEnd, before
        # the footer (a damaged chunk breaks it too): recover checks it on its own
        records = StreamReader(stream, emit_chunks=True, validate_crcs=False).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except READ_ERRORS as exc:
                report.truncated = True
                report.reason = _why(exc)
                return
            if isinstance(record, Chunk):
                try:
                    inner = breakup_chunk(record, validate_crc=True)
                except READ_ERRORS as exc:
                    report.damaged_chunks += 1
                    report.damage = report.damage or _why(exc)
                    continue
                report.chunks += 1
            else:
                inner = [record]
            for item in inner:
                if isinstance(item, Schema | Channel | McapMessage | Metadata):
                    yield item
            if isinstance(record, Footer):
                report.complete = True
                after = os.fstat(stream.fileno()).st_size - stream.tell() - len(MCAP_MAGIC)
                report.trailing, report.magic_cut = max(0, after), after < 0
                return


#: The key recover adds to each metadata record of a log whose data section did not match its CRC.
UNVERIFIED_KEY = "unverified"


def iter_indexed_records(
    path: str | Path, summary: Summary, report: RecoverReport
) -> Iterator[Schema | Channel | McapMessage | Metadata]:
    """The metadata records and then the chunks' records that the (intact) `summary` indexes, each read at
    its indexed offset and length, so that a damaged frame (a chunk's length) does not hide what follows it;
    a chunk is used when its CRC matches. Every chunk is counted in `report` (used, or damaged). Where
    `report.data_crc_mismatch`, each metadata record says so (UNVERIFIED_KEY): no CRC covered it."""
    with _open(path) as stream:
        for meta in summary.metadata_indexes:
            try:
                stream.seek(meta.offset + 9)
                record = Metadata.read(ReadDataStream(io.BytesIO(stream.read(meta.length - 9))))
                if report.data_crc_mismatch:
                    note = "recovered from a log whose data section did not match its CRC: it may be altered"
                    record = Metadata(name=record.name, metadata={**record.metadata, UNVERIFIED_KEY: note})
                yield record
            except READ_ERRORS as exc:
                report.damage = report.damage or f"metadata {meta.name!r}: {_why(exc)}"
        for index in sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset):
            try:
                stream.seek(index.chunk_start_offset)
                record = stream.read(index.chunk_length)
                if len(record) != index.chunk_length or record[0] != Opcode.CHUNK:
                    raise RecordError(f"no chunk at offset {index.chunk_start_offset}")
                inner = breakup_chunk(Chunk.read(ReadDataStream(io.BytesIO(record[9:]))), validate_crc=True)
            except (RecordError, *READ_ERRORS) as exc:
                report.damaged_chunks += 1
                report.damage = report.damage or _why(exc)
                continue
            report.chunks += 1
            yield from (item for item in inner if isinstance(item, Schema | Channel | McapMessage))


def _damaged_log_summary(path: str | Path) -> Summary | None:
    """The summary section of a log whose data section may be damaged; None where it has none or the
    summary itself is damaged."""
    try:
        return _summary(path)
    except RecordError:
        return None


def copy_records(
    records: Iterable[Schema | Channel | McapMessage | Metadata],
    out: LogWriter,
    *,
    keep: Any = None,
    report: RecoverReport | None = None,
    known: tuple[dict[int, Schema], dict[int, Channel]] = ({}, {}),
) -> int:
    """Copy messages (with their schemas and channels) and metadata into `out`; `keep(topic)` filters topics.
    `known`: schemas and channels to start from (a log's summary, for channels whose records were in a
    damaged chunk). A message on a channel never defined is a RecordError, or with a `report` is
    counted there (`orphaned`) and skipped."""
    schemas, channels = dict(known[0]), dict(known[1])
    count = 0
    for record in records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Metadata):
            out.metadata(record.name, record.metadata)  # what made the log stays with it
        else:
            channel = channels.get(record.channel_id)
            if channel is None and report is not None:
                report.orphaned += 1
                continue
            if channel is None:
                raise RecordError(f"message on unknown channel {record.channel_id}: the log is damaged")
            if keep is not None and not keep(channel.topic):
                continue
            schema = schemas.get(channel.schema_id)
            message = LoggedMessage(
                channel.topic,
                schema.name if schema else "",
                record.data,
                record.log_time,
                record.publish_time,
                record.sequence,
            )
            out.write_logged(message, schema, channel.message_encoding)
            count += 1
            if report is not None:
                report.messages += 1
                report.last_log_time = record.log_time
    return count


def recover(src: str | Path, dst: str | Path, *, compression: str = "zstd", overwrite: bool = True) -> RecoverReport:
    """Write every readable message of a (possibly truncated) log `src` into a valid log `dst`.

    Raises RecordError, leaving `dst` as it was, when `src` holds no complete chunk (or is not MCAP),
    or when `dst` exists and not `overwrite`."""
    report = RecoverReport()
    summary = _damaged_log_summary(src)
    known = (dict(summary.schemas), dict(summary.channels)) if summary is not None else ({}, {})
    records: Iterable[Schema | Channel | McapMessage | Metadata]
    if summary is not None and summary.chunk_indexes and summary.statistics is not None:
        # start, end, footer and summary intact: every chunk where the index says, past any damaged frame
        report.complete, report.expected, report.indexed = True, summary.statistics.message_count, True
        report.data_crc_mismatch = not _data_crc_matches(src)
        records = iter_indexed_records(src, summary, report)
    else:
        records = iter_records_tolerant(src, report)
    with output_file(src, dst, "recover", overwrite) as partial, LogWriter(partial, compression=compression) as out:
        copy_records(records, out, report=report, known=known)
        if report.truncated and report.chunks == 0 and report.messages == 0 and "InvalidMagic" in report.reason:
            raise RecordError(f"{src} is not an MCAP file ({report.reason})")
        if report.messages == 0 and not (report.complete and report.damaged_chunks == 0):
            reason = f" ({report.reason or report.damage})" if report.reason or report.damage else ""
            raise RecordError(f"{src}: no complete chunk to recover{reason}; wrote nothing")
    return report


def copy_log(
    src: str | Path,
    dst: str | Path,
    *,
    include: Iterable[str] | None = None,
    exclude: Iterable[str] = (),
    compression: str = "zstd",
    overwrite: bool = True,
) -> int:
    """Copy a log, keeping the topics in `include` (all when None) minus those in `exclude`; RecordError
    when `dst` exists and not `overwrite`."""
    included = None if include is None else set(include)
    excluded = set(exclude)

    def keep(topic: str) -> bool:
        return (included is None or topic in included) and topic not in excluded

    report = RecoverReport()
    with output_file(src, dst, "filter", overwrite) as partial:
        # as every reader of messages: a cut, damaged or altered log (its launch metadata too, which the copy
        # would carry under a new CRC, as if verified) is named, and recover is the way on
        with _open(src) as stream:
            check_complete(stream, src, data_crc=True)
        with LogWriter(partial, compression=compression) as out:
            count = copy_records(iter_records_tolerant(src, report), out, keep=keep, report=report)
            if report.truncated:
                raise RecordError(f"{src} is damaged ({report.reason}); run `palpate bag recover {src}` first")
            if report.damaged_chunks:
                raise RecordError(
                    f"{src} holds {report.damaged_chunks} damaged chunk(s) ({report.damage}); run "
                    f"`palpate bag recover {src}` first"
                )
            if report.orphaned:
                raise RecordError(
                    f"{src} holds {report.orphaned} message(s) on channels it never defines: the file is damaged; "
                    f"run `palpate bag recover {src}` first"
                )
            if count == 0:
                raise RecordError(f"{src}: no message of the topics kept; wrote nothing (see palpate bag info {src})")
    return count


@contextmanager
def output_file(src: str | Path, dst: str | Path, command: str, overwrite: bool = True) -> Iterator[Path]:
    """Where `command` writes the log it makes of `src`: a file beside `dst` that becomes `dst` only when
    the block succeeds, so a failure leaves no partial log (and an existing `dst` as it was).

    Refuses a `dst` that is `src` (under any name) and a `src` it cannot open, before creating anything."""
    src, dst = Path(src), Path(dst)
    try:
        if same_file(src, dst):
            raise RecordError(f"{command} would overwrite its input {src}; choose another output with -o")
        if dst.is_dir():
            raise RecordError(f"{dst} is a directory; give -o a file name")
        if not dst.parent.is_dir():
            raise RecordError(f"{dst}: the folder {dst.parent} does not exist; create it or give -o another path")
        if dst.exists() and not overwrite:
            raise RecordError(f"{dst} exists; pass --force to replace it, or choose another output with -o")
    except OSError as exc:  # a name too long, a loop of links
        raise RecordError(f"-o {dst}: {why_not(exc)}") from exc
    _open(src).close()
    partial = dst.with_name(f".{dst.name}.partial")
    try:
        yield partial
        partial.replace(dst)
    except OSError as exc:  # a full disk, a file size limit
        raise RecordError(f"{command}: cannot write {dst}: {why_not(exc)}; wrote nothing, {src} is untouched") from None
    finally:
        partial.unlink(missing_ok=True)


# --- ticks ---------------------------------------------------------------------------------------


@dataclass
class LogTick:
    """The messages of one recorded tick (markers excluded) and the tick's clock stamp.

    `tick` is None for trailing messages after the last tick marker (final statuses, the stop);
    `stamp_ns` is None for a tick the log holds no Clock of (such as the start-up tick -1).
    """

    tick: int | None
    stamp_ns: int | None
    period_ns: int = 0
    messages: list[LoggedMessage] = field(default_factory=list)


def iter_ticks(messages: Iterable[LoggedMessage]) -> Iterator[LogTick]:
    """Group a log's messages (in file order) into recorded ticks.

    The recorder writes each tick as one block, grouped by publisher, each publisher's messages
    ending with its tick marker (its Clock or its LockstepAck). So a message belongs to the tick of
    the next marker after it. A log without any marker (recorded without the clock) is grouped by
    equal consecutive stamps instead.
    """
    pending: list[LoggedMessage] = []
    open_ticks: dict[int, LogTick] = {}
    seen_marker = False
    for message in messages:
        if message.topic in (topics.CLOCK, topics.LOCKSTEP_ACK):
            marker = _decode_marker(message)
            if marker is None:
                continue
            seen_marker = True
            tick, clock = marker
            for done in sorted(t for t in open_ticks if t < tick):
                yield open_ticks.pop(done)
            entry = open_ticks.setdefault(tick, LogTick(tick=tick, stamp_ns=None))
            entry.messages.extend(pending)
            pending = []
            if clock is not None:
                entry.stamp_ns, entry.period_ns = clock.stamp_ns, clock.period_ns
        else:
            pending.append(message)
    for done in sorted(open_ticks):
        yield open_ticks.pop(done)
    if not seen_marker:
        yield from _ticks_by_stamp(pending)
    elif pending:
        yield LogTick(tick=None, stamp_ns=None, messages=pending)


def _decode_marker(message: LoggedMessage) -> tuple[int, Clock | None] | None:
    try:
        if message.topic == topics.CLOCK:
            clock = codec.decode(message.data, Clock)
            return clock.tick, clock
        ack = codec.decode(message.data, LockstepAck)
        return ack.tick, None
    except MessageError:
        return None


def _ticks_by_stamp(messages: list[LoggedMessage]) -> Iterator[LogTick]:
    current: LogTick | None = None
    index = 0
    for message in messages:
        if current is None or message.log_time != current.stamp_ns:
            if current is not None:
                yield current
            current = LogTick(tick=index, stamp_ns=message.log_time)
            index += 1
        current.messages.append(message)
    if current is not None:
        yield current
