"""The recorder's canonical order does not depend on how publishers' messages interleave on arrival."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import Clock, LockstepAck, RunControl
from palpate.record.mcap_io import peek
from palpate.record.recorder import Entry, TickSorter
from tests.unit.record.synthetic import PERIOD_NS, contacts, lockstep_streams, mesh


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


def _add(sorter: TickSorter, source: str, topic: str, message: Message) -> None:
    payload = codec.encode(message)
    sorter.add(source, topic, payload, peek(payload))


def _ack(node: str, tick: int) -> LockstepAck:
    return LockstepAck(stamp_ns=max(tick, 0) * PERIOD_NS, node=node, tick=tick)


def _clock(tick: int) -> Clock:
    return Clock(stamp_ns=tick * PERIOD_NS, tick=tick, period_ns=PERIOD_NS, lockstep=True)


def _topics(batches: list[list[Entry]]) -> list[list[str]]:
    return [[e.topic for e in batch] for batch in batches]


def test_a_tick_waits_for_the_clocks_next_tick_or_the_stop_and_the_clock_source_goes_first() -> None:
    """The clock source's endpoint sorts after the node's name, yet its messages lead each tick."""
    sorter = TickSorter()
    for source in ("tcp://zz-clock", "tcp://node"):
        sorter.expect(source)
    _add(sorter, "tcp://zz-clock", topics.CONTACTS, contacts(0))
    _add(sorter, "tcp://zz-clock", topics.CLOCK, _clock(0))
    _add(sorter, "tcp://node", topics.SURFACE_MESH, mesh(0))
    _add(sorter, "tcp://node", topics.LOCKSTEP_ACK, _ack("a_node", 0))
    assert sorter.ready() == []  # the clock has not started tick 1: more of tick 0 may come
    _add(sorter, "tcp://zz-clock", topics.CLOCK, _clock(1))
    assert _topics(sorter.ready()) == [[topics.CONTACTS, topics.CLOCK, topics.SURFACE_MESH, topics.LOCKSTEP_ACK]]
    _add(sorter, "tcp://node", topics.LOCKSTEP_ACK, _ack("a_node", 1))
    assert sorter.ready() == []
    stop = RunControl(stamp_ns=PERIOD_NS, command="stop", reason="done")
    _add(sorter, "tcp://zz-clock", topics.GRAPH_CONTROL, stop)
    assert _topics(sorter.ready()) == [[topics.CLOCK, topics.LOCKSTEP_ACK]]  # stopped: tick 1 is the last


def test_a_respawned_nodes_older_marker_files_under_its_last_tick() -> None:
    sorter = TickSorter()
    for source in ("clock", "node"):
        sorter.expect(source)
    for tick in (0, 1):
        _add(sorter, "clock", topics.CLOCK, _clock(tick))
        _add(sorter, "node", topics.SURFACE_MESH, mesh(tick * PERIOD_NS))
        _add(sorter, "node", topics.LOCKSTEP_ACK, _ack("node", tick))
    _add(sorter, "node", topics.SURFACE_MESH, mesh(0, size_m=0.02))  # the node starts over ...
    _add(sorter, "node", topics.LOCKSTEP_ACK, _ack("node", 0))  # ... and acknowledges tick 0 again
    _add(sorter, "clock", topics.CLOCK, _clock(2))
    ticks = sorter.ready()
    assert _topics(ticks) == [
        [topics.CLOCK, topics.SURFACE_MESH, topics.LOCKSTEP_ACK],
        [topics.CLOCK, topics.SURFACE_MESH, topics.LOCKSTEP_ACK, topics.SURFACE_MESH, topics.LOCKSTEP_ACK],
    ]  # tick 1 is complete: the node's last marker is still tick 1


def test_publishers_without_markers_hold_nothing_back_and_go_along_in_arrival_order() -> None:
    sorter = TickSorter()
    for source in ("clock", "m1", "m2"):
        sorter.expect(source)
    for source in ("m1", "m2"):
        sorter.unexpect(source)  # no markers will come from these (not lockstep nodes)
    _add(sorter, "clock", topics.CLOCK, _clock(0))
    arrivals = [("m1", contacts(0, offset=1.0)), ("m2", contacts(0, offset=2.0))]
    arrivals += [("m2", contacts(0, offset=3.0)), ("m1", contacts(0, offset=4.0))]
    for source, message in arrivals:
        _add(sorter, source, topics.CONTACTS, message)
    _add(sorter, "clock", topics.CLOCK, _clock(1))
    (tick0,) = sorter.ready()
    assert [e.payload for e in tick0[1:]] == [codec.encode(m) for _, m in arrivals]


def test_the_recorder_waits_for_markers_only_once_the_clock_has_started(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Two outside walkthroughs: under load the clock source took over 5 s to start after the other nodes
    acknowledged the start, and the recorder said it 'sends no lockstep acknowledgements'. Before the clock
    starts no tick can be written, so nothing waits; after it, a publisher without a marker is no lockstep node."""
    from palpate.record import recorder as recorder_module

    rec = recorder_module.Recorder(tmp_path / "run.mcap", bus_dir=tmp_path / "bus")
    try:
        for source in ("sim", "noise", "tool"):
            rec.sorter.expect(source)
        _add(rec.sorter, "noise", topics.LOCKSTEP_ACK, _ack("noise", -1))
        with caplog.at_level("INFO"):
            rec._check_unmarked(0.0)
            rec._check_unmarked(100.0)  # long after, but the clock has not started: the sim may be loading
            assert "sends no lockstep" not in caplog.text and rec.sorter.sources["sim"].expected
            _add(rec.sorter, "sim", topics.CLOCK, _clock(0))
            rec._check_unmarked(101.0)
            rec._check_unmarked(101.0 + recorder_module.NO_MARKER_TIMEOUT_S + 1.0)
        assert "tool sends no lockstep acknowledgements" in caplog.text and "sim sends" not in caplog.text
        assert not rec.sorter.sources["tool"].expected and rec.sorter.sources["noise"].expected
    finally:
        rec.writer.close()
        rec.tap.close()
