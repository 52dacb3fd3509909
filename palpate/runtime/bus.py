"""The bus: brokerless ZeroMQ publish/subscribe with one publisher socket per node.

Why brokerless: every message takes one hop (publisher to subscriber), so latency is that of raw
pyzmq plus the codec, and a dead broker cannot take the graph down. Each node binds one XPUB socket
(at ``ipc://<bus dir>/<node>.pub`` by default, or a TCP address for nodes on other hosts) and
connects one SUB socket to the publishers of the topics it reads. One socket per node means that
everything a node sends to another travels over one connection, in order: the lockstep protocol
relies on that. Frames are ``[topic, payload]``.

Discovery: the launcher wires static graphs. Each running node also writes a manifest
``<bus dir>/<node>.json`` (endpoint, topics, types), so tools started in another terminal
(`palpate topic echo`, `record`, `replay`) find the same bus with or without a launch.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import zmq

#: Environment variable naming the bus directory (ipc sockets and manifests).
BUS_ENV = "PALPATE_BUS"


def default_bus_dir() -> Path:
    """``$PALPATE_BUS`` or a per-user directory under the system temp dir."""
    configured = os.environ.get(BUS_ENV)
    path = Path(configured) if configured else Path(tempfile.gettempdir()) / f"palpate-{os.getuid()}" / "default"
    path.mkdir(parents=True, exist_ok=True)
    return path


def ipc_endpoint(bus_dir: str | Path, name: str) -> str:
    """The loopback-only ipc address of a publisher called `name`."""
    return f"ipc://{Path(bus_dir) / name}.pub"


@dataclass(frozen=True)
class Manifest:
    """What a running publisher advertises in the bus directory."""

    node: str
    endpoint: str
    pid: int
    publishes: dict[str, str]  # topic -> message type
    subscribes: dict[str, str]
    #: CurveZMQ public key (z85) of the publisher when it is a Curve server, else "": a subscriber
    #: (the recorder) needs it, and any client key pair, to connect.
    curve_public: str = ""

    def write(self, bus_dir: str | Path) -> Path:
        Path(bus_dir).mkdir(parents=True, exist_ok=True)  # a graph of TCP nodes only has no ipc socket there
        path = Path(bus_dir) / f"{self.node}.json"
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(asdict(self), sort_keys=True))
        tmp.replace(path)
        return path


def read_manifests(bus_dir: str | Path) -> list[Manifest]:
    """Manifests of live publishers (entries whose process is gone are skipped)."""
    manifests = []
    for path in sorted(Path(bus_dir).glob("*.json")):
        try:
            manifest = Manifest(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError):
            continue
        if _alive(manifest.pid):
            manifests.append(manifest)
    return manifests


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def publishers_of(bus_dir: str | Path, topics: list[str] | None = None) -> dict[str, list[Manifest]]:
    """Live publishers by topic, optionally only of `topics`."""
    found: dict[str, list[Manifest]] = {}
    for manifest in read_manifests(bus_dir):
        for topic in manifest.publishes:
            if topics is None or topic in topics:
                found.setdefault(topic, []).append(manifest)
    return found


def make_curve_keys(server_public: str | None = None) -> dict[str, str]:
    """A new CurveZMQ key pair as z85 text, with the publisher key its subscriber will trust
    (`server_public`; default: the new pair's own public key, a graph key)."""
    if not zmq.has("curve"):
        raise RuntimeError("this libzmq was built without CurveZMQ support")
    public, secret = zmq.curve_keypair()
    keys = {"public": public.decode(), "secret": secret.decode()}
    keys["server_public"] = server_public or keys["public"]
    return keys


def client_curve(server_public: str) -> dict[str, str]:
    """Curve keys for a subscriber of a publisher whose server key is ``server_public``: a fresh client
    key pair (publishers authenticate no one, so any pair is accepted), or {} when the key is empty."""
    if not server_public:
        return {}
    public, secret = zmq.curve_keypair()
    return {"public": public.decode(), "secret": secret.decode(), "server_public": server_public}


def apply_curve(socket: zmq.Socket[Any], curve: dict[str, str], *, server: bool) -> None:
    """Authenticate and encrypt a TCP socket with CurveZMQ keys (z85 text) when `curve` has them.

    Publishers are Curve servers (their `secret`); subscribers are clients that know the
    publisher's `server_public` key. Generate keys with `palpate keys`.
    """
    if not curve:
        return
    socket.curve_secretkey = curve["secret"].encode()
    socket.curve_publickey = curve["public"].encode()
    if server:
        socket.curve_server = True
    else:
        socket.curve_serverkey = curve["server_public"].encode()


def make_publisher(
    ctx: zmq.Context[Any], endpoint: str, *, lockstep: bool, curve: dict[str, str] | None = None
) -> zmq.Socket[Any]:
    """An XPUB socket bound to `endpoint` that reports every subscription (for start-up counting).

    In lockstep the high-water mark is unlimited, so nothing is ever dropped; the protocol bounds
    what is in flight to one tick.
    """
    sock = ctx.socket(zmq.XPUB)
    sock.setsockopt(zmq.XPUB_VERBOSE, 1)
    sock.setsockopt(zmq.LINGER, 2000)
    if lockstep:
        sock.setsockopt(zmq.SNDHWM, 0)
    apply_curve(sock, curve or {}, server=True)
    if endpoint.startswith("ipc://"):
        Path(endpoint[len("ipc://") :]).parent.mkdir(parents=True, exist_ok=True)
    sock.bind(endpoint)
    return sock


def make_subscriber(
    ctx: zmq.Context[Any],
    endpoints: list[str],
    topics: list[str],
    *,
    lockstep: bool,
    curve: dict[str, str] | None = None,
) -> zmq.Socket[Any]:
    """A SUB socket connected to `endpoints` and subscribed to `topics` (all when the list is empty)."""
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    if lockstep:
        sock.setsockopt(zmq.RCVHWM, 0)
    apply_curve(sock, curve or {}, server=False)
    for topic in topics or [""]:
        sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
    for endpoint in endpoints:
        sock.connect(endpoint)
    return sock


class PublisherTap:
    """For tools that watch a running graph (topic echo/hz, the live viewer): one SUB socket per
    publisher, subscribed to every topic (filtering is the caller's: a subscription by name would add
    to the subscriber counts nodes wait for at start-up) and keyed with the publisher's CurveZMQ
    server key when its manifest has one."""

    def __init__(self) -> None:
        self.context: zmq.Context[Any] = zmq.Context()
        self.poller = zmq.Poller()
        self.socks: dict[str, zmq.Socket[Any]] = {}

    @property
    def endpoints(self) -> set[str]:
        """Publisher endpoints connected so far."""
        return set(self.socks)

    def connect(self, manifests: Iterable[Manifest]) -> None:
        """Connect to the publishers of these manifests not connected yet."""
        for m in manifests:
            if m.endpoint in self.socks:
                continue
            sock = self.context.socket(zmq.SUB)
            apply_curve(sock, client_curve(m.curve_public), server=False)
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.SUBSCRIBE, b"")
            sock.connect(m.endpoint)
            self.socks[m.endpoint] = sock
            self.poller.register(sock, zmq.POLLIN)

    def receive(self, timeout_s: float) -> list[list[bytes]]:
        """The multipart messages that arrive within `timeout_s` (and all already queued)."""
        out = []
        for sock in dict(self.poller.poll(int(timeout_s * 1000))):
            while sock.poll(0):
                out.append(sock.recv_multipart())
        return out

    def close(self) -> None:
        """Close the sockets and the context."""
        for sock in self.socks.values():
            sock.close(linger=0)
        self.socks.clear()
        self.context.term()


class SubscriptionCounter:
    """Counts subscriptions an XPUB socket has seen, per topic, to know when subscribers are there."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def feed(self, frame: bytes) -> None:
        if not frame:
            return
        topic = frame[1:].decode(errors="replace")
        delta = 1 if frame[0] == 1 else -1 if frame[0] == 0 else 0
        self.counts[topic] = self.counts.get(topic, 0) + delta

    def satisfied(self, expected: dict[str, int]) -> bool:
        return all(self.counts.get(topic, 0) >= n for topic, n in expected.items())

    def missing(self, expected: dict[str, int]) -> dict[str, int]:
        return {t: n - self.counts.get(t, 0) for t, n in expected.items() if self.counts.get(t, 0) < n}


def wait_for_subscribers(
    sock: zmq.Socket[Any], counter: SubscriptionCounter, expected: dict[str, int], timeout_s: float
) -> None:
    """Block until `expected` subscriptions have arrived on an XPUB socket, or raise TimeoutError."""
    deadline = time.monotonic() + timeout_s
    while not counter.satisfied(expected):
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError(f"subscribers still missing after {timeout_s:.0f} s: {counter.missing(expected)}")
        if sock.poll(int(min(remaining, 0.1) * 1000)):
            counter.feed(sock.recv())
