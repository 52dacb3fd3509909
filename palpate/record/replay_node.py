"""The `replay` node: a clock source that plays a recorded log's ticks into a live graph.

`palpate launch FILE --replay LOG.mcap` puts it in place of the nodes whose outputs the log holds
(see launch_support). Each `step()` publishes one recorded tick's messages of the replayed topics,
decoded and re-encoded by the runtime (the codec is canonical: the bytes equal the recorded ones),
and returns the tick's recorded stamp, so the runtime then publishes ``Clock`` with it. Nodes
downstream see the inputs they saw in the recorded run, tick for tick, and in lockstep they
produce the same outputs.

Ports: one output per replayed topic, named after the topic (``ports_from_config``); params
``path`` (the log) and ``topics`` (default: every data topic of the log). ``order`` gives each
topic the rank its publisher had in the recorded graph: a tick's messages go out sorted by it, as
the recorded subscribers dispatched them. A log of a message version this build does not speak is
refused before the run; a recorded message that does not decode ends the run as a failure, and
ticks the log lacks (a recovered log) are counted in ``replay_ticks_missing`` and logged.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from palpate.config import Validated
from palpate.errors import LaunchError, MessageError, RecordError
from palpate.messages import codec, topics
from palpate.messages.base import REGISTRY, Message
from palpate.record import mcap_io
from palpate.runtime.spec import Context, NodeSpec, Port

#: Topics the runtime publishes itself; a replay node never republishes them.
RUNTIME_TOPICS = frozenset(topics.RUNTIME_TOPICS)


@dataclass(frozen=True, kw_only=True)
class ReplayConfig(Validated):
    #: The MCAP log to replay.
    path: str
    #: The recorded topics to replay, each an output port of that name; empty: every data topic of the log.
    topics: tuple[str, ...] = ()
    #: Topic -> the rank its publisher had in the recorded graph: a tick's messages go out sorted by it
    #: (others rank 0). ``palpate launch --replay`` fills it in.
    order: dict[str, int] = field(default_factory=dict)


def log_topics(path: str | Path, wanted: tuple[str, ...] | list[str] = ()) -> dict[str, str]:
    """Replayable topics of a log and their message types (runtime topics excluded)."""
    try:
        types = mcap_io.topic_types(path)
    except RecordError as exc:
        raise LaunchError(f"replay log: {exc}") from exc
    data = {t: ty for t, ty in types.items() if t not in RUNTIME_TOPICS}
    missing = [t for t in wanted if t not in data]
    if missing:
        raise LaunchError(f"replay log {path} has no topic {missing[0]!r}; it holds {sorted(data)}")
    return {t: data[t] for t in wanted} if wanted else data


def ports_from_config(config: ReplayConfig) -> tuple[Mapping[str, Port], Mapping[str, Port]]:
    """One output port per replayed topic (port name = topic), typed from the log's schemas."""
    path = config.path
    if not path:
        raise LaunchError("node type 'replay' needs a 'path' parameter naming an MCAP log")
    outputs = {}
    replayed = log_topics(path, list(config.topics))
    for topic, type_name in replayed.items():
        cls = REGISTRY.get(type_name)
        if cls is None:
            raise LaunchError(f"replay log {path}: topic {topic!r} carries {type_name!r}, unknown to this build")
        outputs[topic] = Port(cls, topic=topic, doc=f"recorded {topic}")
    if problem := mcap_io.version_problem(path, replayed):
        raise LaunchError(f"replay log {path}: {problem}")
    return {}, outputs


class ReplayNode:
    """Publishes a recorded tick per step; `period_ns` is the recorded clock period."""

    def __init__(self, config: ReplayConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.ports = set(ctx.outputs)
        wanted = sorted(self.ports | {topics.CLOCK, topics.LOCKSTEP_ACK})
        self._ticks: Iterator[mcap_io.LogTick] = mcap_io.iter_ticks(mcap_io.read_messages(config.path, wanted))
        self._next = self._next_tick()
        self.period_ns = self._next.period_ns if self._next is not None else 0
        self.ticks = 0
        self._last_recorded = -1  # the recorded tick number last replayed (a run's ticks count from 0)

    def _next_tick(self) -> mcap_io.LogTick | None:
        """The next recorded tick with a clock stamp; messages of stamp-less ticks (start-up) join it."""
        carried: list[mcap_io.LoggedMessage] = []
        for tick in self._ticks:
            if tick.tick is None:  # after the last tick: statuses and the stop, not replayed
                return None
            carried.extend(m for m in tick.messages if m.topic in self.ports)
            if tick.stamp_ns is not None:
                tick.messages = carried
                return tick
        return None

    def step(self) -> int | None:
        tick = self._next
        if tick is None or tick.stamp_ns is None:
            return None
        order = self.config.order
        for message in sorted(tick.messages, key=lambda m: order.get(m.topic, 0)):  # stable: keeps publish order
            try:
                decoded: Message = codec.decode(message.data)
            except MessageError as exc:  # a replay that leaves recorded messages out is not the recorded run
                self.ctx.count("replay_decode_errors")
                self.ctx.request_stop(
                    f"replay: the recorded {message.topic} message at {message.log_time * 1e-9:.3f} s cannot be "
                    f"replayed: {exc}",
                    failed=True,
                )
                return None
            self.ctx.publish(message.topic, decoded)
        self._note_gap(tick)
        self._next = self._next_tick()
        self.ticks += 1
        return tick.stamp_ns

    def _note_gap(self, tick: mcap_io.LogTick) -> None:
        """Count and log ticks the log lacks before ``tick`` since the last replayed one (from tick 0: a
        recovered log skips the ticks of its damaged chunks, a recording started late those before it):
        from there the replay is not the recorded run."""
        if tick.tick is None:
            return
        first, last = self._last_recorded + 1, tick.tick - 1
        if last >= first:
            self.ctx.count("replay_ticks_missing", last - first + 1)
            self.ctx.log.warning(
                "replay: the log holds no %s (%d missing: a recovered log lacks its damaged chunks, a recording "
                "started late its start); the graph's results differ from the recorded run from here",
                f"tick {first}" if first == last else f"ticks {first} to {last}",
                last - first + 1,
            )
        self._last_recorded = tick.tick

    def on_tick(self, stamp_ns: int) -> None:
        """A clock source has nothing to do after its own tick."""


SPEC = NodeSpec(
    name="replay",
    config=ReplayConfig,
    factory=ReplayNode,
    clock_source=True,
    doc="Clock source replaying the recorded ticks of an MCAP log (params: path, topics).",
    ports_from_config=ports_from_config,
)
