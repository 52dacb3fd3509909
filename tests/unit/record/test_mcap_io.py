"""MCAP writing and reading: payload headers, round trips, summaries, recovery and tick grouping."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from palpate.cli import main
from palpate.errors import MalformedMessageError, RecordError
from palpate.messages import codec, topics
from palpate.messages.schemas import ContactSet
from palpate.record import mcap_io
from tests.unit.record.synthetic import PERIOD_NS, canonical_log, contacts, write_log


def test_peek_reads_type_version_and_stamp_without_decoding() -> None:
    payload = codec.encode(contacts(123))
    assert mcap_io.peek(payload) == mcap_io.PayloadInfo("ContactSet", ContactSet.VERSION, 123)
    # a header longer than the first read (many string entries) still parses
    big = codec.encode(contacts(7, n=3000))
    assert mcap_io.peek(big).stamp_ns == 7


@pytest.mark.parametrize("payload", [b"", b"\x00\x01garbage", b"\x92\xa1x\xc4\x00", b"\x93\x01\x02\x03"])
def test_peek_rejects_what_is_not_an_envelope(payload: bytes) -> None:
    with pytest.raises(MalformedMessageError):
        mcap_io.peek(payload)


def test_round_trip_keeps_topics_bytes_order_and_stamps(tmp_path: Path) -> None:
    items = canonical_log(5)
    path = tmp_path / "log.mcap"
    write_log(path, items)
    read = list(mcap_io.read_messages(path))
    assert [(m.topic, m.data) for m in read] == [(t, codec.encode(msg)) for t, msg in items]
    assert [m.log_time for m in read] == [msg.stamp_ns for _, msg in items]  # type: ignore[attr-defined]
    assert [m.sequence for m in read] == list(range(len(items)))
    summary = mcap_io.summarize(path)
    assert summary.topics[topics.CLOCK] == 5 and summary.topics[topics.LOCKSTEP_ACK] == 12
    assert summary.types[topics.CONTACTS] == "ContactSet"
    assert (summary.start_ns, summary.end_ns, summary.messages) == (0, 4 * PERIOD_NS, len(items))
    assert json.loads(json.dumps(summary.as_json()))["topics"] == summary.topics


def test_schema_describes_fields_units_and_version() -> None:
    doc = json.loads(mcap_io.schema_bytes("ContactSet", ContactSet.VERSION))
    assert doc["x-palpate-version"] == ContactSet.VERSION and doc["title"] == "ContactSet"
    assert doc["properties"]["positions_m"]["x-shape"] == ["n", 3]
    assert doc["properties"]["positions_m"]["x-unit"] == "m"
    assert doc["properties"]["stamp_ns"]["type"] == "integer"
    # an outside walkthrough: the schema let a reader expect more fields than a message may hold
    assert doc["additionalProperties"] is False and "docs/messages.md" in doc["x-palpate-encoding"]
    assert "unknown" in json.loads(mcap_io.schema_bytes("NoSuchType", 3))["description"]


def test_the_same_messages_give_the_same_bytes(tmp_path: Path) -> None:
    items = canonical_log(4)
    write_log(tmp_path / "a.mcap", items, flush_each=True)
    write_log(tmp_path / "b.mcap", items, flush_each=True)
    data = (tmp_path / "a.mcap").read_bytes()
    assert data == (tmp_path / "b.mcap").read_bytes()
    assert b"palpate-" in data[:200]  # the library field names the writer, nothing names a time


def test_recover_keeps_every_flushed_chunk_of_a_truncated_log(tmp_path: Path) -> None:
    items = canonical_log(6)
    full = tmp_path / "full.mcap"
    sizes = write_log(full, items, flush_each=True)
    data = full.read_bytes()
    expected = [codec.encode(msg) for _, msg in items]
    cuts = sorted({*sizes, *(s + 7 for s in sizes[:-1]), *(s - 1 for s in sizes[1:]), len(data) - 3})
    for cut in cuts:
        broken = tmp_path / "broken.mcap"
        broken.write_bytes(data[:cut])
        with pytest.raises(RecordError, match="bag recover"):
            mcap_io.summarize(broken)
        report = mcap_io.recover(broken, tmp_path / "fixed.mcap")
        kept = sum(1 for size in sizes if size <= cut)
        assert report.messages == kept, cut
        assert report.truncated or cut > sizes[-1], cut  # a cut in the summary loses no message
        recovered = [m.data for m in mcap_io.read_messages(tmp_path / "fixed.mcap")]
        assert recovered == expected[:kept], cut
    report = mcap_io.recover(full, tmp_path / "again.mcap")
    assert not report.truncated and report.messages == len(items)


def test_recover_refuses_a_file_that_is_not_mcap(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordError, match="not an MCAP"):
        mcap_io.recover(bad, tmp_path / "out.mcap")


def test_filter_and_recover_refuse_to_write_over_their_input(tmp_path: Path) -> None:
    src = tmp_path / "run.mcap"
    write_log(src, canonical_log(3))
    data = src.read_bytes()
    (tmp_path / "link.mcap").hardlink_to(src)
    (tmp_path / "alias.mcap").symlink_to(src)
    for dst in (src, tmp_path / "." / "run.mcap", tmp_path / "link.mcap", tmp_path / "alias.mcap"):
        with pytest.raises(RecordError, match="overwrite its input"):
            mcap_io.copy_log(src, dst, include=[topics.CLOCK])
        with pytest.raises(RecordError, match="overwrite its input"):
            mcap_io.recover(src, dst)
    assert src.read_bytes() == data


def test_a_failed_filter_or_recovery_leaves_no_output(tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    with pytest.raises(RecordError, match="cannot open log"):
        mcap_io.copy_log(tmp_path / "missing.mcap", out)
    for name, data in (("garbage.mcap", b"not an mcap file at all"), ("empty.mcap", b"")):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(RecordError):
            mcap_io.recover(tmp_path / name, out)
    truncated = tmp_path / "truncated.mcap"
    write_log(truncated, canonical_log(3))
    truncated.write_bytes(truncated.read_bytes()[:-40])
    with pytest.raises(RecordError, match="bag recover"):
        mcap_io.copy_log(truncated, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mcap", "garbage.mcap", "truncated.mcap"]
    out.write_bytes(b"keep")  # an existing output stays as it was after a failure, and without overwrite
    with pytest.raises(RecordError):
        mcap_io.recover(tmp_path / "garbage.mcap", out)
    with pytest.raises(RecordError, match="exists; pass --force"):
        mcap_io.recover(truncated, out, overwrite=False)
    assert out.read_bytes() == b"keep"


def test_a_log_that_cannot_be_written_is_named_and_leaves_nothing(tmp_path: Path) -> None:
    """An outside walkthrough: a full disk gave three chained tracebacks in bag filter, recover and export."""
    import errno

    src, out = tmp_path / "run.mcap", tmp_path / "out.mcap"
    write_log(src, canonical_log(3))
    expected = f"^filter: cannot write {out}: No space left on device; wrote nothing"
    with pytest.raises(RecordError, match=expected), mcap_io.output_file(src, out, "filter") as partial:
        partial.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


def test_the_recorder_names_a_log_it_cannot_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno

    from palpate.record.recorder import Recorder

    recorder = Recorder(tmp_path / "run.mcap", bus_dir=tmp_path / "bus")

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(recorder, "_write", full)
    with pytest.raises(RecordError, match=r"cannot write log .*run\.mcap: File too large; .* palpate bag recover"):
        recorder.run()


def test_a_recorder_that_wrote_nothing_on_a_full_disk_leaves_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: `palpate record -o` onto a full disk left a 0-byte log, pointed at bag
    recover (which found nothing) and blocked the run again without --force."""
    import errno

    from palpate.record.recorder import Recorder

    log = tmp_path / "run.mcap"
    recorder = Recorder(log, bus_dir=tmp_path / "bus")

    def full(*args: object, **kwargs: object) -> None:
        log.write_bytes(b"")  # what a full disk leaves of the log's header
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recorder, "_write", full)
    monkeypatch.setattr(recorder.writer, "close", lambda: None)
    with pytest.raises(
        RecordError, match=r"cannot write log .*run\.mcap: No space left on device; nothing was recorded$"
    ):
        recorder.run()
    assert not log.exists()


def test_bag_recover_replaces_an_existing_output_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src, out = tmp_path / "run.mcap", tmp_path / "run.recovered.mcap"
    write_log(src, canonical_log(3))
    out.write_bytes(b"precious")
    assert main(["bag", "recover", str(src)]) == 2
    assert f"{out} exists; pass --force" in capsys.readouterr().err and out.read_bytes() == b"precious"
    assert main(["bag", "recover", str(src), "--force"]) == 0
    assert mcap_io.summarize(out).messages == len(canonical_log(3))


def test_bag_filter_and_record_replace_an_existing_log_only_with_force_and_name_topics_not_in_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As launch --record and bag recover: filter and record wrote over an existing log without a word,
    and a --topics typo kept nothing silently (an outside audit)."""
    src, out = tmp_path / "run.mcap", tmp_path / "clock.mcap"
    write_log(src, canonical_log(3))
    out.write_bytes(b"precious")
    assert main(["bag", "filter", str(src), "-o", str(out), "--topics", topics.CLOCK]) == 2
    assert f"{out} exists; pass --force" in capsys.readouterr().err and out.read_bytes() == b"precious"
    assert main(["bag", "filter", str(src), "-o", str(out), "--topics", topics.CLOCK, "clokc", "--force"]) == 0
    assert f"{src} has no topic clokc" in capsys.readouterr().err
    assert mcap_io.summarize(out).topics == {topics.CLOCK: 3}
    assert main(["record", "-o", str(out), "--until-stop"]) == 2
    assert f"{out} exists; pass --force" in capsys.readouterr().err


def test_copy_log_keeps_or_drops_topics(tmp_path: Path) -> None:
    src = tmp_path / "src.mcap"
    write_log(src, canonical_log(3))
    n = mcap_io.copy_log(src, tmp_path / "no_mesh.mcap", exclude=[topics.SURFACE_MESH])
    kept = mcap_io.summarize(tmp_path / "no_mesh.mcap")
    assert topics.SURFACE_MESH not in kept.topics and n == kept.messages
    only = mcap_io.summarize(_copy(src, tmp_path / "only.mcap", [topics.CONTACTS]))
    assert only.topics == {topics.CONTACTS: 3}


def _copy(src: Path, dst: Path, include: list[str]) -> Path:
    mcap_io.copy_log(src, dst, include=include)
    return dst


def test_ticks_are_delimited_by_each_publishers_marker(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    write_log(path, canonical_log(4))
    ticks = list(mcap_io.iter_ticks(mcap_io.read_messages(path)))
    assert [t.tick for t in ticks] == [-1, 0, 1, 2, 3, None]
    assert [t.stamp_ns for t in ticks[1:-1]] == [0, PERIOD_NS, 2 * PERIOD_NS, 3 * PERIOD_NS]
    assert ticks[0].stamp_ns is None and ticks[1].period_ns == PERIOD_NS
    for tick in ticks[1:-1]:
        assert [m.topic for m in tick.messages] == [topics.CONTACTS, topics.SURFACE_MESH]
        assert {m.log_time for m in tick.messages} == {tick.stamp_ns}
    assert [m.topic for m in ticks[-1].messages] == [topics.GRAPH_CONTROL] + [topics.NODE_STATUS] * 3


def test_a_log_without_markers_is_grouped_by_stamp(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    items = [(topics.CONTACTS, contacts(s)) for s in (0, 0, 5, 9, 9, 9)]
    write_log(path, items)
    ticks = list(mcap_io.iter_ticks(mcap_io.read_messages(path)))
    assert [(t.stamp_ns, len(t.messages)) for t in ticks] == [(0, 2), (5, 1), (9, 3)]


def test_reading_a_missing_log_names_it(tmp_path: Path) -> None:
    with pytest.raises(RecordError, match=r"cannot open log .*nothing\.mcap"):
        mcap_io.summarize(tmp_path / "nothing.mcap")


#: Bytes from a chunk record's start to its (compressed) data: opcode, record length, start and end
#: times, uncompressed size, CRC, the compression's name ("zstd") and the data's length.
CHUNK_DATA_OFFSET = 1 + 8 + 8 + 8 + 8 + 4 + 4 + 4 + 8


def test_a_damaged_chunk_is_refused_when_read_and_skipped_by_recover(tmp_path: Path) -> None:
    items = canonical_log(6)
    full = tmp_path / "full.mcap"
    sizes = write_log(full, items, flush_each=True)  # one chunk per message, ending at sizes[i]
    data = bytearray(full.read_bytes())
    data[sizes[3] + CHUNK_DATA_OFFSET + 2] ^= 0x10  # inside the data of message 4's chunk
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    with pytest.raises(RecordError, match="the file is damaged: `palpate bag recover"):
        list(mcap_io.read_messages(damaged))  # never altered data
    report = mcap_io.recover(damaged, tmp_path / "fixed.mcap")
    assert report.complete and not report.truncated and report.damaged_chunks == 1
    expected = [codec.encode(msg) for _, msg in items]
    assert [m.data for m in mcap_io.read_messages(tmp_path / "fixed.mcap")] == expected[:4] + expected[5:]
    # The first chunk defines the first topic's channel. A complete log's summary defines it again, so
    # nothing else is lost; a truncated log has no summary, so that topic's later messages are dropped.
    first = bytearray(full.read_bytes())
    first_chunk = 8 + 9 + int.from_bytes(first[9:17], "little")  # magic, then the header record
    assert first[first_chunk] == 0x06  # a chunk's opcode
    first[first_chunk + CHUNK_DATA_OFFSET + 2] ^= 0x10
    for cut, lost in ((0, 0), (40, sum(1 for t, _ in items[1:] if t == items[0][0]))):
        damaged.write_bytes(bytes(first[: len(first) - cut]))
        report = mcap_io.recover(damaged, tmp_path / "fixed.mcap")
        assert report.damaged_chunks == 1 and report.orphaned == lost and report.messages == len(items) - 1 - lost


def test_what_is_not_a_complete_log_is_named(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    write_log(full, canonical_log(3))
    cases = {"empty.mcap": (b"", "is empty"), "text.mcap": (b"hello\n", "does not start with MCAP's magic")}
    cases["cut.mcap"] = (full.read_bytes()[:-40], "ends before the log's footer: its recorder was killed")
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(RecordError, match=message):
            mcap_io.summarize(tmp_path / name)
        with pytest.raises(RecordError, match=message):
            list(mcap_io.read_messages(tmp_path / name))


def test_recover_copies_a_complete_log_without_messages(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    write_log(empty, [])
    report = mcap_io.recover(empty, tmp_path / "out.mcap")
    assert report.complete and report.messages == 0 and mcap_io.summarize(tmp_path / "out.mcap").messages == 0


def test_recover_and_filter_keep_what_made_the_log(tmp_path: Path) -> None:
    about = {"launch_file": "launch/explore.yaml", "args": "{}", "seed": "3"}
    src = tmp_path / "run.mcap"
    with mcap_io.LogWriter(src) as writer:
        writer.metadata(mcap_io.LAUNCH_METADATA, about)
        for seq, (topic, message) in enumerate(canonical_log(3)):
            payload = codec.encode(message)
            writer.write(topic, payload, mcap_io.peek(payload), seq)
            writer.flush()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[:-60])  # a killed recorder's log
    mcap_io.recover(cut, tmp_path / "recovered.mcap")
    mcap_io.copy_log(src, tmp_path / "clocks.mcap", include=[topics.CLOCK])
    for made in ("recovered.mcap", "clocks.mcap"):
        assert mcap_io.launch_info(tmp_path / made) == about


def test_a_player_holds_its_name_on_the_bus_as_a_launch_does(tmp_path: Path) -> None:
    from palpate.errors import BusError
    from palpate.record.bag import Player, PlayOptions
    from palpate.runtime import bus

    log = tmp_path / "run.mcap"
    write_log(log, canonical_log(2))
    player = Player(log, tmp_path / "bus", PlayOptions(name="sim"))
    launched = bus.NameClaim(tmp_path / "bus", ["sim"])  # a graph whose clock source is called sim
    with pytest.raises(RecordError, match=r"node name 'sim' is in use .*; or choose another --name"):
        player._claim_name()
    launched.release()
    held = player._claim_name()
    with pytest.raises(BusError, match="node name 'sim' is in use"):  # a launch started now stops at once
        bus.NameClaim(tmp_path / "bus", ["sim"])
    held.release()


def test_bag_info_check_reads_every_chunk_and_filter_refuses_to_keep_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    items = canonical_log(6)
    full = tmp_path / "full.mcap"
    sizes = write_log(full, items, flush_each=True)
    data = bytearray(full.read_bytes())
    data[sizes[3] + CHUNK_DATA_OFFSET + 2] ^= 0x10
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    assert main(["bag", "info", str(damaged)]) == 0  # the summary alone looks whole
    assert main(["bag", "info", str(damaged), "--check"]) == 2
    assert "the file is damaged" in capsys.readouterr().err
    assert main(["bag", "info", str(full), "--check"]) == 0
    out = tmp_path / "none.mcap"
    assert main(["bag", "filter", str(full), "-o", str(out), "--topics", "controller/nothing"]) == 2
    assert "no message of the topics kept; wrote nothing" in capsys.readouterr().err and not out.exists()


def _top_records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of a log's top-level records, after the leading magic."""
    out, pos = [], len(mcap_io.MCAP_MAGIC)
    while pos + 9 <= len(data):
        length = int.from_bytes(data[pos + 1 : pos + 9], "little")
        out.append((data[pos], pos, pos + 9 + length))
        if data[pos] == 0x02:  # the footer
            break
        pos += 9 + length
    return out


def test_a_summary_that_loses_or_repeats_a_chunk_or_its_offset_is_refused_by_name(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    write_log(full, canonical_log(4), flush_each=True)  # one chunk per message
    data = full.read_bytes()
    indexes = [(s, e) for op, s, e in _top_records(data) if op == 0x08]  # the summary's chunk indexes
    s, e = indexes[2]
    damaged = tmp_path / "damaged.mcap"

    def without_crc(content: bytes) -> bytes:
        """The log with its footer's summary CRC zeroed ("not computed"), so the reader's own checks speak."""
        end = len(content) - len(mcap_io.MCAP_MAGIC)
        return content[: end - 4] + bytes(4) + content[end:]

    for content in (data[:s] + data[e:], data[:e] + data[s:e] + data[e:]):  # a chunk index lost, repeated
        damaged.write_bytes(content)
        with pytest.raises(RecordError, match=r"damaged\.mcap: its summary does not match the CRC its footer holds"):
            list(mcap_io.read_messages(damaged))
        damaged.write_bytes(without_crc(content))
        with pytest.raises(RecordError, match=r"damaged\.mcap: its summary counts \d+ messages, its chunks hold"):
            list(mcap_io.read_messages(damaged))  # not one message fewer or more without a word
        with pytest.raises(RecordError, match=r"damaged\.mcap: its summary counts \d+ messages of the topics"):
            list(mcap_io.read_messages(damaged, [topics.CLOCK, topics.CONTACTS, topics.LOCKSTEP_ACK]))
    offset = bytearray(data)
    offset[s + 9 + 8 + 8 + 7] ^= 0x80  # the chunk index's chunk start offset, beyond any file
    damaged.write_bytes(without_crc(bytes(offset)))
    with pytest.raises(RecordError, match=r"damaged\.mcap: cannot read the MCAP log"):  # not OSError
        list(mcap_io.read_messages(damaged))
    assert len(list(mcap_io.read_messages(full))) == len(canonical_log(4))


def test_a_message_on_a_channel_the_log_never_defines_is_named(tmp_path: Path) -> None:
    from mcap.writer import Writer

    path = tmp_path / "orphan.mcap"
    payload = codec.encode(contacts(0))
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile=mcap_io.PROFILE, library="test")
        schema = writer.register_schema("ContactSet", mcap_io.SCHEMA_ENCODING, b"{}")
        channel = writer.register_channel(topics.CONTACTS, mcap_io.MESSAGE_ENCODING, schema)
        writer.add_message(channel, 0, payload, 0)
        writer.add_message(channel + 7, 1, payload, 1)  # a channel id no record defines
        writer.add_message(channel, 2, payload, 2)
        writer.finish()
    with pytest.raises(RecordError, match=r"orphan\.mcap: cannot read .*channel or schema id \d+"):  # not KeyError
        list(mcap_io.read_messages(path))
    with pytest.raises(RecordError, match=r"orphan\.mcap holds 1 message\(s\) on channels it never defines"):
        mcap_io.copy_log(path, tmp_path / "copy.mcap")
    report = mcap_io.recover(path, tmp_path / "fixed.mcap")
    assert report.messages == 2 and report.orphaned == 1


def test_recover_of_a_log_cut_inside_its_first_record_says_so_in_words(tmp_path: Path) -> None:
    """An outside walkthrough: a 30-byte head of a log gave 'error: unpack requires a buffer of 4 bytes'."""
    src = tmp_path / "run.mcap"
    write_log(src, canonical_log(2))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[:30])
    with pytest.raises(RecordError, match=r"no complete chunk to recover \(a record shorter than its fields: cut off"):
        mcap_io.recover(cut, tmp_path / "out.mcap")


def test_a_file_too_short_for_a_footer_is_named(tmp_path: Path) -> None:
    short = tmp_path / "short.mcap"
    for content in (mcap_io.MCAP_MAGIC * 2, mcap_io.MCAP_MAGIC + b"\x01" * 20 + mcap_io.MCAP_MAGIC):
        short.write_bytes(content)
        with pytest.raises(RecordError, match=r"short\.mcap ends before the log's footer"):  # not OSError
            mcap_io.summarize(short)
        with pytest.raises(RecordError, match=r"short\.mcap"):
            mcap_io.recover(short, tmp_path / "fixed.mcap")


def test_a_file_that_opens_but_cannot_be_read_is_named() -> None:
    with pytest.raises(RecordError, match=r"cannot read log '/proc/self/mem'"):
        mcap_io.summarize("/proc/self/mem")  # OSError: [Errno 5] Input/output error


def test_bag_info_check_names_the_ticks_a_log_lacks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An outside audit: a recovered log (ticks 198 to 209 lost with a damaged chunk) passed `bag info`
    without a word, and its replay gave other results than the run."""
    from palpate.commands.bag import tick_gaps

    assert tick_gaps([0, 1, 2]) == [] and tick_gaps([]) == []
    assert tick_gaps([2, 3, 7, 7, 9]) == [(0, 1), (4, 6), (8, 8)]
    lost = {2 * PERIOD_NS, 3 * PERIOD_NS}
    path = tmp_path / "recovered.mcap"
    write_log(path, [(t, m) for t, m in canonical_log(6) if m.stamp_ns not in lost or t == topics.NODE_STATUS])
    assert main(["bag", "info", str(path), "--check"]) == 0
    assert "  clock: 2 ticks missing (2-3): a recovered log lacks its damaged chunks" in capsys.readouterr().out
    assert main(["bag", "info", str(path), "--check", "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["ticks_missing"] == 2
    whole = tmp_path / "whole.mcap"
    write_log(whole, canonical_log(6))
    assert main(["bag", "info", str(whole), "--check"]) == 0
    assert "missing" not in capsys.readouterr().out


def test_a_damaged_summary_or_bytes_after_the_end_are_named(tmp_path: Path) -> None:
    """An outside walkthrough: a changed byte in the summary's channel record and a log concatenated with
    itself passed `bag info --check` (half the file unread); `echo x >> LOG` was called a killed recorder."""
    log = tmp_path / "run.mcap"
    write_log(log, canonical_log(3))
    data = log.read_bytes()
    twice, appended, flipped = tmp_path / "twice.mcap", tmp_path / "appended.mcap", tmp_path / "flipped.mcap"
    twice.write_bytes(data + data)
    appended.write_bytes(data + b"garbage\n")
    at = data.rindex(b"sensors/contacts")  # the topic's name in the summary's channel record
    flipped.write_bytes(data[:at] + b"sensors/cpntacts" + data[at + 16 :])
    for path in (twice, flipped):
        with pytest.raises(RecordError, match=r"its summary does not match the CRC its footer holds"):
            list(mcap_io.read_messages(path))
    with pytest.raises(RecordError, match=r"appended\.mcap holds 8 bytes after the end of its log \(appended to\?\)"):
        list(mcap_io.read_messages(appended))
    assert len(list(mcap_io.read_messages(log))) > 0
    for path, trailing in ((appended, 8), (twice, len(data)), (log, 0)):
        report = mcap_io.recover(path, tmp_path / f"{path.stem}.recovered.mcap")
        assert report.complete and report.trailing == trailing


def _launch_log(path: Path, about: dict[str, str]) -> list[tuple[str, object]]:
    """A log with the launch's metadata and one chunk per message; returns what it holds."""
    items = canonical_log(4)
    with mcap_io.LogWriter(path) as writer:
        writer.metadata(mcap_io.LAUNCH_METADATA, about)
        for seq, (topic, message) in enumerate(items):
            payload = codec.encode(message)
            writer.write(topic, payload, mcap_io.peek(payload), seq)
            writer.flush()
    return items  # type: ignore[return-value]


def test_recover_reads_past_a_damaged_chunk_frame_by_the_logs_index(tmp_path: Path) -> None:
    """An outside audit: one byte of a chunk's length field (or of the header's) made recover keep the first
    chunk and drop the ten intact ones after it, without saying how many messages were lost."""
    about = {"launch_file": "launch/probe.yaml", "args": "{}", "seed": "0"}
    src = tmp_path / "run.mcap"
    items = _launch_log(src, about)
    data = src.read_bytes()
    chunks = [start for opcode, start, _ in _top_records(data) if opcode == 0x06]
    assert len(chunks) == len(items)
    expected = [codec.encode(msg) for _, msg in items]  # type: ignore[arg-type]
    for at in (chunks[1] + 3, 9):  # the second chunk's record length; the header's
        damaged = bytearray(data)
        damaged[at] ^= 0x5A
        (tmp_path / "damaged.mcap").write_bytes(bytes(damaged))
        with pytest.raises(RecordError, match=r"its data section does not match the CRC .* bag recover"):
            list(mcap_io.read_messages(tmp_path / "damaged.mcap"))
        report = mcap_io.recover(tmp_path / "damaged.mcap", tmp_path / "fixed.mcap")
        assert report.data_crc_mismatch and report.lost() == 0 and report.chunks == len(items)
        assert [m.data for m in mcap_io.read_messages(tmp_path / "fixed.mcap")] == expected
        recovered = mcap_io.launch_info(tmp_path / "fixed.mcap", verify=True)
        assert recovered == {**about, mcap_io.UNVERIFIED_KEY: recovered[mcap_io.UNVERIFIED_KEY]}  # no CRC covered it
    assert mcap_io.recover(src, tmp_path / "same.mcap").lost() == 0  # an intact log: nothing to say


def test_altered_launch_metadata_is_refused_where_it_would_mislead(tmp_path: Path) -> None:
    """An outside audit: seed 0 edited to 7 in the file passed every check, and a replay's note quoted it."""
    src = tmp_path / "run.mcap"
    items = _launch_log(src, {"launch_file": "launch/probe.yaml", "args": "{}", "seed": "0"})
    data = src.read_bytes()
    at = data.index(b"seed") + len(b"seed") + 4  # past the value's length prefix: its one character
    assert data[at : at + 1] == b"0"
    (tmp_path / "altered.mcap").write_bytes(data[:at] + b"7" + data[at + 1 :])
    assert mcap_io.launch_info(tmp_path / "altered.mcap")["seed"] == "7"  # unverified: as bag info shows it
    with pytest.raises(RecordError, match=r"such as the launch's metadata\); the file is damaged"):
        mcap_io.launch_info(tmp_path / "altered.mcap", verify=True)
    with pytest.raises(RecordError, match=r"its data section does not match"):
        list(mcap_io.read_messages(tmp_path / "altered.mcap"))
    # an outside walkthrough: filter carried the altered metadata into a log with a new CRC, where it then
    # passed as verified; and the viewer drew such a log
    with pytest.raises(RecordError, match=r"altered\.mcap: its data section does not match .* bag recover"):
        mcap_io.copy_log(tmp_path / "altered.mcap", tmp_path / "filtered.mcap")
    assert not (tmp_path / "filtered.mcap").exists()
    from palpate.errors import ViewerError
    from palpate.viewer.sources import LogSource

    with pytest.raises(ViewerError, match=r"its data section does not match .*, and view the result"):
        list(LogSource(tmp_path / "altered.mcap"))
    report = mcap_io.recover(tmp_path / "altered.mcap", tmp_path / "kept.mcap")
    assert report.data_crc_mismatch and report.lost() == 0 and report.indexed
    kept = mcap_io.launch_info(tmp_path / "kept.mcap", verify=True)  # a valid log now, its metadata marked
    assert kept["seed"] == "7" and "may be altered" in kept[mcap_io.UNVERIFIED_KEY]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:-3])  # inside the closing magic bytes
    report = mcap_io.recover(cut, tmp_path / "uncut.mcap")
    assert report.magic_cut and report.complete and report.messages == len(items)


def test_recover_of_a_damaged_chunk_beside_appended_bytes_still_reads_to_the_footer(tmp_path: Path) -> None:
    """The review: the data section's CRC, checked while scanning, ended the scan at DataEnd, so a log with a
    damaged chunk and bytes appended lost its footer and the note on the appended bytes."""
    items = canonical_log(6)
    full = tmp_path / "full.mcap"
    sizes = write_log(full, items, flush_each=True)
    data = bytearray(full.read_bytes())
    data[sizes[3] + CHUNK_DATA_OFFSET + 2] ^= 0x10  # message 4's chunk
    (tmp_path / "damaged.mcap").write_bytes(bytes(data) + bytes(16))  # and 16 bytes appended: no summary read
    report = mcap_io.recover(tmp_path / "damaged.mcap", tmp_path / "fixed.mcap")
    assert not report.indexed and report.complete and report.trailing == 16 and report.damaged_chunks == 1
    assert report.messages + report.orphaned == len(items) - 1  # orphaned: on a channel the damaged chunk defined


def test_a_damaged_footer_is_named_not_a_traceback(tmp_path: Path) -> None:
    """The review: the data section's check read the summary's offset from a damaged footer and sought past
    the file's end (OSError) where the reader had named the damage."""
    src = tmp_path / "run.mcap"
    _launch_log(src, {"launch_file": "launch/probe.yaml", "args": "{}", "seed": "0"})
    data = bytearray(src.read_bytes())
    footer_at = len(data) - len(mcap_io.MCAP_MAGIC) - mcap_io.FOOTER_BYTES
    data[footer_at] = 0x22  # no footer's opcode
    data[footer_at + 9 + 7] = 0x7F  # a summary offset far beyond the file
    (tmp_path / "footer.mcap").write_bytes(bytes(data))
    for read in (mcap_io.read_messages, lambda path: mcap_io.launch_info(path, verify=True)):
        with pytest.raises(RecordError, match=r"footer\.mcap: cannot read the MCAP log .* bag recover"):
            list(read(tmp_path / "footer.mcap"))


def test_bag_info_check_names_clocks_stamped_before_the_one_before(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: a real-time driver's clock that went back was recorded, passed `bag info
    --check` as fine, and its lockstep replay then stalled."""
    import dataclasses

    from palpate.messages.schemas import Clock

    items = [
        (t, dataclasses.replace(m, stamp_ns=0) if isinstance(m, Clock) and m.tick == 4 else m)
        for t, m in canonical_log(6)
    ]
    path = tmp_path / "went_back.mcap"
    write_log(path, items)
    assert main(["bag", "info", str(path), "--check"]) == 0
    assert "  clock: 1 Clock stamped before the one before (the first at tick 4)" in capsys.readouterr().out
    assert main(["bag", "info", str(path), "--check", "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["clock_stamps_back"] == 1
    whole = tmp_path / "whole.mcap"
    write_log(whole, canonical_log(6))
    assert main(["bag", "info", str(whole), "--check", "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["clock_stamps_back"] == 0
