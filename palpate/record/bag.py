"""Bag tools: describe a log, and play it back onto the bus (`palpate replay`).

The player binds one publisher socket like a node (``ipc://<bus dir>/<name>.pub``) and writes a
manifest, so recorders, `palpate topic echo` and nodes find it the way they find a launched graph.
It never drops a message: the socket blocks when a subscriber's queue is full (XPUB_NODROP), so
``--fast`` goes exactly as fast as the slowest subscriber takes messages, and a paced replay falls
behind schedule rather than losing data. Before sending, it waits for subscribers (``--subscribers``).
"""

from __future__ import annotations

import logging
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

import zmq

from palpate.errors import RecordError
from palpate.record import mcap_io
from palpate.runtime import bus

log = logging.getLogger("palpate.replay")


def describe(summary: mcap_io.LogSummary, path: Path) -> str:
    """A log's per-topic counts, types and rates, and its time span, as a table."""
    span_s = (summary.end_ns - summary.start_ns) * 1e-9
    lines = [
        f"log {path}: {summary.messages} messages on {len(summary.topics)} topics, "
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
        self.bus_dir.mkdir(parents=True, exist_ok=True)
        summary = mcap_io.summarize(path)
        missing = [t for t in options.topics if t not in summary.topics]
        if missing:
            raise RecordError(f"{path} has no topic {missing[0]!r}; it holds {sorted(summary.topics)}")
        self.types = {t: ty for t, ty in summary.types.items() if not options.topics or t in options.topics}
        if not self.types:
            raise RecordError(f"{path} holds no messages to replay")
        self.start_ns = summary.start_ns + round(options.start_s * 1e9)
        self.subscriptions: dict[str, int] = {}
        self.interrupted = False
        self.sent = 0

    def _check_name(self) -> None:
        for manifest in bus.read_manifests(self.bus_dir):
            if manifest.node == self.options.name:
                raise RecordError(
                    f"a publisher named {self.options.name!r} already runs (pid {manifest.pid}) on bus "
                    f"{self.bus_dir}; choose another --name"
                )

    def run(self) -> int:
        """Play until the end of the log (or forever with `loop`); returns an exit code."""
        self._check_name()
        context: zmq.Context[Any] = zmq.Context()
        sock = context.socket(zmq.XPUB)
        sock.setsockopt(zmq.XPUB_VERBOSE, 1)
        sock.setsockopt(zmq.XPUB_NODROP, 1)
        sock.setsockopt(zmq.SNDHWM, self.options.send_hwm)
        sock.setsockopt(zmq.LINGER, 30_000)
        sock.setsockopt(zmq.SNDTIMEO, 100)
        endpoint = bus.ipc_endpoint(self.bus_dir, self.options.name)
        sock.bind(endpoint)
        manifest = bus.Manifest(
            node=self.options.name, endpoint=endpoint, pid=_pid(), publishes=dict(self.types), subscribes={}
        )
        manifest_path = manifest.write(self.bus_dir)
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        started = time.monotonic()
        try:
            self._wait_for_subscribers(sock)
            while not self.interrupted:
                self._play_once(sock)
                if not self.options.loop:
                    break
        finally:
            manifest_path.unlink(missing_ok=True)
            for s, handler in previous.items():
                signal.signal(s, handler)
            sock.close()
            context.term()  # waits (up to LINGER) until queued messages have left
        elapsed = time.monotonic() - started
        log.info("replayed %d messages from %s in %.2f s", self.sent, self.path, elapsed)
        return 130 if self.interrupted and not self.options.loop else 0

    def _covered(self) -> int:
        """The most subscriptions any replayed topic has (a subscription covers the topics it prefixes)."""
        best = 0
        for topic in self.types:
            best = max(best, sum(n for prefix, n in self.subscriptions.items() if topic.startswith(prefix)))
        return best

    def _read_subscriptions(self, sock: zmq.Socket[Any], timeout_ms: int) -> None:
        if not sock.poll(timeout_ms, zmq.POLLIN):
            return
        while sock.poll(0, zmq.POLLIN):
            frame = sock.recv()
            if frame and frame[0] in (0, 1):
                topic = frame[1:].decode(errors="replace")
                self.subscriptions[topic] = self.subscriptions.get(topic, 0) + (1 if frame[0] == 1 else -1)

    def _wait_for_subscribers(self, sock: zmq.Socket[Any]) -> None:
        wanted = self.options.subscribers
        if wanted <= 0:
            return
        deadline = time.monotonic() + self.options.wait_timeout_s
        while not self.interrupted and self._covered() < wanted:
            if self.options.wait_timeout_s > 0 and time.monotonic() > deadline:
                log.warning(
                    "only %d of %d subscribers after %.0f s: replaying anyway",
                    self._covered(),
                    wanted,
                    self.options.wait_timeout_s,
                )
                return
            self._read_subscriptions(sock, 100)
        self._read_subscriptions(sock, 50)  # the rest of a subscriber's subscriptions arrive together

    def _play_once(self, sock: zmq.Socket[Any]) -> None:
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
                    self._read_subscriptions(sock, int(left * 1000) + 1)
            self._send(sock, [message.topic.encode(), message.data])

    def _send(self, sock: zmq.Socket[Any], frames: list[bytes]) -> None:
        while not self.interrupted:
            try:
                sock.send_multipart(frames)  # blocks up to SNDTIMEO while a subscriber's queue is full
                self.sent += 1
                return
            except zmq.Again:  # still full: keep waiting (never drop), but stay responsive to signals
                self._read_subscriptions(sock, 0)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.interrupted = True


def _pid() -> int:
    return os.getpid()
