"""`palpate launch FILE --replay LOG.mcap`: replace nodes of the graph by a replay node of the log.

By default the replay node stands in for the clock source (the simulator or a hardware driver: the
sensor data) and every other node runs live, so a full recording re-runs the estimators, planners
and controllers on recorded sensor data. ``--replay-nodes A,B`` names the nodes to replace instead
(the clock source among them: the replay node takes over the clock); the log must hold every topic of
theirs that a node which re-runs reads (their other topics, truth a hardware driver never published say,
are left out, and said). The replay node publishes those topics tick by tick.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from palpate.errors import LaunchError, PalpateError
from palpate.launch.graph import (
    REPLAY_TYPE,
    Graph,
    GraphNode,
    check_facts,
    check_facts_against,
    resolve,
    stated_facts,
)
from palpate.launch.loader import LaunchFile, NodeEntry, Where, apply_params, load_launch
from palpate.paths import REPO_ROOT
from palpate.record.mcap_io import UNVERIFIED_KEY, launch_info, launch_values
from palpate.record.replay_node import log_topics

REPLAY_NODE_NAME = "replay"


def replace_publishers_with_log(
    launch: LaunchFile, log_path: str | Path, nodes: Sequence[str] | None = None, notes: list[str] | None = None
) -> LaunchFile:
    """`launch` with the clock source (or the named `nodes`) replaced by one `replay` node of `log_path`.
    ``notes``, when given, gets a line naming the replaced nodes' topics the log lacks and no node reads."""
    log_path = Path(log_path).resolve()
    recorded = log_topics(log_path)
    # Resolving validates the original graph and gives the topics after remaps and namespaces, and
    # the ranks the recorded subscribers dispatched by. The bus directory only names endpoints here.
    graph = resolve(launch, bus_dir=Path("/nonexistent-bus-dir"), facts=False)  # (the replaced nodes' are the log's)
    clock = graph.clock_source
    if nodes is None:
        if clock is None:
            raise LaunchError(
                f"--replay {log_path}: the graph has no clock source to replace; name nodes with --replay-nodes"
            )
        nodes = [clock.name]
    unknown = sorted(set(nodes) - set(graph.by_name))
    if unknown:
        raise LaunchError(f"--replay-nodes: no node {unknown} in the graph; its nodes: {sorted(graph.by_name)}")
    replaced = [graph.by_name[name] for name in dict.fromkeys(nodes)]
    gone = {n.name for n in replaced}
    read = {t for n in graph.nodes if n.name not in gone for t in n.subscribes.values()}
    for node in replaced:
        # a topic no node that re-runs reads need not be in the log: a hardware driver that stood in for
        # the sim published only what the graph's nodes read
        missing = sorted(t for t in node.publishes.values() if t not in recorded and t in read)
        if missing or not any(t in recorded for t in node.publishes.values()):
            what = f"lacks {missing} of" if missing else "has nothing to publish for"
            raise LaunchError(
                f"--replay {log_path}: the log {what} node {node.name!r}, so it cannot stand in for it "
                f"(the log holds {sorted(recorded)})"
            )
    if clock is not None and clock not in replaced:
        raise LaunchError(
            f"--replay-nodes {','.join(nodes)}: the clock source {clock.name!r} must be among them; the replay "
            "node takes over the clock"
        )
    _check_open_loop(graph, replaced)
    _check_recorded_facts(graph, replaced, log_path)
    published = {t for node in replaced for t in node.publishes.values()}
    replayed = sorted(published & set(recorded))
    absent = sorted(published - set(recorded))
    if absent and notes is not None:
        notes.append(
            f"note: the log holds no {absent}, which no node that re-runs reads; the replay goes without them "
            "(a recording of it, or a viewer, lacks them too)"
        )
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
            "type": REPLAY_TYPE,
            "params": {
                "path": str(log_path),
                "topics": replayed,
                "order": {t: node.rank for node in replaced for t in node.publishes.values() if t in recorded},
            },
        },
        where=Where(str(log_path), 0),
    )
    kept = [e for e in launch.nodes if e.fields["name"] not in gone]
    return dataclasses.replace(launch, nodes=[entry, *kept])


def _check_recorded_facts(graph: Graph, replaced: Sequence[GraphNode], log_path: Path) -> None:
    """LaunchError when a node that re-runs states a fact (NodeSpec.facts: where the hand is mounted) other
    than the replaced nodes stated in the recorded run, read from the launch file, arguments and ``--set``
    the log names (when that file is still where it was recorded from): a mapper mounted for another
    scene maps the replayed contacts, given in the hand's frames, in the wrong place. With nothing to
    compare with (no launch metadata, a moved or changed file) the nodes of ``graph`` must agree among
    themselves, as in a launch."""
    info = launch_info(log_path, verify=True)
    named = info.get("launch_file", "") if info and UNVERIFIED_KEY not in info else ""
    # a launch file of the repository's own is stored relative to it; another as given
    found = [p for p in (REPO_ROOT / named, Path(named)) if named and p.is_file()]
    recorded_graph = None
    if found:
        values = launch_values(info)
        args = values["args"] if isinstance(values.get("args"), dict) else {}
        params = values["params"] if isinstance(values.get("params"), dict) else {}
        try:
            then = load_launch(found[0], args)
            apply_params(then, params.items())
            recorded_graph = resolve(then, bus_dir=Path("/nonexistent-bus-dir"))
        except PalpateError:
            pass
    if recorded_graph is None:  # nothing recorded to compare with: the nodes of this file, as a launch would
        check_facts(graph)
        return
    stated = stated_facts(recorded_graph, [node.name for node in replaced])
    live = dataclasses.replace(graph, nodes=[n for n in graph.nodes if n not in replaced])
    check_facts_against(live, stated, f"the recorded run ({found[0]}, --replay {log_path.name})")


def _check_open_loop(graph: Graph, replaced: Sequence[GraphNode]) -> None:
    """LaunchError when a replaced node other than the clock source reads a topic of a node that re-runs:
    the replay node publishes its recorded outputs with the clock, before that node's messages of the same
    tick, so a node downstream of both gets them in another order (a planner got the GPIS node's meshes
    before the controller's touch they answer, and never planned)."""
    live = {t: n.name for n in graph.nodes if n not in replaced for t in n.publishes.values()}
    for node in replaced:
        if node is graph.clock_source:
            continue  # it opens every tick: its data came first in the recorded run too
        fed = sorted(f"{topic} of {live[topic]!r}" for topic in node.subscribes.values() if topic in live)
        if fed:
            raise LaunchError(
                f"--replay-nodes: node {node.name!r} reads {', '.join(fed)}; those nodes re-run, so its recorded "
                f"outputs would not come in step with theirs: replace them too, or leave {node.name!r} live"
            )


def replay_note(launch: LaunchFile, log_path: str | Path, nodes: Sequence[str] | None = None) -> str | None:
    """A note when the log was recorded from another launch file, or with arguments that set the replaced
    nodes' parameters otherwise (default: the clock source's), or another seed: the replayed sensor
    data and truth are then that run's, whatever this launch says."""
    info = launch_info(log_path, verify=True)  # a note from altered metadata would mislead
    if not info:
        return None
    if UNVERIFIED_KEY in info:
        return f"note: {log_path} says it was recorded from {info.get('launch_file', '?')}, but {info[UNVERIFIED_KEY]}"
    graph = resolve(launch, bus_dir=Path("/nonexistent-bus-dir"), facts=False)  # replace_publishers_with_log's
    if nodes is None:
        nodes = [graph.clock_source.name] if graph.clock_source is not None else []
    drivers = _drivers_rerun(info, graph, nodes)
    recorded = Path(info.get("launch_file", "")).name
    if recorded and recorded != launch.path.name:
        return (
            f"note: {log_path} was recorded from {info['launch_file']}, not {launch.path.name}: the replayed "
            "sensor data, object and clock are that run's" + (f"; {drivers}" if drivers else "")
        )
    values = launch_values(info)
    then: dict[str, Any] = values["args"] if isinstance(values.get("args"), dict) else {}
    params_then: dict[str, Any] = values["params"] if isinstance(values.get("params"), dict) else {}
    changes = _params_changed(launch.path, then, {k: v for k, v in launch.args.items() if k in then and then[k] != v})

    def listed(names: Sequence[str]) -> str:
        return ", ".join(f"{k}:={then[k]!r} (here {launch.args[k]!r})" for k in names)

    replayed = [k for k, changed in changes.items() if changed is None or changed & set(nodes)]
    differ = [listed(replayed)] if replayed else []
    if info.get("seed") not in (None, str(launch.seed)):
        differ.append(f"seed {info['seed']} (here {launch.seed})")
    absent = object()
    set_keys = [
        k
        for k in params_then.keys() | launch.overrides.keys()
        if params_then.get(k, absent) != launch.overrides.get(k, absent)
    ]
    set_nodes = {key.partition(".")[0] for key in set_keys}
    sets = f"--set {params_then or 'nothing'} (here {launch.overrides or 'nothing'})"
    if set_nodes & set(nodes):  # --set: the replaced nodes' parameters differ from the recorded run's
        differ.append(sets)
    notes = (
        [f"{log_path} was recorded with {', '.join(differ)}; the replayed sensor data is that run's"] if differ else []
    )
    steering = [  # the nodes whose outputs reach the replayed ones; evaluators observe
        name for name in sorted(graph.feeding(nodes) - set(nodes)) if not graph.by_name[name].evaluator
    ]
    steered = [  # what differs, and the steering nodes it changes (an argument in `replayed` is noted above)
        f"{listed([k])} changes {', '.join(sorted(changed & set(steering)))}"
        for k, changed in changes.items()
        if k not in replayed and changed is not None and changed & set(steering)
    ]
    if set_nodes & set(steering) and not set_nodes & set(nodes):
        steered.append(f"{sets} changes {', '.join(sorted(set_nodes & set(steering)))}")
    if steered:
        notes.append(
            f"{'; '.join(steered)}: nodes whose outputs steered the recorded motion (of {', '.join(steering)}); "
            "the replay does not follow them, so what they decide now need not match the motion in the log"
        )
    if drivers:
        notes.append(drivers)
    return "note: " + "; ".join(notes) if notes else None


def _drivers_rerun(info: dict[str, str], graph: Graph, replaced: Sequence[str]) -> str:
    """What to say of nodes a driver played in the recorded run that palpate's own node plays in this
    replay ("" when none): their outputs need not be the recorded ones."""
    then = [name for name in info.get("external", "").split(",") if name]
    rerun = [n for n in then if n in graph.by_name and n not in replaced and not graph.by_name[n].external]
    if not rerun:
        return ""
    names = ",".join(rerun)
    return (
        f"{', '.join(rerun)} played by a driver in the recorded run, palpate's own node here, so its outputs need "
        f"not be the recorded ones (--replay-nodes {names} replays them as recorded; --external {names} with the "
        "driver started again re-runs it)"
    )


def _params_changed(path: Path, args: dict[str, Any], changes: dict[str, Any]) -> dict[str, set[str] | None]:
    """Per argument of `changes` (sorted by name), the nodes whose params it changes when set to its value
    there instead of its value in `args`; None when the recorded arguments no longer load (say so rather
    than guess). The launch file is loaded once for `args` and once per argument."""

    def params(overrides: dict[str, Any]) -> dict[str, Any]:
        return {str(e.fields.get("name")): e.fields.get("params") for e in load_launch(path, overrides).nodes}

    try:
        then = params(args)
    except LaunchError:
        return dict.fromkeys(sorted(changes))
    out: dict[str, set[str] | None] = {}
    for name in sorted(changes):
        try:
            now = params({**args, name: changes[name]})
        except LaunchError:
            out[name] = None
            continue
        out[name] = {node for node in then.keys() | now.keys() if then.get(node) != now.get(node)}
    return out
