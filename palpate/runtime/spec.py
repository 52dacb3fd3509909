"""What a node declares (NodeSpec) and what the launcher hands a node process (NodeProcessSpec)."""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from palpate.config import KeyPath, load
from palpate.messages.base import Message

C = TypeVar("C")

#: How many ticks the clock source may run ahead of a trailing node (NodeSpec.may_trail): enough to
#: take the node's handling off the clock's round trip and absorb its jitter; at most this many ticks of
#: its input wait in its queue.
TRAIL_TICKS = 3

#: Exit code of a node process that ended the run with ``ctx.request_stop(reason, failed=True)``, after
#: the orderly stop (the other nodes still finish the tick and close); ``palpate launch`` then exits 1.
EXIT_RUN_FAILED = 4
#: How long a node waits at start-up for its subscribers (seconds) before it gives up, naming them.
START_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class Port:
    """A named input or output of a node, carrying one message type on a (remappable) topic."""

    message: type[Message]
    topic: str = ""  # empty: the message type's default topic
    doc: str = ""
    #: An optional input may have no publisher in a graph (a request topic, say).
    optional: bool = False

    @property
    def default_topic(self) -> str:
        return self.topic or self.message.TOPIC


class Context(Protocol):
    """What a node object sees of the graph: the one argument besides its config that its factory gets.

    The process runtime (palpate/runtime/node.py) and the in-process executor (palpate/runtime/inprocess.py)
    provide it; a unit test may pass any object with these members.
    """

    #: Generator seeded from the launch file: the node's only source of randomness.
    rng: np.random.Generator
    #: Stamp of the tick being handled, nanoseconds (set by the runtime before each tick's inputs).
    stamp_ns: int
    #: Why the run ended when another node ended it ("" while it runs, or when this node ended it).
    run_stopped_by: str
    #: Why the run failed, when it did: this node's failed stop or a RunControl "fail" ("" otherwise).
    failure: str
    log: logging.Logger

    @property
    def outputs(self) -> Mapping[str, str]:
        """Output port -> the topic it is wired to."""
        ...

    @property
    def metrics(self) -> dict[str, float]:
        """Figures reported in the node's status (write entries; do not replace the dict)."""
        ...

    @property
    def timings(self) -> dict[str, float]:
        """Wall-clock figures (``ms_per_update``): in the status in real-time mode only, since a lockstep
        log must not depend on CPU speed (same launch and seed, same bytes); logged at exit in lockstep."""
        ...

    @property
    def counters(self) -> dict[str, int]:
        """Event counts reported in the node's status; the runtime's own are messages_in, messages_out,
        decode_errors and input_errors."""
        ...

    def publish(self, port: str, message: Message) -> None:
        """Send `message` on the topic wired to output `port` (validated first)."""
        ...

    def count(self, name: str, n: int = 1) -> None:
        """Add `n` to the counter `name`."""
        ...

    def request_stop(self, reason: str, *, failed: bool = False) -> None:
        """Ask the graph to end the run after this tick (not for a node whose spec says ``may_trail``).
        ``failed``: the run ends because something went wrong (``palpate launch`` then exits 1)."""
        ...


class NodeLike(Protocol):
    """What the runtime calls on a node object. Handlers are methods named `on_<input port>`."""

    def on_tick(self, stamp_ns: int) -> None: ...


class ClockSource(NodeLike, Protocol):
    """A node that drives the graph's clock (the simulator, a replayed log, a hardware driver).

    It may also have an attribute `period_ns`, its tick period, which the runtime puts in each Clock
    message (and paces real-time runs with).
    """

    def step(self) -> int | None:
        """Publish one tick's data; returns the tick's stamp in nanoseconds, or None when the run is over."""
        ...


@dataclass(frozen=True)
class NodeSpec(Generic[C]):
    """A node type: its config dataclass, its ports and how to build it.

    `factory(config, ctx)` returns the node object; for each input port `p` the object has a method
    `on_p(message)`; `on_tick(stamp_ns)` runs once per clock tick after the tick's inputs.
    A clock source (the simulator, a replayed log, a hardware driver) is a `ClockSource`: it also has
    `step()`, which publishes one tick's data and returns its stamp, or None when the run is over.
    """

    name: str
    config: type[C]
    factory: Callable[[C, Context], NodeLike]
    inputs: Mapping[str, Port] = field(default_factory=dict)
    outputs: Mapping[str, Port] = field(default_factory=dict)
    clock_source: bool = False
    doc: str = ""
    #: For nodes whose ports depend on their configuration (a replayed log, the sim's effector): the
    #: validated config -> (inputs, outputs).
    ports_from_config: Callable[[C], tuple[Mapping[str, Port], Mapping[str, Port]]] | None = None
    #: Facts about the world that the node's config states: config -> {fact: (value, key path of the
    #: params that state it)}, e.g. where the hand is mounted. The launcher checks that every node of a
    #: graph that states a fact states the same value (a simulator and the mappers of its finger). A
    #: fact named ``"PORT:name"`` is about what travels through the node's port PORT: only nodes at the
    #: two ends of that port's topic must agree (a planner and the GPIS node whose surface it reads).
    facts: Callable[[C], Mapping[str, tuple[Any, KeyPath]]] | None = None
    #: Parameters the node leaves to its graph ("auto"): (config, stated) -> {key path of the params: value},
    #: where ``stated(fact)`` lists the values the graph's other nodes state for a fact (named as in
    #: `facts`). The launcher writes the values into the node's params before it checks the facts, e.g.
    #: the GPIS node gives the GP variance only when a planner reading its surface rates by it. They may
    #: not change the node's ports.
    settle: Callable[[C, Callable[[str], list[Any]]], Mapping[KeyPath, Any]] | None = None
    #: Files the node reads when it starts: config -> {key path of the params: path}. The launcher
    #: checks, before it starts any process, that those of the nodes it starts itself exist (an
    #: external node may see another filesystem), naming the launch file's line.
    files: Callable[[C], Mapping[KeyPath, str]] | None = None
    #: What is wrong in those files that only reading them shows (a mesh in millimetres read as metres):
    #: config -> {key path of the params: the problem}. ``palpate launch`` runs it for the nodes it
    #: starts, before it starts any process; in-process runs leave it to the node (an evaluation checks
    #: its objects itself, once, rather than at every run).
    checks: Callable[[C], Mapping[KeyPath, str]] | None = None
    #: The node never asks to end a run (``ctx.request_stop`` raises). In lockstep, when nothing it
    #: publishes reaches the clock source (a sink, a noise stage feeding a mapper), the clock source then
    #: runs up to TRAIL_TICKS ticks ahead of it instead of waiting for it every tick (docs/runtime.md).
    may_trail: bool = False

    def with_config(self, config: C) -> NodeSpec[C]:
        """This spec with its ports resolved for `config` (itself when its ports are fixed)."""
        if self.ports_from_config is None:
            return self
        inputs, outputs = self.ports_from_config(config)
        return dataclasses.replace(self, inputs=inputs, outputs=outputs, ports_from_config=None)

    def with_params(self, params: Mapping[str, Any]) -> NodeSpec[C]:
        """`with_config` of the config that `params` give (ConfigError when they are invalid)."""
        if self.ports_from_config is None:
            return self
        return self.with_config(load(self.config, params, f"node type {self.name!r} params"))


@dataclass(frozen=True, kw_only=True)
class NodeProcessSpec:
    """Everything a node process needs, resolved by the launcher (serialised as JSON)."""

    name: str
    type: str  # the launch file's type name, for messages
    node_spec: str  # `module:ATTRIBUTE` of the NodeSpec the process runs
    params: dict[str, Any]
    bus_dir: str
    endpoint: str  # where this node's publisher binds
    publishes: dict[str, str]  # output port -> topic
    subscribes: dict[str, str]  # input port -> topic
    connect: list[str]  # publisher endpoints this node subscribes to
    mode: str = "lockstep"  # or "realtime"
    seed: int = 0
    clock_source: bool = False
    expected_subscribers: dict[str, int] = field(default_factory=dict)
    # lockstep: acknowledgements to wait for before handling tick t (forward) or t+1 (backward).
    forward_upstream: list[str] = field(default_factory=list)
    backward_upstream: list[str] = field(default_factory=list)
    lockstep_nodes: list[str] = field(default_factory=list)  # clock source: every node that acknowledges
    #: Clock source: each of `lockstep_nodes` -> {"forward": its forward_upstream, "backward": its
    #: backward_upstream}, to name the node that holds a tick up (the others wait for it).
    lockstep_upstream: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    topic_order: dict[str, int] = field(default_factory=dict)  # topic -> publisher rank, for dispatch order
    #: topic -> the node publishing it, and the clock source's name: each input is filed under the tick its
    #: publisher was in when it sent it (a trailing node receives ticks its publishers are ahead by).
    topic_publishers: dict[str, str] = field(default_factory=dict)
    clock_name: str = ""
    #: Clock source: the nodes that trail it (lockstep_nodes it waits for `trail_ticks` ticks late).
    trailing_nodes: list[str] = field(default_factory=list)
    trail_ticks: int = 0
    curve: dict[str, str] = field(default_factory=dict)  # CurveZMQ keys (z85): public, secret, server_public
    #: With `curve`: the client public keys (z85) the publisher admits (ZAP): its subscribers' and a recorder's.
    curve_clients: list[str] = field(default_factory=list)
    #: topic -> message type (`TYPE`) of every topic in `publishes` and `subscribes`, for the manifest.
    topic_types: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> NodeProcessSpec:
        return cls(**json.loads(text))
