"""`palpate record`, `palpate replay` and `palpate bag info|recover|filter`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from palpate import jsonio
from palpate.argtypes import non_negative_float, non_negative_int, path_arg
from palpate.errors import MessageError, RecordError
from palpate.messages import codec, topics
from palpate.messages.schemas import Clock
from palpate.record import mcap_io, recorder
from palpate.record.bag import Player, PlayOptions, counted, describe
from palpate.runtime import bus


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    r = sub.add_parser("record", help="record bus topics into an MCAP log")
    recorder.add_arguments(r)
    r.add_argument("--force", action="store_true", help="overwrite an existing log")
    r.set_defaults(func=run_record)

    p = sub.add_parser("replay", help="publish a recorded log on the bus")
    p.add_argument("file", type=path_arg, help="MCAP log")
    p.add_argument(
        "--rate", type=non_negative_float, default=1.0, help="speed factor of the recorded sim-time pacing (0: --fast)"
    )
    p.add_argument("--fast", action="store_true", help="as fast as the subscribers take the messages")
    p.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    p.add_argument("--topics", nargs="+", default=[], metavar="TOPIC", help="replay only these topics")
    p.add_argument(
        "--start", type=non_negative_float, default=0.0, metavar="S", help="skip the first S seconds of sim time"
    )
    p.add_argument("--bus", type=path_arg, help=f"bus directory (default ${bus.BUS_ENV} or a per-user temp dir)")
    p.add_argument("--name", default="replay", help="publisher name on the bus (manifest and ipc socket)")
    p.add_argument(
        "--subscribers",
        type=non_negative_int,
        default=1,
        metavar="N",
        help="wait for N subscribers first (default 1; 0: no)",
    )
    p.add_argument(
        "--wait-timeout",
        type=non_negative_float,
        default=30.0,
        metavar="S",
        help="give up waiting after S s (default 30; 0: never)",
    )
    p.set_defaults(func=run_replay)

    b = sub.add_parser("bag", help="inspect, repair and filter MCAP logs")
    bsub = b.add_subparsers(dest="bag_command", required=True, metavar="BAG_COMMAND")
    info = bsub.add_parser("info", help="per-topic counts, types and the time span of a log")
    info.add_argument("file", type=path_arg)
    info.add_argument(
        "--json", action="store_true", help="one JSON line: topics, types, start_ns, end_ns, messages, launch"
    )
    info.add_argument(
        "--check", action="store_true", help="also read every message, checking each chunk (the summary alone is not)"
    )
    info.set_defaults(func=run_info)
    rec = bsub.add_parser("recover", help="rewrite a truncated log (recorder killed) into a valid one")
    rec.add_argument("file", type=path_arg)
    rec.add_argument("-o", "--output", type=path_arg, help="output log (default FILE.recovered.mcap)")
    rec.add_argument("--force", action="store_true", help="overwrite an existing output log")
    rec.set_defaults(func=run_recover)
    flt = bsub.add_parser("filter", help="copy a log keeping or dropping topics")
    flt.add_argument("file", type=path_arg)
    flt.add_argument("-o", "--output", type=path_arg, required=True)
    flt.add_argument("--topics", nargs="+", metavar="TOPIC", help="keep only these topics")
    flt.add_argument("--exclude", nargs="+", default=[], metavar="TOPIC", help="drop these topics")
    flt.add_argument("--force", action="store_true", help="overwrite an existing output log")
    flt.set_defaults(func=run_filter)
    exp = bsub.add_parser(
        "export", help="rewrite a log for another tool: --foxglove, Foxglove's schemas (scene, transforms, plots)"
    )
    exp.add_argument("file", type=path_arg)
    exp.add_argument("-o", "--output", type=path_arg, required=True, help="output MCAP file")
    fmt = exp.add_mutually_exclusive_group(required=True)
    fmt.add_argument(
        "--foxglove",
        action="store_true",
        help="Foxglove's own schemas (protobuf, needs pip install 'palpate[foxglove]'); docs/viewer.md",
    )
    exp.add_argument("--topics", nargs="+", metavar="TOPIC", help="export only these topics")
    exp.add_argument("--force", action="store_true", help="overwrite an existing output file")
    exp.set_defaults(func=run_export)


def run_replay(args: argparse.Namespace) -> int:
    options = PlayOptions(
        rate=0.0 if args.fast else args.rate,
        loop=args.loop,
        topics=tuple(args.topics),
        start_s=args.start,
        name=args.name,
        subscribers=args.subscribers,
        wait_timeout_s=args.wait_timeout,
    )
    return Player(args.file, args.bus, options).run()


def run_record(args: argparse.Namespace) -> int:
    """`palpate record`: as the recorder, refusing to replace an existing log without --force."""
    try:
        exists = args.output.is_file()
    except OSError as exc:  # a name too long
        raise RecordError(f"-o {args.output}: {exc.strerror}") from exc
    if exists and not args.force:
        raise RecordError(f"{args.output} exists; pass --force to replace it, or choose another output with -o")
    return recorder.run(args)


def tick_gaps(ticks: Sequence[int]) -> list[tuple[int, int]]:
    """The spans (first, last) of ticks from 0 to the largest that ``ticks`` (a log's Clocks) lack."""
    seen = sorted(set(ticks))
    gaps, expected = [], 0
    for tick in seen:
        if tick > expected:
            gaps.append((expected, tick - 1))
        expected = max(expected, tick + 1)
    return gaps


def run_info(args: argparse.Namespace) -> int:
    summary = mcap_io.summarize(args.file)
    launch = mcap_io.launch_info(args.file)
    gaps: list[tuple[int, int]] = []
    back: list[int] = []  # ticks of Clocks stamped before the Clock before them
    if args.check:
        read, ticks, last_ns = 0, [], -1
        for message in mcap_io.read_messages(args.file):  # RecordError at a damaged chunk
            read += 1
            if message.topic == topics.CLOCK:
                try:
                    clock = codec.decode(message.data, Clock)
                except MessageError:  # a recorded Clock this build cannot read counts no tick
                    continue
                ticks.append(clock.tick)
                if clock.stamp_ns < last_ns:
                    back.append(clock.tick)
                last_ns = clock.stamp_ns
        if read != summary.messages:
            raise RecordError(
                f"{args.file}: its summary counts {summary.messages} messages, its chunks hold {read}; "
                f"`palpate bag recover {args.file}` rewrites what it holds"
            )
        gaps = tick_gaps(ticks)
    missing = sum(last - first + 1 for first, last in gaps)
    if args.json:
        extra = {"ticks_missing": missing, "clock_stamps_back": len(back)} if args.check else {}
        print(jsonio.dumps({**summary.as_json(), **extra, "launch": mcap_io.launch_values(launch)}))
    else:
        print(describe(summary, args.file))
        if args.check:
            messages = counted(summary.messages, "message")
            print(f"  checked: every chunk's CRC, and {messages} read as the summary counts")
        if gaps:
            spans = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in gaps[:10]) + (
                ", ..." if len(gaps) > 10 else ""
            )
            print(
                f"  clock: {counted(missing, 'tick')} missing ({spans}): a recovered log lacks its damaged "
                "chunks, a recording started late its start; a replay of it differs from the run from there"
            )
        if back:
            print(
                f"  clock: {counted(len(back), 'Clock')} stamped before the one before (the first at tick {back[0]}): "
                "a real-time clock that went back (a restarted driver); a lockstep replay stops there, "
                "mode:=realtime replays it"
            )
        if launch:
            print(
                f"  recorded by palpate launch {launch.get('launch_file', '?')}, seed {launch.get('seed', '?')}, "
                f"arguments {launch.get('args', '{}')}"
                + (f", parameters set {launch['params']}" if "params" in launch else "")
                + (f", nodes played by drivers: {launch['external']}" if "external" in launch else "")
                + (
                    f" ({mcap_io.UNVERIFIED_KEY}: {launch[mcap_io.UNVERIFIED_KEY]})"
                    if mcap_io.UNVERIFIED_KEY in launch
                    else ""
                )
            )
    return 0


def run_recover(args: argparse.Namespace) -> int:
    if not args.file.name:  # `/`: no name to put the default output beside
        raise RecordError(f"{args.file} is a directory, not a log; give the log file to recover")
    output = args.output or args.file.with_name(args.file.stem + ".recovered.mcap")
    report = mcap_io.recover(args.file, output, overwrite=args.force)
    state = f"input truncated ({report.reason})" if report.truncated else "input was complete"
    if report.magic_cut:
        state += "; the file ends inside the closing magic bytes, after the footer"
    if report.indexed and (report.data_crc_mismatch or report.damaged_chunks):
        state += "; every chunk was read where the log's index puts it"
    if report.data_crc_mismatch and not report.damaged_chunks:
        state += (
            "; its data section did not match its CRC although every chunk did: a chunk's frame or a record "
            "between the chunks is damaged, maybe the launch's metadata (kept as read, marked unverified)"
        )
    if report.trailing:
        state += f"; left out the {report.trailing} bytes after the log's end (appended to it)"
    if report.damaged_chunks:
        state += (
            f"; skipped {report.damaged_chunks} damaged chunk(s), whose messages are lost ({report.damage}): "
            "a lockstep log then lacks those ticks"
        )
    if report.orphaned:
        state += f"; {report.orphaned} message(s) on channels defined only in damaged chunks were dropped"
    if (lost := report.lost()) is not None and (lost or report.truncated or report.damaged_chunks):
        state += f"; {lost} of the {report.expected} messages the log's summary counts are lost"
    last = f", last stamp {report.last_log_time * 1e-9:.3f} s" if report.last_log_time is not None else ""
    print(f"recovered {report.messages} messages from {report.chunks} chunks into {output}{last}; {state}")
    return 0


def run_filter(args: argparse.Namespace) -> int:
    _not_in_log(args.file, [*(args.topics or []), *args.exclude])
    count = mcap_io.copy_log(args.file, args.output, include=args.topics, exclude=args.exclude, overwrite=args.force)
    print(f"wrote {count} messages to {args.output}")
    return 0


def _not_in_log(path: Path, topics: list[str]) -> None:
    """Say on stderr which of `topics` the log does not hold (a typo keeps or drops nothing)."""
    try:
        if not path.is_file():
            return  # the copy names it
    except OSError:  # a name too long: the copy names it too
        return
    missing = sorted(set(topics) - set(mcap_io.topic_types(path)))
    if missing:
        print(f"palpate bag: {path} has no topic {', '.join(missing)} (see palpate bag info)", file=sys.stderr)


def run_export(args: argparse.Namespace) -> int:
    from palpate.viewer.foxglove_export import export_foxglove  # needs the foxglove extra

    _not_in_log(args.file, args.topics or [])
    report = export_foxglove(args.file, args.output, args.topics, overwrite=args.force)
    total = sum(report.written.values())
    print(
        f"exported {report.converted} of {report.read} messages as {total} Foxglove messages to {args.output}"
        + (f"; {report.undecodable} undecodable skipped" if report.undecodable else "")
        + (f"; {report.unusable} unusable skipped (last: {report.last_unusable})" if report.unusable else "")
    )
    width = max([len(t) for t, _ in report.written] + [5])
    for (topic, schema), count in sorted(report.written.items()):
        print(f"  {topic:<{width}}  {schema:<24}  {count:>8}")
    return 0
