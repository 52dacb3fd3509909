"""Builders of small synthetic logs, shaped like the recorder's output."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import Clock, ContactSet, LockstepAck, NodeStatus, RunControl, SurfaceMesh
from palpate.nodes.demo.core import box_mesh
from palpate.record.mcap_io import LogWriter, peek

PERIOD_NS = 10_000_000


def contacts(stamp_ns: int, n: int = 2, offset: float = 0.0) -> ContactSet:
    positions = np.arange(3 * n, dtype=float).reshape(n, 3) * 1e-3 + offset
    return ContactSet(
        stamp_ns=stamp_ns,
        positions_m=positions,
        local_positions_m=np.zeros((n, 3)),
        normals=np.tile([0.0, 0.0, 1.0], (n, 1)),
        forces_n=np.ones(n),
        links=["probe"] * n,
    )


def mesh(stamp_ns: int, size_m: float = 0.01) -> SurfaceMesh:
    vertices, faces, normals = box_mesh(np.zeros(3), np.full(3, size_m))
    return SurfaceMesh(
        stamp_ns=stamp_ns,
        region="global",
        num_contacts=1,
        vertices_m=vertices,
        faces=faces,
        vertex_normals=normals,
        variance_vertices=np.arange(8, dtype=np.int32),
        vertex_variance=np.zeros(8),
    )


def status(node: str, stamp_ns: int) -> NodeStatus:
    return NodeStatus(
        stamp_ns=stamp_ns,
        node=node,
        state="finished",
        message="",
        counter_names=["messages_in"],
        counter_values=np.array([1], dtype=np.int64),
        metric_names=[],
        metric_values=np.zeros(0),
    )


def lockstep_streams(ticks: int) -> dict[str, list[tuple[str, Message]]]:
    """Per-publisher message streams of a lockstep run: clock source `cube`, followers `stats` and `est`."""
    cube: list[tuple[str, Message]] = []
    stats: list[tuple[str, Message]] = [(topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node="stats", tick=-1))]
    est: list[tuple[str, Message]] = [(topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node="est", tick=-1))]
    for t in range(ticks):
        stamp = t * PERIOD_NS
        cube += [(topics.CONTACTS, contacts(stamp, offset=t)), (topics.CLOCK, _clock(t))]
        est += [(topics.SURFACE_MESH, mesh(stamp, size_m=0.01 * (t + 1)))]
        est += [(topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=stamp, node="est", tick=t))]
        stats += [(topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=stamp, node="stats", tick=t))]
    last = (ticks - 1) * PERIOD_NS
    cube += [
        (topics.GRAPH_CONTROL, RunControl(stamp_ns=last, command="stop", reason="done")),
        (topics.NODE_STATUS, status("cube", last)),
    ]
    stats.append((topics.NODE_STATUS, status("stats", last)))
    est.append((topics.NODE_STATUS, status("est", last)))
    return {"cube": cube, "stats": stats, "est": est}


def _clock(tick: int, lockstep: bool = True) -> Clock:
    return Clock(stamp_ns=tick * PERIOD_NS, tick=tick, period_ns=PERIOD_NS, lockstep=lockstep)


def write_log(path: Path, items: list[tuple[str, Message]], *, flush_each: bool = False) -> list[int]:
    """Write (topic, message) pairs; returns the file size after each flush when `flush_each`."""
    sizes = []
    with LogWriter(path) as writer:
        for seq, (topic, message) in enumerate(items):
            payload = codec.encode(message)
            writer.write(topic, payload, peek(payload), seq)
            if flush_each:
                writer.flush()
                sizes.append(path.stat().st_size)
    return sizes


def canonical_log(ticks: int) -> list[tuple[str, Message]]:
    """What the recorder writes for `lockstep_streams`: tick by tick, publisher by publisher."""
    segments: dict[int, dict[str, list[tuple[str, Message]]]] = {}
    for name, items in lockstep_streams(ticks).items():
        pending: list[tuple[str, Message]] = []
        for topic, message in items:
            pending.append((topic, message))
            if topic in (topics.CLOCK, topics.LOCKSTEP_ACK):
                segments.setdefault(message.tick, {})[name] = pending  # type: ignore[attr-defined]
                pending = []
        segments.setdefault(ticks, {})[name] = pending  # after the last marker
    out: list[tuple[str, Message]] = []
    for tick in sorted(segments):
        for name in ("cube", "est", "stats"):  # clock source first, then by name
            out += segments[tick].get(name, [])
    return out
