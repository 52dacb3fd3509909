"""Bag tools: describe a log, and play it back onto the bus (`palpate replay`).

The player binds one publisher socket like a node (``ipc://<bus dir>/<name>.pub``, a
`bus.BlockingPublisher`) and writes a manifest, so recorders, `palpate topic echo` and nodes find it
the way they find a launched graph. It never drops a message: a send waits while a subscriber's
queue is full, so ``--fast`` goes exactly as fast as the slowest subscriber takes messages, and a
paced replay falls behind schedule rather than losing data. Before sending, it waits for
subscribers (``--subscribers``).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from palpate.errors import BusError, RecordError
from palpate.record import mcap_io
from palpate.runtime import bus

log = logging.getLogger("palpate.replay")


def describe(summary: mcap_io.LogSummary, path: Path) -> str:
    """A log's per-topic counts, types and rates, and its time span, as a table."""
    span_s = (summary.end_ns - summary.start_ns) * 1e-9
    lines = [
        f"log {path}: {counted(summary.messages, 'message')} on {counted(len(summary.topics), 'topic')}, "
        f"sim time {summary.start_ns * 1e-9:.3f} .. {summary.end_ns * 1e-9:.3f} s ({span_s:.3f} s)"
    ]
    width = max([len(t) for t in summary.topics] + [5])
    type_width = max([len(t) for t in summary.types.values()] + [4])
    lines.append(f"  {'topic':<{width}}  {'type':<{type_width}}  {'count':>8}  {'rate':>10}")
    for topic in sorted(summary.topics):
        count = summary.topics[topic]
        rate = f"{count / span_s:.1f} Hz" if span_s > 0 else "-"
        lines.append(f"  {topic:<{width}}  {summary.types.get(topic, ''):<{type_width}}  {count:>8}  {rate:>10}")
    return "\n".join(lines)


def counted(n: int, noun: str) -> str:
    """'1 message', '2 messages'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


@dataclass(frozen=True, kw_only=True)
class PlayOptions:
    """How to play a log: speed (rate <= 0: as fast as subscribers take it), topics, start, looping."""

    rate: float = 1.0
    loop: bool = False
    topics: tuple[str, ...] = ()
    start_s: float = 0.0
    name: str = "replay"
    subscribers: int = 1
    wait_timeout_s: float = 30.0
    send_hwm: int = 10_000


class Player:
    """Publishes a log's messages with their recorded sim-time pacing scaled by `rate`."""

    def __init__(self, path: Path, bus_dir: Path | None, options: PlayOptions):
        self.path = path
        self.options = options
        self.bus_dir = bus_dir if bus_dir is not None else bus.default_bus_dir()
        try:
            bus.usable_dir(self.bus_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordError(f"--bus {self.bus_dir}: cannot create the bus directory: {exc.strerror}") from exc
        summary = mcap_io.summarize(path)
        missing = [t for t in options.topics if t not in summary.topics]
        if missing:
            raise RecordError(f"{path} has no topic {missing[0]!r}; it holds {sorted(summary.topics)}")
        self.types = {t: ty for t, ty in summary.types.items() if not options.topics or t in options.topics}
        if not self.types:
            raise RecordError(f"{path} holds no messages to replay")
        _check_speaks_palpate(path, self.types)
        offset_ns = options.start_s * 1e9
        if not math.isfinite(offset_ns) or summary.start_ns + round(offset_ns) > summary.end_ns:
            span_s = (summary.end_ns - summary.start_ns) * 1e-9
            raise RecordError(f"--start {options.start_s:g} s is past the end of {path}, which spans {span_s:.3f} s")
        self.start_ns = summary.start_ns + round(offset_ns)
        self.interrupted = False
        self.sent = 0

    def _claim_name(self) -> bus.NameClaim:
        """This player's name on the bus, as a launch claims its nodes' (a graph started later cannot
        take its socket); RecordError when a running publisher has it."""
        for manifest in bus.read_manifests(self.bus_dir):
            if manifest.node == self.options.name:
                raise RecordError(
                    f"a publisher named {self.options.name!r} already runs (pid {manifest.pid}) on bus "
                    f"{self.bus_dir}; choose another --name"
                )
        try:
            return bus.NameClaim(self.bus_dir, [self.options.name])
        except BusError as exc:
            raise RecordError(f"{exc}; or choose another --name") from exc

    def run(self) -> int:
        """Play until the end of the log (or forever with `loop`); returns an exit code."""
        claim = self._claim_name()
        try:
            return self._run()
        finally:
            claim.release()

    def _run(self) -> int:
        endpoint = bus.ipc_endpoint(self.bus_dir, self.options.name)
        pub = bus.BlockingPublisher(endpoint, send_hwm=self.options.send_hwm)
        manifest = bus.Manifest(
            node=self.options.name, endpoint=endpoint, pid=_pid(), publishes=dict(self.types), subscribes={}
        )
        manifest_path = manifest.write(self.bus_dir)
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        started = time.monotonic()
        try:
            self._wait_for_subscribers(pub)
            while not self.interrupted:
                self._play_once(pub)
                if not self.options.loop:
                    break
        finally:
            manifest_path.unlink(missing_ok=True)
            for s, handler in previous.items():
                signal.signal(s, handler)
            pub.close()  # waits (up to its linger time) until queued messages have left
        elapsed = time.monotonic() - started
        log.info("replayed %d messages from %s in %.2f s", self.sent, self.path, elapsed)
        return 130 if self.interrupted and not self.options.loop else 0

    def _covered(self, pub: bus.BlockingPublisher) -> int:
        """The most subscriptions any replayed topic has (a subscription covers the topics it prefixes)."""
        return max(pub.counter.covering(topic) for topic in self.types)

    def _wait_for_subscribers(self, pub: bus.BlockingPublisher) -> None:
        wanted = self.options.subscribers
        if wanted <= 0:
            return
        log.info(
            "waiting for %d subscriber(s) on bus %s before playing (at most %g s; --subscribers 0 plays at once)",
            wanted,
            self.bus_dir,
            self.options.wait_timeout_s,
        )
        deadline = time.monotonic() + self.options.wait_timeout_s
        while not self.interrupted and self._covered(pub) < wanted:
            if self.options.wait_timeout_s > 0 and time.monotonic() > deadline:
                log.warning(
                    "only %d of %d subscribers after %.0f s: replaying anyway",
                    self._covered(pub),
                    wanted,
                    self.options.wait_timeout_s,
                )
                return
            pub.read_subscriptions(100)
        pub.read_subscriptions(50)  # the rest of a subscriber's subscriptions arrive together

    def _play_once(self, pub: bus.BlockingPublisher) -> None:
        rate = self.options.rate
        first_stamp: int | None = None
        wall0 = 0.0
        topics = list(self.types)
        for message in mcap_io.read_messages(self.path, topics):
            if self.interrupted:
                return
            if message.log_time < self.start_ns:
                continue
            if rate > 0:
                if first_stamp is None:
                    first_stamp, wall0 = message.log_time, time.monotonic()
                due = wall0 + (message.log_time - first_stamp) * 1e-9 / rate
                while (left := due - time.monotonic()) > 0 and not self.interrupted:
                    pub.read_subscriptions(int(left * 1000) + 1)
            self._send(pub, [message.topic.encode(), message.data])

    def _send(self, pub: bus.BlockingPublisher, frames: list[bytes]) -> None:
        while not self.interrupted:
            if pub.send(frames):  # waits up to its send timeout while a subscriber's queue is full
                self.sent += 1
                return
            pub.read_subscriptions(0)  # still full: keep waiting (never drop), but stay responsive to signals

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.interrupted = True


def _check_speaks_palpate(path: Path, types: dict[str, str]) -> None:
    """RecordError unless every topic to replay is in palpate's msgpack, in this build's version of its type:
    the nodes on the bus would refuse every other message (``launch --replay`` refuses such a log too)."""
    encodings = mcap_io.topic_encodings(path)
    foreign = sorted(t for t in types if encodings.get(t, mcap_io.MESSAGE_ENCODING) != mcap_io.MESSAGE_ENCODING)
    if foreign:
        raise RecordError(
            f"{path}: topic {foreign[0]!r} is encoded as {encodings[foreign[0]]!r}, not {mcap_io.MESSAGE_ENCODING}: "
            "palpate's bus carries palpate's messages only (--topics to replay the others)"
        )
    if problem := mcap_io.version_problem(path, types):
        raise RecordError(
            f"{path}: {problem}, and the graph's nodes would refuse every message (--topics to replay the others)"
        )


def _pid() -> int:
    return os.getpid()
