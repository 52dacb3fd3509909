"""Where the node processes of a launched graph run: the launch file's ``placement`` (Linux only).

``placement: os`` (the default) leaves it to the operating system. ``placement: loop`` is for a
lockstep graph of light nodes (the probe benchmark, a simulator with a scripted driver):

- the clock source and every node it waits for each tick (the loop) share one CPU, the least busy
  one of those the launcher may use; the trailing nodes get the others;
- every node process the launcher starts runs under ``SCHED_BATCH``: a woken process does not
  preempt a running one.

Where the loop is a chain (sim -> driver -> sim), only one of its nodes works at a time, so one CPU
loses no parallelism and saves each hop of a tick a wake-up on a CPU that has gone idle; without
preemption, a node that receives its inputs one by one is not switched in for each of them. Nodes
of the loop that would handle a tick side by side (two followers of the clock alone) take turns.
Measured on the 2-core development VM: the probe graph's median round 11.9 against 7.6 times real
time (docs/benchmarks.md, Simulation, "Seventh pass"). Not for loops of heavy nodes that use
threads (the GPIS node's BLAS): on one CPU they lose them. Placement changes wall time only, never
a lockstep run's messages. External nodes, the recorder and the launcher itself are not placed.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from palpate.launch.graph import Graph

PLACEMENTS = ("os", "loop")
_PROC_STAT = Path("/proc/stat")


@dataclass(frozen=True)
class CpuPlacement:
    """The CPUs one node process may run on; it runs under SCHED_BATCH."""

    cpus: frozenset[int]

    def __str__(self) -> str:
        return f"CPU {','.join(map(str, sorted(self.cpus)))}"

    def apply(self) -> None:
        """Place the calling process (for a child: between fork and exec, so that every thread it
        starts inherits it). Each of the two settings is tried; OSError where the system refuses one."""
        refused: OSError | None = None
        try:
            os.sched_setaffinity(0, self.cpus)
        except OSError as exc:
            refused = exc
        try:
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
        except OSError as exc:
            refused = refused or exc
        if refused is not None:
            raise refused


def supported() -> bool:
    """Whether this system can place processes (Linux's affinity and scheduling calls)."""
    return all(hasattr(os, name) for name in ("sched_setaffinity", "sched_getaffinity", "SCHED_BATCH"))


def plan_loop(
    loop: Iterable[str], trailing: Iterable[str], allowed: Iterable[int], loop_cpu: int
) -> dict[str, CpuPlacement]:
    """``placement: loop``: the loop's nodes on `loop_cpu`, the trailing nodes on the other `allowed`
    CPUs (on `loop_cpu` too when it is the only one)."""
    allowed = frozenset(allowed)
    if loop_cpu not in allowed:
        raise ValueError(f"loop CPU {loop_cpu} is not among the allowed CPUs {sorted(allowed)}")
    others = allowed - {loop_cpu} or allowed
    placement = {name: CpuPlacement(frozenset({loop_cpu})) for name in loop}
    placement.update({name: CpuPlacement(others) for name in trailing})
    return placement


def busy_ticks(stat_text: str) -> dict[int, tuple[int, int]]:
    """Per CPU, (busy, total) clock ticks from the text of /proc/stat."""
    out: dict[int, tuple[int, int]] = {}
    for line in stat_text.splitlines():
        name, _, rest = line.partition(" ")
        if not (name.startswith("cpu") and name[3:].isdigit()):
            continue
        ticks = [int(v) for v in rest.split()]
        idle = sum(ticks[3:5])  # idle, iowait
        out[int(name[3:])] = (sum(ticks[:8]) - idle, sum(ticks[:8]))
    return out


def least_busy(
    before: Mapping[int, tuple[int, int]], after: Mapping[int, tuple[int, int]], allowed: Iterable[int]
) -> int:
    """The allowed CPU with the smallest busy share between two /proc/stat readings. Ties go to the
    highest number (CPU 0 often serves the interrupts); a CPU the readings miss counts as busy."""

    def share(cpu: int) -> float:
        if cpu not in before or cpu not in after:
            return 1.0
        busy = after[cpu][0] - before[cpu][0]
        total = after[cpu][1] - before[cpu][1]
        return busy / total if total > 0 else 0.0

    return min(sorted(allowed, reverse=True), key=share)


def least_busy_cpu(allowed: Iterable[int], sample_s: float = 0.1) -> int:
    """The allowed CPU that was least busy over the next `sample_s` seconds (/proc/stat; without
    it, the highest allowed CPU)."""
    allowed = sorted(allowed)
    try:
        before = busy_ticks(_PROC_STAT.read_text())
        time.sleep(sample_s)
        after = busy_ticks(_PROC_STAT.read_text())
    except OSError:
        return allowed[-1]
    return least_busy(before, after, allowed)


def graph_placement(graph: Graph) -> dict[str, CpuPlacement]:
    """Per node the launcher starts (not external ones), where it runs; empty when the OS places
    them: for ``placement: os``, and for ``loop`` on a system that cannot place processes (the
    launcher says so)."""
    if graph.source.placement != "loop" or not supported():
        return {}
    trailing = {n.name for n in graph.trailing_nodes()}
    started = [n.name for n in graph.nodes if not n.external]
    allowed = os.sched_getaffinity(0)
    return plan_loop(
        [n for n in started if n not in trailing],
        [n for n in started if n in trailing],
        allowed,
        least_busy_cpu(allowed),
    )


def describe(placement: Mapping[str, CpuPlacement]) -> str:
    """Which nodes run on which CPUs, one group per CPU set, in the order of the nodes."""
    groups: dict[CpuPlacement, list[str]] = {}
    for name, place in placement.items():
        groups.setdefault(place, []).append(name)
    return "; ".join(f"{place}: {', '.join(names)}" for place, names in groups.items())
