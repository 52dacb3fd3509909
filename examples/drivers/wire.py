"""The palpate wire format and bus handshake in plain Python: pyzmq, msgpack and numpy, no palpate import.

Written from docs/messages.md (payloads) and docs/runtime.md ("External nodes": where to bind, what to
subscribe to, whom to wait for, how to acknowledge ticks). Both example drivers use it; a driver in
another language needs the same few pieces.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zmq

#: Schema versions of the types the drivers use (docs/messages.md gives every type's version).
VERSIONS = {"Clock": 1, "LockstepAck": 1, "RunControl": 1, "ContactSet": 1, "NodeStatus": 1}
#: Topics every node reads besides its inputs (docs/runtime.md).
CLOCK, ACK, CONTROL = "clock", "lockstep/ack", "graph/control"


# --- payloads (docs/messages.md, "Wire format") -------------------------------------------------------
def encode(type_name: str, fields: dict[str, Any]) -> bytes:
    """[header, blob]: scalars and string lists in the header, numpy arrays in the blob (8-byte aligned)."""
    header: dict[str, Any] = {}
    blob = bytearray()
    for name, value in fields.items():
        if isinstance(value, np.ndarray):
            array = np.ascontiguousarray(value)
            blob += b"\0" * (-len(blob) % 8)
            header[name] = {
                "dtype": array.dtype.str,
                "shape": list(array.shape),
                "offset": len(blob),
                "nbytes": array.nbytes,
            }
            blob += array.tobytes()
        else:
            header[name] = value
    envelope = {"type": type_name, "version": VERSIONS[type_name], "fields": header}
    return msgpack.packb([envelope, bytes(blob)], use_bin_type=True)


def decode(payload: bytes, type_name: str) -> dict[str, Any]:
    """The fields of a payload of type `type_name`, arrays as read-only numpy views of the blob.

    Raises ValueError for another type or version (a real driver also checks shapes and finiteness).
    """
    envelope, blob = msgpack.unpackb(payload, raw=False)
    if envelope["type"] != type_name or envelope["version"] != VERSIONS[type_name]:
        raise ValueError(f"expected {type_name} v{VERSIONS[type_name]}, got {envelope['type']} v{envelope['version']}")
    fields = {}
    for name, value in envelope["fields"].items():
        if isinstance(value, dict):  # an array: {dtype, shape, offset, nbytes} into the blob
            count = math.prod(value["shape"])
            array = np.frombuffer(blob, dtype=value["dtype"], count=count, offset=value["offset"])
            fields[name] = array.reshape(value["shape"])
        else:
            fields[name] = value
    return fields


# --- the bus (docs/runtime.md, "External nodes") -------------------------------------------------------
def read_spec(bus_dir: str, name: str, timeout_s: float = 60.0) -> dict[str, Any]:
    """The process spec the launcher writes for external node `name`: <bus dir>/external/<name>.json
    (says once that it waits; a one-line exit after `timeout_s`)."""
    path = Path(bus_dir) / "external" / f"{name}.json"
    deadline = time.monotonic() + timeout_s
    if not path.is_file():
        print(f"[{name}] waiting for {path} (palpate launch FILE --external {name} --bus {bus_dir})", flush=True)
    while not path.is_file():
        if time.monotonic() > deadline:
            raise SystemExit(
                f"[{name}] {path} did not appear in {timeout_s:.0f} s: is `palpate launch` running on that bus, "
                f"with a node {name!r} marked external?"
            )
        time.sleep(0.05)
    return json.loads(path.read_text())


def heartbeat(sock: zmq.Socket) -> None:
    """ZMTP heartbeats, as palpate's TCP sockets send them: a peer whose host vanished is dropped after 5 s."""
    sock.setsockopt(zmq.HEARTBEAT_IVL, 1000)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 5000)
    sock.setsockopt(zmq.HEARTBEAT_TTL, 5000)


class Node:
    """One node's sockets: an XPUB bound at spec['endpoint'] and a SUB connected to spec['connect']."""

    def __init__(self, spec: dict[str, Any], types: dict[str, str]) -> None:
        """types: topic -> message type of every topic this node publishes (for its manifest)."""
        if spec.get("curve"):
            raise SystemExit(
                f"node {spec['name']!r} has CurveZMQ keys: these example drivers speak plain ZeroMQ only "
                "(a keyed driver needs a Curve server and a ZAP allow-list, docs/runtime.md)"
            )
        self.spec = spec
        self.name = spec["name"]
        lockstep = spec["mode"] == "lockstep"
        self.context = context = zmq.Context()
        self.pub = context.socket(zmq.XPUB)
        if spec["endpoint"].startswith("tcp://"):
            heartbeat(self.pub)
        self.pub.setsockopt(zmq.XPUB_VERBOSE, 1)  # report every subscription, to count subscribers
        self.pub.setsockopt(zmq.LINGER, 2000)
        if lockstep:
            self.pub.setsockopt(zmq.SNDHWM, 0)  # never drop: lockstep keeps one tick in flight
        endpoint = spec["endpoint"]
        if endpoint.startswith("ipc://"):
            Path(endpoint[len("ipc://") :]).parent.mkdir(parents=True, exist_ok=True)
        self.pub.bind(endpoint)
        self.sub = context.socket(zmq.SUB)
        if any(peer.startswith("tcp://") for peer in spec["connect"]):
            heartbeat(self.sub)
        self.sub.setsockopt(zmq.LINGER, 0)
        if lockstep:
            self.sub.setsockopt(zmq.RCVHWM, 0)
        # inputs, the three graph topics and hello/<own name>, which tells each publisher "I am here"
        for topic in {*spec["subscribes"].values(), CLOCK, ACK, CONTROL, f"hello/{self.name}"}:
            self.sub.setsockopt(zmq.SUBSCRIBE, topic.encode())
        for peer in spec["connect"]:
            self.sub.connect(peer)
        self.subscribers: dict[str, int] = {}
        self.left_at: dict[str, float] = {}  # peer -> when its hello/<peer> subscription went (it left)
        self.backlog: list[tuple[str, bytes]] = []
        self.poller = zmq.Poller()
        self.poller.register(self.pub, zmq.POLLIN)
        self.poller.register(self.sub, zmq.POLLIN)
        # a manifest, so that palpate's tools (record, topic echo, node list) find this node
        self.manifest = Path(spec["bus_dir"]) / f"{self.name}.json"
        self.manifest.write_text(
            json.dumps(
                {
                    "node": self.name,
                    "endpoint": endpoint,
                    "pid": os.getpid(),
                    "publishes": types,
                    "subscribes": {t: spec["topic_types"].get(t, "") for t in spec["subscribes"].values()},
                    "curve_public": "",
                }
            )
        )

    def wait_for_subscribers(self, timeout_s: float = 60.0) -> None:
        """Block until every subscriber in spec['expected_subscribers'] is connected (nothing is lost)."""
        expected = self.spec["expected_subscribers"]
        deadline = time.monotonic() + timeout_s
        while any(self.subscribers.get(t, 0) < n for t, n in expected.items()):
            if time.monotonic() > deadline:
                missing = {
                    t: n - self.subscribers.get(t, 0) for t, n in expected.items() if self.subscribers.get(t, 0) < n
                }
                raise TimeoutError(f"subscribers never connected: {missing}")
            self.backlog.extend(self._arrived(50))  # kept for receive: a peer's tick -1 may come meanwhile

    def receive(self, timeout_ms: int) -> list[tuple[str, bytes]]:
        """(topic, payload) of every frame waiting, after at most timeout_ms; counts subscriptions too."""
        frames, self.backlog = self.backlog, []
        return frames + self._arrived(0 if frames else timeout_ms)

    def _arrived(self, timeout_ms: int) -> list[tuple[str, bytes]]:
        """The frames that arrive within timeout_ms (none kept from before); counts subscriptions too."""
        frames: list[tuple[str, bytes]] = []
        events = dict(self.poller.poll(timeout_ms))
        if self.pub in events:
            while self.pub.poll(0):
                frame = self.pub.recv()  # b"\x01topic" subscribe, b"\x00topic" unsubscribe
                topic = frame[1:].decode()
                self.subscribers[topic] = self.subscribers.get(topic, 0) + (1 if frame[:1] == b"\x01" else -1)
                if frame[:1] == b"\x00" and topic.startswith("hello/"):
                    self.left_at[topic.removeprefix("hello/")] = time.monotonic()
        if self.sub in events:
            while self.sub.poll(0):
                topic, payload = self.sub.recv_multipart()
                frames.append((topic.decode(), payload))  # subscriptions match prefixes: compare exactly
        return frames

    def gone(self, peer: str, grace_s: float = 2.0) -> bool:
        """Whether `peer` left more than grace_s ago (its subscriptions ended with its connection). A
        clock source that left without a stop failed: a follower waits grace_s for the stop first."""
        left = self.left_at.get(peer)
        return left is not None and time.monotonic() - left > grace_s

    def send(self, topic: str, type_name: str, fields: dict[str, Any]) -> None:
        self.pub.send_multipart([topic.encode(), encode(type_name, fields)])

    def acknowledge(self, tick: int, stamp_ns: int) -> None:
        """LockstepAck: every output of `tick` has been sent (it travels behind them on the same socket)."""
        self.send(ACK, "LockstepAck", {"stamp_ns": stamp_ns, "node": self.name, "tick": tick})

    def close(self) -> None:
        self.manifest.unlink(missing_ok=True)
        self.pub.close(linger=1000)
        self.sub.close()
        self.context.term()  # returns when the last messages have left (or the linger is over)
        if self.spec["endpoint"].startswith("ipc://"):  # the socket file
            Path(self.spec["endpoint"][len("ipc://") :]).unlink(missing_ok=True)
