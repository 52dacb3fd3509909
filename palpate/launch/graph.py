"""Validate a launch file and resolve it into a graph: topics, types, wiring and lockstep roles.

Everything is checked before any process starts: node types, parameters (unknown, missing,
mistyped), subscriptions without a publisher, publisher/subscriber type mismatches, ground-truth
topics wired into non-evaluator nodes, nodes that disagree on a fact about the world (a mapper
mounted where the simulator's finger is not). Each error names the file, the line and the key.
"""

from __future__ import annotations

import copy
import math
import re
import shlex
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from palpate import jsonio
from palpate.config import KeyPath, load
from palpate.errors import BusError, ConfigError, LaunchError, PalpateError
from palpate.launch.loader import LaunchFile, NodeEntry, Where
from palpate.launch.node_types import load_node_type, node_spec_reference
from palpate.messages import topics
from palpate.runtime import bus
from palpate.runtime.spec import TRAIL_TICKS, NodeProcessSpec, NodeSpec

_T = TypeVar("_T")
_SHARED_TOPICS = {topics.NODE_STATUS, topics.GRAPH_CONTROL}
#: A node name: it names the node's socket file in the bus directory, so no '/', '..' or ''.
_NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*")


@dataclass
class GraphNode:
    """A node of the resolved graph."""

    name: str
    type: str
    spec: NodeSpec[Any]
    params: dict[str, Any]
    publishes: dict[str, str]  # port -> topic
    subscribes: dict[str, str]
    where: Where
    entry: NodeEntry
    external: bool = False
    evaluator: bool = False
    respawn: bool = False
    max_restarts: int = 0
    sigterm_timeout_s: float = 5.0
    endpoint: str = ""
    curve: dict[str, str] = field(default_factory=dict)
    rank: int = 0
    #: The node's config, loaded from its params.
    config: Any = None
    #: Parameters the graph set (NodeSpec.settle): key path -> (value in the file, value set).
    settled: dict[KeyPath, tuple[Any, Any]] = field(default_factory=dict)


@dataclass
class Graph:
    """The whole resolved graph of a launch file."""

    source: LaunchFile
    nodes: list[GraphNode]
    bus_dir: Path
    mode: str
    seed: int
    record_all: bool = False

    @property
    def by_name(self) -> dict[str, GraphNode]:
        return {n.name: n for n in self.nodes}

    def publishers(self, topic: str) -> list[GraphNode]:
        return [n for n in self.nodes if topic in n.publishes.values()]

    def topic_types(self) -> dict[str, str]:
        types: dict[str, str] = {}
        for node in self.nodes:
            for port, topic in node.publishes.items():
                types[topic] = node.spec.outputs[port].message.TYPE
        return types

    @property
    def clock_source(self) -> GraphNode | None:
        sources = [n for n in self.nodes if n.spec.clock_source]
        return sources[0] if sources else None

    def process_specs(
        self, *, extra_subscribers: int = 0, extra_curve_clients: Sequence[str] = ()
    ) -> list[NodeProcessSpec]:
        """What each node process gets; `extra_subscribers` counts a recorder connected to every node, and
        `extra_curve_clients` are its CurveZMQ public keys, which every keyed publisher then admits."""
        return [self._process_spec(n, extra_subscribers, extra_curve_clients) for n in self.nodes]

    @property
    def keyed(self) -> bool:
        """Whether any node uses CurveZMQ keys."""
        return any(n.curve for n in self.nodes)

    def in_process_members(self) -> list[tuple[NodeSpec[Any], NodeProcessSpec]]:
        """Each node's spec and process spec in rank order: what an in-process executor runs."""
        ranked = sorted(zip(self.nodes, self.process_specs(), strict=True), key=lambda pair: pair[0].rank)
        return [(node.spec, process) for node, process in ranked]

    def upstream(self, node: GraphNode) -> list[GraphNode]:
        topics_in = set(node.subscribes.values())
        return [n for n in self.nodes if n is not node and topics_in & set(n.publishes.values())]

    def trailing_nodes(self) -> list[GraphNode]:
        """Nodes the clock source need not wait for every tick (lockstep only): not external (a driver speaks
        the plain protocol), ``may_trail`` in their spec, and nothing they publish reaches the clock source
        through any chain of subscriptions, so no node of the loop reads what they say in a tick."""
        clock = self.clock_source
        if clock is None or self.mode != "lockstep":
            return []
        feeding = self.feeding([clock.name])
        return [n for n in self.nodes if n.name not in feeding and n.spec.may_trail and not n.external]

    def feeding(self, names: Iterable[str]) -> set[str]:
        """`names` and the names of every node whose outputs reach one of them through a chain of topics."""
        found = set(names)
        frontier = [n for n in self.nodes if n.name in found]
        while frontier:
            for peer in self.upstream(frontier.pop()):
                if peer.name not in found:
                    found.add(peer.name)
                    frontier.append(peer)
        return found

    def _connections(self, node: GraphNode) -> list[GraphNode]:
        """Publishers `node` connects to: those of its inputs, plus the clock source (and, for the
        clock source, every node, for acknowledgements and stop requests)."""
        clock = self.clock_source
        if node is clock:
            return [n for n in self.nodes if n is not node]
        peers = self.upstream(node)
        if clock is not None and clock not in peers and clock is not node:
            peers.append(clock)
        return peers

    def _process_spec(
        self, node: GraphNode, extra_subscribers: int, extra_curve_clients: Sequence[str] = ()
    ) -> NodeProcessSpec:
        lockstep = self.mode == "lockstep"
        connectors = [n for n in self.nodes if node in self._connections(n)]
        # a keyed publisher admits exactly the keys of the nodes that connect to it (validation made sure
        # they have keys) and of the recorder
        clients = {n.curve["public"] for n in connectors if n.curve} | set(extra_curve_clients)
        expected: dict[str, int] = {}
        for topic in set(node.publishes.values()):
            count = sum(1 for n in connectors if topic in n.subscribes.values()) + extra_subscribers
            if count:
                expected[topic] = count
        wiring_topic = topics.LOCKSTEP_ACK if lockstep else topics.GRAPH_CONTROL
        expected[wiring_topic] = len(connectors) + extra_subscribers
        if not expected[wiring_topic]:
            del expected[wiring_topic]
        for peer in connectors:
            expected[f"hello/{peer.name}"] = 1
        clock = self.clock_source
        trailing = self.trailing_nodes() if node is clock else []
        waits = self._ack_upstream(node)
        others = [n for n in self.nodes if n is not node] if node is clock else []
        return NodeProcessSpec(
            name=node.name,
            type=node.type,
            node_spec=node_spec_reference(node.type),
            params=node.params,
            bus_dir=str(self.bus_dir),
            endpoint=node.endpoint,
            publishes=dict(node.publishes),
            subscribes=dict(node.subscribes),
            connect=[n.endpoint for n in self._connections(node)],
            mode=self.mode,
            seed=self.seed + _stable_hash(node.name) if "seed" not in node.params else int(node.params["seed"]),
            clock_source=node is clock,
            expected_subscribers=expected,
            forward_upstream=waits["forward"],
            backward_upstream=waits["backward"],
            lockstep_nodes=[n.name for n in others],
            lockstep_upstream={n.name: self._ack_upstream(n) for n in others},
            topic_order={t: p.rank for p in self.nodes for t in p.publishes.values()},
            topic_publishers={t: p.name for p in self.nodes for t in p.publishes.values()},
            clock_name=clock.name if clock is not None else "",
            trailing_nodes=[n.name for n in trailing],
            trail_ticks=TRAIL_TICKS if trailing else 0,
            curve=node.curve,
            curve_clients=sorted(clients) if node.curve else [],
            topic_types={
                **{t: node.spec.inputs[p].message.TYPE for p, t in node.subscribes.items()},
                **{t: node.spec.outputs[p].message.TYPE for p, t in node.publishes.items()},
            },
        )

    def _ack_upstream(self, node: GraphNode) -> dict[str, list[str]]:
        """The nodes whose acknowledgement `node` waits for (lockstep): of tick t before it handles tick t
        ("forward": ranked before it) and of tick t - 1 ("backward": a feedback edge). Never the clock
        source, whose Clock(t) follows its own data."""
        upstream = [n for n in self.upstream(node) if n is not self.clock_source]
        return {
            "forward": [n.name for n in upstream if n.rank < node.rank],
            "backward": [n.name for n in upstream if n.rank > node.rank],
        }


#: Hosts whose bind takes the port on every interface of the machine.
_EVERY_INTERFACE = {"*", "0.0.0.0", "::", "[::]"}


def _bound_address(endpoint: str) -> tuple[str, str]:
    """What binding `endpoint` occupies: (host, port) of a tcp endpoint, localhost as 127.0.0.1 and
    every interface as "*"; (endpoint, "") otherwise."""
    if not endpoint.startswith("tcp://"):
        return endpoint, ""
    host, _, port = endpoint[len("tcp://") :].rpartition(":")
    host = host.lower()
    host = "127.0.0.1" if host == "localhost" else "*" if host in _EVERY_INTERFACE else host
    return host, port


def _clashes(a: str, b: str) -> bool:
    """Whether binding endpoints `a` and `b` on one machine collide (the same port of one interface)."""
    (host_a, port_a), (host_b, port_b) = _bound_address(a), _bound_address(b)
    return port_a == port_b and (host_a == host_b or (port_a != "" and "*" in (host_a, host_b)))


def resolve(launch: LaunchFile, *, bus_dir: Path | None = None, facts: bool = True) -> Graph:
    """Validate `launch` and resolve its graph, or raise LaunchError naming file, line and key.

    ``facts=False`` leaves out the check that nodes stating one fact agree (``check_facts``): a replay
    compares the nodes that re-run with the recorded ones instead of those it replaces."""
    bus_dir = bus.usable_dir(bus_dir) if bus_dir else bus.default_bus_dir()
    names: dict[str, Where] = {}
    endpoints: dict[str, GraphNode] = {}
    nodes = []
    for index, entry in enumerate(launch.nodes):
        node = _resolve_node(entry, index, bus_dir)
        if node.name in names:
            raise LaunchError(f"{entry.at('name')}: node name {node.name!r} is already used at {names[node.name]}")
        other = next((n for e, n in endpoints.items() if _clashes(e, node.endpoint)), None)
        if other is not None:
            raise LaunchError(
                f"{entry.at('port')}: node {node.name!r} binds {node.endpoint}, the port node {other.name!r} "
                f"({other.entry.at('port')}) binds at {other.endpoint}; give one of them another port"
            )
        names[node.name] = entry.at("name")
        endpoints[node.endpoint] = node
        nodes.append(node)
    graph = Graph(source=launch, nodes=nodes, bus_dir=bus_dir, mode=launch.mode, seed=launch.seed)
    _check_wiring(graph)
    _settle(graph)
    if facts:
        check_facts(graph)
    _check_files(graph)
    _check_curve(graph)
    _rank(graph)
    return graph


def _resolve_node(entry: NodeEntry, index: int, bus_dir: Path) -> GraphNode:
    f = entry.fields
    name, node_type = f["name"], f["type"]
    for key, kind in (("name", str), ("type", str), ("namespace", str), ("host", str)):
        if key in f and not isinstance(f[key], kind):
            raise LaunchError(f"{entry.at(key)}: {key} must be a string, got {f[key]!r}")
    if not _NODE_NAME.fullmatch(name):
        raise LaunchError(
            f"{entry.at('name')}: node name {name!r} must be letters, digits, '_' and '-', starting with a letter "
            "or '_' (it names the node's socket file)"
        )
    try:
        spec = load_node_type(node_type)
    except LaunchError as exc:
        raise LaunchError(f"{entry.at('type')}: {exc}") from exc
    params = f.get("params") or {}
    if not isinstance(params, dict):
        raise LaunchError(f"{entry.at('params')}: params must be a mapping")
    config = _check_params(entry, spec, params)
    try:
        spec = spec.with_config(config)  # ports that depend on the (validated) configuration
    except LaunchError as exc:
        raise LaunchError(f"{entry.at('params')}: {exc}") from exc
    remaps = f.get("remaps") or {}
    if not isinstance(remaps, dict):
        raise LaunchError(f"{entry.at('remaps')}: remaps must be a mapping port: topic")
    ports = {**spec.inputs, **spec.outputs}
    for port, topic in remaps.items():
        at = entry.remap_lines.get(port, entry.at("remaps"))
        if port not in ports:
            raise LaunchError(f"{at}: node {name!r} ({node_type}) has no port {port!r}; ports: {sorted(ports)}")
        bare = topic.strip("/") if isinstance(topic, str) else ""
        if not bare:  # null would be the topic 'None', '' every topic
            raise LaunchError(f"{at}: node {name!r} remaps port {port!r} to {topic!r}; a topic is a non-empty string")
        if bare in topics.RUNTIME_TOPICS or bare.startswith(topics.HELLO_PREFIX):
            raise LaunchError(
                f"{at}: node {name!r} remaps port {port!r} to the runtime's own topic {topic!r} (the runtime's "
                f"topics: {', '.join(topics.RUNTIME_TOPICS)}, {topics.HELLO_PREFIX}<node>)"
            )
    namespace = str(f.get("namespace", "")).strip("/")

    def topic_of(port: str) -> str:
        topic = str(remaps.get(port, ports[port].default_topic))
        if topic.startswith("/") or not namespace:
            return topic.lstrip("/")
        return f"{namespace}/{topic}"

    host = f.get("host")
    if "port" in f and not host:
        raise LaunchError(f"{entry.at('port')}: port needs a host; without one the node publishes over ipc")
    port_number = f.get("port", 5600 + index)
    if isinstance(port_number, bool) or not isinstance(port_number, int) or not 0 < port_number < 65536:
        raise LaunchError(f"{entry.at('port')}: port must be an integer from 1 to 65535, got {port_number!r}")
    try:
        endpoint = f"tcp://{host}:{port_number}" if host else bus.ipc_endpoint(bus_dir, name)
    except BusError as exc:
        raise LaunchError(f"{entry.at('name')}: node {name!r}: {exc}") from exc
    node = GraphNode(
        name=name,
        type=node_type,
        spec=spec,
        params=params,
        publishes={p: topic_of(p) for p in spec.outputs},
        subscribes={p: topic_of(p) for p in spec.inputs},
        where=entry.where,
        entry=entry,
        external=_flag(entry, "external"),
        evaluator=_flag(entry, "evaluator"),
        respawn=_flag(entry, "respawn"),
        max_restarts=_number(entry, "max_restarts", 3 if _flag(entry, "respawn") else 0, int),
        sigterm_timeout_s=_number(entry, "sigterm_timeout_s", 5.0, float),
        endpoint=endpoint,
        curve=_curve(entry),
        config=config,
    )
    return node


def _check_params(entry: NodeEntry, spec: NodeSpec[Any], params: dict[str, Any]) -> Any:
    """Load the node's config from its params; an error names the line of the offending key."""
    try:
        return load(spec.config, params, "params")
    except ConfigError as exc:
        raise LaunchError(f"{entry.param_at(exc.path)}: node {entry.fields['name']!r}: {exc}") from exc


def _of_config(node: GraphNode, function: Callable[[Any], _T]) -> _T:
    """``function(node.config)`` (a NodeSpec hook); a PalpateError is a LaunchError at the node's params."""
    try:
        return function(node.config)
    except PalpateError as exc:
        raise LaunchError(f"{node.entry.at('params')}: node {node.name!r}: {exc}") from exc


def _facts_of(node: GraphNode) -> Mapping[str, tuple[Any, KeyPath]]:
    """The facts `node` states (NodeSpec.facts), by the name they are given in the spec."""
    return {} if node.spec.facts is None else _of_config(node, node.spec.facts)


def _settle(graph: Graph) -> None:
    """Parameters a node leaves to the graph (NodeSpec.settle) take the values the other nodes' facts call
    for; the node's params and config then hold them, as if the launch file had written them."""
    settling = [n for n in graph.nodes if n.spec.settle is not None]
    if not settling:
        return
    stated = [
        (node, _fact_name(node, fact), value) for node in graph.nodes for fact, (value, _) in _facts_of(node).items()
    ]
    for node in settling:
        assert node.spec.settle is not None

        def others(fact: str, node: GraphNode = node) -> list[Any]:
            name = _fact_name(node, fact)
            return [value for n, fact_name, value in stated if n is not node and fact_name == name]

        values = node.spec.settle(node.config, others)
        if not values:
            continue
        params = copy.deepcopy(node.params)
        for path, value in values.items():
            *parents, key = path
            inner: Any = params
            for part in parents:
                inner = inner[part]
            node.settled[path] = (inner.get(key), value)
            inner[key] = value
        node.params, node.config = params, _check_params(node.entry, node.spec, params)


def check_facts(graph: Graph) -> None:
    """Nodes that state the same fact about the world (NodeSpec.facts) state the same value."""
    stating = [n for n in graph.nodes if n.spec.facts is not None]
    if len(stating) < 2:
        return
    first: dict[str, tuple[GraphNode, str, Any, Where, str, KeyPath]] = {}
    for node in stating:
        for fact, (value, path) in _facts_of(node).items():
            name = _fact_name(node, fact)
            where, key = node.entry.param_at(path), ".".join(["params", *map(str, path)])
            if name not in first:
                first[name] = (node, fact, value, where, key, path)
                continue
            other, other_fact, other_value, other_where, other_key, other_path = first[name]
            if value != other_value:
                tries = [(node, fact, path, value, other_value), (other, other_fact, other_path, other_value, value)]
                # a set on a driver's node first (its params only say what its hardware is), then on a node
                # other than the clock source (the simulator's scene is the world the others model)
                tries.sort(key=lambda t: 0 if t[0].external else 2 if t[0].spec.clock_source else 1)
                hint = _same_by_set(*tries[0]) or _same_by_set(*tries[1])
                played = [n.name for n in (node, other) if n.external]
                raise LaunchError(
                    f"{where}: node {node.name!r} ({key}) and node {other.name!r} ({other_key}, {other_where}) "
                    f"disagree on {name}: {_difference(value, other_value)}; make them the same"
                    + (f", e.g. {hint}" if hint else "")
                    + (
                        f" (node {played[0]!r} is played by a driver: its params say what the hardware is, "
                        "so give them the hardware's values)"
                        if len(played) == 1
                        else ""
                    )
                )


def stated_facts(graph: Graph, names: Iterable[str]) -> dict[str, tuple[str, Any]]:
    """The facts the nodes ``names`` of ``graph`` state (NodeSpec.facts), by the name they are compared
    under: fact -> (the node's name, the value)."""
    wanted = set(names)
    return {
        _fact_name(node, fact): (node.name, value)
        for node in graph.nodes
        if node.name in wanted
        for fact, (value, _) in _facts_of(node).items()
    }


def check_facts_against(graph: Graph, stated: Mapping[str, tuple[str, Any]], source: str) -> None:
    """LaunchError when a node of ``graph`` states one of the facts ``stated`` (``stated_facts`` of another
    graph, which ``source`` names) with another value, naming both and the ``--set`` that agrees."""
    for node in graph.nodes:
        for fact, (value, path) in _facts_of(node).items():
            name = _fact_name(node, fact)
            if name not in stated or stated[name][1] == value:
                continue
            other, wanted = stated[name]
            hint = _same_by_set(node, fact, path, value, wanted)
            key = ".".join(["params", *map(str, path)])
            raise LaunchError(
                f"{node.entry.param_at(path)}: node {node.name!r} ({key}) and node {other!r} of {source} disagree on "
                f"{name}: {_difference(value, wanted)}; make them the same" + (f", e.g. {hint}" if hint else "")
            )


def _same_by_set(node: GraphNode, fact: str, path: KeyPath, value: Any, wanted: Any) -> str:
    """The ``--set`` arguments that make `node` state `wanted` for `fact` instead of `value`, tried: the
    fact's differing keys set as keys of the params at `path` (a mapper's mount), then the node's config
    loaded and the fact stated again; '' when that does not give `wanted` (the sim's scene says it
    otherwise)."""
    if not (isinstance(value, dict) and isinstance(wanted, dict) and set(value) == set(wanted)):
        return ""
    changed = [k for k in value if value[k] != wanted[k]]
    params = copy.deepcopy(node.params) if isinstance(node.params, dict) else {}
    inner: Any = params
    for part in path:
        inner = inner.setdefault(part, {}) if isinstance(inner, dict) else None
    if not isinstance(inner, dict) or node.spec.facts is None:
        return ""
    inner.update({k: wanted[k] for k in changed})
    try:
        stated = node.spec.facts(load(node.spec.config, params, "params"))[fact][0]
    except (PalpateError, KeyError, TypeError, ValueError):
        return ""
    if stated != wanted:
        return ""
    dotted = ".".join([node.name, *map(str, path)])
    return " ".join(
        "--set " + shlex.quote(f"{dotted}.{k}={jsonio.dumps(wanted[k], separators=(',', ':'))}") for k in changed
    )


def _check_files(graph: Graph) -> None:
    """The files that the nodes this launcher starts read at their start (NodeSpec.files) exist."""
    for node in graph.nodes:
        if node.external or node.spec.files is None:
            continue
        for path, name in _of_config(node, node.spec.files).items():
            if not Path(name).is_file():
                what = "does not exist" if not Path(name).exists() else "is not a file"
                raise LaunchError(
                    f"{node.entry.param_at(path)}: node {node.name!r} (params.{'.'.join(map(str, path))}): "
                    f"{name} {what} (resolved from {Path.cwd()})"
                )


def check_file_contents(graph: Graph) -> None:
    """What the files of the nodes this launcher starts hold (NodeSpec.checks): LaunchError at the line
    that names the file. It reads them, so ``palpate launch`` calls it, not every in-process run."""
    for node in graph.nodes:
        if node.external or node.spec.checks is None:
            continue
        for path, problem in _of_config(node, node.spec.checks).items():
            raise LaunchError(
                f"{node.entry.param_at(path)}: node {node.name!r} (params.{'.'.join(map(str, path))}): {problem}"
            )


def _fact_name(node: GraphNode, fact: str) -> str:
    """The name a fact is compared under: a fact of a port (``"PORT:name"``) under its topic, ``"topic:name"``."""
    port, sep, name = fact.partition(":")
    if not sep:
        return fact
    topic = node.publishes.get(port) or node.subscribes.get(port)
    if topic is None:
        raise LaunchError(
            f"{node.entry.at('type')}: node {node.name!r} states fact {fact!r} of a port it does not have"
        )
    return f"{topic}:{name}"


def _difference(here: Any, there: Any) -> str:
    """What differs between two stated values: the differing keys of two mappings, else both values."""
    if isinstance(here, dict) and isinstance(there, dict) and set(here) == set(there):
        return "; ".join(f"{k} {here[k]!r} here, {there[k]!r} there" for k in here if here[k] != there[k])
    return f"{here!r} here, {there!r} there"


#: Message types that move something: a graph whose commands no node reads moves nothing (an exploration
#: graph whose sim holds a scripted hand instead of the probe ran to its end, exit 0).
_COMMAND_TYPES = {"CartesianVelocityCommand", "JointCommand"}
#: The node type `palpate launch --replay` puts in the place of the nodes a log stands in for.
REPLAY_TYPE = "replay"


def _readers_of(graph: Graph, type_name: str) -> str:
    """' (node X reads that type on port P, as topic T)' for the nodes that read `type_name` elsewhere."""
    found = [
        f"node {n.name!r} reads {type_name} on {topic!r}"
        for n in graph.nodes
        for port, topic in n.subscribes.items()
        if type_name == n.spec.inputs[port].message.TYPE
    ]
    if found:
        return f" ({'; '.join(found)})"
    return f" (no node of the graph reads {type_name}: a sim whose effector follows a scripted motion takes none)"


def _check_wiring(graph: Graph) -> None:
    types = graph.topic_types()
    for node in graph.nodes:
        for port, topic in node.subscribes.items():
            where = node.entry.remap_lines.get(port, node.where)
            wanted = node.spec.inputs[port].message.TYPE
            if topics.is_truth(topic) and not node.evaluator:
                raise LaunchError(
                    f"{where}: node {node.name!r} reads ground truth {topic!r} on port {port!r}; only evaluators may "
                    "(add 'evaluator: true' to the node if it only evaluates)"
                )
            if topic not in types and node.spec.inputs[port].optional:
                continue
            if topic not in types:
                fix = "add a publisher, remap the port, or mark a hardware driver 'external: true'"
                if node.external:
                    fix = (
                        "its params declare an input this graph does not feed: give them what the hardware is"
                        + (
                            " (a driver playing the sim states its scene, whose effector decides the sim's inputs)"
                            if node.type == "sim"
                            else ""
                        )
                        + ", or remap the port"
                    )
                raise LaunchError(
                    f"{where}: node {node.name!r} subscribes to {topic!r} (port {port!r}, {wanted}) but no node "
                    f"publishes it; {fix}"
                )
            if types[topic] != wanted:
                pubs = ", ".join(p.name for p in graph.publishers(topic))
                raise LaunchError(
                    f"{where}: type mismatch on {topic!r}: {pubs} publishes {types[topic]}, "
                    f"but node {node.name!r} port {port!r} expects {wanted}"
                )
    read = {topic for node in graph.nodes for topic in node.subscribes.values()}
    replayed = any(node.type == REPLAY_TYPE for node in graph.nodes)  # the log stands in for their reader
    for node in graph.nodes:
        for port, topic in node.publishes.items():
            if node.spec.outputs[port].message.TYPE in _COMMAND_TYPES and topic not in read and not replayed:
                readers = _readers_of(graph, node.spec.outputs[port].message.TYPE)
                raise LaunchError(
                    f"{node.entry.remap_lines.get(port, node.where)}: node {node.name!r} commands on {topic!r} "
                    f"(port {port!r}), which no node reads{readers}: its commands would move nothing; read "
                    "them (an effector that takes commands, such as the sim's probe), remap, or mark the "
                    "reader 'external: true'"
                )
    for topic in types:
        publishers = graph.publishers(topic)
        if len(publishers) > 1 and topic not in _SHARED_TOPICS:
            first, second = publishers[0], publishers[1]
            raise LaunchError(
                f"{second.where}: topic {topic!r} has two publishers ({first.name} and {second.name}); remap one"
            )
    for node in graph.nodes:
        if node.external and node.respawn:
            raise LaunchError(
                f"{node.entry.at('respawn')}: node {node.name!r} is external: its driver starts it, and restarts it, "
                "not palpate launch; remove respawn (or external)"
            )
    if graph.mode == "lockstep":
        for node in graph.nodes:
            if node.respawn:
                raise LaunchError(
                    f"{node.entry.at('respawn')}: node {node.name!r}: respawn needs 'mode: realtime'; in lockstep a "
                    "restarted node cannot rejoin the tick it died in, so the run would stall"
                )
    sources = [n for n in graph.nodes if n.spec.clock_source]
    if len(sources) > 1:
        raise LaunchError(f"{sources[1].where}: two clock sources ({sources[0].name}, {sources[1].name}); keep one")
    if graph.mode == "lockstep" and not sources:
        at = graph.source.mode_at or graph.source.path
        raise LaunchError(
            f"{at}: a lockstep graph (mode lockstep, the default) needs a clock source (a sim, replay or "
            "driver node); add one, or set mode: realtime"
        )


def _check_curve(graph: Graph) -> None:
    """A node's subscriber is one CurveZMQ client (or none) for all its links, so keys must agree."""
    for node in graph.nodes:
        for peer in graph._connections(node):
            if node.curve and peer.curve.get("public") != node.curve["server_public"]:
                has = "has no CurveZMQ keys" if not peer.curve else "publishes with another key"
                raise LaunchError(
                    f"{node.entry.at('curve_keys')}: node {node.name!r} connects to {peer.name!r}, which {has}; "
                    "give the nodes of a graph one key file (palpate keys -o FILE)"
                )
            if peer.curve and not node.curve:
                raise LaunchError(
                    f"{peer.entry.at('curve_keys')}: node {peer.name!r} uses CurveZMQ keys but {node.name!r}, "
                    "which connects to it, has none; give it the same curve_keys"
                )


def _rank(graph: Graph) -> None:
    """Order nodes topologically: reverse post-order of a depth-first search from the clock source.

    With this order, an edge from a later to an earlier node is always a feedback edge (its target is
    an ancestor of its source), which is what the lockstep protocol needs to stay deterministic.
    """
    postorder: list[GraphNode] = []
    seen: set[str] = set()

    def visit(node: GraphNode) -> None:
        seen.add(node.name)
        for topic in node.publishes.values():
            for sub in graph.nodes:
                if sub.name not in seen and topic in sub.subscribes.values():
                    visit(sub)
        postorder.append(node)

    clock = graph.clock_source
    roots = ([clock] if clock is not None else []) + graph.nodes
    for root in roots:  # the clock first: everything it reaches ranks after it
        if root.name not in seen:
            visit(root)
    for rank, node in enumerate(reversed(postorder)):
        node.rank = rank


def _flag(entry: NodeEntry, key: str) -> bool:
    value = entry.fields.get(key, False)
    if not isinstance(value, bool):
        raise LaunchError(f"{entry.at(key)}: {key} must be true or false, got {value!r}")
    return value


#: Largest restart count or timeout a node entry may give (an int beyond a float's range cannot be one).
MAX_NUMBER = 1e9


def _number(entry: NodeEntry, key: str, default: Any, kind: type) -> Any:
    value = entry.fields.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or (kind is int and not isinstance(value, int)):
        raise LaunchError(f"{entry.at(key)}: {key} must be a{'n integer' if kind is int else ' number'}, got {value!r}")
    if value < 0 or not (isinstance(value, int) or math.isfinite(value)) or value > MAX_NUMBER:
        raise LaunchError(
            f"{entry.at(key)}: {key} must be finite, not negative and at most {MAX_NUMBER:,.0f}, got {value!r}"
        )
    return kind(value)


def _curve(entry: NodeEntry) -> dict[str, str]:
    path = entry.fields.get("curve_keys")
    if path is None:
        return {}
    try:
        keys = bus.read_key_file(str(path))
    except BusError as exc:
        raise LaunchError(f"{entry.at('curve_keys')}: {exc}") from exc
    if "server_public" not in keys:
        raise LaunchError(f"{entry.at('curve_keys')}: key file {path!r} lacks ['server_public']")
    return keys


def _stable_hash(text: str) -> int:
    """A small deterministic per-node seed offset (Python's hash() is salted per process)."""
    value = 0
    for ch in text.encode():
        value = (value * 131 + ch) % 1_000_003
    return value
