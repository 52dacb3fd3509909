"""The recorder: messages of the bus into an MCAP file, in a canonical order that does not depend on timing.

Finding the bus: with ``--connect EP...`` the recorder connects to those publisher endpoints (the
launcher passes every node's); otherwise it reads the manifests in the bus directory and looks for
new publishers every 0.5 s, so ``palpate record`` finds a graph the same way with or without a launch.
It opens one SUB socket per publisher (a `bus.PublisherTap` that never drops and reports connections
and disconnections), so it knows where each message came from.

Canonical order (lockstep runs): messages arrive interleaved across publishers in an order that
depends on scheduling. Each publisher's own stream, though, is ordered, and the lockstep protocol
cuts it into ticks: the clock source's tick t ends with its ``Clock(t)``, every other node's with its
``LockstepAck(t)``. The recorder files each message under the tick of the next marker from the
same publisher, and writes tick t once it holds ``Clock(t+1)`` (or the stop) and every acknowledging
publisher's marker of tick t. A tick is written publisher by publisher (the clock source first, then
the nodes by name), each in its publish order, so equal stamps keep their publish order, every
publisher's block ends with its marker, and a replay recorded again comes out the same. In
real-time mode (no acknowledgements) there is no such order: messages are written as they arrive.

Durability: in lockstep every ``--chunk-ticks`` written ticks (10 by default) close an MCAP chunk
and push it to the OS (so that many ticks at most are lost to SIGKILL, and chunk boundaries depend on
the data only, keeping the file reproducible; a chunk per tick held 424 bytes of chunk index in
memory per tick until the file closed, 150 MB per simulated hour, and compressed each tick alone);
in real-time mode the chunk closes at least every second.
SIGINT and SIGTERM write what is queued and finish the file.
"""

from __future__ import annotations

import argparse
import errno
import logging
import signal
import sys
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any, NamedTuple

from palpate.argtypes import json_object, json_string_map, path_arg, positive_int
from palpate.errors import MalformedMessageError, MessageError, PalpateError, RecordError
from palpate.messages import codec, topics
from palpate.messages.schemas import Clock, LockstepAck, RunControl
from palpate.paths import why_not
from palpate.record.mcap_io import (
    COMPRESSIONS,
    INTERNAL_TOPICS,
    LAUNCH_METADATA,
    MCAP_MAGIC,
    LogWriter,
    PayloadInfo,
    peek,
)
from palpate.runtime import bus

log = logging.getLogger("palpate.record")
#: Lockstep ticks per MCAP chunk (see Durability above).
CHUNK_TICKS = 10

DISCOVERY_PERIOD_S = 0.5
#: The main loop runs at most this often, so that messages are handled in batches: a wake-up per
#: message costs more than the message (latency does not matter to a recorder; SUB queues are unbounded).
BATCH_PERIOD_S = 0.01
FLUSH_PERIOD_S = 1.0
#: Without any tick marker for this long, the recorder stops waiting for one and writes as messages come.
NO_CLOCK_TIMEOUT_S = 2.0
#: A publisher that sends no tick marker for this long after the clock started is not a lockstep node.
NO_MARKER_TIMEOUT_S = 5.0


class Entry(NamedTuple):
    """A received message: topic, payload, header fields, publish order in its source, arrival order."""

    topic: str
    payload: bytes
    info: PayloadInfo
    seq: int
    arrival: int


@dataclass
class _Source:
    """What the sorter knows of one publisher's stream."""

    key: str
    role: int = 2  # 0: publishes Clock; 1: acknowledges ticks; 2: no marker seen yet
    name: str = ""
    seq: int = 0
    marker: int | None = None  # highest tick marker seen
    live: bool = True
    expected: bool = True  # holds ticks back until its first marker (every lockstep node acknowledges)
    open: list[Entry] = field(default_factory=list)
    closed: deque[tuple[int, list[Entry]]] = field(default_factory=deque)  # by tick, oldest first

    def order(self) -> tuple[int, str]:
        return (self.role, self.name or self.key)


class TickSorter:
    """Puts messages from several publishers into the canonical order (pure: no sockets, no clock).

    Feed messages with `add(source, ...)` in the order they arrive from each source; take the
    batches that are ready with `ready()`, and everything left with `finish()`.
    """

    def __init__(self) -> None:
        self.sources: dict[str, _Source] = {}
        self.mode = "unknown"  # "lockstep" or "stream" once a marker says which
        self.clock_tick = -2
        self.stopped = False
        self.arrivals = 0

    def add(self, source: str, topic: str, payload: bytes, info: PayloadInfo) -> None:
        src = self.sources.get(source)
        if src is None:
            src = self.sources[source] = _Source(key=source)
        src.seq += 1
        self.arrivals += 1
        src.open.append(Entry(topic, payload, info, src.seq, self.arrivals))
        if topic == topics.CLOCK and info.type == Clock.TYPE:
            clock = _decode(payload, Clock)
            if clock is not None:
                src.role = 0
                self.clock_tick = max(self.clock_tick, clock.tick)
                if self.mode == "unknown":
                    self.mode = "lockstep" if clock.lockstep else "stream"
                self._close(src, clock.tick)
        elif topic == topics.LOCKSTEP_ACK and info.type == LockstepAck.TYPE:
            ack = _decode(payload, LockstepAck)
            if ack is not None:
                if src.role != 0:
                    src.role = 1
                src.name = src.name or ack.node
                if self.mode == "unknown":
                    self.mode = "lockstep"
                self._close(src, ack.tick)
        elif topic == topics.GRAPH_CONTROL and info.type == RunControl.TYPE:
            control = _decode(payload, RunControl)
            if control is not None and control.command in RunControl.ENDS_RUN:
                self.stopped = True

    def expect(self, source: str) -> None:
        """Declare a publisher before its first message: no tick is complete until it has sent a marker.

        Without this, a recorder that received a clock source's ticks before a node's first
        acknowledgement (an unlucky scheduling at start-up) would write those ticks without the node.
        """
        if source not in self.sources:
            self.sources[source] = _Source(key=source)

    def unexpect(self, source: str) -> None:
        """A publisher that sends no markers (not a lockstep node): stop waiting for it."""
        src = self.sources.get(source)
        if src is not None:
            src.expected = False

    def unmarked(self) -> list[str]:
        """Live publishers that tick completion is waiting for because they have sent no marker yet."""
        return [s.key for s in self.sources.values() if s.live and s.expected and s.marker is None and s.role != 0]

    def set_live(self, source: str, live: bool) -> None:
        """A source connected or went away; a source that went away no longer holds ticks back."""
        src = self.sources.get(source)
        if src is not None:
            src.live = live

    def assume_stream(self) -> None:
        """No tick marker will come (a graph without a clock): write messages as they arrive."""
        if self.mode == "unknown":
            self.mode = "stream"

    @property
    def pending(self) -> int:
        return sum(len(s.open) + sum(len(e) for _, e in s.closed) for s in self.sources.values())

    def ready(self) -> list[list[Entry]]:
        """Batches (one per tick in lockstep) that can be written now, in canonical order."""
        if self.mode == "unknown":
            return []
        if self.mode == "stream":
            batch = self._take_all_by_arrival()
            return [batch] if batch else []
        batches = []
        while (tick := self.oldest_tick()) is not None and self._complete(tick):
            batches.append(self._take(tick))
        return batches

    def finish(self) -> list[list[Entry]]:
        """Everything still held: the remaining ticks, then each source's messages after its last marker."""
        if self.mode != "lockstep":
            batch = self._take_all_by_arrival()
            return [batch] if batch else []
        batches = []
        while (tick := self.oldest_tick()) is not None:
            batches.append(self._take(tick))
        trailing: list[Entry] = []
        for src in sorted(self.sources.values(), key=_Source.order):
            trailing.extend(src.open)
            src.open = []
        if trailing:
            batches.append(trailing)
        return batches

    def _close(self, src: _Source, tick: int) -> None:
        # a marker older than the source's last (a respawned node starting over) files under the last
        src.marker = tick if src.marker is None else max(src.marker, tick)
        src.closed.append((src.marker, src.open))
        src.open = []

    def oldest_tick(self) -> int | None:
        """The oldest tick waiting to be written, if any."""
        heads = [s.closed[0][0] for s in self.sources.values() if s.closed]
        return min(heads) if heads else None

    def _complete(self, tick: int) -> bool:
        if self.clock_tick < tick + 1 and not self.stopped:
            return False
        for src in self.sources.values():
            if not src.live or src.role == 0:
                continue
            if src.marker is None:
                if src.expected:
                    return False
            elif src.marker < tick:
                return False
        return True

    def _take(self, tick: int) -> list[Entry]:
        batch: list[Entry] = []
        for src in sorted(self.sources.values(), key=_Source.order):
            while src.closed and src.closed[0][0] <= tick:
                batch.extend(src.closed.popleft()[1])
        # publishers that never sent a marker are outside the protocol: their messages go along as they came
        markerless = [s for s in self.sources.values() if s.marker is None and not s.expected and s.open]
        if markerless:
            batch.extend(sorted((e for s in markerless for e in s.open), key=lambda e: e.arrival))
            for src in markerless:
                src.open = []
        return batch

    def _take_all_by_arrival(self) -> list[Entry]:
        everything = []
        for src in self.sources.values():
            for _, entries in src.closed:
                everything.extend(entries)
            everything.extend(src.open)
            src.closed, src.open = deque(), []
        everything.sort(key=lambda e: e.arrival)
        return everything


def _decode(payload: bytes, cls: Any) -> Any:
    try:
        return codec.decode(payload, cls)
    except MessageError:
        return None


# --- sockets -------------------------------------------------------------------------------------


@dataclass
class _Connection:
    endpoint: str
    key: str
    subscribed: set[str] = field(default_factory=set)
    manifest_seen: bool = False
    ever_connected: bool = False
    connected: bool = False


#: What a write to a log can fail with (full disk or quota, file size limit, I/O error, read-only).
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS}


def _endpoint_name(endpoint: str) -> str:
    """A stable name for a publisher endpoint: the node name of an ipc socket file, else the address."""
    if endpoint.startswith("ipc://"):
        name = Path(endpoint[len("ipc://") :]).name
        return name[: -len(".pub")] if name.endswith(".pub") else name
    return endpoint


class Recorder:
    """Connects to publishers, sorts their messages and writes them to an MCAP file."""

    def __init__(
        self,
        output: Path,
        *,
        topics_wanted: Sequence[str] = (),
        connect: Sequence[str] = (),
        bus_dir: Path | None = None,
        until_stop: bool = False,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
        chunk_ticks: int = CHUNK_TICKS,
        grace_s: float = 2.0,
        server_keys: Mapping[str, str] | None = None,
        client_keys: Mapping[str, str] | None = None,
        about: Mapping[str, str] | None = None,
    ):
        """`about`: what made the run (launch file, arguments, seed), kept as the log's metadata."""
        self.output = output
        #: endpoint -> CurveZMQ server key of a keyed publisher (from the launcher or the manifests)
        self.server_keys = dict(server_keys or {})
        self.wanted = list(topics_wanted)
        self.keep = set(self.wanted) | set(INTERNAL_TOPICS) if self.wanted else None
        self.static = list(connect)
        self.bus_dir = bus_dir if bus_dir is not None else bus.default_bus_dir()
        self.until_stop = until_stop
        self.chunk_ticks = max(1, chunk_ticks)
        self.grace_s = grace_s
        # never drop: the recorder must see every message; keyed publishers admit it by its client keys
        self.tap = bus.PublisherTap(never_drop=True, monitor=True, client_keys=client_keys)
        self.connections: dict[str, _Connection] = {}
        self.sorter = TickSorter()
        self.writer = LogWriter(output, compression=compression, chunk_size=chunk_size)
        if about:
            self.writer.metadata(LAUNCH_METADATA, about)
        self.interrupted = False
        self.rejected = 0
        self.received = 0
        self.ticks_unflushed = 0
        self.last_message = time.monotonic()
        self.first_held: float | None = None
        self.first_message: float | None = None
        self.unmarked_since: dict[str, float] = {}
        self.undeclared = bus.UndeclaredTopics(self.wanted, self.bus_dir)  # wanted topics no publisher declares

    # --- discovery ---------------------------------------------------------------------------------
    def _base_topics(self) -> list[str]:
        """Subscriptions of a new connection.

        Nodes count the subscriptions of each topic at start-up to know their subscribers are there.
        A recorder the launcher planned for (``--connect``) subscribes to every topic by name, as
        the count expects; a recorder started on its own must not add to those counts, so it
        subscribes to everything ("") and filters topics itself.
        """
        if not self.static:
            return [""]
        if self.wanted:
            return sorted(set(self.wanted) | set(INTERNAL_TOPICS))
        return ["", *INTERNAL_TOPICS]

    def _connect(self, endpoint: str, name: str) -> _Connection:
        base = self._base_topics()
        self.tap.add(endpoint, base, server_public=self.server_keys.get(endpoint, ""))
        conn = _Connection(endpoint=endpoint, key=name, subscribed=set(base))
        self.connections[endpoint] = conn
        self.sorter.expect(name)
        return conn

    def _subscribe_manifest(self, conn: _Connection, manifest: bus.Manifest) -> None:
        """Planned recorder: subscribe by name to each topic the publisher declares (see _base_topics)."""
        conn.manifest_seen = True
        if not self.static:
            return
        for topic in sorted(manifest.publishes):
            if topic not in conn.subscribed and (not self.wanted or topic in self.wanted):
                self.tap.subscribe(conn.endpoint, topic)
                conn.subscribed.add(topic)

    def _manifests(self) -> list[bus.Manifest]:
        dirs = {self.bus_dir}
        for endpoint in self.static:
            if endpoint.startswith("ipc://"):
                dirs.add(Path(endpoint[len("ipc://") :]).parent)
        found = []
        for directory in sorted(dirs):
            if directory.is_dir():
                found.extend(bus.read_manifests(directory))
        return found

    def discover(self) -> None:
        """Connect to new publishers (manifest mode) and subscribe to the topics their manifests declare."""
        manifests = self._manifests()
        if not self.static:
            for manifest in manifests:
                if manifest.endpoint not in self.connections:
                    log.info("recording %s at %s", manifest.node, manifest.endpoint)
                    if manifest.curve_public:
                        self.server_keys[manifest.endpoint] = manifest.curve_public
                    self._connect(manifest.endpoint, manifest.node)
        for manifest in manifests:
            conn = self.connections.get(manifest.endpoint)
            if conn is not None and not conn.manifest_seen:
                self._subscribe_manifest(conn, manifest)
        self._note_undeclared(manifests)

    def _note_undeclared(self, manifests: list[bus.Manifest]) -> None:
        """Say once for each wanted topic that no publisher on the bus declares (a typo records nothing);
        not for --connect endpoints, which need not write manifests here."""
        if self.static:
            return
        now = time.monotonic()
        for note in self.undeclared.notes(manifests, now):
            log.warning("%s; it is recorded if a publisher of it appears", note)
        if empty := self.undeclared.empty_bus_note(manifests, now):
            log.warning("%s", empty)

    # --- receiving ---------------------------------------------------------------------------------
    def _drain(self, conn: _Connection, limit: int = 5000) -> None:
        for frames in self.tap.take(conn.endpoint, limit):
            self.last_message = time.monotonic()
            if len(frames) != 2:
                self.rejected += 1
                continue
            if self.first_message is None:
                self.first_message = self.last_message
            topic = frames[0].decode(errors="replace")
            if self.keep is not None and topic not in self.keep:
                continue  # a prefix match of a wanted topic
            try:
                info = peek(frames[1])
            except MalformedMessageError as exc:
                self.rejected += 1
                if self.rejected <= 10:
                    log.warning("topic %s from %s: not recorded: %s", topic, conn.key, exc)
                continue
            self.received += 1
            self.sorter.add(conn.key, topic, frames[1], info)

    def _on_connection_changes(self, conn: _Connection) -> None:
        for connected in self.tap.connection_changes(conn.endpoint):
            if connected:
                conn.connected = conn.ever_connected = True
                self.sorter.set_live(conn.key, True)
            else:
                self._drain(conn, limit=1 << 30)  # what the publisher sent before it left is queued already
                conn.connected = False
                self.sorter.set_live(conn.key, False)

    # --- writing -----------------------------------------------------------------------------------
    def _write(self, batches: list[list[Entry]], *, lockstep: bool) -> None:
        for batch in batches:
            for entry in batch:
                self.writer.write(entry.topic, entry.payload, entry.info, entry.seq)
            if lockstep:
                self.ticks_unflushed += 1
                if self.ticks_unflushed >= self.chunk_ticks:
                    self.writer.flush()
                    self.ticks_unflushed = 0

    def _finished(self, now: float) -> bool:
        conns = list(self.connections.values())
        gone = bool(conns) and all(c.ever_connected and not c.connected for c in conns)
        if self.sorter.stopped:
            return gone or now - self.last_message > self.grace_s
        return gone

    def run(self) -> int:
        """Record until SIGINT/SIGTERM (or, with until_stop, the end of the run); returns an exit code."""
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
        started = time.monotonic()
        last_flush = last_discovery = last_iteration = started
        failure: OSError | None = None  # the file could not be written (a full disk, a file size limit)
        try:
            for endpoint in self.static:
                self._connect(endpoint, _endpoint_name(endpoint))
            self.discover()
            while not self.interrupted:
                now = time.monotonic()
                if (idle := BATCH_PERIOD_S - (now - last_iteration)) > 0:
                    time.sleep(idle)
                    now = time.monotonic()
                last_iteration = now
                unmatched = any(not c.manifest_seen for c in self.connections.values())
                period = 0.1 if self.static and unmatched else DISCOVERY_PERIOD_S
                if now - last_discovery >= period and (not self.static or unmatched):
                    self.discover()
                    last_discovery = now
                events = self.tap.poll(0.1)
                for endpoint in events.messages:
                    self._drain(self.connections[endpoint])
                for endpoint in events.connections:
                    self._on_connection_changes(self.connections[endpoint])
                now = time.monotonic()
                self._check_clockless(now)
                self._check_unmarked(now)
                self._write(self.sorter.ready(), lockstep=self.sorter.mode == "lockstep")
                if self.sorter.mode != "lockstep" and now - last_flush >= FLUSH_PERIOD_S:
                    self.writer.flush()
                    last_flush = now
                if self.until_stop and self._finished(now):
                    break
            for conn in self.connections.values():
                self._drain(conn, limit=1 << 30)
            self._write(self.sorter.ready(), lockstep=self.sorter.mode == "lockstep")
            self._write(self.sorter.finish(), lockstep=False)
        except OSError as exc:
            if exc.errno not in WRITE_ERRNOS:
                raise
            failure = exc
        finally:
            try:
                self.writer.close()
            except OSError as exc:
                failure = failure or exc
            self.tap.close()
            for s, handler in previous.items():
                signal.signal(s, handler)
        if failure is not None:
            if _holds_no_record(self.output):  # nothing was written: a file of nothing would only block a rerun
                Path(self.output).unlink(missing_ok=True)
                raise RecordError(f"cannot write log {self.output}: {why_not(failure)}; nothing was recorded")
            raise RecordError(
                f"cannot write log {self.output}: {why_not(failure)}; what it holds up to there: "
                f"palpate bag recover {self.output}"
            )
        skipped = f"; {self.rejected} malformed frames skipped" if self.rejected else ""
        if self.first_message is None:
            log.info(
                "recorded no message to %s in %.1f s: no publisher sent any (is a graph running on bus %s?)%s",
                self.output,
                time.monotonic() - started,
                self.bus_dir,
                skipped,
            )
            return 0
        if missing := [t for t in self.wanted if t not in self.writer.topics]:
            log.warning("recorded no message on %s (see palpate topic list)", ", ".join(missing))
        active = time.monotonic() - self.first_message
        log.info(
            "recorded %d messages to %s, %.0f msg/s over %.1f s from the first message%s",
            self.writer.messages,
            self.output,
            self.writer.messages / max(active, 1e-9),
            active,
            skipped,
        )
        return 0

    def _check_unmarked(self, now: float) -> None:
        """Stop waiting for a publisher that has sent no marker NO_MARKER_TIMEOUT_S after the clock started: the
        clock source starts only once every lockstep node has acknowledged the start, so before that a slow
        node (or the clock source itself, loading its model under load) was taken for a tool."""
        if self.sorter.mode != "lockstep":
            return
        started = self.sorter.clock_tick >= 0 and self.sorter.oldest_tick() is not None
        unmarked = self.sorter.unmarked() if started else []
        for key in list(self.unmarked_since):
            if key not in unmarked:
                del self.unmarked_since[key]
        for key in unmarked:
            since = self.unmarked_since.setdefault(key, now)
            if now - since > NO_MARKER_TIMEOUT_S:
                log.info("%s sends no lockstep acknowledgements: recording its messages as they come", key)
                self.sorter.unexpect(key)

    def _check_clockless(self, now: float) -> None:
        if self.sorter.mode != "unknown":
            self.first_held = None
            return
        if self.sorter.pending and self.first_held is None:
            self.first_held = now
        if self.first_held is not None and now - self.first_held > NO_CLOCK_TIMEOUT_S:
            log.info("no clock or acknowledgement on the bus: recording messages in arrival order")
            self.sorter.assume_stream()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.interrupted = True


# --- command line --------------------------------------------------------------------------------


def _holds_no_record(path: str | Path) -> bool:
    """Whether the log at ``path`` is missing or too short to hold more than MCAP's magic and one record's
    frame (nothing to recover)."""
    try:
        return Path(path).stat().st_size <= len(MCAP_MAGIC) + 9
    except OSError:
        return True


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The recorder's options (shared by `palpate record` and `python -m palpate.record.recorder`)."""
    p.add_argument(
        "topics",
        nargs="*",
        metavar="TOPIC",
        help=f"topics to record (default: every topic); {', '.join(INTERNAL_TOPICS)} come too: a replay and "
        "bag info --check need the ticks",
    )
    p.add_argument("-o", "--output", type=path_arg, required=True, metavar="FILE.mcap", help="log file to write")
    p.add_argument("--bus", type=path_arg, help=f"bus directory (default ${bus.BUS_ENV} or a per-user temp dir)")
    p.add_argument("--connect", nargs="+", default=[], metavar="EP", help="publisher endpoints (default: manifests)")
    p.add_argument("--until-stop", action="store_true", help="exit after the graph's stop and its last messages")
    p.add_argument(
        "--compression", choices=sorted(COMPRESSIONS), default="zstd", help="chunk compression (default zstd)"
    )
    p.add_argument(
        "--chunk-size", type=positive_int, default=1 << 20, metavar="BYTES", help="largest chunk (default 1 MiB)"
    )
    p.add_argument(
        "--chunk-ticks",
        type=positive_int,
        default=CHUNK_TICKS,
        metavar="N",
        help=f"lockstep: close a chunk every N ticks (a SIGKILL loses at most N ticks; default {CHUNK_TICKS})",
    )
    p.add_argument(
        "--curve-servers",
        type=json_string_map,
        default={},
        metavar="JSON",
        help='CurveZMQ server keys of keyed publishers, {"ENDPOINT": "z85 public key"} (manifest mode reads them)',
    )
    p.add_argument(
        "--curve-keys",
        type=path_arg,
        metavar="FILE",
        help="CurveZMQ key file the recorder connects to keyed publishers with (one their launch admits)",
    )
    p.add_argument(
        "--about",
        type=json_object,
        default={},
        metavar="JSON",
        help='what made the run, kept in the log: {"launch_file": ..., "args": ..., "seed": ...} (palpate launch)',
    )


def run(args: argparse.Namespace) -> int:
    """Run a recorder configured by `add_arguments` options."""
    if args.output.suffix != ".mcap":
        log.warning("writing MCAP to %s (the usual extension is .mcap)", args.output)
    try:
        args.output.parent.mkdir(parents=True, exist_ok=True)
    except (OSError, RecursionError) as exc:  # (RecursionError: mkdir of a path of 1,000s of parts)
        why = why_not(exc)
        raise RecordError(f"-o {args.output}: cannot create its folder: {why}") from None
    recorder = Recorder(
        args.output,
        topics_wanted=args.topics,
        connect=args.connect,
        bus_dir=args.bus,
        until_stop=args.until_stop,
        compression=args.compression,
        chunk_size=args.chunk_size,
        chunk_ticks=args.chunk_ticks,
        server_keys=args.curve_servers,
        client_keys=bus.read_key_file(args.curve_keys) if args.curve_keys else None,
        about={str(k): str(v) for k, v in args.about.items()},
    )
    return recorder.run()


def main(argv: list[str] | None = None) -> int:
    """``python -m palpate.record.recorder -o OUT.mcap [TOPIC...] [--connect EP...] [--until-stop]``."""
    parser = argparse.ArgumentParser(prog="palpate record", description="record bus messages into an MCAP file")
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="[recorder] %(levelname)s %(message)s", stream=sys.stderr)
    try:
        return run(args)
    except PalpateError as exc:
        log.error("%s", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())
