"""The recorder's canonical order does not depend on how publishers' messages interleave on arrival."""

from __future__ import annotations

import numpy as np

from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import Clock, LockstepAck, RunControl
from palpate.record.mcap_io import peek
from palpate.record.recorder import Entry, TickSorter
from tests.unit.record.synthetic import PERIOD_NS, contacts, lockstep_streams


def _interleave(
    streams: dict[str, list[tuple[str, Message]]], rng: np.random.Generator
) -> list[tuple[str, str, bytes]]:
    """A random arrival order that keeps each publisher's own order."""
    cursors = dict.fromkeys(streams, 0)
    out = []
    while any(cursors[n] < len(streams[n]) for n in streams):
        name = rng.choice([n for n in streams if cursors[n] < len(streams[n])])
        topic, message = streams[name][cursors[name]]
        cursors[name] += 1
        out.append((name, topic, codec.encode(message)))
    return out


def _record(arrivals: list[tuple[str, str, bytes]], rng: np.random.Generator) -> list[list[Entry]]:
    sorter = TickSorter()
    for source in sorted({a[0] for a in arrivals}):
        sorter.expect(source)  # the recorder knows its publishers before their first message
    batches: list[list[Entry]] = []
    for source, topic, payload in arrivals:
        sorter.add(source, topic, payload, peek(payload))
        if rng.random() < 0.3:  # the recorder writes whenever it gets round to it
            batches += sorter.ready()
    return batches + sorter.ready() + sorter.finish()


def _flat(batches: list[list[Entry]]) -> list[tuple[str, bytes]]:
    return [(e.topic, e.payload) for batch in batches for e in batch]


def test_any_interleaving_gives_the_same_log() -> None:
    streams = lockstep_streams(6)
    reference = _flat(_record(_interleave(streams, np.random.default_rng(0)), np.random.default_rng(0)))
    assert len(reference) == sum(len(s) for s in streams.values())
    for seed in range(1, 40):
        rng = np.random.default_rng(seed)
        assert _flat(_record(_interleave(streams, rng), rng)) == reference, seed


def test_ticks_are_written_publisher_by_publisher_each_ending_with_its_marker() -> None:
    streams = lockstep_streams(3)
    rng = np.random.default_rng(5)
    batches = _record(_interleave(streams, rng), rng)
    batches = [b for b in batches if b]
    assert len(batches) == 3 + 2  # tick -1, three ticks, the trailing statuses and stop
    for batch in batches[1:-1]:
        topics_of = [e.topic for e in batch]
        assert topics_of == [
            topics.CONTACTS,
            topics.CLOCK,
            topics.SURFACE_MESH,
            topics.LOCKSTEP_ACK,
            topics.LOCKSTEP_ACK,
        ]
        assert len({e.info.stamp_ns for e in batch}) == 1
    for source in streams:  # each publisher's messages keep their publish order
        mine = [(e.topic, e.payload) for b in batches for e in b if e.seq and _source_of(e, streams) == source]
        assert mine == [(t, codec.encode(m)) for t, m in streams[source]]


def _source_of(entry: Entry, streams: dict[str, list[tuple[str, Message]]]) -> str:
    for name, items in streams.items():
        if any(entry.payload == codec.encode(m) and entry.topic == t for t, m in items):
            return name
    raise AssertionError("entry from nowhere")


def _feed(sorter: TickSorter, source: str, topic: str, message: Message) -> None:
    payload = codec.encode(message)
    sorter.add(source, topic, payload, peek(payload))


def test_a_tick_waits_for_the_next_clock_and_every_acknowledgement() -> None:
    sorter = TickSorter()
    _feed(sorter, "stats", topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node="stats", tick=-1))
    _feed(sorter, "est", topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node="est", tick=-1))
    assert sorter.ready() == []  # no clock yet: more acknowledging publishers may be on their way
    _feed(sorter, "cube", topics.CONTACTS, contacts(0))
    _feed(sorter, "cube", topics.CLOCK, Clock(stamp_ns=0, tick=0, period_ns=PERIOD_NS, lockstep=True))
    assert [len(b) for b in sorter.ready()] == [2]  # tick -1
    _feed(sorter, "stats", topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node="stats", tick=0))
    _feed(sorter, "cube", topics.CLOCK, Clock(stamp_ns=PERIOD_NS, tick=1, period_ns=PERIOD_NS, lockstep=True))
    assert sorter.ready() == []  # `est` has not acknowledged tick 0
    sorter.set_live("est", False)  # ... and never will: it went away
    assert [[e.topic for e in b] for b in sorter.ready()] == [[topics.CONTACTS, topics.CLOCK, topics.LOCKSTEP_ACK]]


def test_real_time_clock_means_arrival_order() -> None:
    sorter = TickSorter()
    _feed(sorter, "b", topics.CONTACTS, contacts(5))
    _feed(sorter, "a", topics.CLOCK, Clock(stamp_ns=0, tick=0, period_ns=PERIOD_NS, lockstep=False))
    _feed(sorter, "b", topics.CONTACTS, contacts(6))
    assert sorter.mode == "stream"
    assert [e.info.stamp_ns for b in sorter.ready() for e in b] == [5, 0, 6]


def test_without_markers_nothing_is_written_until_told_there_is_no_clock() -> None:
    sorter = TickSorter()
    _feed(sorter, "b", topics.CONTACTS, contacts(5))
    assert sorter.ready() == [] and sorter.pending == 1
    sorter.assume_stream()
    assert [e.info.stamp_ns for b in sorter.ready() for e in b] == [5]


def test_a_stop_or_a_fail_ends_the_recording_and_no_other_command_does() -> None:
    """`record --until-stop` and `palpate launch --record` end with the run, a failed one too (the clock
    source closes it with "fail")."""
    for command, ends in (("stop", True), ("fail", True), ("pause", False)):
        sorter = TickSorter()
        message = RunControl(stamp_ns=0, command=command, reason="x")
        payload = codec.encode(message)
        sorter.add("sim", topics.GRAPH_CONTROL, payload, peek(payload))
        assert sorter.stopped is ends, command
