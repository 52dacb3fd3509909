"""`palpate launch FILE --replay LOG.mcap`: replace the nodes the log can stand in for by a replay node.

A node is replaced when it publishes something and the log holds every topic it publishes; the
replay node (a clock source) publishes those topics tick by tick, and everything else runs live.
So a log of sensor topics re-runs the estimators downstream of them on recorded data. The clock
source must be among the replaced nodes (the replay node takes over the clock).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from palpate.errors import LaunchError
from palpate.launch.graph import resolve
from palpate.launch.loader import LaunchFile, NodeEntry, Where
from palpate.record.replay_node import log_topics

REPLAY_NODE_NAME = "replay"


def replace_publishers_with_log(launch: LaunchFile, log_path: str | Path) -> LaunchFile:
    """`launch` with the nodes whose outputs `log_path` holds replaced by one `replay` node."""
    log_path = Path(log_path).resolve()
    recorded = log_topics(log_path)
    # Resolving validates the original graph and gives the topics after remaps and namespaces, and
    # the ranks the recorded subscribers dispatched by. The bus directory only names endpoints here.
    graph = resolve(launch, bus_dir=Path("/nonexistent-bus-dir"))
    replaced = [node for node in graph.nodes if node.publishes and all(t in recorded for t in node.publishes.values())]
    if not replaced:
        raise LaunchError(
            f"--replay {log_path}: the log holds no node's complete outputs; it has {sorted(recorded)}, "
            f"the graph publishes {sorted(graph.topic_types())}"
        )
    clock = graph.clock_source
    if clock is not None and clock not in replaced:
        missing = sorted(t for t in clock.publishes.values() if t not in recorded)
        raise LaunchError(
            f"--replay {log_path}: the log lacks {missing} of the clock source {clock.name!r}; the replay node "
            "replaces the clock, so the log must hold every topic of the clock source"
        )
    replayed = sorted({t for node in replaced for t in node.publishes.values()})
    for topic in replayed:
        if recorded[topic] != graph.topic_types()[topic]:
            raise LaunchError(
                f"--replay {log_path}: topic {topic!r} is {recorded[topic]} in the log "
                f"but {graph.topic_types()[topic]} in the graph"
            )
    names = {n.name for n in graph.nodes}
    name = REPLAY_NODE_NAME
    while name in names - {n.name for n in replaced}:
        name = f"_{name}"
    entry = NodeEntry(
        fields={
            "name": name,
            "type": "replay",
            "params": {
                "path": str(log_path),
                "topics": replayed,
                "order": {t: node.rank for node in replaced for t in node.publishes.values()},
            },
        },
        where=Where(str(log_path), 0),
    )
    gone = {n.name for n in replaced}
    kept = [e for e in launch.nodes if e.fields["name"] not in gone]
    return dataclasses.replace(launch, nodes=[entry, *kept])
