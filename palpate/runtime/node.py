"""The node process wrapper: sockets, the lockstep protocol, error counting and shutdown.

A node object (built by its NodeSpec factory) only sees a NodeContext: it publishes messages on its
output ports and receives decoded messages in `on_<port>` methods. Everything about transport lives
here, written once for every node.

Lockstep protocol (deterministic, independent of CPU speed):
1. Start-up: each node waits until every declared subscriber of its topics is connected (XPUB
   subscription counting), then acknowledges tick -1. The clock source starts tick 0 only when
   every node has.
2. The clock source publishes tick t's data, then `Clock(t)`, then waits for `LockstepAck(t)` from
   every node (from a trailing node, `LockstepAck(t - trail_ticks)`: one whose outputs never reach
   the clock source and whose spec says `may_trail`). Only then does it handle the commands it
   received and step again.
3. A node handles tick t when it has `Clock(t)`, `LockstepAck(t)` from every upstream node before it
   in the graph order and `LockstepAck(t-1)` from every upstream node after it (feedback edges).
   Because each publisher-subscriber pair is one ordered connection, every message of tick t from a
   node arrives before that node's acknowledgement (or the clock source's Clock), so each input is
   filed under its publisher's tick. Tick t's inputs are dispatched in a canonical order (publisher
   rank, then arrival), the node's `on_tick` runs, its outputs go out and it acknowledges tick t.
In real-time mode nothing waits: inputs are dispatched as they arrive, and for state topics only
the latest message of a burst is kept.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
import time
import warnings
from collections import Counter, deque
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, cast

import numpy as np
import zmq
from msgpack.exceptions import UnpackException

from palpate.config import load
from palpate.errors import MessageError, OutputError, PalpateError, PeerLostError
from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import Clock, LockstepAck, NodeStatus, RunControl
from palpate.runtime import bus, memory, timing
from palpate.runtime.spec import (
    EXIT_RUN_FAILED,
    START_TIMEOUT_S,
    TRAIL_TICKS,
    ClockSource,
    NodeLike,
    NodeProcessSpec,
    NodeSpec,
)

STOP_TOPIC = topics.GRAPH_CONTROL
#: RunControl commands: "stop" ends the run; "fail" ends it as a failure (each node that receives it exits
#: with EXIT_RUN_FAILED): how a node that is not palpate's (an external driver) makes a run fail.
STOP, FAIL = RunControl.ENDS_RUN
#: Every node publishes its NodeStatus at ticks 0, 100, 200, ... and at exit.
STATUS_EVERY_TICKS = 100
#: In lockstep, a node whose hello/<node> subscription has been gone this long has left the run (its
#: process died or closed its sockets): no lockstep node can rejoin, so the run ends naming it. The grace
#: lets a clean stop arrive first (the stop and the unsubscription come over different connections).
PEER_GRACE_S = 2.0
#: In real time, how often a node looks whether a node that reads from it has left or come back (seconds).
PEER_CHECK_S = 0.5
#: The stop's reason when the clock source's step() ended the run (its simulated duration ran out).
CLOCK_FINISHED = "clock source finished"
_INTERNAL = (topics.CLOCK, topics.LOCKSTEP_ACK, STOP_TOPIC)
#: What odd bytes can raise from decoding besides the codec's named MessageError (a bool where numpy wants
#: an int raised a TypeError that ended the node): counted as decode errors, logged with their type.
_UNDECODABLE = (ValueError, TypeError, KeyError, IndexError, OverflowError, RecursionError, UnpackException)
_LOG_FIRST_ERRORS = 10

log = logging.getLogger("palpate.node")
#: A lockstep follower that has waited this long (wall seconds) for its next tick says once what it waits
#: for (an external clock source's driver that hangs left every node waiting without a word); the
#: environment variable WAIT_NOTE_ENV overrides it.
FOLLOWER_WAIT_NOTE_S = 30.0
WAIT_NOTE_ENV = "PALPATE_WAIT_NOTE_S"
#: In real time, a Clock stamped this much later than the one before is a jump (its stamps are the
#: hardware's time: a driver that paused, or a clock that was set forward), counted and said once.
REALTIME_CLOCK_JUMP_NS = 1_000_000_000

#: A clock source logs how far the run has got every this many seconds of wall time (progress of long
#: graphs); the environment variable PROGRESS_ENV overrides it.
PROGRESS_PERIOD_S = 30.0
PROGRESS_ENV = "PALPATE_PROGRESS_S"


def hello_topic(node: str) -> str:
    """The topic a node subscribes to so that its publishers know it is connected."""
    return f"{topics.HELLO_PREFIX}{node}"


class NodeContext:
    """The node object's view of the graph: publishing, time, randomness and counters (a spec.Context)."""

    def __init__(
        self,
        name: str,
        seed: int,
        send: Callable[[str, Message], None],
        outputs: dict[str, str],
        *,
        send_checks: bool = False,
        may_stop: bool = True,
    ):
        """`send(topic, message)` delivers a message; with `send_checks` it raises MessageError for a
        message that breaks its schema before it delivers anything (the in-process executor's
        `codec.transfer` checks what `codec.validate` checks), so `publish` need not validate first.
        `may_stop`: False for a node whose spec says `may_trail` (its `request_stop` is a bug)."""
        self.name = name
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.stamp_ns = 0
        self.tick = -1
        self.outputs = outputs
        self.counters: dict[str, int] = {
            "messages_in": 0,
            "messages_out": 0,
            "decode_errors": 0,
            "input_errors": 0,
        }
        self.metrics: dict[str, float] = {}
        self.timings: dict[str, float] = {}
        self.stop_requested = ""
        #: Why the run ended when another node ended it (its RunControl reason; "" otherwise), for a node's
        #: close() to report.
        self.run_stopped_by = ""
        #: The reason of the first stop this node asked for with ``failed=True`` ("" if none).
        self.failure = ""
        self._send = send
        self._send_checks = send_checks
        self._may_stop = may_stop
        self._rejections: dict[tuple[str, str], int] = {}
        self._first_rejection = ""
        self.log = logging.getLogger(f"palpate.{name}")

    def publish(self, port: str, message: Message) -> None:
        """Validate and send `message` on the topic wired to output `port`."""
        if port not in self.outputs:
            raise KeyError(f"node {self.name!r} has no output port {port!r}; ports: {sorted(self.outputs)}")
        try:
            if not (self._send_checks and _transfer_checks_all(type(message))):
                codec.validate(message)
            self._send(self.outputs[port], message)
        except MessageError as exc:
            self.counters["output_errors"] = self.counters.get("output_errors", 0) + 1
            raise OutputError(
                f"node {self.name!r} published an invalid {message.TYPE} on port {port!r}: {exc}"
            ) from exc

    def request_stop(self, reason: str, *, failed: bool = False) -> None:
        """Ask the graph to end the run after this tick; ``failed``: because something went wrong (the
        node's process then exits with EXIT_RUN_FAILED, and ``palpate launch`` with 1)."""
        if not self._may_stop:  # the clock source may be ticks ahead of this node: no stop at this tick
            raise RuntimeError(
                f"node {self.name!r} asked to stop the run ({reason}), but its NodeSpec says may_trail=True, "
                "which promises it never does: remove may_trail from the spec"
            )
        rejected = self.counters["input_errors"]
        if failed and rejected and not self.failure:  # the likelier cause, which the reason may not know
            self.log.error(
                "node %s: the failure below follows %d rejected input message(s); the first: %s",
                self.name,
                rejected,
                self._first_rejection,
            )
        self.stop_requested = reason
        if failed and not self.failure:
            self.failure = reason

    def count(self, name: str, n: int = 1) -> None:
        self.counters[name] = self.counters.get(name, 0) + n

    def reject_input(self, topic: str, message: Message, error: PalpateError) -> None:
        """Count a message the node refused (its handler raised `error`) in `input_errors` and log it.

        One line names node, topic, field and reason; per (topic, field) the first 10 rejections are
        logged, then every 100th, each with the running count.
        """
        self.counters["input_errors"] += 1
        field = getattr(error, "field", "")
        where = f"field {message.TYPE}.{field}" if field else message.TYPE
        n = self._rejections[topic, where] = self._rejections.get((topic, where), 0) + 1
        reason = getattr(error, "reason", str(error))
        if not self._first_rejection:
            self._first_rejection = f"topic {topic}, {where}: {reason}"
        if _worth_logging(n):
            self.log.warning(
                "node %s, topic %s: input rejected, %s: %s (%d so far)", self.name, topic, where, reason, n
            )


_TRANSFER_CHECKS_ALL: dict[type[Message], bool] = {}


def _transfer_checks_all(cls: type[Message]) -> bool:
    """True when `codec.transfer` refuses every `cls` message that `codec.validate` refuses: all its
    array fields are floating point (transfer converts an array to the schema's dtype before checking
    it, so a NaN bound for an integer field would pass it as garbage, which validate refuses)."""
    known = _TRANSFER_CHECKS_ALL.get(cls)
    if known is None:
        known = _TRANSFER_CHECKS_ALL[cls] = all(
            spec.kind != "array" or np.dtype(spec.dtype).kind == "f" for spec in cls.field_specs().values()
        )
    return known


def deliver(ctx: NodeContext, node: NodeLike, port: str, topic: str, message: Message) -> bool:
    """Hand one decoded message to the node's ``on_<port>`` handler; False when the node rejected it.

    A PalpateError from the handler (an InputError naming the field, or a core's EstimationError or
    PlanningError) means the message was schema-valid but unusable: it is counted and logged by
    `NodeContext.reject_input`, and the node keeps the state it had. Handlers validate before they
    change state. Any other exception, and an OutputError (the node's own message broke its schema),
    is a bug in the node and propagates.
    """
    return deliver_to(ctx, getattr(node, f"on_{port}"), topic, message)


def deliver_to(ctx: NodeContext, handler: Callable[[Message], object], topic: str, message: Message) -> bool:
    """`deliver` to a handler already looked up (the in-process executor keeps them per topic)."""
    try:
        handler(message)
    except OutputError:
        raise
    except PalpateError as exc:
        ctx.reject_input(topic, message, exc)
        return False
    return True


class NodeRunner:
    """Runs one node object on the bus, in lockstep or real-time mode."""

    def __init__(self, spec: NodeSpec[Any], process: NodeProcessSpec, *, start_timeout_s: float = START_TIMEOUT_S):
        """`spec` as registered; its ports are resolved here for the config of `process.params`."""
        config: Any = load(spec.config, process.params, f"node {process.name!r} params")  # before any socket
        self.spec = spec.with_config(config)
        self.process = process
        self.lockstep = process.mode == "lockstep"
        self.start_timeout_s = start_timeout_s
        self.ack_timeout_s = 120.0
        self.zmq: zmq.Context[Any] = zmq.Context()  # its own: flush_before_exit terminates it
        # a Curve publisher admits only the client keys the launcher lists (a ZAP handler in this process)
        self.allow = bus.ClientAllowList(self.zmq) if process.curve else None
        self.pub = bus.make_publisher(
            self.zmq,
            process.endpoint,
            lockstep=self.lockstep,
            curve=process.curve,
            allow=self.allow,
            curve_clients=process.curve_clients,
        )
        # hello/<name> tells each publisher that this very node is connected (tools that subscribe
        # to topics by name cannot stand in for it in the start-up count)
        wanted = sorted({*process.subscribes.values(), *_INTERNAL, hello_topic(process.name)})
        try:
            self.sub = bus.make_subscriber(
                self.zmq, process.connect, wanted, lockstep=self.lockstep, curve=process.curve
            )
            self.ctx = NodeContext(
                process.name, process.seed, self._send, dict(process.publishes), may_stop=not self.spec.may_trail
            )
            self.node: NodeLike = self.spec.factory(config, self.ctx)
        except BaseException:  # the node never ran: leave no socket, ipc file or ZAP thread behind
            self._close_sockets(linger_ms=0)
            raise
        self.counter = bus.SubscriptionCounter()
        self.poller = zmq.Poller()
        self.poller.register(self.sub, zmq.POLLIN)
        self.poller.register(self.pub, zmq.POLLIN)
        self.port_of_topic = {topic: port for port, topic in process.subscribes.items()}
        self.input_types = {topic: self.spec.inputs[port].message for port, topic in process.subscribes.items()}
        #: (tick due, publisher rank, arrival, topic, payload) of every input not handled yet
        self.buffer: list[tuple[int, int, int, str, bytes]] = []
        self.seq = 0
        self.acks: dict[str, int] = {}
        self.clock_ticks: deque[Clock] = deque()
        self._bad_by_topic: dict[str, int] = {}  # payloads rejected per topic (their log lines are throttled)
        self._undecoded_acks = 0  # acknowledgements that did not decode: no node of theirs to name
        self._refused_by_topic: dict[str, int] = {}  # messages the node's handler refused, per topic
        self._used_topics: set[str] = set()  # topics of which the node took at least one message
        self._superseded_by_topic: Counter[str] = Counter()  # real time: state messages a newer one replaced unread
        self.last_clock = -1  # the last Clock tick received (sent, in the clock source)
        self.last_clock_stamp_ns = -1  # and its stamp (lockstep: the next may not be earlier)
        self._realtime_last_tick: int | None = None  # real time: the tick of the Clock before
        self.refused_clock = ""  # why the last Clock was refused, while no later one was taken
        self.moved_at = time.monotonic()  # when a Clock or an acknowledgement last came: the graph moved
        self._clock_restarted_after = 0  # lockstep: the tick after which a Clock of tick 0 came again
        #: How far ahead of the last Clock an upstream acknowledgement may be: one tick, and a trailing
        #: node's upstream may run TRAIL_TICKS ahead of it.
        self._ack_lead = TRAIL_TICKS if self.spec.may_trail else 0
        self.backward = set(process.backward_upstream)
        self.stopping = False
        self.stop_reason = ""  # the first reason another node (or a signal) gave for stopping the run
        self.fail_asked = False  # a RunControl "fail" came: a clock source ends the run with "fail" too
        self.interrupted = False
        self._absent_since: dict[str, float] = {}  # peer -> when its hello/<peer> subscription was first seen gone
        self._refused_acks: dict[str, str] = {}  # node -> why its first refused acknowledgement was refused
        self._restarted: dict[str, int] = {}  # lockstep: node -> its last tick before it said it was ready again
        #: real time: the nodes that read from this one, those said to have left, and when they were looked at
        hello = topics.HELLO_PREFIX
        self._readers = sorted(t.removeprefix(hello) for t in process.expected_subscribers if t.startswith(hello))
        self._said_gone: set[str] = set()
        self._readers_checked_at = -math.inf
        _install_signal_handlers(self)  # before the manifest: a signal from now on ends the run cleanly
        manifest = bus.Manifest(
            node=process.name,
            endpoint=process.endpoint,
            pid=_pid(),
            publishes={t: self.spec.outputs[p].message.TYPE for p, t in process.publishes.items()},
            subscribes={t: self.input_types[t].TYPE for t in self.input_types},
            curve_public=process.curve.get("public", ""),
        )
        self.manifest_path = manifest.write(process.bus_dir)
        self.timer = timing.recorder(process.name)  # per-tick timestamps when $PALPATE_TICK_TIMING is set
        self._last_sent: tuple[Message | None, bytes] = (None, b"")  # a message published on two topics

    # --- sending -------------------------------------------------------------------------------------
    def _send(self, topic: str, message: Message) -> None:
        if not self.counter.covering(topic):  # no subscriber (ZeroMQ would drop it): do not encode it
            self.ctx.counters["messages_out"] += 1
            return
        last, payload = self._last_sent
        if last is not message:  # the same message on a second topic is encoded once
            payload = self._encode(message)
            self._last_sent = (message, payload)
        self.pub.send_multipart([topic.encode(), payload], copy=False)
        self.ctx.counters["messages_out"] += 1

    def _send_internal(self, topic: str, message: Message) -> None:
        self.pub.send_multipart([topic.encode(), self._encode(message)])

    def _encode(self, message: Message) -> bytes:
        if self.timer is None:
            return codec.encode(message)
        start = time.perf_counter()
        payload = codec.encode(message)
        self.timer.add("encode_s", time.perf_counter() - start)
        return payload

    def publish_status(self, state: str, message: str = "") -> None:
        """Counters and metrics on `status`; wall-clock timings only in real-time mode (a lockstep status,
        like everything else in a lockstep log, depends on the launch and seed alone)."""
        names = sorted(self.ctx.counters)
        figures = self.ctx.metrics if self.lockstep else {**self.ctx.metrics, **self.ctx.timings}
        metric_names = sorted(figures)
        status = NodeStatus(
            stamp_ns=self.ctx.stamp_ns,
            node=self.process.name,
            state=state,
            message=message,
            counter_names=names,
            counter_values=np.array([self.ctx.counters[n] for n in names], dtype=np.int64),
            metric_names=metric_names,
            metric_values=np.array([figures[n] for n in metric_names], dtype=np.float64),
        )
        self._send_internal(topics.NODE_STATUS, status)

    # --- receiving -----------------------------------------------------------------------------------
    def _receive(self, timeout_ms: int) -> bool:
        """Take everything waiting on the sockets; True when something arrived."""
        events = dict(self.poller.poll(timeout_ms))
        got = False
        if self.pub in events:
            while self.pub.poll(0):
                self.counter.feed(self.pub.recv())
        if self.sub in events:
            while self.sub.poll(0):
                frames = self.sub.recv_multipart(copy=False)
                self._on_frames(frames)
                got = True
        return got

    def _on_frames(self, frames: list[Any]) -> None:
        if len(frames) != 2:
            topic = bytes(frames[0].buffer).decode(errors="replace") if frames else "?"
            self._bad_input(topic, f"expected 2 frames [topic, payload], got {len(frames)}")
            return
        topic = bytes(frames[0].buffer).decode(errors="replace")
        payload = frames[1].buffer
        if topic == topics.CLOCK:
            clock = self._decode(topic, payload, Clock)
            if clock is not None and self.lockstep and clock.tick <= self.last_clock:
                if clock.tick == 0 and self.last_clock > 0:  # the clock source's process started again
                    self._clock_restarted_after = self._clock_restarted_after or self.last_clock
                self._refuse_clock(f"Clock tick {clock.tick} repeats or goes back (last {self.last_clock})")
            elif clock is not None and self.lockstep and clock.tick > self.last_clock + 1:
                # the clock source starts at tick 0, waits for this node before its next tick and sends every
                # tick in turn: a tick further on comes from another publisher on the topic
                source = repr(self.process.clock_name) if self.process.clock_name else "the graph's clock source"
                self._refuse_clock(
                    f"Clock tick {clock.tick} skips ahead of tick {self.last_clock + 1}; a lockstep clock source "
                    f"sends every tick in turn from 0 (only it, {source}, publishes on this topic)",
                )
            elif clock is not None and self.lockstep and clock.stamp_ns < max(0, self.last_clock_stamp_ns):
                # simulated time does not run back (the nodes' watchdogs and schedules follow it)
                self._refuse_clock(
                    f"Clock tick {clock.tick} is stamped {clock.stamp_ns} ns, before "
                    + (
                        "the start (0)"
                        if clock.stamp_ns < 0
                        else f"tick {self.last_clock}'s {self.last_clock_stamp_ns} ns"
                    ),
                )
            elif clock is not None:
                if not self.lockstep:
                    self._note_realtime_clock(clock)
                self.clock_ticks.append(clock)
                self.last_clock = max(self.last_clock, clock.tick)
                self.last_clock_stamp_ns = clock.stamp_ns
                self.refused_clock = ""
                self.moved_at = time.monotonic()
                if self.timer is not None:
                    self.timer.mark(clock.tick, "clock_received")
        elif topic == topics.LOCKSTEP_ACK:
            ack = self._decode(topic, payload, LockstepAck)
            self._undecoded_acks += ack is None
            if ack is not None and self.lockstep and ack.tick > self.last_clock + 1 + self._ack_lead:
                # no node acknowledges a tick the clock source has not sent; believed, it would file every
                # later message of that node under a tick that never comes
                reason = (
                    f"LockstepAck of tick {ack.tick} from {ack.node!r} is ahead of the clock "
                    f"(last tick {self.last_clock})"
                )
                self._refused_acks.setdefault(ack.node, reason)
                self._bad_input(topic, reason)
            elif ack is not None:
                if ack.tick == -1 and self.acks.get(ack.node, -2) >= 0:  # ready again, after ticks: it restarted
                    self._restarted.setdefault(ack.node, self.acks[ack.node])
                self.acks[ack.node] = max(ack.tick, self.acks.get(ack.node, -2))
                self.moved_at = time.monotonic()
        elif topic == STOP_TOPIC:
            control = self._decode(topic, payload, RunControl)
            if control is not None and control.command not in (STOP, FAIL):
                self._bad_input(topic, f"unknown RunControl command {control.command!r}; known: 'stop', 'fail'")
            elif control is not None:
                reason = control.reason or ("no reason given" if control.command == FAIL else "")
                if control.command == FAIL and not self.ctx.failure:  # this node's exit code says so too
                    self.ctx.failure = f"{reason} (asked by a RunControl 'fail')"
                self.fail_asked = self.fail_asked or control.command == FAIL
                self.stopping = True
                self.stop_reason = self.stop_reason or reason
                if reason != CLOCK_FINISHED:  # the clock running out is no node ending the run
                    self.ctx.run_stopped_by = self.ctx.run_stopped_by or reason
        elif topic in self.input_types:
            self.seq += 1
            rank = self.process.topic_order.get(topic, 1 << 30)
            self.buffer.append((self._due(topic), rank, self.seq, topic, payload))
        # anything else is a prefix match of another topic: not ours.

    def _note_realtime_clock(self, clock: Clock) -> None:
        """In real time a Clock is the hardware's time and is taken as it comes; one whose stamp goes back,
        repeats a tick, or jumps more than REALTIME_CLOCK_JUMP_NS ahead is counted (``clock_went_back``,
        ``clock_tick_repeated``, ``clock_jumped``) and said once per kind: the nodes' watchdogs and
        odometers follow these stamps, and a lockstep replay of the log refuses such a Clock."""
        last_ns, last_tick = self.last_clock_stamp_ns, self._realtime_last_tick
        self._realtime_last_tick = clock.tick
        if last_tick is None:
            return
        if clock.stamp_ns < last_ns:
            kind = "clock_went_back"
            text = f"stamped {(last_ns - clock.stamp_ns) / 1e9:.6g} s before the one before"
        elif clock.tick <= last_tick:
            kind, text = "clock_tick_repeated", "no later than the tick before"
        elif clock.stamp_ns - last_ns > REALTIME_CLOCK_JUMP_NS:
            kind = "clock_jumped"
            ahead_s = (clock.stamp_ns - last_ns) / 1e9
            text = f"stamped {ahead_s:.6g} s after the one before (a pause, or a clock set forward)"
        else:
            return
        self.ctx.count(kind)
        if self.ctx.counters[kind] == 1:
            source = repr(self.process.clock_name) if self.process.clock_name else "the clock source"
            log.warning(
                "node %s: Clock tick %d (from tick %d) is %s; taken as it comes in real time (counted as %s): a "
                "restarted %s continues its stamps and ticks from where it stopped",
                self.process.name,
                clock.tick,
                last_tick,
                text,
                kind,
                source,
            )

    def _refuse_clock(self, reason: str) -> None:
        """Count and log a refused Clock, and keep the reason for the note of a wait that follows."""
        self.refused_clock = reason
        self._bad_input(topics.CLOCK, reason)

    def _due(self, topic: str) -> int:
        """The tick in which this node handles an input on `topic` that arrives now (lockstep): its
        publisher's tick (messages of a tick precede the publisher's Clock or acknowledgement of it, over
        one ordered connection), one later from a feedback edge; -1 (the next tick) for an unknown one."""
        publisher = self.process.topic_publishers.get(topic, "")
        if not publisher:
            return -1
        tick = self.last_clock + 1 if publisher == self.process.clock_name else self.acks.get(publisher, -1) + 1
        return tick + 1 if publisher in self.backward else tick

    def _note_refused_inputs(self) -> None:
        """At the end of the run, a warning for each topic with refused messages: how many (its first
        refusals are logged above with their reasons), and for an input topic of which every message was
        refused, that the node ran without it. In real time a state message that a newer one replaced was
        never read, so it counts apart; where the node used the topic, how many it skipped so is said too."""
        for topic in sorted(set(self._superseded_by_topic) & self._used_topics):
            log.warning(
                "node %s skipped %d message(s) on %s in this run: newer ones replaced them before it read them "
                "(real time: it handles the newest of a burst; counter superseded)",
                self.process.name,
                self._superseded_by_topic[topic],
                topic,
            )
        for topic in sorted({*self._bad_by_topic, *self._refused_by_topic}):
            undecoded, refused = self._bad_by_topic.get(topic, 0), self._refused_by_topic.get(topic, 0)
            if topic in self._used_topics or topic not in self.input_types:
                log.warning(
                    "node %s refused %d message(s) on %s in this run (%d did not decode, %d were unusable)",
                    self.process.name,
                    undecoded + refused,
                    topic,
                    undecoded,
                    refused,
                )
            else:
                superseded = self._superseded_by_topic.get(topic, 0)
                log.warning(
                    "node %s used no message on %s: %s%d were refused (%d did not decode, %d were unusable)%s",
                    self.process.name,
                    topic,
                    "" if superseded else "all ",
                    undecoded + refused,
                    undecoded,
                    refused,
                    f", {superseded} more were replaced by newer ones unread" if superseded else "",
                )

    def _decode(self, topic: str, payload: Any, cls: type[Message]) -> Any:
        """The message in `payload`, or None after counting and logging why it is unusable."""
        try:
            return codec.decode(payload, cls)
        except MessageError as exc:
            self._bad_input(topic, str(exc))
        except _UNDECODABLE as exc:  # a fault the codec does not name must not end the node either
            self._bad_input(topic, f"undecodable payload ({type(exc).__name__}: {exc})")
        return None

    def _bad_input(self, topic: str, reason: str) -> None:
        """Count a payload this node could not use in `decode_errors`; per topic the first 10 are logged,
        then every 100th, each with the topic's running count."""
        self.ctx.counters["decode_errors"] += 1
        n = self._bad_by_topic[topic] = self._bad_by_topic.get(topic, 0) + 1
        if _worth_logging(n):
            log.warning("node %s, topic %s: rejected message (%d so far): %s", self.process.name, topic, n, reason)

    def dispatch(self, latest_only: bool = False, tick: int | None = None) -> None:
        """Decode and hand buffered inputs to the node: in lockstep those due by `tick` (None: all), in
        canonical order (publisher rank, then arrival)."""
        if self.lockstep:
            if tick is None:
                batch, self.buffer = self.buffer, []
            else:
                batch = [item for item in self.buffer if item[0] <= tick]
                self.buffer = [item for item in self.buffer if item[0] > tick] if len(batch) < len(self.buffer) else []
            batch.sort(key=_canonical)
        else:
            batch, self.buffer = self.buffer, []
        if latest_only:
            kept = _latest_state_messages(batch, self.input_types)
            if len(kept) < len(batch):
                self._superseded_by_topic.update(Counter(item[3] for item in batch) - Counter(item[3] for item in kept))
                skipped = len(batch) - len(kept)
                self.ctx.counters["superseded"] = self.ctx.counters.get("superseded", 0) + skipped
            batch = kept
        for _, _, _, topic, payload in batch:
            message = self._decode(topic, payload, self.input_types[topic])
            if message is None:
                continue
            self.ctx.counters["messages_in"] += 1
            if deliver(self.ctx, self.node, self.port_of_topic[topic], topic, message):
                self._used_topics.add(topic)
            else:
                self._refused_by_topic[topic] = self._refused_by_topic.get(topic, 0) + 1

    # --- main loops ----------------------------------------------------------------------------------
    def run(self) -> int:
        """Run until the graph stops or a signal arrives; returns the process exit code."""
        try:
            self._start_up()
            if self.spec.clock_source:
                self._run_clock_source()
            else:
                self._run_follower()
            if self.lockstep and self.ctx.timings:
                timings = ", ".join(f"{k} {v:.4g}" for k, v in sorted(self.ctx.timings.items()))
                log.info("node %s wall-clock timings: %s", self.process.name, timings)
            self._note_refused_inputs()
            if self.ctx.failure:
                log.error("node %s ended the run as a failure: %s", self.process.name, self.ctx.failure)
                self.publish_status("error", self.ctx.failure)
                return EXIT_RUN_FAILED
            self.publish_status("finished", self.ctx.stop_requested)
            return 0
        except (TimeoutError, PeerLostError) as exc:
            log.error("node %s: %s", self.process.name, exc)
            self._note_refused_inputs()  # (what it refused may be why)
            self.publish_status("error", str(exc))
            return 3
        except PalpateError as exc:
            log.error("node %s stopped: %s", self.process.name, exc)
            self._note_refused_inputs()
            self.publish_status("error", str(exc))
            return 2
        finally:
            try:
                close = getattr(self.node, "close", None)
                if close is not None:
                    close()
                if self.timer is not None:
                    self.timer.write(self.spec.clock_source, self.process.trailing_nodes)
            finally:  # even when the node's close() fails: no stale manifest, socket or ipc file
                self.manifest_path.unlink(missing_ok=True)
                self._close_sockets(linger_ms=1000)  # what is queued still leaves: see flush_before_exit

    def _close_sockets(self, linger_ms: int) -> None:
        """Close the sockets this runner opened, remove its ipc file and stop its ZAP handler."""
        self.pub.close(linger=linger_ms)
        if hasattr(self, "sub"):
            self.sub.close()
        bus.remove_ipc_file(self.process.endpoint)  # now: zmq would unlink it later, in its I/O thread
        if self.allow is not None:
            self.allow.close()

    def _start_up(self) -> None:
        deadline = time.monotonic() + self.start_timeout_s
        expected = self.process.expected_subscribers
        while not self.counter.satisfied(expected):
            if self.interrupted:
                return
            if time.monotonic() > deadline:
                missing = self.counter.missing(expected)
                hello = topics.HELLO_PREFIX
                names = sorted(t.removeprefix(hello) for t in missing if t.startswith(hello))
                absent = ", ".join(names)
                hello_of = f"{hello}{names[0]}" if len(names) == 1 else f"{hello}<its name>"
                hint = (
                    f"; not connected: {absent} (an external node's driver not started, or not subscribed to "
                    f"{hello_of}?)"
                    if absent
                    else ""
                )
                raise TimeoutError(f"subscribers never connected within {self.start_timeout_s:.0f} s: {missing}{hint}")
            self._receive(50)
        if self.lockstep:
            self._send_internal(topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node=self.process.name, tick=-1))

    def _wait_for_acks(self, nodes: list[str], tick: int) -> None:
        deadline = time.monotonic() + self.ack_timeout_s
        what = f"tick {tick}" if tick >= 0 else "the start (tick -1: every node ready)"
        while not self.interrupted and any(self.acks.get(n, -2) < tick for n in nodes):
            if restarted := [n for n in nodes if n in self._restarted and self.acks.get(n, -2) < tick]:
                raise PeerLostError(
                    f"no acknowledgement of {what}: {', '.join(map(repr, restarted))} started again after tick "
                    f"{self._restarted[restarted[0]]} (it acknowledged the start anew); a lockstep node cannot rejoin "
                    "a run: start a new launch"
                )
            if time.monotonic() > deadline:
                late = holding_up(self.acks, tick, self.process, nodes)
                refused = "".join(
                    f"; {n} sent an acknowledgement that was refused: {self._refused_acks[n]}"
                    for n in late
                    if n in self._refused_acks
                )
                if self._undecoded_acks:  # perhaps the late node's, but none of them can be named
                    refused += f"; {self._undecoded_acks} acknowledgement(s) did not decode (logged above)"
                raise TimeoutError(f"no acknowledgement of {what} from {late} in {self.ack_timeout_s:.0f} s{refused}")
            if not self._receive(100) and (gone := self._gone(self.process.lockstep_nodes)):
                raise PeerLostError(f"no acknowledgement of {what}: {_left(gone)}")

    def _gone(self, peers: list[str]) -> list[str]:
        """Those of `peers` (each subscribed hello/<peer> here at start-up) whose subscription has been gone
        for PEER_GRACE_S."""
        now = time.monotonic()
        gone = []
        for peer in peers:
            if self.counter.counts.get(hello_topic(peer), 0) > 0:
                self._absent_since.pop(peer, None)
            elif now - self._absent_since.setdefault(peer, now) >= PEER_GRACE_S:
                gone.append(peer)
        return gone

    def _note_readers(self) -> None:
        """Real time: say once that a node reading from this one has left (its hello/<peer> subscription
        gone for PEER_GRACE_S: a driver that died), and that it is back when it reconnects. Nothing waits
        for it, so without this line a dead driver went unnoticed."""
        now = time.monotonic()
        if self.lockstep or now - self._readers_checked_at < PEER_CHECK_S:
            return
        self._readers_checked_at = now
        gone = set(self._gone(self._readers))
        if gone - self._said_gone:
            self._receive(0)  # a stop already here (the readers left at the run's end) is no driver lost
            if self.stopping:
                return
        for peer in sorted(gone - self._said_gone):
            log.warning(
                "node %s: %r disconnected (subscription %s gone for %.0f s: its process died or closed its sockets); "
                "the real-time graph runs on without it, and takes it back when it reconnects",
                self.process.name,
                peer,
                hello_topic(peer),
                PEER_GRACE_S,
            )
        for peer in sorted(p for p in self._said_gone if self.counter.counts.get(hello_topic(p), 0) > 0):
            log.info("node %s: %r reconnected", self.process.name, peer)
            self._said_gone.discard(peer)
        self._said_gone |= gone

    def _run_clock_source(self) -> None:
        step = cast(ClockSource, self.node).step  # spec.clock_source says so
        period_ns = int(getattr(self.node, "period_ns", 0))
        trailing = sorted(self.process.trailing_nodes)
        in_loop = [n for n in self.process.lockstep_nodes if n not in trailing]
        if self.lockstep:
            self._wait_for_acks(self.process.lockstep_nodes, -1)
        start = time.monotonic()
        progress_s = _seconds_from_env(PROGRESS_ENV, PROGRESS_PERIOD_S)
        next_report = start + progress_s
        tick = 0
        timer = self.timer
        while not self.interrupted:
            self.ctx.tick = tick
            if timer is not None:
                timer.tick = tick
                timer.mark(tick, "step")
            stamp = step()
            if stamp is None:
                break
            if self.lockstep and (why := clock_went_back(self.process.name, tick, stamp, self.ctx.stamp_ns)):
                self.ctx.request_stop(why, failed=True)  # every follower would refuse it, and wait in vain
                break
            self._last_sent = (None, b"")
            if timer is not None:
                timer.mark(tick, "stepped")
            self.ctx.stamp_ns = stamp
            if timer is not None:
                timer.mark(tick, "clock_sent")  # just before: the hop includes encoding the Clock
            self._send_internal(
                topics.CLOCK, Clock(stamp_ns=stamp, tick=tick, period_ns=period_ns, lockstep=self.lockstep)
            )
            self.last_clock = tick
            if self.lockstep:
                self._wait_for_acks(in_loop, tick)
                if trailing:  # nodes that read nothing of the loop: up to trail_ticks ticks behind
                    self._wait_for_acks(trailing, tick - self.process.trail_ticks)
                if timer is not None:
                    timer.mark(tick, "acked")
                self.dispatch()
                if timer is not None:
                    timer.mark(tick, "dispatched")
            else:
                wake = start + (tick + 1) * period_ns * 1e-9
                while (left := wake - time.monotonic()) > 0 and not self.interrupted:
                    self._receive(int(left * 1000) + 1)
                self._receive(0)
                self.dispatch(latest_only=True)
                self._note_readers()
            if tick % STATUS_EVERY_TICKS == 0:
                self.publish_status("running")
            if self.stopping or self.ctx.stop_requested:
                break
            tick += 1
            if (now := time.monotonic()) >= next_report:
                next_report = now + progress_s
                wall_s, sim_s = now - start, self.ctx.stamp_ns * 1e-9
                log.info("t = %.1f s after %.0f s of wall time (%.2fx real time)", sim_s, wall_s, sim_s / wall_s)
        reason = self.ctx.stop_requested or self.stop_reason or CLOCK_FINISHED
        log.info("run stopped at t = %.3f s: %s", self.ctx.stamp_ns * 1e-9, reason)
        command = FAIL if self.fail_asked else STOP  # a "fail" reaches the nodes that hear only the clock
        self._send_internal(STOP_TOPIC, RunControl(stamp_ns=self.ctx.stamp_ns, command=command, reason=reason))

    def _run_follower(self) -> None:
        tick = 0
        timer = self.timer
        waiting_since, told = time.monotonic(), False  # since the last tick ran; whether the wait was said
        note_s = _seconds_from_env(WAIT_NOTE_ENV, FOLLOWER_WAIT_NOTE_S)
        while not self.interrupted:
            if self.lockstep:
                due = self._due_tick(tick)
                if due is None:
                    if self.stopping and not self.clock_ticks:
                        break
                    waited_s = time.monotonic() - waiting_since
                    if tick > 0 and not told and waited_s >= note_s:  # (not a slow start)
                        told = True
                        log.warning(
                            "node %s: no tick for %.0f s: waiting for %s",
                            self.process.name,
                            waited_s,
                            self._awaited(tick),
                        )
                    clock_name = self.process.clock_name  # "" in a spec made without a launcher: no clock to lose
                    received = self._receive(100)
                    still_s = time.monotonic() - max(waiting_since, self.moved_at)
                    if not self.stopping and (why := self._clock_lost(clock_name, received, tick, still_s)):
                        # nothing more will come: close in order, as a failed run (the launch exits 1), and say so
                        # to the graph (a clock source still there then ends the run as a failure too)
                        self.ctx.failure = self.ctx.run_stopped_by = why
                        reason = f"{self.process.name}: {why}"
                        self._send_internal(
                            STOP_TOPIC, RunControl(stamp_ns=self.ctx.stamp_ns, command=FAIL, reason=reason)
                        )
                        break
                    continue
                tick = due
                waiting_since, told = time.monotonic(), False
                if timer is not None:
                    timer.tick = tick
                    timer.mark(tick, "ready")
                clock = self.clock_ticks.popleft()
                self.ctx.stamp_ns, self.ctx.tick = clock.stamp_ns, clock.tick
                self.dispatch(tick=tick)
                if timer is not None:
                    timer.mark(tick, "dispatched")
                self.node.on_tick(clock.stamp_ns)
                self._after_tick()
                self._last_sent = (None, b"")
                if timer is not None:
                    timer.mark(tick, "ack_sent")  # just before: the hop includes encoding the acknowledgement
                self._send_internal(
                    topics.LOCKSTEP_ACK,
                    LockstepAck(stamp_ns=clock.stamp_ns, node=self.process.name, tick=tick),
                )
                tick += 1
            else:
                self._receive(100)
                self.dispatch(latest_only=True)
                self._note_readers()
                told = told or self._said_no_clock(time.monotonic() - waiting_since, note_s)
                while self.clock_ticks:
                    clock = self.clock_ticks.popleft()
                    self.ctx.stamp_ns, self.ctx.tick = clock.stamp_ns, clock.tick
                    self.node.on_tick(clock.stamp_ns)
                    self._after_tick()
                if self.stopping:
                    break

    def _said_no_clock(self, waited_s: float, note_s: float) -> bool:
        """In real time, in a graph with a clock source: say (True) that inputs arrive but no Clock has come
        once ``waited_s`` >= ``note_s`` (a clock-source driver that sends no Clock left the graph doing
        nothing without a word)."""
        if not self.process.clock_name:  # a real-time graph may have no clock source: nothing to wait for
            return False
        if self.last_clock >= 0 or not self.ctx.counters["messages_in"] or waited_s < note_s:
            return False
        log.warning(
            "node %s: inputs arrive but no Clock came in %.0f s: in real time a node acts on each Clock of the "
            "clock source (a driver that plays it publishes Clock on topic %s)",
            self.process.name,
            waited_s,
            topics.CLOCK,
        )
        return True

    def _clock_lost(self, clock_name: str, received: bool, tick: int, still_s: float) -> str:
        """Why a lockstep follower waiting for `tick` will get no more ticks ("" while it may): the clock
        source left, started again (a Clock of tick 0 after others), or nothing moved in the graph (no Clock,
        no acknowledgement) for ``still_s`` > twice ack_timeout_s: the clock source gives up on a slow node
        after ack_timeout_s, so only a hung one stays still that long."""
        if clock_name and not received and self._gone([clock_name]):
            return f"the clock source {_left([clock_name])}"
        if self._clock_restarted_after:
            return (
                f"the clock source {clock_name or 'of the graph'} started again after tick "
                f"{self._clock_restarted_after} (a Clock of tick 0 came); a lockstep run cannot go on with it: start a "
                "new launch"
            )
        if tick > 0 and still_s > 2 * self.ack_timeout_s:
            awaited = self._awaited(tick)
            return (
                f"nothing moved in the graph for {still_s:.0f} s (no Clock, no acknowledgement): waited for {awaited}"
            )
        return ""

    def _awaited(self, tick: int) -> str:
        """What a lockstep follower waits for to run `tick`: the clock source's Clock, or acknowledgements."""
        if not self.clock_ticks:
            clock = self.process.clock_name or "the clock source"
            refused = f"; this node refused its last Clock: {self.refused_clock}" if self.refused_clock else ""
            return (
                f"tick {tick} from the clock source {clock} (its process or driver hung, or a node it waits for is "
                f"slow{refused})"
            )
        due = self.clock_ticks[0].tick
        late = [n for n in self.process.forward_upstream if self.acks.get(n, -2) < due]
        late += [n for n in self.process.backward_upstream if self.acks.get(n, -2) < due - 1]
        return f"the acknowledgements of tick {due} from {', '.join(sorted(set(late)))}"

    def _due_tick(self, tick: int) -> int | None:
        """The tick to run now (lockstep): the oldest Clock's, which is `tick` (Clocks come in turn from 0:
        ``_on_frames`` refuses the others); None until it and the upstream nodes' acknowledgements are in."""
        if not self.clock_ticks:
            return None
        due = self.clock_ticks[0].tick
        forward = all(self.acks.get(n, -2) >= due for n in self.process.forward_upstream)
        backward = all(self.acks.get(n, -2) >= due - 1 for n in self.process.backward_upstream)
        if not (forward and backward):
            return None
        return due

    def _after_tick(self) -> None:
        if self.ctx.stop_requested:
            self._send_internal(
                STOP_TOPIC,
                RunControl(stamp_ns=self.ctx.stamp_ns, command="stop", reason=self.ctx.stop_requested),
            )
            self.ctx.stop_requested = ""
        if self.ctx.tick % STATUS_EVERY_TICKS == 0:
            self.publish_status("running")


def clock_went_back(name: str, tick: int, stamp_ns: int, last_ns: int) -> str:
    """Why a lockstep clock source ``name`` cannot publish ``stamp_ns`` at ``tick`` after ``last_ns`` at the
    tick before ("" when it can): a lockstep clock runs forward from 0."""
    if stamp_ns >= (last_ns if tick else 0):
        return ""
    before = f"tick {tick - 1}'s {last_ns} ns" if tick else "the start (0)"
    return (
        f"{name}: the clock's stamp at tick {tick} is {stamp_ns} ns, before {before}: a lockstep clock runs forward "
        "(a log recorded in real time whose clock went back replays with mode:=realtime)"
    )


def holding_up(
    acks: dict[str, int], tick: int, process: NodeProcessSpec, waited: Sequence[str] | None = None
) -> list[str]:
    """The nodes that hold tick `tick` up (clock source, lockstep): of those waited for (default every
    lockstep node; not the trailing ones when the clock waits for tick t - trail_ticks of those) that have not
    acknowledged it, the ones that have every acknowledgement their own next tick needs
    (`process.lockstep_upstream`); the others wait for them. All that have not, if none has (a graph the
    spec does not describe)."""
    late = [n for n in (process.lockstep_nodes if waited is None else waited) if acks.get(n, -2) < tick]

    def ready(node: str) -> bool:
        next_tick = acks.get(node, -2) + 1
        waits = process.lockstep_upstream.get(node, {})
        return next_tick < 0 or (
            all(acks.get(n, -2) >= next_tick for n in waits.get("forward", []))
            and all(acks.get(n, -2) >= next_tick - 1 for n in waits.get("backward", []))
        )

    return [n for n in late if ready(n)] or late


def _seconds_from_env(name: str, default: float) -> float:
    """Seconds from environment variable `name`, else `default` (also, with a warning, for a value that is
    not a positive number: every node read it and failed)."""
    text = os.environ.get(name)
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0:
        log.warning("$%s=%r is not a positive number of seconds; using %g", name, text, default)
        return default
    return value


def _left(peers: list[str]) -> str:
    """What a lost lockstep peer's error says."""
    hellos = ", ".join(topics.HELLO_PREFIX + peer for peer in peers)
    return (
        f"{', '.join(map(repr, peers))} disconnected without a stop (subscription {hellos} gone for "
        f"{PEER_GRACE_S:.0f} s: the process died or closed its sockets; a lockstep node cannot rejoin a run)"
    )


def _worth_logging(n: int) -> bool:
    """Whether the n-th rejection of one kind is logged: the first 10, then every 100th."""
    return n <= _LOG_FIRST_ERRORS or n % 100 == 0


def _canonical(item: tuple[int, int, int, str, bytes]) -> tuple[int, int]:
    """Dispatch order of a buffered input: publisher rank, then arrival."""
    return item[1], item[2]


def _latest_state_messages(
    batch: list[tuple[int, int, int, str, bytes]], types: dict[str, type[Message]]
) -> list[tuple[int, int, int, str, bytes]]:
    """Keep, for topics of state messages, only the newest entry of the batch."""
    latest: dict[str, int] = {}
    for i, (_, _, _, topic, _) in enumerate(batch):
        if getattr(types[topic], "STATE", False):
            latest[topic] = i
    return [item for i, item in enumerate(batch) if not getattr(types[item[3]], "STATE", False) or latest[item[3]] == i]


def _pid() -> int:
    return os.getpid()


def _install_signal_handlers(runner: NodeRunner) -> None:
    def handle(signum: int, frame: FrameType | None) -> None:
        runner.interrupted = True
        reason = f"interrupted by {signal.Signals(signum).name}"
        runner.stop_reason = runner.stop_reason or reason
        # for close(): the run was ended, not finished (an evaluator reports `stopped`, not `clock`)
        runner.ctx.run_stopped_by = runner.ctx.run_stopped_by or reason

    signal.signal(signal.SIGTERM, handle)
    signal.signal(signal.SIGINT, handle)


def main(argv: list[str] | None = None) -> int:
    """Entry point of a node process: ``python -m palpate.runtime.node SPEC.json``."""
    from palpate.runtime.registry import load_node_spec

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m palpate.runtime.node NODE_SPEC.json", file=sys.stderr)
        return 64
    process = NodeProcessSpec.from_json(Path(args[0]).read_text())
    memory.keep_freed_buffers()  # reuse big payload buffers instead of faulting fresh pages in per message
    logging.basicConfig(level=logging.INFO, format=f"[{process.name}] %(levelname)s %(message)s", stream=sys.stderr)
    warnings.showwarning = _log_warning
    try:
        runner = NodeRunner(load_node_spec(process.node_spec, label=process.type), process)
    except PalpateError as exc:
        log.error("node %s could not start: %s", process.name, exc)
        return 2
    except KeyboardInterrupt:  # a signal while the node object was being built (before its handlers)
        log.info("node %s interrupted while starting", process.name)
        return 130
    try:
        return runner.run()
    finally:
        if not flush_before_exit(runner.zmq, timeout_s=1.0):
            log.warning("node %s: messages still queued after 1 s at exit were dropped", process.name)


def _log_warning(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> None:
    """A warning in a node process as one log line, ``[node] WARNING MeshWarning: ...`` (Python's own
    format adds the source line that raised it, which says nothing to a user)."""
    log.warning("%s: %s", category.__name__, message)


def flush_before_exit(context: zmq.Context[Any], timeout_s: float) -> bool:
    """Let the messages still queued on the closed sockets of `context` (the final NodeStatus, the
    clock source's stop) leave before the process exits, for at most `timeout_s`; True when they did.
    Terminates `context`: call it last, on a context of one's own.

    pyzmq does not terminate its context at exit, and without that the queued messages die with the
    process. ``term()`` blocks until every socket is closed, so it runs in a daemon thread: a socket
    left open cannot hold the exit longer than `timeout_s`.
    """
    ender = threading.Thread(target=context.term, name="zmq-flush", daemon=True)
    ender.start()
    ender.join(timeout_s)
    return not ender.is_alive()


if __name__ == "__main__":
    sys.exit(main())
