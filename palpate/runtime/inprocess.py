"""Run a resolved graph in one process, with exactly the lockstep semantics of the bus.

Evaluations run hundreds of episodes; starting processes and moving bytes through sockets for each
would dominate their cost. This executor builds the same node objects from the same launch file and
calls them in the order the lockstep protocol guarantees (see palpate/runtime/node.py):

- tick t: the clock source steps and publishes; then every other node, in graph rank order,
  handles its buffered inputs sorted by (publisher rank, publish order), runs `on_tick` and
  publishes; messages a node sends to an earlier-ranked node (a feedback edge) wait for tick t+1;
  last, the clock source handles its inputs.
- a stop request ends the run after the tick in which it was made.

Messages go through the codec (`codec.transfer`: what `decode(encode(message))` gives, without the
bytes), so nodes see exactly what they would see on the bus; a message on a topic that no node reads
(and no listener) is only validated, as a node process only validates what no subscriber receives.
A message published on several topics in a row (a sim's joint states, also its truth) is transferred
or validated once. A test runs a launch file both ways and compares the contacts. The executor takes
the nodes already resolved (a launch file's `Graph.in_process_members()`), so the runtime needs no
launcher.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

from palpate.config import load
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.runtime.node import NodeContext, clock_went_back, deliver_to
from palpate.runtime.spec import ClockSource, NodeLike, NodeProcessSpec, NodeSpec

#: Called for every message published: (tick, node name, topic, message).
Listener = Callable[[int, str, str, Message], None]


@dataclass
class _Member:
    rank: int
    spec: NodeSpec[Any]
    process: NodeProcessSpec
    ctx: NodeContext
    obj: NodeLike
    inbox: list[tuple[int, int, str, Message]] = field(default_factory=list)
    #: The last message this node sent and what subscribers got (a message sent on two topics is
    #: transferred once); forgotten after every tick.
    last_sent: tuple[Message | None, Message | None] = (None, None)
    #: Per input topic: the bound ``on_<port>`` handler of its port, looked up at the first message.
    handlers: dict[str, Callable[[Message], object]] = field(default_factory=dict)
    #: The names of this node's parts in `InProcessGraph.timing`: its input handling and its on_tick.
    inputs_part: str = field(init=False)
    on_tick_part: str = field(init=False)

    def __post_init__(self) -> None:
        self.inputs_part = f"{self.process.name}.inputs"
        self.on_tick_part = f"{self.process.name}.on_tick"


class InProcessGraph:
    """A graph whose nodes run as objects in this process, in lockstep order."""

    def __init__(
        self,
        nodes: Sequence[tuple[NodeSpec[Any], NodeProcessSpec]],
        *,
        listener: Listener | None = None,
        profile: bool = False,
    ):
        """`nodes`: each node's spec and process spec, in graph rank order (the clock source first).

        With `profile`, `timing` accumulates wall seconds per part of a tick: ``step`` (the clock
        source's step, its publishing included), ``transfer`` (delivering messages), and per node
        ``<name>.inputs`` (its handlers) and ``<name>.on_tick`` (publishing included).
        """
        self.listener = listener
        self.timing: dict[str, float] | None = {} if profile else None
        #: With `profile`: the first tick timed (ticks before it warm up).
        self.profile_from_tick = 0
        self._timing_now: dict[str, float] | None = None
        self.seq = 0
        self.tick = -1
        self.stop_reason = ""
        #: The reason of the first stop a node asked for as a failure ("" if none).
        self.failure = ""
        self.members: list[_Member] = []
        for rank, (spec, process) in enumerate(nodes):
            ranked = {process.topic_order.get(topic, rank) for topic in process.publishes.values()}
            if ranked - {rank}:
                raise ValueError(
                    f"node {process.name!r} is passed at position {rank} but ranks {min(ranked - {rank})} in its "
                    "graph: pass the nodes in rank order (Graph.in_process_members())"
                )
            # codec.transfer checks each message as validate would: publish need not validate first
            ctx = NodeContext(
                process.name,
                process.seed,
                self._sender(rank),
                dict(process.publishes),
                send_checks=True,
                may_stop=not spec.may_trail,
            )
            config = load(spec.config, process.params, f"node {process.name!r} params")
            self.members.append(_Member(rank, spec, process, ctx, spec.factory(config, ctx)))
        self.subscribers: dict[str, list[_Member]] = {}
        for member in self.members:
            for topic in member.process.subscribes.values():
                self.subscribers.setdefault(topic, []).append(member)
        self.clock = next(m for m in self.members if m.process.clock_source)
        self.followers = [m for m in self.members if m is not self.clock]

    def _sender(self, rank: int) -> Callable[[str, Message], None]:
        def send(topic: str, message: Message) -> None:
            sender = self.members[rank]
            receivers = self.subscribers.get(topic, [])
            last, decoded = sender.last_sent
            if not receivers and self.listener is None:  # nobody receives it: only the check (as on the bus)
                if last is not message:  # a message on several topics is checked once, as it is transferred once
                    codec.validate(message)
                    sender.last_sent = (message, None)
                sender.ctx.counters["messages_out"] += 1
                return
            if last is not message or decoded is None:
                timing = self._timing_now
                start = time.perf_counter() if timing is not None else 0.0
                decoded = codec.transfer(message)  # = decode(encode(message)), without the bytes
                sender.last_sent = (message, decoded)
                if timing is not None:
                    _add(timing, "transfer", start)
            self.seq += 1
            for member in receivers:
                member.inbox.append((rank, self.seq, topic, decoded))
            sender.ctx.counters["messages_out"] += 1
            if self.listener is not None:
                self.listener(self.tick, sender.process.name, topic, decoded)

        return send

    def run(self, max_ticks: int | None = None) -> int:
        """Run until the clock source ends, a node asks to stop, or `max_ticks`; returns ticks run."""
        ticks = 0
        while max_ticks is None or ticks < max_ticks:
            self.tick = ticks
            self.clock.ctx.tick = ticks
            timing = self.timing if ticks >= self.profile_from_tick else None
            self._timing_now = timing
            start = time.perf_counter() if timing is not None else 0.0
            stamp = cast(ClockSource, self.clock.obj).step()  # the launcher checked: process.clock_source
            if timing is not None:
                _add(timing, "step", start)
            if stamp is None:
                break
            if why := clock_went_back(self.clock.process.name, ticks, stamp, self.clock.ctx.stamp_ns):
                self.clock.ctx.request_stop(why, failed=True)  # as the process runtime does
                self._collect_stop(self.clock)
                break
            for member in self.members:
                member.ctx.stamp_ns, member.ctx.tick = stamp, ticks
                member.last_sent = (None, None)
            for member in self.followers:
                if timing is None:
                    self._dispatch(member)
                    member.obj.on_tick(stamp)
                else:
                    start = time.perf_counter()
                    self._dispatch(member)
                    _add(timing, member.inputs_part, start)
                    start = time.perf_counter()
                    member.obj.on_tick(stamp)
                    _add(timing, member.on_tick_part, start)
                self._collect_stop(member)
            start = time.perf_counter() if timing is not None else 0.0
            self._dispatch(self.clock)
            if timing is not None:
                _add(timing, self.clock.inputs_part, start)
            self._collect_stop(self.clock)
            ticks += 1
            if self.stop_reason:
                break
        for member in self.members:
            if member.ctx.stop_requested != self.stop_reason:  # another node ended the run
                member.ctx.run_stopped_by = self.stop_reason
            close = getattr(member.obj, "close", None)
            if close is not None:
                close()
        return ticks

    def _dispatch(self, member: _Member) -> None:
        if not member.inbox:
            return
        # entries arrive in publish order (seq), so a stable sort by publisher rank gives (rank, seq)
        batch = sorted(member.inbox, key=_publisher_rank) if len(member.inbox) > 1 else member.inbox
        member.inbox = []
        counters, handlers = member.ctx.counters, member.handlers
        for _, _, topic, message in batch:
            counters["messages_in"] += 1
            handler = handlers.get(topic)
            if handler is None:
                handler = handlers[topic] = self._handler(member, topic)
            deliver_to(member.ctx, handler, topic, message)

    @staticmethod
    def _handler(member: _Member, topic: str) -> Callable[[Message], object]:
        """The ``on_<port>`` handler of the port that reads `topic`."""
        port = {wired: port for port, wired in member.process.subscribes.items()}[topic]
        handler: Callable[[Message], object] = getattr(member.obj, f"on_{port}")
        return handler

    def _collect_stop(self, member: _Member) -> None:
        if member.ctx.stop_requested and not self.stop_reason:
            self.stop_reason = member.ctx.stop_requested
        if member.ctx.failure and not self.failure:
            self.failure = member.ctx.failure

    def node(self, name: str) -> Any:
        """The node object called `name` (for reading results after a run)."""
        return next(m.obj for m in self.members if m.process.name == name)


def _publisher_rank(item: tuple[int, int, str, Message]) -> int:
    return item[0]


def _add(timing: dict[str, float], name: str, start: float) -> None:
    """Add the wall seconds since ``start`` to ``timing[name]``."""
    timing[name] = timing.get(name, 0.0) + time.perf_counter() - start
