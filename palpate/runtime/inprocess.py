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
bytes), so nodes see exactly what they would see on the bus. A test runs a launch file both ways and
compares the contacts. The executor takes the nodes already resolved (a launch file's
`Graph.in_process_members()`), so the runtime needs no launcher.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

from palpate.config import load
from palpate.errors import MessageError, PalpateError
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.runtime.node import NodeContext
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


class InProcessGraph:
    """A graph whose nodes run as objects in this process, in lockstep order."""

    def __init__(self, nodes: Sequence[tuple[NodeSpec[Any], NodeProcessSpec]], *, listener: Listener | None = None):
        """`nodes`: each node's spec and process spec, in graph rank order (the clock source first)."""
        self.listener = listener
        self.seq = 0
        self.tick = -1
        self.stop_reason = ""
        self.members: list[_Member] = []
        for rank, (spec, process) in enumerate(nodes):
            ctx = NodeContext(process.name, process.seed, self._sender(rank), dict(process.publishes))
            config = load(spec.config, process.params, f"node {process.name!r} params")
            self.members.append(_Member(rank, spec, process, ctx, spec.factory(config, ctx)))
        self.subscribers: dict[str, list[_Member]] = {}
        for member in self.members:
            for topic in member.process.subscribes.values():
                self.subscribers.setdefault(topic, []).append(member)
        self.clock = next(m for m in self.members if m.process.clock_source)
        self.followers = [m for m in self.members if m is not self.clock]

    def _sender(self, rank: int) -> Callable[[str, Message], None]:
        last: list[Message] = []  # the last message sent and what subscribers got: sent twice, copied once

        def send(topic: str, message: Message) -> None:
            if last and last[0] is message:
                decoded = last[1]
            else:
                decoded = codec.transfer(message)  # = decode(encode(message)), without the bytes
                last[:] = [message, decoded]
            self.seq += 1
            for member in self.subscribers.get(topic, []):
                member.inbox.append((rank, self.seq, topic, decoded))
            sender = self.members[rank]
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
            stamp = cast(ClockSource, self.clock.obj).step()  # the launcher checked: process.clock_source
            if stamp is None:
                break
            for member in [self.clock, *self.followers]:
                member.ctx.stamp_ns, member.ctx.tick = stamp, ticks
            for member in self.followers:
                self._dispatch(member)
                member.obj.on_tick(stamp)
                self._collect_stop(member)
            self._dispatch(self.clock)
            self._collect_stop(self.clock)
            ticks += 1
            if self.stop_reason:
                break
        for member in self.members:
            close = getattr(member.obj, "close", None)
            if close is not None:
                close()
        return ticks

    def _dispatch(self, member: _Member) -> None:
        batch = sorted(member.inbox, key=lambda item: (item[0], item[1]))
        member.inbox = []
        ports = {topic: port for port, topic in member.process.subscribes.items()}
        for _, _, topic, message in batch:
            member.ctx.counters["messages_in"] += 1
            try:
                getattr(member.obj, f"on_{ports[topic]}")(message)
            except MessageError:
                member.ctx.counters["decode_errors"] += 1
            except PalpateError:
                member.ctx.counters["input_errors"] += 1

    def _collect_stop(self, member: _Member) -> None:
        if member.ctx.stop_requested and not self.stop_reason:
            self.stop_reason = member.ctx.stop_requested

    def node(self, name: str) -> Any:
        """The node object called `name` (for reading results after a run)."""
        return next(m.obj for m in self.members if m.process.name == name)
