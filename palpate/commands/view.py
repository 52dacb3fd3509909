"""`palpate view`: the exploration in the rerun viewer, live from the bus or from an MCAP log.

Needs the optional viewer extra (rerun-sdk); without it the command stops with exit code 2 and says
how to install it. With ``--save FILE.rrd`` it writes a recording instead of opening a window (for
machines without a display; open the file later with ``rerun FILE.rrd``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from palpate.argtypes import non_negative_float, path_arg
from palpate.commands.introspect import CURVE_KEYS_HELP
from palpate.errors import InputError, ViewerError
from palpate.runtime import bus
from palpate.viewer import require_rerun
from palpate.viewer.rerun_log import SHOWN_TYPES, SceneLogger

if TYPE_CHECKING:
    from palpate.messages.base import Message
    from palpate.viewer.sources import SourceStats


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    shown = ", ".join(cls.TYPE for cls in SHOWN_TYPES)
    p = sub.add_parser(
        "view",
        help="show the exploration in the rerun viewer (needs the viewer extra)",
        description=(
            "Show true mesh, contacts and normals, the estimated surface coloured by GP variance, candidate "
            "scores, the planned curve, the fingertip trail and occupancy grids, on a sim-time timeline, live "
            f"from the bus or from an MCAP log. Shown types: {shown}. Needs: pip install 'palpate[viewer]'."
        ),
    )
    p.add_argument("--log", type=path_arg, metavar="FILE.mcap", help="view a recorded log instead of the live bus")
    p.add_argument("--bus", type=path_arg, help=f"bus directory (default ${bus.BUS_ENV} or a per-user temp dir)")
    p.add_argument("--save", type=path_arg, metavar="FILE.rrd", help="write a rerun recording file instead of a window")
    p.add_argument("--force", action="store_true", help="replace an existing --save file")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="show only these topics (default: every shown type)")
    p.add_argument("--curve-keys", type=path_arg, metavar="FILE", help=CURVE_KEYS_HELP)
    p.add_argument(
        "--duration",
        type=non_negative_float,
        default=0.0,
        metavar="S",
        help="live: stop after S s (0: at the graph's stop or Ctrl-C)",
    )
    p.set_defaults(func=run_view)


def has_display() -> bool:
    """Whether a viewer window can open: always on macOS and Windows, with X11 or Wayland elsewhere."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def run_view(args: argparse.Namespace) -> int:
    if args.log is not None and args.bus is not None:
        raise ViewerError("give --log FILE.mcap or --bus DIR, not both")
    require_rerun()
    if args.save is None and not has_display():
        raise ViewerError(
            "no display (DISPLAY and WAYLAND_DISPLAY are unset): write a recording with --save FILE.rrd "
            "and open it with `rerun FILE.rrd` on a machine with a display"
        )
    from palpate.viewer.sink import SaveTarget, open_recording  # imports rerun
    from palpate.viewer.sources import BusSource, LogSource

    target = None if args.save is None else SaveTarget.of(args.save, force=args.force)
    writing = None if target is None else target.writing
    scene = SceneLogger()
    try:
        if args.log is not None:
            log_source = LogSource(args.log, args.topics)  # checks the file before the recording is created
            _note_missing_topics(log_source.missing_topics(), f"{args.log} has no topic")
            sink = open_recording(save=writing)
            try:
                for topic, message in log_source:
                    _draw(scene, sink, topic, message, log_source.stats)
            finally:
                sink.close()
            stats, origin, code = log_source.stats, str(args.log), 0
        else:
            bus_dir = Path(args.bus) if args.bus else bus.default_bus_dir()
            sink = open_recording(save=writing)
            client_keys = bus.read_key_file(args.curve_keys) if args.curve_keys else None
            bus_source = BusSource(bus_dir, args.topics, client_keys)
            print(f"palpate view: watching bus {bus_dir} (Ctrl-C to stop)", flush=True)
            try:
                for topic, message in bus_source.messages(args.duration):
                    _draw(scene, sink, topic, message, bus_source.stats)
            finally:
                bus_source.close()
                sink.close()
            stats, origin, code = bus_source.stats, f"bus {bus_dir}", 130 if bus_source.interrupted else 0
    except BaseException:
        if target is not None:  # a log can be viewed again; a live run cannot: keep what it recorded
            kept = target.abandon(keep=args.log is None)
            if kept is not None:
                print(f"palpate view: the recording up to the failure is in {kept}", file=sys.stderr)
        raise
    empty_log = stats.shown == 0 and args.log is not None  # a log viewed again shows nothing again
    if target is not None and empty_log:
        target.abandon(keep=False)
    elif target is not None:
        target.commit()
    print(f"palpate view: {stats.shown} of {stats.received} messages shown from {origin}", flush=True)
    if stats.shown == 0:
        print(
            f"palpate view: nothing to show; the viewer shows {', '.join(c.TYPE for c in SHOWN_TYPES)}"
            + (f"; {args.save} not written" if target is not None and empty_log else ""),
            file=sys.stderr,
        )
    if stats.undecodable:
        print(
            f"palpate view: {stats.undecodable} undecodable messages skipped, last: {stats.last_error}", file=sys.stderr
        )
    if stats.unusable:
        print(
            f"palpate view: {stats.unusable} messages with values it cannot draw skipped, last: {stats.last_unusable}",
            file=sys.stderr,
        )
    if empty_log:
        return 1
    if target is not None and target.path.is_file():
        size = target.path.stat().st_size
        print(f"palpate view: wrote {args.save} ({size / 1024:.1f} KiB); open it with `rerun {args.save}`")
    elif target is not None:
        print(f"palpate view: wrote the recording into {args.save}")
    return code


def _note_missing_topics(missing: list[str], what: str) -> None:
    """Say on stderr which asked-for topics there are none of (a typo shows nothing and says nothing else)."""
    if missing:
        print(f"palpate view: {what} {', '.join(missing)} (see palpate bag info / palpate topic list)", file=sys.stderr)


def _draw(scene: SceneLogger, sink: Any, topic: str, message: Message, stats: SourceStats) -> None:
    """Log one message to the viewer; one that decodes but holds values it cannot draw is skipped and
    counted (as a node skips it), not the end of the viewer."""
    try:
        scene.log_message(sink, topic, message)
    except InputError as exc:
        stats.shown -= 1  # counted as shown when it was received
        stats.unusable += 1
        stats.last_unusable = f"{topic} at {message.stamp_ns} ns: {exc}"
