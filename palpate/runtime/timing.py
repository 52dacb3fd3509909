"""Where a tick's wall time goes: per-tick timestamps of a graph run (used by `palpate bench sim`).

Off by default. With ``$PALPATE_TICK_TIMING`` set to a directory, every node process records, per
lockstep tick, the moments it reaches (``time.perf_counter``: CLOCK_MONOTONIC on Linux, one clock for
all processes of a machine) and the time it spent encoding, and writes ``<dir>/<node>.json`` at exit.
:func:`breakdown` turns the files of one run into mean milliseconds per tick: the clock source's
step, encoding, each hop of the Clock message, each node's handling, the acknowledgement hop and the
clock source's own handling of the commands.

Marks of the clock source: ``step`` (before ``step()``), ``stepped`` (after it: simulation and
publishing), ``clock_sent`` (just before encoding and sending the Clock), ``acked`` (the last
acknowledgement arrived), ``dispatched`` (commands handled). Marks of a follower:
``clock_received``, ``ready`` (upstream acknowledgements there too), ``dispatched`` (inputs decoded and
handled), ``ticked`` (``on_tick`` and its publishing done), ``ack_sent`` (just before encoding and
sending the acknowledgement). Every node also records ``encode_s``, its encoding time in the tick.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from palpate import jsonio

#: Environment variable naming the directory that receives the timing files.
TIMING_ENV = "PALPATE_TICK_TIMING"


class TickRecorder:
    """Timestamps per tick of one node; ``None``-cheap when timing is off (see :func:`recorder`)."""

    def __init__(self, node: str, path: Path) -> None:
        self.node = node
        self.path = path
        self.rows: dict[int, dict[str, float]] = {}
        self.tick = -1

    def mark(self, tick: int, name: str) -> None:
        """Record that this node reached ``name`` in ``tick`` now."""
        self.rows.setdefault(tick, {})[name] = time.perf_counter()

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` to the sum ``name`` of the current tick (``self.tick``)."""
        row = self.rows.setdefault(self.tick, {})
        row[name] = row.get(name, 0.0) + seconds

    def write(self, clock_source: bool, trailing: Sequence[str] = ()) -> None:
        """Write the records as JSON (``{"node", "clock_source", "trailing", "ticks": {tick: {mark: seconds}}}``;
        ``trailing``: the clock source's trailing nodes)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = {
            "node": self.node,
            "clock_source": clock_source,
            "trailing": list(trailing),
            "ticks": {str(t): r for t, r in self.rows.items()},
        }
        self.path.write_text(jsonio.dumps(data))


def recorder(node: str) -> TickRecorder | None:
    """A recorder writing to ``$PALPATE_TICK_TIMING/<node>.json``, or None when timing is off."""
    folder = os.environ.get(TIMING_ENV)
    return TickRecorder(node, Path(folder) / f"{node}.json") if folder else None


def breakdown(folder: str | Path, first_tick: int = 0) -> dict[str, Any]:
    """Mean milliseconds per tick over the ticks from ``first_tick`` on, from one run's timing files
    (the ``PALPATE_TICK_TIMING`` folder ``folder``).

    Keys: ``tick_ms`` (clock source step start to the next one), ``step_ms`` (the clock source's
    step without its encoding: simulation and building messages), ``encode_ms`` (every node's
    encoding), ``clock_hop_ms`` (per follower: Clock sent to received), ``wait_ms`` (per follower:
    Clock received to ready, waiting for upstream acknowledgements), ``handle_ms`` (per follower:
    ready to acknowledged: decoding, handlers, on_tick, publishing), ``ack_hop_ms`` (last
    acknowledgement sent to received by the clock source), ``round_trip_ms`` (Clock sent to the last
    acknowledgement received), ``source_dispatch_ms`` (the clock source handling its inputs), ``trailing``
    (the nodes the clock source runs ahead of: their handling is off the round trip and out of
    ``ack_hop_ms``; their ``clock_hop_ms`` and ``wait_ms`` include the ticks they are behind).
    """
    files = [json.loads(p.read_text()) for p in sorted(Path(folder).glob("*.json"))]
    sources = [f for f in files if f["clock_source"]]
    if len(sources) != 1:
        raise ValueError(f"{folder}: expected one clock source's timing file, found {len(sources)}")
    source = {int(t): r for t, r in sources[0]["ticks"].items()}
    trailing = list(sources[0].get("trailing", []))
    followers = {f["node"]: {int(t): r for t, r in f["ticks"].items()} for f in files if not f["clock_source"]}
    ticks = sorted(t for t in source if t >= first_tick and t + 1 in source and _complete(t, source, followers))
    if not ticks:
        raise ValueError(f"{folder}: no complete tick from {first_tick} on")

    def mean(values: Sequence[float]) -> float:
        return 1000.0 * sum(values) / len(values)

    in_loop = {n: r for n, r in followers.items() if n not in trailing}
    out: dict[str, Any] = {
        "ticks": len(ticks),
        "trailing": trailing,
        "tick_ms": mean([source[t + 1]["step"] - source[t]["step"] for t in ticks]),
        "step_ms": mean([source[t]["stepped"] - source[t]["step"] - source[t].get("encode_s", 0.0) for t in ticks]),
        "encode_ms": mean(
            [
                source[t].get("encode_s", 0.0) + sum(rows[t].get("encode_s", 0.0) for rows in followers.values())
                for t in ticks
            ]
        ),
        "round_trip_ms": mean([source[t]["acked"] - source[t]["clock_sent"] for t in ticks]),
        "ack_hop_ms": mean([source[t]["acked"] - max(r[t]["ack_sent"] for r in in_loop.values()) for t in ticks])
        if in_loop
        else 0.0,
        "source_dispatch_ms": mean([source[t]["dispatched"] - source[t]["acked"] for t in ticks]),
        "clock_hop_ms": {
            n: mean([r[t]["clock_received"] - source[t]["clock_sent"] for t in ticks]) for n, r in followers.items()
        },
        "wait_ms": {n: mean([r[t]["ready"] - r[t]["clock_received"] for t in ticks]) for n, r in followers.items()},
        "handle_ms": {n: mean([r[t]["ack_sent"] - r[t]["ready"] for t in ticks]) for n, r in followers.items()},
    }
    return out


def _complete(tick: int, source: Mapping[int, Mapping[str, float]], followers: Mapping[str, Any]) -> bool:
    marks = ("step", "stepped", "clock_sent", "acked", "dispatched")
    if not all(m in source[tick] for m in marks):
        return False
    needed = ("clock_received", "ready", "ack_sent")
    return all(tick in rows and all(m in rows[tick] for m in needed) for rows in followers.values())
