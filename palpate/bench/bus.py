"""`palpate bench bus`: one-hop latency and throughput of palpate's bus against raw pyzmq.

Two processes per transport on one machine: this one (the pinger) and an echo process. Both
transports use the same socket pattern -- the pinger's XPUB to the echo's SUB and the echo's XPUB to
the pinger's SUB, over ipc, with the unlimited high-water marks of lockstep mode -- and carry the
same float64 array of 64 B, 4 KB or 1 MB:

- palpate: a `ParticleSetSummary` whose `weights` hold the array. A send runs `codec.encode` and
  sends ``[topic, payload]`` with copy=False on sockets made by `palpate.runtime.bus`; a receipt runs
  `codec.decode` (which checks types, shapes and finiteness; arrays are zero-copy). With
  `--validate`, a send also runs `codec.validate` first, as `NodeContext.publish` does.
- raw: pyzmq's `send_array` example: ``[topic, JSON {dtype, shape}, array bytes]`` with copy=False,
  rebuilt with `np.frombuffer`.

Latency is measured by ping-pong (one hop = round trip / 2, on one clock). Throughput: the pinger
streams messages with at most WINDOW unacknowledged (the echo decodes each and acknowledges every
ACK_EVERY-th), then a flush message that the echo answers with the count it received; throughput =
array bytes / time until that answer. Rounds alternate between the transports (AB, BA, AB, ...) so
that machine noise hits both alike. Every process tunes its allocator as node processes do
(`palpate.runtime.memory`). Not included: the node runner's lockstep bookkeeping (polling,
acknowledgements), which is per tick rather than per message.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import zmq

from palpate import jsonio
from palpate.argtypes import positive_int
from palpate.errors import BenchmarkError
from palpate.messages import codec
from palpate.messages.schemas import ParticleSetSummary
from palpate.runtime import bus, memory

#: Array sizes measured, bytes of float64 data per message.
SIZES_BYTES = (64, 4096, 1 << 20)

PING, PONG, STREAM, FLUSH, STOP = b"bench/ping", b"bench/pong", b"bench/stream", b"bench/flush", b"bench/stop"
ACK = b"bench/ack"
_ECHO_TOPICS = (PING, STREAM, FLUSH, STOP)
_PINGER_TOPICS = (PONG, ACK)
#: Streaming keeps at most WINDOW messages unacknowledged; the echo acknowledges every ACK_EVERY-th.
WINDOW, ACK_EVERY = 8, 4
_BIG_BYTES = 64 * 1024  # sizes above this use fewer pings and stream messages per round
TRANSPORTS = ("palpate", "raw")


@dataclass(frozen=True, kw_only=True)
class BusBenchConfig:
    """How much to measure. Rounds are short and many, so that load changes hit both transports alike.

    Counts are per round and transport; sizes above 64 KB use an eighth of the pings and a tenth of
    the streamed messages.
    """

    rounds: int = 40
    pings_per_round: int = 100
    stream_messages: int = 400
    warmup_pings: int = 50
    timeout_s: float = 30.0
    validate: bool = False  # palpate sends also run codec.validate, as NodeContext.publish does

    def pings(self, size_bytes: int) -> int:
        return self.pings_per_round if size_bytes <= _BIG_BYTES else max(2, self.pings_per_round // 8)

    def streamed(self, size_bytes: int) -> int:
        return self.stream_messages if size_bytes <= _BIG_BYTES else max(2, self.stream_messages // 10)


#: `--quick`: a few seconds on a 2-core machine.
QUICK = BusBenchConfig(rounds=20, pings_per_round=50, stream_messages=100, warmup_pings=20)


@dataclass(frozen=True)
class SizeResult:
    """Figures for one array size: latency of one hop in microseconds, throughput in GB/s (1e9 B/s)."""

    size_bytes: int
    palpate_p50_us: float
    palpate_p99_us: float
    raw_p50_us: float
    raw_p99_us: float
    palpate_gbps: float
    raw_gbps: float
    palpate_msgs_per_s: float
    raw_msgs_per_s: float

    @property
    def latency_ratio(self) -> float:
        """p50 latency of palpate over raw pyzmq."""
        return self.palpate_p50_us / self.raw_p50_us

    @property
    def latency_ratio_p99(self) -> float:
        return self.palpate_p99_us / self.raw_p99_us

    @property
    def throughput_ratio(self) -> float:
        return self.palpate_gbps / self.raw_gbps


# --- the two transports ------------------------------------------------------------------------------
class _PalpateLink:
    """palpate's bus: sockets from palpate.runtime.bus, encode on send, decode on receipt."""

    def __init__(
        self, ctx: zmq.Context[Any], bind: str, connect: str, topics: tuple[bytes, ...], *, validate: bool = False
    ):
        self.validate = validate
        self.pub = bus.make_publisher(ctx, bind, lockstep=True)
        self.sub = bus.make_subscriber(ctx, [connect], [t.decode() for t in topics], lockstep=True)

    @staticmethod
    def item(values: np.ndarray) -> ParticleSetSummary:
        return ParticleSetSummary(
            stamp_ns=0,
            num_particles=len(values),
            effective_sample_size=1.0,
            best_index=0,
            resampled=False,
            joint_names=[],
            pose_mean_rad=np.zeros(0),
            pose_best_rad=np.zeros(0),
            weights=values,
        )

    @staticmethod
    def flush_item(count: int) -> ParticleSetSummary:
        """A tiny message carrying a count (the echo's answer to a flush)."""
        return replace(_PalpateLink.item(np.zeros(0)), num_particles=count)

    @staticmethod
    def count_of(item: ParticleSetSummary) -> int:
        return item.num_particles

    def send(self, topic: bytes, message: ParticleSetSummary) -> None:
        if self.validate:
            codec.validate(message)
        self.pub.send_multipart([topic, codec.encode(message)], copy=False)

    def recv(self) -> tuple[bytes, ParticleSetSummary]:
        topic, payload = self.sub.recv_multipart(copy=False)
        return topic.bytes, codec.decode(payload.buffer, ParticleSetSummary)


class _RawLink:
    """Raw pyzmq with the same socket pattern: pyzmq's send_array / recv_array."""

    def __init__(self, ctx: zmq.Context[Any], bind: str, connect: str, topics: tuple[bytes, ...]):
        self.pub = ctx.socket(zmq.XPUB)
        self.pub.setsockopt(zmq.XPUB_VERBOSE, 1)
        self.pub.setsockopt(zmq.SNDHWM, 0)
        self.pub.setsockopt(zmq.LINGER, 2000)
        self.pub.bind(bind)
        self.sub = ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.RCVHWM, 0)
        self.sub.setsockopt(zmq.LINGER, 0)
        for topic in topics:
            self.sub.setsockopt(zmq.SUBSCRIBE, topic)
        self.sub.connect(connect)

    @staticmethod
    def item(values: np.ndarray) -> np.ndarray:
        return values

    @staticmethod
    def flush_item(count: int) -> np.ndarray:
        return np.full(1, count, dtype=np.int64)

    @staticmethod
    def count_of(item: np.ndarray) -> int:
        return int(item[0])

    def send(self, topic: bytes, array: np.ndarray) -> None:
        self.pub.send(topic, zmq.SNDMORE)
        self.pub.send_json({"dtype": str(array.dtype), "shape": array.shape}, zmq.SNDMORE)
        self.pub.send(array, copy=False)

    def recv(self) -> tuple[bytes, np.ndarray]:
        topic = self.sub.recv()
        meta = self.sub.recv_json()
        frame = self.sub.recv(copy=False)
        return topic, np.frombuffer(frame.buffer, dtype=meta["dtype"]).reshape(meta["shape"])


class _Link(Protocol):
    pub: zmq.Socket[Any]
    sub: zmq.Socket[Any]

    def item(self, values: np.ndarray) -> Any: ...
    def flush_item(self, count: int) -> Any: ...
    def count_of(self, item: Any) -> int: ...
    def send(self, topic: bytes, item: Any) -> None: ...
    def recv(self) -> tuple[bytes, Any]: ...


def _link(
    transport: str, ctx: zmq.Context[Any], bind: str, connect: str, topics: tuple[bytes, ...], validate: bool
) -> _Link:
    if transport == "palpate":
        return _PalpateLink(ctx, bind, connect, topics, validate=validate)
    return _RawLink(ctx, bind, connect, topics)


def _endpoints(workdir: Path, transport: str) -> tuple[str, str]:
    """(pinger's endpoint, echo's endpoint) of a transport."""
    return bus.ipc_endpoint(workdir, f"{transport}-ping"), bus.ipc_endpoint(workdir, f"{transport}-echo")


def _wait_subscribed(pub: zmq.Socket[Any], topics: tuple[bytes, ...], timeout_s: float) -> None:
    bus.wait_for_subscribers(pub, bus.SubscriptionCounter(), {t.decode(): 1 for t in topics}, timeout_s)


# --- the echo process ------------------------------------------------------------------------------
def echo(transport: str, workdir: Path, timeout_s: float = 30.0, validate: bool = False) -> None:
    """Answer pings with the same content, count streamed messages, answer flushes with the count."""
    memory.keep_freed_buffers()  # as node processes do
    ctx: zmq.Context[Any] = zmq.Context()
    ping_endpoint, echo_endpoint = _endpoints(workdir, transport)
    link = _link(transport, ctx, echo_endpoint, ping_endpoint, _ECHO_TOPICS, validate)
    _wait_subscribed(link.pub, _PINGER_TOPICS, timeout_s)
    link.sub.setsockopt(zmq.RCVTIMEO, int(timeout_s * 1000))  # an orphaned echo ends by itself
    received = 0
    while True:
        try:
            topic, item = link.recv()
        except zmq.Again:
            break
        if topic == PING:
            link.send(PONG, item)
        elif topic == STREAM:
            received += 1
            if received % ACK_EVERY == 0:
                link.send(ACK, link.flush_item(received))
        elif topic == FLUSH:
            link.send(PONG, link.flush_item(received))
            received = 0
        elif topic == STOP:
            break
    link.pub.close(linger=0)
    link.sub.close()
    ctx.term()


# --- the pinger ------------------------------------------------------------------------------------
class _Pinger:
    """This process's end of one transport, and its echo process."""

    def __init__(self, transport: str, ctx: zmq.Context[Any], workdir: Path, timeout_s: float, validate: bool):
        self.transport = transport
        self.timeout_s = timeout_s
        ping_endpoint, echo_endpoint = _endpoints(workdir, transport)
        self.link = _link(transport, ctx, ping_endpoint, echo_endpoint, _PINGER_TOPICS, validate)
        self.link.sub.setsockopt(zmq.RCVTIMEO, int(timeout_s * 1000))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "palpate.bench.bus", "echo", transport, str(workdir), str(timeout_s)]
            + (["validate"] if validate else []),
            stdin=subprocess.DEVNULL,
        )

    def wait_ready(self) -> None:
        try:
            _wait_subscribed(self.link.pub, _ECHO_TOPICS, self.timeout_s)
        except TimeoutError as exc:
            raise BenchmarkError(f"{self.transport} echo process never subscribed: {exc}{self._exit_note()}") from exc

    def recv(self) -> tuple[bytes, Any]:
        try:
            return self.link.recv()
        except zmq.Again:
            raise BenchmarkError(
                f"{self.transport} echo process did not answer within {self.timeout_s:.0f} s{self._exit_note()}"
            ) from None

    def latency_us(self, item: Any, pings: int) -> np.ndarray:
        """One-hop latencies (round trip / 2) of `pings` ping-pongs, microseconds."""
        samples = np.empty(pings)
        send, recv, clock = self.link.send, self.recv, time.perf_counter_ns
        for i in range(pings):
            start = clock()
            send(PING, item)
            recv()
            samples[i] = (clock() - start) / 2000.0
        return samples

    def throughput_s(self, item: Any, messages: int) -> float:
        """Seconds to stream `messages` items and have the echo confirm it received them all.

        At most WINDOW messages are unacknowledged at any time, as in lockstep, where a tick bounds
        what is in flight: an unbounded queue would measure the allocator (every queued payload is a
        fresh buffer, whose pages fault in) more than the bus.
        """
        start = time.perf_counter()
        acknowledged = 0
        for i in range(messages):
            while i - acknowledged >= WINDOW:
                acknowledged = self.link.count_of(self.recv()[1])
            self.link.send(STREAM, item)
        self.link.send(FLUSH, self.link.flush_item(0))
        while True:
            topic, answer = self.recv()
            if topic == PONG:
                break
        elapsed = time.perf_counter() - start
        if self.link.count_of(answer) != messages:
            raise BenchmarkError(
                f"{self.transport}: the echo received {self.link.count_of(answer)} of {messages} streamed messages"
            )
        return elapsed

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.link.send(STOP, self.link.flush_item(0))
                self.proc.wait(timeout=5)
            except (subprocess.TimeoutExpired, zmq.ZMQError):
                self.proc.kill()
                self.proc.wait()
        self.link.pub.close(linger=0)
        self.link.sub.close()

    def _exit_note(self) -> str:
        code = self.proc.poll()
        return "" if code is None else f" (it exited with code {code})"


def run(config: BusBenchConfig, progress: Callable[[str], None] | None = None) -> list[SizeResult]:
    """Measure every size of `config` through both transports, in alternating rounds."""
    say = progress or (lambda text: None)
    memory.keep_freed_buffers()  # as node processes do
    workdir = Path(tempfile.mkdtemp(prefix="palpate-bench-"))
    ctx: zmq.Context[Any] = zmq.Context()
    pingers: dict[str, _Pinger] = {}
    try:
        for transport in TRANSPORTS:
            pingers[transport] = _Pinger(transport, ctx, workdir, config.timeout_s, config.validate)
        for pinger in pingers.values():
            pinger.wait_ready()
        rng = np.random.default_rng(0)
        results = []
        for size in SIZES_BYTES:
            values = rng.uniform(0.5, 1.5, size // 8)
            items = {t: pingers[t].link.item(values) for t in TRANSPORTS}
            pings, streamed = config.pings(size), config.streamed(size)
            latencies: dict[str, list[np.ndarray]] = {t: [] for t in TRANSPORTS}
            seconds: dict[str, list[float]] = {t: [] for t in TRANSPORTS}
            for t in TRANSPORTS:  # warm up: connections, caches, and the heap for the stream's buffers
                pingers[t].latency_us(items[t], config.warmup_pings)
                pingers[t].throughput_s(items[t], streamed)
            for r in range(config.rounds):
                for t in TRANSPORTS if r % 2 == 0 else TRANSPORTS[::-1]:  # AB, BA, AB, ...
                    latencies[t].append(pingers[t].latency_us(items[t], pings))
                for t in TRANSPORTS if r % 2 == 1 else TRANSPORTS[::-1]:
                    seconds[t].append(pingers[t].throughput_s(items[t], streamed))
            results.append(_summarise(size, streamed, latencies, seconds))
            say(f"  {_label(size)}: done")
        return results
    finally:
        for pinger in pingers.values():
            pinger.close()
        ctx.term()
        shutil.rmtree(workdir, ignore_errors=True)


def _summarise(
    size: int, streamed: int, latencies: dict[str, list[np.ndarray]], seconds: dict[str, list[float]]
) -> SizeResult:
    lat = {t: np.concatenate(latencies[t]) for t in TRANSPORTS}
    rate = {t: streamed / float(np.median(seconds[t])) for t in TRANSPORTS}  # messages per second
    return SizeResult(
        size_bytes=size,
        palpate_p50_us=float(np.percentile(lat["palpate"], 50)),
        palpate_p99_us=float(np.percentile(lat["palpate"], 99)),
        raw_p50_us=float(np.percentile(lat["raw"], 50)),
        raw_p99_us=float(np.percentile(lat["raw"], 99)),
        palpate_gbps=rate["palpate"] * size / 1e9,
        raw_gbps=rate["raw"] * size / 1e9,
        palpate_msgs_per_s=rate["palpate"],
        raw_msgs_per_s=rate["raw"],
    )


# --- reporting -------------------------------------------------------------------------------------
def _label(size: int) -> str:
    for unit, scale in (("MB", 1 << 20), ("KB", 1 << 10)):
        if size >= scale and size % scale == 0:
            return f"{size // scale}{unit}"
    return f"{size}B"


#: The goals the table is judged by (docs/benchmarks.md): palpate's worst p50 latency at most this many
#: times raw pyzmq's, and at least this many GB/s for 1 MB messages.
LATENCY_RATIO_GOAL = 1.5
THROUGHPUT_GOAL_GBPS = 1.0


def summary(results: list[SizeResult], config: BusBenchConfig, quick: bool) -> dict[str, Any]:
    """The JSON object: headline figures plus every figure per size (keyed '64B', '4KB', '1MB')."""
    by_size = {r.size_bytes: r for r in results}
    small, big = by_size[64], by_size[1 << 20]
    out: dict[str, Any] = {
        "benchmark": "bus",
        "quick": quick,
        "transport": "ipc",
        "message": ParticleSetSummary.TYPE,
        "latency_ratio_max": max(r.latency_ratio for r in results),
        "latency_p50_us_small": small.palpate_p50_us,
        "latency_p99_us_small": small.palpate_p99_us,
        "raw_latency_p50_us_small": small.raw_p50_us,
        "throughput_1mb_gbps": big.palpate_gbps,
        "raw_throughput_1mb_gbps": big.raw_gbps,
        "pass": bool(
            max(r.latency_ratio for r in results) <= LATENCY_RATIO_GOAL and big.palpate_gbps >= THROUGHPUT_GOAL_GBPS
        ),
        "rounds": config.rounds,
        "validate": config.validate,
        "load_average_1min": os.getloadavg()[0],
        "sizes": {},
    }
    for r in results:
        out["sizes"][_label(r.size_bytes)] = {
            **asdict(r),
            "latency_ratio": r.latency_ratio,
            "latency_ratio_p99": r.latency_ratio_p99,
            "throughput_ratio": r.throughput_ratio,
        }
    return out


def table(results: list[SizeResult]) -> str:
    """The human-readable table (Markdown)."""
    head = (
        "| size | palpate p50 / p99 (us) | raw pyzmq p50 / p99 (us) | p50 ratio | p99 ratio "
        "| palpate msg/s (GB/s) | raw msg/s (GB/s) | throughput ratio |"
    )
    lines = [head, "|---" * (head.count("|") - 1) + "|"]
    for r in results:
        lines.append(
            f"| {_label(r.size_bytes)} | {r.palpate_p50_us:.1f} / {r.palpate_p99_us:.1f} "
            f"| {r.raw_p50_us:.1f} / {r.raw_p99_us:.1f} | {r.latency_ratio:.2f} | {r.latency_ratio_p99:.2f} "
            f"| {r.palpate_msgs_per_s:.0f} ({r.palpate_gbps:.3f}) | {r.raw_msgs_per_s:.0f} ({r.raw_gbps:.3f}) "
            f"| {r.throughput_ratio:.2f} |"
        )
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `palpate bench bus` beyond the shared --quick and --json."""
    parser.add_argument("--rounds", type=positive_int, help="alternating rounds per size and transport")
    parser.add_argument("--pings", type=positive_int, help="ping-pongs per round (sizes above 64 KB: an eighth)")
    parser.add_argument("--validate", action="store_true", help="palpate sends also run codec.validate")
    parser.add_argument(
        "--stream", type=positive_int, help="messages streamed per throughput round (above 64 KB: a tenth)"
    )


def config_from_args(args: argparse.Namespace) -> BusBenchConfig:
    """QUICK or the full configuration, with --rounds, --pings and --stream applied."""
    config = QUICK if args.quick else BusBenchConfig()
    if getattr(args, "rounds", None):
        config = replace(config, rounds=args.rounds)
    if getattr(args, "pings", None):
        config = replace(config, pings_per_round=args.pings, warmup_pings=min(config.warmup_pings, args.pings))
    if getattr(args, "stream", None):
        config = replace(config, stream_messages=args.stream)
    if getattr(args, "validate", False):
        config = replace(config, validate=True)
    return config


def main(args: argparse.Namespace) -> int:
    """`palpate bench bus [--quick] [--json]`: print the table, and with --json a last line of JSON."""
    config = config_from_args(args)
    print(
        f"palpate bench bus: {config.rounds} alternating rounds per size and transport, ipc, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; one hop = round trip / 2"
        + ("; palpate sends run codec.validate" if config.validate else ""),
        flush=True,
    )
    results = run(config, progress=lambda text: print(text, file=sys.stderr, flush=True))
    print(table(results))
    out = summary(results, config, bool(args.quick))
    print(
        f"worst p50 latency ratio palpate/raw: {out['latency_ratio_max']:.2f} (goal <= {LATENCY_RATIO_GOAL:g}); "
        f"1 MB throughput {out['throughput_1mb_gbps']:.2f} GB/s (goal >= {THROUGHPUT_GOAL_GBPS:g}): "
        + ("met" if out["pass"] else "MISSED")
    )
    if args.json:
        print(jsonio.dumps(out, sort_keys=True))
    return 0 if out["pass"] else 1  # as the other benchmarks: a missed goal is exit 1


def _echo_main(argv: list[str]) -> int:
    if len(argv) not in (4, 5) or argv[0] != "echo" or argv[1] not in TRANSPORTS or argv[4:] not in ([], ["validate"]):
        print("usage: python -m palpate.bench.bus echo {palpate|raw} WORKDIR TIMEOUT_S [validate]", file=sys.stderr)
        return 64
    try:
        echo(argv[1], Path(argv[2]), float(argv[3]), validate=argv[4:] == ["validate"])
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group: the parent says so, not a traceback
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(_echo_main(sys.argv[1:]))
