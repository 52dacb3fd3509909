"""The bus helpers tools use (PublisherTap, BlockingPublisher), on real ipc sockets in a temp dir, in one process."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

from palpate.runtime import bus

TIMEOUT_S = 10.0


@pytest.fixture
def ctx() -> Iterator[zmq.Context[Any]]:
    context: zmq.Context[Any] = zmq.Context()
    yield context
    context.destroy(linger=0)


def _until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"


def test_counter_covering_counts_prefix_subscriptions() -> None:
    counter = bus.SubscriptionCounter()
    for frame in (b"\x01", b"\x01sensors/", b"\x01sensors/", b"\x01sensors/contacts", b"\x01other", b"\x00sensors/"):
        counter.feed(frame)
    assert counter.covering("sensors/contacts") == 3  # "", "sensors/" once (subscribed twice, left once), itself
    assert counter.covering("sensors/wrench") == 2
    assert counter.covering("planner/target") == 1
    assert bus.SubscriptionCounter().covering("x") == 0


def test_tap_takes_each_publishers_messages_and_reports_connections(ctx: zmq.Context[Any], tmp_path: Path) -> None:
    endpoint = bus.ipc_endpoint(tmp_path, "pub")
    pub = bus.make_publisher(ctx, endpoint, lockstep=True)
    counter = bus.SubscriptionCounter()
    tap = bus.PublisherTap(never_drop=True, monitor=True)
    try:
        tap.add(endpoint, ["a"])
        bus.wait_for_subscribers(pub, counter, {"a": 1}, TIMEOUT_S)
        changes: list[bool] = []
        _until(lambda: changes.extend(tap.connection_changes(endpoint)) or bool(changes), "the connection")
        assert changes == [True]

        tap.subscribe(endpoint, "c")
        bus.wait_for_subscribers(pub, counter, {"c": 1}, TIMEOUT_S)
        for frames in ([b"a", b"1"], [b"b", b"2"], [b"a", b"3"], [b"c", b"4"]):
            pub.send_multipart(frames)
        received: list[list[bytes]] = []
        _until(lambda: endpoint in tap.poll(0.1).messages, "messages")
        received.extend(tap.take(endpoint, limit=1))
        assert received == [[b"a", b"1"]]  # at most `limit`
        _until(lambda: received.extend(tap.take(endpoint)) or len(received) >= 3, "all messages")
        assert received == [[b"a", b"1"], [b"a", b"3"], [b"c", b"4"]]  # "b": not subscribed
        assert list(tap.take(endpoint)) == []  # nothing left: returns without waiting

        pub.close(linger=0)
        changes.clear()
        _until(lambda: changes.extend(tap.connection_changes(endpoint)) or bool(changes), "the disconnection")
        assert changes == [False]
    finally:
        pub.close(linger=0)
        tap.close()


def test_tap_connects_to_manifests_once(ctx: zmq.Context[Any], tmp_path: Path) -> None:
    endpoint = bus.ipc_endpoint(tmp_path, "pub")
    pub = bus.make_publisher(ctx, endpoint, lockstep=True)
    manifest = bus.Manifest("pub", endpoint, 1, {"a": "T"}, {})
    tap = bus.PublisherTap()
    try:
        tap.connect([manifest])
        tap.connect([manifest])  # already connected: no second socket, no second subscription
        assert tap.endpoints == {endpoint}
        counter = bus.SubscriptionCounter()
        bus.wait_for_subscribers(pub, counter, {"": 1}, TIMEOUT_S)
        bus.read_subscriptions(pub, counter, 200)
        assert counter.counts == {"": 1}
        pub.send_multipart([b"a", b"1"])
        got: list[list[bytes]] = []
        _until(lambda: got.extend(tap.receive(0.1)) or bool(got), "a message")
        assert got == [[b"a", b"1"]]
    finally:
        pub.close(linger=0)
        tap.close()


def test_tap_poll_without_publishers_waits_out_its_timeout() -> None:
    tap = bus.PublisherTap()
    try:
        started = time.monotonic()
        assert tap.poll(0.05) == bus.TapEvents([], [])
        assert time.monotonic() - started >= 0.05  # a tool's loop does not spin while the bus is empty
    finally:
        tap.close()


def test_blocking_publisher_waits_instead_of_dropping(ctx: zmq.Context[Any], tmp_path: Path) -> None:
    endpoint = bus.ipc_endpoint(tmp_path, "player")
    pub = bus.BlockingPublisher(endpoint, send_hwm=1, linger_ms=0, send_timeout_ms=20)
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 1)
    sub.setsockopt(zmq.SUBSCRIBE, b"t")
    sub.connect(endpoint)
    payload = bytes(1 << 20)
    try:
        _until(lambda: pub.read_subscriptions(100) or pub.counter.covering("t/x") == 1, "the subscription")
        sent = 0
        for _ in range(200):  # a slow subscriber: the queues fill within a few megabytes
            if not pub.send([b"t/x", payload]):
                break
            sent += 1
        else:
            pytest.fail("200 MiB went out to a subscriber that reads nothing")
        assert sent > 0
        received = 0
        deadline = time.monotonic() + 10.0  # everything that send accepted arrives; nothing was dropped
        while received < sent and time.monotonic() < deadline:
            if sub.poll(100):
                sub.recv_multipart()
                received += 1
        assert received == sent
        assert pub.send([b"t/x", payload])  # the queue has room again
    finally:
        sub.close(linger=0)
        pub.close()
    assert not (tmp_path / "player.pub").exists()  # closing deletes the socket file


def test_undeclared_names_the_closest_declared_topic() -> None:
    running = [
        bus.Manifest("sim", "ipc:///x", 1, {"sensors/contacts": "ContactSet", "sensors/effector_pose": "Pose"}, {})
    ]
    assert bus.undeclared("sensors/contact", running) == (
        "no publisher on the bus declares topic 'sensors/contact' (did you mean 'sensors/contacts'?); "
        "see palpate topic list"
    )
    assert bus.undeclared("zzz", running) == "no publisher on the bus declares topic 'zzz'; see palpate topic list"
    assert bus.undeclared("sensors/contacts", running) is None  # declared
    assert bus.undeclared("clock", running) is None  # the runtime's own topics are in no manifest
    assert bus.undeclared("hello/sim", running) is None
    assert bus.undeclared("sensors/contact", []) is None  # nothing running yet: a publisher may come


def test_undeclared_topics_are_told_once_the_running_publishers_settle() -> None:
    """An outside review: a tool started before `palpate launch` said so while the nodes were still
    writing their manifests one by one."""
    sim = bus.Manifest("sim", "ipc:///sim", 1, {"sensors/contacts": "ContactSet"}, {})
    gpis = bus.Manifest("gpis", "ipc:///gpis", 2, {"surface/mesh": "SurfaceMesh"}, {})
    told = bus.UndeclaredTopics(["surface/mesh", "surface/msh"], settle_s=2.0)
    assert told.notes([sim], 0.0) == []  # the graph is starting
    assert told.notes([sim], 1.0) == []
    assert told.notes([sim, gpis], 1.5) == []  # another publisher came: the clock starts again
    assert told.notes([sim, gpis], 3.0) == []
    notes = told.notes([sim, gpis], 3.6)
    assert len(notes) == 1 and notes[0].startswith("no publisher on the bus declares topic 'surface/msh' (did you")
    assert told.notes([sim, gpis], 10.0) == []  # once


def test_a_topic_command_on_a_bus_without_publishers_says_so_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: `topic echo clock --bus /nonexistent` waited for ever without a word."""
    from palpate.commands import introspect

    monkeypatch.setattr(introspect, "EMPTY_BUS_NOTE_S", 0.0)
    tap = introspect.TopicTap(tmp_path / "nowhere", "clock", command="topic echo")
    try:
        tap.discover()
        assert capsys.readouterr().err == ""  # the first look starts the wait
        tap.discover()
        tap.discover()
    finally:
        tap.close()
    err = capsys.readouterr().err
    assert err.count("topic echo: no publisher on bus ") == 1 and "a folder that does not exist yet" in err


def test_an_empty_bus_is_told_once_after_it_settles_and_only_with_a_bus_dir(tmp_path: Path) -> None:
    sim = bus.Manifest("sim", "ipc:///sim", 1, {"sensors/contacts": "ContactSet"}, {})
    told = bus.UndeclaredTopics([], tmp_path, settle_s=2.0)
    assert told.empty_bus_note([], 0.0) is None  # the wait starts
    assert told.empty_bus_note([sim], 1.0) is None  # a publisher came: the wait is over
    assert told.empty_bus_note([], 1.5) is None
    assert told.empty_bus_note([], 3.0) is None
    note = told.empty_bus_note([], 3.5)
    assert note is not None and note.startswith(f"no publisher on bus {tmp_path}; waiting for a graph launched")
    assert told.empty_bus_note([], 10.0) is None  # once
    assert bus.UndeclaredTopics([], settle_s=0.0).empty_bus_note([], 5.0) is None  # no bus dir: no note


def test_the_recorder_and_the_viewer_say_when_their_bus_has_no_publisher(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """An outside walkthrough: only `palpate topic` said so; `record` and `view` on a wrong --bus waited silently."""
    from palpate.record.recorder import Recorder
    from palpate.viewer.sources import BusSource

    nowhere = tmp_path / "nowhere"
    recorder = Recorder(tmp_path / "run.mcap", bus_dir=nowhere)
    recorder.undeclared.settle_s = 0.0
    source = BusSource(nowhere)
    source.undeclared.settle_s = 0.0
    try:
        with caplog.at_level(logging.WARNING):
            for _ in range(3):
                recorder.discover()
                source.discover()
    finally:
        source.close()
        recorder.writer.close()
        recorder.tap.close()
    assert caplog.text.count(f"no publisher on bus {nowhere}, a folder that does not exist yet") == 1
    assert capsys.readouterr().err.count(f"palpate view: no publisher on bus {nowhere}") == 1


def test_a_publisher_that_waits_when_full_is_held_back_by_a_never_drop_tap(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside audit: `palpate replay --fast` into `palpate record` piled the whole log up in both
    processes (the tap's unbounded queue made ZeroMQ's pipe unbounded, so the player never waited)."""
    payload = bytes(10_000)  # large enough that the kernel's socket buffer holds few

    def fill(queue: int, name: str) -> int:
        """Messages a player sends before it has to wait, to a tap that reads none; then all of them are read."""
        monkeypatch.setattr(bus, "NEVER_DROP_QUEUE", queue)
        endpoint = bus.ipc_endpoint(tmp_path, name)
        player = bus.BlockingPublisher(endpoint, send_hwm=20, linger_ms=0, send_timeout_ms=50)
        tap = bus.PublisherTap(never_drop=True)
        try:
            tap.add(endpoint, ["a"])
            bus.wait_for_subscribers(player.sock, player.counter, {"a": 1}, TIMEOUT_S)
            sent = 0
            while sent < 2000 and player.send([b"a", sent.to_bytes(4, "little") + payload]):
                sent += 1
            received: list[list[bytes]] = []
            _until(lambda: received.extend(tap.take(endpoint)) or len(received) >= sent, "the queued messages")
            assert [int.from_bytes(m[1][:4], "little") for m in received] == list(range(sent))  # all, in order
            assert player.send([b"a", b"more"])  # room again
            return sent
        finally:
            player.close()
            tap.close()

    assert fill(0, "unbounded") == 2000  # the player never waits: every message piles up in the queues
    assert 20 <= fill(50, "bounded") < 500  # 20 + 50 queued (and what the kernel's buffer holds): it waits
