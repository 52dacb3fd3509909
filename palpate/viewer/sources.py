"""Where `palpate view` gets messages: a palpate MCAP log, or the running bus.

Both yield `(topic, message)` for the message types the viewer shows (`rerun_log.SHOWN_TYPE_NAMES`),
skipping the others before decoding them, and count what they saw in `stats`.

A palpate log has one channel per topic with message encoding ``msgpack``, the schema name is the
message type and the message data is the palpate payload (see palpate/record/mcap_io.py).

On the bus, the viewer finds publishers through the manifests in the bus directory (like
`palpate topic echo`), looks for new ones every 0.5 s and subscribes to every topic with the empty
prefix: publishers count subscriptions per topic name at start-up, and a viewer must not stand in
for a node the graph waits for. It stops at the graph's RunControl "stop".
"""

from __future__ import annotations

import difflib
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from mcap.reader import make_reader

from palpate.errors import MessageError, PalpateError, RecordError, ViewerError
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import RunControl
from palpate.record.mcap_io import READ_ERRORS, check_complete, topic_types
from palpate.runtime import bus
from palpate.viewer.rerun_log import SHOWN_TYPE_NAMES

MESSAGE_ENCODING = "msgpack"
DISCOVERY_PERIOD_S = 0.1


@dataclass
class SourceStats:
    """Messages seen, shown (decoded, of a shown type and drawn), undecodable, and unusable (decoded
    but holding values the viewer cannot draw, such as a surface naming vertices it lacks)."""

    received: int = 0
    shown: int = 0
    undecodable: int = 0
    last_error: str = ""
    unusable: int = 0
    last_unusable: str = ""


def _wanted(topic: str, wanted: frozenset[str] | None) -> bool:
    return wanted is None or topic in wanted


class LogSource:
    """Messages of an MCAP log in file order (the recorder writes them in sim-time order)."""

    def __init__(self, path: Path, wanted_topics: list[str] | None = None):
        self.path = Path(path)
        self.wanted = frozenset(wanted_topics) if wanted_topics else None
        self.stats = SourceStats()
        if not self.path.is_file():
            raise ViewerError(f"no log file {str(self.path)!r}")

    def missing_topics(self) -> list[str]:
        """The asked-for topics the log holds no channel of, each with the closest it holds ("surface/msh
        (did you mean 'surface/mesh'?)"); none when it cannot be read: iterating names that."""
        if not self.wanted:
            return []
        try:
            held = sorted(topic_types(self.path))
        except (PalpateError, *READ_ERRORS):
            return []
        out = []
        for topic in sorted(self.wanted - set(held)):
            close = difflib.get_close_matches(topic, held, n=1)
            out.append(f"{topic} (did you mean {close[0]!r}?)" if close else topic)
        return out

    def __iter__(self) -> Iterator[tuple[str, Message]]:
        with self.path.open("rb") as stream:
            try:
                check_complete(stream, self.path, data_crc=True)  # a cut, damaged or altered log named as bag names it
            except RecordError as exc:
                then = ", and view the result" if "bag recover" in str(exc) else ""
                raise ViewerError(f"{exc}{then}") from exc
            try:
                reader = make_reader(stream, validate_crcs=True)
                records = reader.iter_messages(
                    topics=sorted(self.wanted) if self.wanted else None, log_time_order=False
                )
                for schema, channel, record in records:
                    self.stats.received += 1
                    if channel.message_encoding != MESSAGE_ENCODING:
                        continue
                    if schema is None or schema.name not in SHOWN_TYPE_NAMES:
                        continue
                    try:
                        message: Message = codec.decode(record.data)
                    except MessageError as exc:
                        self.stats.undecodable += 1
                        self.stats.last_error = f"{channel.topic}: {exc}"
                        continue
                    self.stats.shown += 1
                    yield channel.topic, message
            except READ_ERRORS as exc:
                raise ViewerError(
                    f"{self.path}: cannot read the MCAP log ({type(exc).__name__}: {exc}); if its recorder was "
                    f"killed or the file is damaged, run `palpate bag recover {self.path}` and view the result"
                ) from exc


class BusSource:
    """Messages from every publisher of the bus, found (and re-found every 0.5 s) through the manifests."""

    def __init__(
        self, bus_dir: Path, wanted_topics: list[str] | None = None, client_keys: dict[str, str] | None = None
    ):
        self.bus_dir = Path(bus_dir)
        self.wanted = frozenset(wanted_topics) if wanted_topics else None
        self.stats = SourceStats()
        self.tap = bus.PublisherTap(client_keys=client_keys)  # client_keys: for keyed publishers
        self.types: dict[str, str] = {}  # topic -> message type, from the manifests
        self.last_discovery = -float("inf")
        self.stopped = False  # the graph published RunControl "stop"
        self.interrupted = False
        self.undeclared = bus.UndeclaredTopics(sorted(self.wanted or ()), self.bus_dir)  # topics nobody declares

    def discover(self) -> None:
        """Connect to publishers not yet connected and learn the types of their topics."""
        manifests = bus.read_manifests(self.bus_dir)
        for manifest in manifests:
            self.types.update(manifest.publishes)
        self.tap.connect(manifests)
        self.last_discovery = time.monotonic()
        for note in self.undeclared.notes(manifests, self.last_discovery):
            print(f"palpate view: {note}; waiting for one", file=sys.stderr, flush=True)
        if empty := self.undeclared.empty_bus_note(manifests, self.last_discovery):
            print(f"palpate view: {empty}", file=sys.stderr, flush=True)

    def _shown(self, topic: str) -> bool:
        type_name = self.types.get(topic)
        return _wanted(topic, self.wanted) and (type_name is None or type_name in SHOWN_TYPE_NAMES)

    def receive(self, timeout_s: float) -> list[tuple[str, Message]]:
        """Shown messages that arrive within `timeout_s` (and all that are already queued)."""
        if time.monotonic() - self.last_discovery >= DISCOVERY_PERIOD_S:
            self.discover()
        out: list[tuple[str, Message]] = []
        for frames in self.tap.receive(timeout_s):
            if len(frames) != 2:
                continue
            self.stats.received += 1
            topic = frames[0].decode(errors="replace")
            if topic == RunControl.TOPIC:  # graph/control: the end of the run
                self._control(frames[1])
                continue
            if not self._shown(topic):
                continue
            try:
                message: Message = codec.decode(frames[1])
            except MessageError as exc:
                self.stats.undecodable += 1
                self.stats.last_error = f"{topic}: {exc}"
                continue
            if type(message).TYPE in SHOWN_TYPE_NAMES:
                self.stats.shown += 1
                out.append((topic, message))
        return out

    def _control(self, payload: bytes) -> None:
        try:
            control = codec.decode(payload, RunControl)
        except MessageError:
            return
        if control.command in RunControl.ENDS_RUN:
            self.stopped = True

    def messages(self, duration_s: float = 0.0) -> Iterator[tuple[str, Message]]:
        """Shown messages until the graph stops, SIGINT/SIGTERM, or `duration_s` (0: no limit)."""
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        deadline = time.monotonic() + duration_s if duration_s > 0 else None
        try:
            self.discover()
            while not (self.stopped or self.interrupted) and (deadline is None or time.monotonic() < deadline):
                yield from self.receive(0.1)
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)

    def close(self) -> None:
        """Close the sockets."""
        self.tap.close()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.interrupted = True
