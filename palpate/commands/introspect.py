"""`palpate topic list|echo|hz` and `palpate node list`: look at a running bus.

These tools find publishers through the manifests in the bus directory (``--bus``, else
``$PALPATE_BUS`` or the per-user default), so they work the same with a launched graph, a replayed
log or a single hardware driver, and they keep looking for new publishers every 0.5 s.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np

from palpate import jsonio
from palpate.argtypes import bounded_positive_int, non_negative_float, non_negative_int, path_arg
from palpate.errors import MessageError
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.record.mcap_io import peek
from palpate.runtime import bus

DISCOVERY_PERIOD_S = 0.5
#: A topic command says once that the bus has no publisher when it has had none this long.
EMPTY_BUS_NOTE_S = 2.0
_INLINE_ELEMENTS = 6
#: Largest `topic hz --window` (messages kept for the rate).
MAX_WINDOW = 10_000_000


#: Help of the tools' `--curve-keys` option.
CURVE_KEYS_HELP = "CurveZMQ key file for keyed publishers (they admit only the keys of their launch file's nodes)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    bus_help = f"bus directory (default ${bus.BUS_ENV} or a per-user temp dir)"
    t = sub.add_parser("topic", help="list, print and measure topics of the running bus")
    tsub = t.add_subparsers(dest="topic_command", required=True, metavar="TOPIC_COMMAND")
    tl = tsub.add_parser("list", help="topics with their types, publishers and subscribers")
    tl.add_argument("--bus", type=path_arg, help=bus_help)
    tl.add_argument("--json", action="store_true", help="one JSON line")
    tl.set_defaults(func=run_topic_list)
    te = tsub.add_parser("echo", help="print the messages of a topic, arrays summarised")
    te.add_argument("topic")
    te.add_argument(
        "-n",
        "--count",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="exit after N messages (default 0: no limit)",
    )
    te.add_argument("--bus", type=path_arg, help=bus_help)
    te.add_argument("--full", action="store_true", help="print arrays in full")
    te.add_argument("--timeout", type=non_negative_float, default=0.0, metavar="S", help="give up after S s (0: never)")
    te.add_argument("--curve-keys", type=path_arg, metavar="FILE", help=CURVE_KEYS_HELP)
    te.set_defaults(func=run_topic_echo)
    th = tsub.add_parser("hz", help="message rate of a topic, in wall-clock and sim time")
    th.add_argument("topic")
    th.add_argument(
        "--window",
        type=bounded_positive_int(MAX_WINDOW),
        default=100,
        metavar="N",
        help="messages the rate is measured over",
    )
    th.add_argument("--duration", type=non_negative_float, default=0.0, metavar="S", help="exit after S s (0: never)")
    th.add_argument("--bus", type=path_arg, help=bus_help)
    th.add_argument("--curve-keys", type=path_arg, metavar="FILE", help=CURVE_KEYS_HELP)
    th.set_defaults(func=run_topic_hz)

    n = sub.add_parser("node", help="nodes of the running bus")
    nsub = n.add_subparsers(dest="node_command", required=True, metavar="NODE_COMMAND")
    nl = nsub.add_parser("list", help="running nodes: pid, endpoint, topics")
    nl.add_argument("--bus", type=path_arg, help=bus_help)
    nl.add_argument("--json", action="store_true", help="one JSON line")
    nl.set_defaults(func=run_node_list)


def _client_keys(args: argparse.Namespace) -> dict[str, str] | None:
    return bus.read_key_file(args.curve_keys) if args.curve_keys else None


def _bus_dir(args: argparse.Namespace) -> Path:
    return Path(args.bus) if args.bus else bus.default_bus_dir()


# --- lists ---------------------------------------------------------------------------------------


def topic_table(manifests: list[bus.Manifest]) -> dict[str, dict[str, Any]]:
    """Topic -> {type, publishers, subscribers} from publisher manifests."""
    table: dict[str, dict[str, Any]] = {}
    for m in manifests:
        for topic, type_name in m.publishes.items():
            entry = table.setdefault(topic, {"type": type_name, "publishers": [], "subscribers": []})
            entry["publishers"].append(m.node)
        for topic, type_name in m.subscribes.items():
            entry = table.setdefault(topic, {"type": type_name, "publishers": [], "subscribers": []})
            entry["subscribers"].append(m.node)
    return dict(sorted(table.items()))


def run_topic_list(args: argparse.Namespace) -> int:
    table = topic_table(bus.read_manifests(_bus_dir(args)))
    if args.json:
        print(jsonio.dumps(table))
        return 0
    if not table:
        print(f"no publishers on bus {_bus_dir(args)}")
        return 0
    width = max(len(t) for t in table)
    for topic, entry in table.items():
        pubs = ", ".join(entry["publishers"]) or "-"
        subs = ", ".join(entry["subscribers"]) or "-"
        print(f"{topic:<{width}}  [{entry['type']}]  {pubs} -> {subs}")
    return 0


def run_node_list(args: argparse.Namespace) -> int:
    manifests = bus.read_manifests(_bus_dir(args))
    if args.json:
        print(
            jsonio.dumps(
                {
                    m.node: {"pid": m.pid, "endpoint": m.endpoint, "publishes": m.publishes, "subscribes": m.subscribes}
                    for m in manifests
                }
            )
        )
        return 0
    if not manifests:
        print(f"no nodes on bus {_bus_dir(args)}")
        return 0
    for m in manifests:
        print(f"{m.node} (pid {m.pid}) {m.endpoint}")
        for topic, type_name in sorted(m.publishes.items()):
            print(f"    publishes  {topic} [{type_name}]")
        for topic, type_name in sorted(m.subscribes.items()):
            print(f"    subscribes {topic} [{type_name}]")
    return 0


# --- subscribing ---------------------------------------------------------------------------------


class TopicTap:
    """A SUB socket on one topic that follows the publishers appearing in the bus directory."""

    def __init__(self, bus_dir: Path, topic: str, client_keys: dict[str, str] | None = None, command: str = "topic"):
        self.bus_dir, self.topic, self.command = bus_dir, topic, command
        self.tap = bus.PublisherTap(client_keys=client_keys)
        self.last_discovery = 0.0
        self.interrupted = False
        self.undeclared = bus.UndeclaredTopics([topic], bus_dir, settle_s=EMPTY_BUS_NOTE_S)

    @property
    def endpoints(self) -> set[str]:
        """Publisher endpoints connected so far."""
        return self.tap.endpoints

    def discover(self) -> None:
        """Connect to every publisher of the topic (to every publisher when none declares it: runtime topics)."""
        manifests = bus.read_manifests(self.bus_dir)
        declared = [m for m in manifests if self.topic in m.publishes]
        self.tap.connect(declared or manifests)
        self.last_discovery = time.monotonic()
        for note in self.undeclared.notes(manifests, self.last_discovery):
            print(f"{self.command}: {note}; waiting for one", file=sys.stderr, flush=True)
        if empty := self.undeclared.empty_bus_note(manifests, self.last_discovery):
            print(f"{self.command}: {empty}", file=sys.stderr, flush=True)

    def receive(self, timeout_s: float) -> list[tuple[float, bytes]]:
        """Payloads of the topic that arrive within `timeout_s`, with their arrival times."""
        if time.monotonic() - self.last_discovery >= DISCOVERY_PERIOD_S:
            self.discover()
        return [
            (time.monotonic(), frames[1])
            for frames in self.tap.receive(timeout_s)
            if len(frames) == 2 and frames[0].decode(errors="replace") == self.topic
        ]

    def run(self, handle: Callable[[float, bytes], bool], duration_s: float = 0.0) -> int:
        """Call `handle(arrival, payload)` per message until it returns False, a signal, or `duration_s`."""
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        deadline = time.monotonic() + duration_s if duration_s > 0 else None
        try:
            self.discover()
            while not self.interrupted and (deadline is None or time.monotonic() < deadline):
                for arrival, payload in self.receive(0.1):
                    if not handle(arrival, payload):
                        return 0
            return 0 if deadline is not None or not self.interrupted else 130
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
            self.close()

    def close(self) -> None:
        """Close the sockets and the context."""
        self.tap.close()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.interrupted = True


# --- echo ----------------------------------------------------------------------------------------


def format_value(value: Any, *, full: bool = False) -> str:
    """A field value for humans: small arrays inline, large ones as dtype, shape and range."""
    if isinstance(value, np.ndarray):
        if full or value.size <= _INLINE_ELEMENTS:
            return np.array2string(value, precision=6, separator=", ", threshold=sys.maxsize if full else 1000)
        head = f"<{value.dtype} {tuple(value.shape)}"
        if value.size and value.dtype.kind in "fiu":
            finite = value[np.isfinite(value)] if value.dtype.kind == "f" else value
            if finite.size:
                head += f" min {finite.min():.6g} max {finite.max():.6g} mean {finite.mean():.6g}"
            if finite.size < value.size:
                head += f", {value.size - finite.size} non-finite"
        return head + ">"
    if isinstance(value, list):
        if full or len(value) <= _INLINE_ELEMENTS:
            return repr(value)
        return f"[{', '.join(repr(v) for v in value[:3])}, ... ({len(value)} items)]"
    return repr(value)


def format_message(topic: str, message: Message, *, full: bool = False) -> str:
    """A decoded message as a block of `field: value` lines with units."""
    cls = type(message)
    lines = [f"--- {topic} [{cls.TYPE} v{cls.VERSION}] at {message.stamp_ns * 1e-9:.6f} s"]
    for name, spec in cls.field_specs().items():
        unit = f" [{spec.unit}]" if spec.unit else ""
        lines.append(f"{name}{unit}: {format_value(getattr(message, name), full=full)}")
    return "\n".join(lines)


def run_topic_echo(args: argparse.Namespace) -> int:
    tap = TopicTap(_bus_dir(args), args.topic, _client_keys(args), command="topic echo")
    seen = 0

    def handle(arrival: float, payload: bytes) -> bool:
        nonlocal seen
        try:
            message: Message = codec.decode(payload)
        except MessageError as exc:
            print(f"--- {args.topic}: undecodable message ({len(payload)} bytes): {exc}", flush=True)
        else:
            print(format_message(args.topic, message, full=args.full), flush=True)
        seen += 1
        return not (args.count and seen >= args.count)

    code = tap.run(handle, args.timeout)
    if code == 0 and seen == 0:
        print(f"topic echo: nothing arrived on {args.topic!r} in {args.timeout:g} s", file=sys.stderr)
        return 1
    if args.count and seen < args.count:
        print(f"topic echo: got {seen} of {args.count} messages on {args.topic!r}", file=sys.stderr)
        return 1 if code == 0 else code
    return code


# --- hz ------------------------------------------------------------------------------------------


class RateMeter:
    """Rates over the last `window` messages, in wall-clock time and in sim time (from the stamps); the
    window starts again where sim time goes back before it (publishers interleaved a tick apart do not)."""

    def __init__(self, window: int):
        self.arrivals: deque[float] = deque(maxlen=max(2, window))
        self.stamps: deque[int] = deque(maxlen=max(2, window))
        self.total = 0

    def add(self, arrival_s: float, stamp_ns: int) -> None:
        if self.stamps and stamp_ns < self.stamps[0]:  # before the window: a replay looped, a new run; anew
            self.arrivals.clear()
            self.stamps.clear()
        self.arrivals.append(arrival_s)
        self.stamps.append(stamp_ns)
        self.total += 1

    def wall_hz(self) -> float:
        span = self.arrivals[-1] - self.arrivals[0] if len(self.arrivals) > 1 else 0.0
        return (len(self.arrivals) - 1) / span if span > 0 else 0.0

    def sim_hz(self) -> float:
        span = (self.stamps[-1] - self.stamps[0]) * 1e-9 if len(self.stamps) > 1 else 0.0
        return (len(self.stamps) - 1) / span if span > 0 else 0.0

    def report(self) -> str:
        if len(self.arrivals) < 2:
            return f"{self.total} messages: not enough for a rate"
        gaps = np.diff(np.array(self.arrivals))
        return (
            f"rate {self.wall_hz():.2f} Hz wall, {self.sim_hz():.2f} Hz sim over {len(self.arrivals)} messages; "
            f"gap min {gaps.min() * 1e3:.2f} ms max {gaps.max() * 1e3:.2f} ms; {self.total} in total"
        )


def run_topic_hz(args: argparse.Namespace) -> int:
    tap = TopicTap(_bus_dir(args), args.topic, _client_keys(args), command="topic hz")
    meter = RateMeter(args.window)
    last_report = time.monotonic()

    def handle(arrival: float, payload: bytes) -> bool:
        nonlocal last_report
        try:
            meter.add(arrival, peek(payload).stamp_ns)
        except MessageError:
            return True
        if arrival - last_report >= 1.0:
            print(meter.report(), flush=True)
            last_report = arrival
        return True

    code = tap.run(handle, args.duration)
    print(meter.report(), flush=True)
    return code
