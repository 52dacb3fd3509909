"""ZMTP heartbeats: a subscriber whose host vanishes (no TCP FIN) is dropped, so its subscriptions go."""

from __future__ import annotations

import select
import socket
import threading
from typing import Any

import zmq

from palpate.runtime.bus import HEARTBEAT_INTERVAL_MS, HEARTBEAT_TIMEOUT_MS, keep_alive, make_publisher, make_subscriber


class FreezingRelay:
    """A TCP relay from a local port to `upstream`; `freeze()` stops it forwarding while its
    connections stay open, as a peer behaves whose host lost power or its cable."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.frozen = threading.Event()
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        down, _ = self.listener.accept()
        up = socket.create_connection(self.upstream)
        peer = {down: up, up: down}
        while not self.stopped.is_set():
            if self.frozen.is_set():
                self.stopped.wait(0.05)  # hold the connections open, forward nothing
                continue
            readable, _, _ = select.select([down, up], [], [], 0.05)
            for s in readable:
                data = s.recv(65536)
                if data:
                    peer[s].sendall(data)
        down.close()
        up.close()

    def freeze(self) -> None:
        self.frozen.set()

    def close(self) -> None:
        self.stopped.set()
        self.thread.join(timeout=5)
        self.listener.close()


def _subscription(pub: zmq.Socket[Any], timeout_ms: int) -> bytes | None:
    return pub.recv() if pub.poll(timeout_ms) else None


def test_a_subscriber_behind_a_frozen_link_is_dropped_and_its_subscription_goes() -> None:
    ctx: zmq.Context[Any] = zmq.Context()
    pub = ctx.socket(zmq.XPUB)
    sub = ctx.socket(zmq.SUB)
    relay = None
    try:
        for sock in (pub, sub):
            keep_alive(sock, interval_ms=100, timeout_ms=500)
            sock.setsockopt(zmq.LINGER, 0)
        pub.setsockopt(zmq.XPUB_VERBOSE, 1)
        port = pub.bind_to_random_port("tcp://127.0.0.1")
        relay = FreezingRelay(("127.0.0.1", port))
        sub.setsockopt(zmq.SUBSCRIBE, b"hello/node")
        sub.connect(f"tcp://127.0.0.1:{relay.port}")
        assert _subscription(pub, 5000) == b"\x01hello/node"
        relay.freeze()
        # Without heartbeats the publisher would keep the subscription for ever (TCP sees nothing).
        assert _subscription(pub, 5000) == b"\x00hello/node"
    finally:
        if relay is not None:
            relay.close()
        pub.close()
        sub.close()
        ctx.term()


def test_the_bus_sockets_use_heartbeats_over_tcp(tmp_path: Any) -> None:
    ctx: zmq.Context[Any] = zmq.Context()
    with socket.socket() as probe:  # a free port
        probe.bind(("127.0.0.1", 0))
        tcp = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    ipc = f"ipc://{tmp_path}/pub"
    sockets = [make_publisher(ctx, tcp, lockstep=True), make_subscriber(ctx, [tcp], ["a"], lockstep=True)]
    sockets += [make_publisher(ctx, ipc, lockstep=True), make_subscriber(ctx, [ipc], ["a"], lockstep=True)]
    try:
        for sock in sockets[:2]:
            assert sock.getsockopt(zmq.HEARTBEAT_IVL) == HEARTBEAT_INTERVAL_MS
            assert sock.getsockopt(zmq.HEARTBEAT_TIMEOUT) == HEARTBEAT_TIMEOUT_MS
        for sock in sockets[2:]:  # the kernel closes a dead process's ipc sockets: none needed
            assert sock.getsockopt(zmq.HEARTBEAT_IVL) == 0
    finally:
        for sock in sockets:
            sock.close(linger=0)
        ctx.term()
