"""A node fed garbage keeps running: 1000 random frames are 1000 counted decode errors, NaN is refused by
name, and the fuzzer's schema-valid extremes are counted input errors.

The test plays the rest of the graph by hand: it binds the publisher the node subscribes to, acts as
the clock source of a lockstep graph (so every buffered frame is decoded, none superseded), and
reads the node's acknowledgements and NodeStatus from the node's own publisher.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

from palpate.bench import fuzz
from palpate.launch.node_types import node_spec_reference
from palpate.messages import codec, topics
from palpate.messages.schemas import Clock, ContactSet, LockstepAck, NodeStatus, RunControl
from palpate.paths import REPO_ROOT
from palpate.runtime import bus
from palpate.runtime.spec import EXIT_RUN_FAILED, TRAIL_TICKS, NodeProcessSpec
from tests.integration.launch_helpers import child_env, kill_session, text

STATS_INPUT = "sensors/contacts"


@dataclass
class Harness:
    """The node process and the test's two sockets around it."""

    proc: subprocess.Popen[bytes]
    log: Path
    pub: zmq.Socket[Any]
    sub: zmq.Socket[Any]
    statuses: list[NodeStatus]

    def send(self, topic: str, payload: bytes) -> None:
        self.pub.send_multipart([topic.encode(), payload])

    def receive_until_ack(self, tick: int, timeout_s: float = 60.0) -> None:
        """Read the node's publisher until it acknowledges `tick` (collecting NodeStatus on the way)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.sub.poll(100):
                topic, payload = self.sub.recv_multipart()
                if topic == topics.NODE_STATUS.encode():
                    self.statuses.append(codec.decode(payload, NodeStatus))
                elif topic == topics.LOCKSTEP_ACK.encode() and codec.decode(payload, LockstepAck).tick >= tick:
                    return
            elif self.proc.poll() is not None:
                break
        raise AssertionError(f"no acknowledgement of tick {tick}; node output:\n{text(self.log)}")

    def tick(self, tick: int) -> None:
        self.send(
            topics.CLOCK,
            codec.encode(Clock(stamp_ns=tick * 10_000_000, tick=tick, period_ns=10_000_000, lockstep=True)),
        )
        self.receive_until_ack(tick)

    def stop(self) -> int:
        self.send(topics.GRAPH_CONTROL, codec.encode(RunControl(stamp_ns=0, command="stop", reason="test over")))
        code = self.proc.wait(timeout=60)
        deadline = time.monotonic() + 10.0  # the final status went out just before exit: wait for it
        while time.monotonic() < deadline and not (self.statuses and self.statuses[-1].state != "running"):
            if self.sub.poll(100):
                topic, payload = self.sub.recv_multipart()
                if topic == topics.NODE_STATUS.encode():
                    self.statuses.append(codec.decode(payload, NodeStatus))
        return code


@contextmanager
def node_process(
    tmp_path: Path,
    *,
    name: str,
    node_type: str,
    params: dict[str, Any],
    publishes: dict[str, str],
    subscribes: dict[str, str],
    wanted: dict[str, int],
    timeout_s: float,
) -> Iterator[Harness]:
    """One node process in lockstep mode, fed by the test's publisher at ipc://TMP/feeder.pub and read
    through its own; ``wanted``: the feed topics (and subscriber counts) the node must have subscribed
    to before anything is sent, since ZeroMQ drops earlier frames."""
    ctx = zmq.Context()
    feed = f"ipc://{tmp_path}/feeder.pub"
    pub = bus.make_publisher(ctx, feed, lockstep=True)
    counter = bus.SubscriptionCounter()
    spec = NodeProcessSpec(
        name=name,
        type=node_type,
        node_spec=node_spec_reference(node_type),
        params=params,
        bus_dir=str(tmp_path),
        endpoint=f"ipc://{tmp_path}/{name}.pub",
        publishes=publishes,
        subscribes=subscribes,
        connect=[feed],
        mode="lockstep",
        expected_subscribers={topics.LOCKSTEP_ACK: 1},  # the test's subscriber
    )
    spec_path = tmp_path / f"{name}.json"
    spec_path.write_text(spec.to_json())
    log = tmp_path / f"{name}.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "palpate.runtime.node", str(spec_path)],
            cwd=REPO_ROOT,
            env=child_env(tmp_path),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    sub = bus.make_subscriber(ctx, [spec.endpoint], [topics.LOCKSTEP_ACK, topics.NODE_STATUS], lockstep=True)
    harness = Harness(proc=proc, log=log, pub=pub, sub=sub, statuses=[])
    try:
        bus.wait_for_subscribers(pub, counter, wanted, timeout_s)
        harness.receive_until_ack(-1, timeout_s=timeout_s)  # start-up done
        yield harness
    finally:
        kill_session(proc)
        pub.close(linger=0)
        sub.close(linger=0)
        ctx.term()


@contextmanager
def contact_stats_node(tmp_path: Path) -> Iterator[Harness]:
    """A `contact_stats` node process in lockstep mode, wired to sockets owned by the test."""
    with node_process(
        tmp_path,
        name="stats",
        node_type="contact_stats",
        params={"report": True},
        publishes={},
        subscribes={"contacts": STATS_INPUT},
        wanted={STATS_INPUT: 1, topics.CLOCK: 1, topics.GRAPH_CONTROL: 1},
        timeout_s=20.0,
    ) as harness:
        yield harness


@contextmanager
def shipped_node(tmp_path: Path, node_type: str) -> Iterator[tuple[Harness, fuzz.FuzzTarget]]:
    """A node process of `node_type` as the shipped launch files configure it (the fuzzer's target), in
    lockstep mode, wired to sockets owned by the test; with that target."""
    target = next(t for t in fuzz.targets(one_per_type=True) if t.process.type == node_type)
    inputs = dict(target.process.subscribes)
    with node_process(
        tmp_path,
        name=node_type,
        node_type=node_type,
        params=target.process.params,
        publishes=dict(target.process.publishes),
        subscribes=inputs,
        wanted={**dict.fromkeys(inputs.values(), 1), topics.CLOCK: 1, topics.GRAPH_CONTROL: 1},
        timeout_s=30.0,
    ) as harness:
        yield harness, target


def contacts(n: int = 3, nan: bool = False) -> ContactSet:
    positions = np.arange(3.0 * n).reshape(n, 3) * 0.01
    if nan:
        positions[n - 1, 1] = np.nan
    return ContactSet(
        stamp_ns=0,
        positions_m=positions,
        local_positions_m=np.zeros((n, 3)),
        normals=np.tile([0.0, 0.0, 1.0], (n, 1)),
        forces_n=np.ones(n),
        links=["tip"] * n,
    )


def counters(status: NodeStatus) -> dict[str, int]:
    return dict(zip(status.counter_names, status.counter_values.tolist(), strict=True))


def test_1000_random_frames_are_counted_and_the_node_keeps_running(tmp_path: Path) -> None:
    rng = np.random.default_rng(1234)
    with contact_stats_node(tmp_path) as node:
        for _ in range(1000):
            node.send(STATS_INPUT, rng.bytes(int(rng.integers(0, 300))))
        node.tick(0)
        assert node.proc.poll() is None, "the node died of garbage input"
        node.send(STATS_INPUT, codec.encode(contacts(3)))  # and it still handles good input
        node.tick(1)
        assert node.stop() == 0
    finished = node.statuses[-1]
    assert (finished.node, finished.state) == ("stats", "finished")
    assert counters(finished)["decode_errors"] == 1000
    assert counters(finished)["messages_in"] == 1
    assert finished.metric_names == ["contacts"] and finished.metric_values.tolist() == [3.0]
    first = next(s for s in node.statuses if s.state == "running")  # published after tick 0
    assert counters(first)["decode_errors"] == 1000
    out = text(node.log)
    assert "node stats, topic sensors/contacts: rejected message (1 so far): " in out
    assert "(1000 so far)" in out  # the log is rate-limited: first 10, then every 100th
    assert out.count("rejected message") == 10 + 10
    assert "summary: 1 contact sets, 3 contacts" in out and "decode errors 1000" in out


def test_nan_in_a_finite_field_is_rejected_with_the_field_name(tmp_path: Path) -> None:
    with contact_stats_node(tmp_path) as node:
        node.send(STATS_INPUT, codec.encode(contacts(2, nan=True)))  # encode() does not validate
        node.send(STATS_INPUT, codec.encode(contacts(4)))
        node.tick(0)
        assert node.stop() == 0
    assert counters(node.statuses[-1])["decode_errors"] == 1
    assert counters(node.statuses[-1])["messages_in"] == 1
    out = text(node.log)
    assert (
        "node stats, topic sensors/contacts: rejected message (1 so far): ContactSet.positions_m must be finite" in out
    )
    assert "summary: 1 contact sets, 4 contacts" in out
    assert "used no message" not in out  # it used one: no end-of-run warning


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (
            codec.encode(Clock(stamp_ns=0, tick=0, period_ns=1, lockstep=True)),
            "expected a ContactSet message, got Clock",
        ),
        (b"\x92\x83\xa4type\xaaContactSet\xa7version\x02\xa6fields\x80\xc4\x00", "ContactSet has schema version 2"),
    ],
    ids=["wrong-type", "wrong-version"],
)
def test_wrong_type_or_version_on_a_topic_is_rejected(tmp_path: Path, payload: bytes, reason: str) -> None:
    with contact_stats_node(tmp_path) as node:
        node.send(STATS_INPUT, payload)
        node.tick(0)
        assert node.stop() == 0
    assert counters(node.statuses[-1])["decode_errors"] == 1
    assert reason in text(node.log)
    # nothing on its input was usable: the end of the run says so, once
    assert "node stats used no message on sensors/contacts: all 1 were refused (1 did not decode" in text(node.log)


@pytest.mark.parametrize("node_type", ["controller", "mapper"])
def test_a_node_process_survives_the_fuzzer_and_counts_what_it_refused(tmp_path: Path, node_type: str) -> None:
    """The issue's check with real processes: 300 fuzz frames per input topic (schema-valid extremes and
    malformed payloads) into the two nodes that died of them; the node acknowledges every tick, every
    frame is counted once (decoded and handled, refused as undecodable, or refused as unusable), and a
    refused input is logged with node, topic, field and reason. The node may end its run as a failure
    (the controller, when a fuzzed pose puts the fingertip past its initial target without a contact):
    an orderly stop whose exit status and log say so."""
    frames = 300
    with shipped_node(tmp_path, node_type) as (node, target):
        inputs = dict(target.process.subscribes)
        rng = np.random.default_rng(15)
        generators = {port: fuzz.FrameGenerator(target.spec.inputs[port].message, rng) for port in inputs}
        for tick in range(frames):
            for port, topic in inputs.items():
                node.send(topic, generators[port].payload()[0])
            node.tick(tick)
        assert node.proc.poll() is None, f"the node died:\n{text(node.log)}"
        status = node.stop()
    assert status in (0, EXIT_RUN_FAILED)
    assert (status == EXIT_RUN_FAILED) == (f"node {node_type} ended the run as a failure" in text(node.log))
    final = counters(node.statuses[-1])
    assert final["messages_in"] + final["decode_errors"] == frames * len(inputs)
    assert final["decode_errors"] > 0.2 * frames and final["input_errors"] > 0.1 * frames
    assert final["messages_in"] > final["input_errors"]  # some input was good enough to use
    out = text(node.log)
    assert f"node {node_type}, topic " in out and ": input rejected, field " in out
    assert "Traceback" not in out


def test_crafted_payloads_repeated_clocks_and_unknown_commands_leave_the_node_running(tmp_path: Path) -> None:
    """Found by an outside fuzzer: an array shape of msgpack `true` (a bool is no int), a Clock of a tick
    already run, and a RunControl that is not "stop" are counted decode errors, and the node goes on;
    the log's throttle counts per topic, so a burst on one topic does not hide another's first error."""
    payload = codec.encode(contacts(3))
    assert payload.count(b"\xa5shape\x91\x03") == 1  # forces_n's shape [3]
    with contact_stats_node(tmp_path) as node:
        node.send(topics.GRAPH_CONTROL, codec.encode(RunControl(stamp_ns=0, command="status?", reason="")))
        for _ in range(11):
            node.send(topics.GRAPH_CONTROL, b"\x00garbage")
        node.send(STATS_INPUT, payload.replace(b"\xa5shape\x91\x03", b"\xa5shape\x91\xc3"))
        node.tick(0)
        node.send(topics.CLOCK, codec.encode(Clock(stamp_ns=0, tick=0, period_ns=10_000_000, lockstep=True)))
        node.send(STATS_INPUT, payload)
        node.tick(1)
        node.tick(2)
        assert node.proc.poll() is None, f"the node stopped:\n{text(node.log)}"
        assert node.stop() == 0
    finished = node.statuses[-1]
    assert finished.state == "finished"
    assert counters(finished)["decode_errors"] == 1 + 11 + 1 + 1
    assert counters(finished)["messages_in"] == 1
    out = text(node.log)
    assert "topic sensors/contacts: rejected message (1 so far): ContactSet.forces_n: shape must be a list" in out
    assert "topic clock: rejected message (1 so far): Clock tick 0 repeats or goes back (last 0)" in out
    assert "unknown RunControl command 'status?'" in out


def test_a_clock_that_skips_ahead_and_an_acknowledgement_ahead_of_the_clock_are_refused(tmp_path: Path) -> None:
    """An outside driver audit: a Clock of tick 25 published by a follower at tick 20 was followed, then the
    clock source's own tick 21 refused as going back, and the run died blaming the controller; one
    LockstepAck of tick t + 1000 filed every later message of its sender under a tick that never came.
    A lockstep clock sends every tick in turn, and no node acknowledges a tick not yet sent: both are
    counted, logged and dropped, and the node goes on."""
    with contact_stats_node(tmp_path) as node:
        node.send(topics.CLOCK, codec.encode(Clock(stamp_ns=0, tick=3, period_ns=10_000_000, lockstep=True)))
        node.tick(0)  # a lockstep clock starts at 0: a first Clock of tick 3 is another publisher's too
        node.send(topics.CLOCK, codec.encode(Clock(stamp_ns=0, tick=25, period_ns=10_000_000, lockstep=True)))
        node.send(topics.LOCKSTEP_ACK, codec.encode(LockstepAck(stamp_ns=0, node="noise", tick=1000)))
        node.send(topics.LOCKSTEP_ACK, codec.encode(LockstepAck(stamp_ns=0, node="noise", tick=1)))  # may be
        node.send(STATS_INPUT, codec.encode(contacts(2)))
        node.pub.send_multipart([STATS_INPUT.encode(), codec.encode(contacts(2)), b"extra"])  # its topic is named
        node.tick(1)
        node.tick(2)
        assert node.proc.poll() is None, f"the node stopped:\n{text(node.log)}"
        assert node.stop() == 0
    finished = counters(node.statuses[-1])
    assert finished["decode_errors"] == 4 and finished["messages_in"] == 1
    out = text(node.log)
    assert "topic clock: rejected message (1 so far): Clock tick 3 skips ahead of tick 0" in out
    assert "topic clock: rejected message (2 so far): Clock tick 25 skips ahead of tick 1" in out
    assert "LockstepAck of tick 1000 from 'noise' is ahead of the clock (last tick 0)" in out
    assert f"topic {STATS_INPUT}: rejected message (1 so far): expected 2 frames [topic, payload], got 3" in out


def test_a_node_that_may_trail_takes_acknowledgements_up_to_trail_ticks_ahead_and_no_further(
    tmp_path: Path,
) -> None:
    """The bound is tight (a review): the clock runs up to TRAIL_TICKS ahead of a node that may trail, so
    an upstream node's acknowledgement may be that far past its last Clock plus one, and no further."""
    with shipped_node(tmp_path, "noise") as (node, target):
        assert target.spec.may_trail
        node.tick(0)
        for ahead in (TRAIL_TICKS + 1, TRAIL_TICKS + 2):  # 0 + 1 + TRAIL_TICKS is the last it takes
            node.send(topics.LOCKSTEP_ACK, codec.encode(LockstepAck(stamp_ns=0, node="sim", tick=ahead)))
        node.tick(1)
        assert node.stop() == 0
    assert counters(node.statuses[-1])["decode_errors"] == 1
    assert f"LockstepAck of tick {TRAIL_TICKS + 2} from 'sim' is ahead of the clock (last tick 0)" in text(node.log)


def test_a_node_started_without_a_launcher_waits_out_a_slow_driver(tmp_path: Path) -> None:
    """The harness's spec names no clock source (clock_name ""), as a spec written by hand may not: two
    silences of the test more than PEER_GRACE_S (2 s) apart once ended such a node, "the clock source ''
    disconnected", since it looked for a subscription hello/ that nobody makes."""
    with contact_stats_node(tmp_path) as node:
        node.tick(0)
        time.sleep(2.3)  # the test thinks between ticks, longer than the grace
        node.send(STATS_INPUT, codec.encode(contacts(2)))
        node.tick(1)
        assert node.stop() == 0
    out = text(node.log)
    assert "disconnected" not in out, out
    assert "summary: 1 contact sets, 2 contacts" in out, out
