"""Reading launch files: YAML with line numbers, arguments (`${name}`, `name:=value`) and includes.

Every value keeps the file and line it came from, so that validation errors can name them.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from palpate.config import KeyPath, YamlLoader, key_lines, line_at
from palpate.errors import ConfigError, LaunchError, PalpateError
from palpate.launch.placement import PLACEMENTS
from palpate.paths import read_start

_CONSTRUCTOR = yaml.constructor.SafeConstructor()
#: What PyYAML's constructors raise for a tagged value they cannot build (`!!bool maybe`, `!!timestamp x`,
#: `!!int` with no value: an IndexError).
_CONSTRUCT_ERRORS = (ValueError, KeyError, AttributeError, TypeError, OverflowError, IndexError)
#: Most values a launch file may expand to, aliases included (a "billion laughs" file is refused).
MAX_VALUES = 1_000_000
#: A launch file larger than this (bytes) is refused unread: /dev/zero as the file would fill the memory.
MAX_LAUNCH_BYTES = 16 << 20
_ARG = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")

TOP_KEYS = {"args", "mode", "seed", "include", "nodes", "description", "placement"}
NODE_KEYS = {
    "name",
    "type",
    "params",
    "remaps",
    "namespace",
    "respawn",
    "max_restarts",
    "sigterm_timeout_s",
    "external",
    "evaluator",
    "host",
    "port",
    "curve_keys",
}
INCLUDE_KEYS = {"file", "args"}


@dataclass(frozen=True)
class Where:
    """A place in a launch file."""

    file: str
    line: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass
class NodeEntry:
    """One node of a launch file, with the place of each of its keys."""

    fields: dict[str, Any]
    where: Where
    key_lines: dict[str, Where] = field(default_factory=dict)
    #: The line of every key and list item under ``params``, by key path (``("scene", "object", "kind")``).
    param_lines: dict[KeyPath, Where] = field(default_factory=dict)
    remap_lines: dict[str, Where] = field(default_factory=dict)

    def at(self, key: str) -> Where:
        return self.key_lines.get(key, self.where)

    def param_at(self, path: KeyPath) -> Where:
        """The line of the deepest key of ``path`` written in the file (else the ``params`` line)."""
        return line_at(self.param_lines, path) or self.at("params")


@dataclass
class LaunchFile:
    """A launch file after arguments and includes are resolved."""

    path: Path
    mode: str
    seed: int
    args: dict[str, Any]
    nodes: list[NodeEntry]
    description: str = ""
    #: Where the node processes run (palpate.launch.placement): "os" or "loop".
    placement: str = "os"
    #: Where the file sets its mode (its `mode` key, else its `nodes` key, else line 1), for errors about it.
    mode_at: Where | None = None
    #: Node parameters set from outside the file (``--set node.key=value``: ``apply_params``), by dotted key.
    overrides: dict[str, Any] = field(default_factory=dict)


def parse_cli_args(items: Sequence[str], separator: str = ":=", option: str = "") -> dict[str, Any]:
    """`name:=value` pairs (or `name<separator>value`) from the command line; values are parsed as
    YAML scalars, an empty value is the empty string. A name given twice is refused (`option`, such as
    "--set", names where the pairs came from)."""
    out: dict[str, Any] = {}
    given: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition(separator)
        if not sep or not name:
            raise LaunchError(f"launch argument {item!r} must look like name{separator}value")
        if name in given:  # the last would win without a word, as no launch file's key may repeat
            what = f"{option} {name!r}" if option else f"launch argument {name!r}"
            raise LaunchError(f"{what} is given twice on the command line ({given[name]!r} and {item!r}); give it once")
        given[name] = item
        try:
            out[name] = yaml.load(value, Loader=YamlLoader) if value else ""
        except RecursionError:
            raise LaunchError(
                f"launch argument {item[:80]!r} from the command line: nested too deeply to read (lists or "
                "mappings inside each other)"
            ) from None
        except (yaml.YAMLError, *_CONSTRUCT_ERRORS) as exc:
            problem = getattr(exc, "problem", None) or _construct_problem(exc, "")
            raise LaunchError(
                f"launch argument {item!r} from the command line: its value is not valid YAML ({problem}); "
                "quote it to pass text"
            ) from exc
    return out


def parse_node_params(items: Sequence[str]) -> dict[str, Any]:
    """``--set`` items ``["node.key=value", ...]`` -> {"node.key": value}, values parsed as YAML scalars."""
    for item in items:
        if "=" not in item or item.startswith("="):
            raise ConfigError(f"--set {item!r}: expected NODE.KEY=VALUE, e.g. planner.candidate_step_m=0.005")
    out = parse_cli_args(items, separator="=", option="--set")
    for key in out:
        if "." not in key:
            raise ConfigError(f"--set {key!r}: expected NODE.KEY=VALUE, e.g. planner.candidate_step_m=0.005")
    return out


def _named_nodes(launch: LaunchFile) -> dict[str, NodeEntry]:
    """The nodes of `launch` by name; a name that is no string is the error `resolve` would raise for it."""
    for entry in launch.nodes:
        name = entry.fields["name"]
        if not isinstance(name, str):
            raise LaunchError(f"{entry.at('name')}: name must be a string, got {name!r}")
    return {entry.fields["name"]: entry for entry in launch.nodes}


def apply_params(launch: LaunchFile, params: Iterable[tuple[str, Any]]) -> None:
    """Set dotted node parameters ``"node.key.subkey" = value`` in a loaded launch file, in place."""
    nodes = _named_nodes(launch)
    for dotted, value in params:
        name, _, path = dotted.partition(".")
        if name not in nodes or not path:
            raise ConfigError(f"parameter override {dotted!r}: expected node.key with node one of {sorted(nodes)}")
        entry = nodes[name]
        if entry.fields.get("params") is None:  # no params, or `params:` with no value: none set yet
            entry.fields["params"] = {}
        target = entry.fields["params"]
        if not isinstance(target, dict):
            raise LaunchError(f"{entry.at('params')}: params must be a mapping")
        keys = path.split(".")
        for key in keys[:-1]:
            target = target.setdefault(key, {})
            if not isinstance(target, dict):
                raise ConfigError(f"parameter override {dotted!r}: {key!r} is not a mapping")
        old = target.get(keys[-1])
        target[keys[-1]] = _merged(old, value) if isinstance(old, dict) and isinstance(value, dict) else value
        launch.overrides[dotted] = value


def arguments_set_at(path: str | Path, args: Mapping[str, Any], sets: Mapping[str, Any]) -> dict[str, list[str]]:
    """For each ``--set`` key of `sets` (dotted node parameter -> value), the arguments of `args` whose value
    the launch file puts where that ``--set`` writes (a mapping is merged key by key, so only under its
    keys). Each argument is found by loading the file with a value no parameter holds in its place; one
    the file refuses so is left out."""
    found: dict[str, list[str]] = {key: [] for key in sets}
    for name in sorted(args):
        marker = f"<palpate: where is argument {name}?>"
        try:
            probed = load_launch(path, {**args, name: marker}).nodes
        except PalpateError:
            continue
        params = {entry.fields.get("name"): entry.fields.get("params") for entry in probed}
        for key, value in sets.items():
            node, _, rest = key.partition(".")
            if any(_written_over(params.get(node), leaf.split("."), marker) for leaf in _leaves(rest, value)):
                found[key].append(name)
    return {key: names for key, names in found.items() if names}


def _leaves(key: str, value: Any) -> list[str]:
    """The dotted keys a --set of `value` at `key` writes: a mapping is merged, so its leaves."""
    if isinstance(value, dict) and value:
        return [leaf for k, v in value.items() for leaf in _leaves(f"{key}.{k}", v)]
    return [key]


def _written_over(params: Any, path: list[str], marker: str) -> bool:
    """Whether setting `path` in `params` replaces a value that holds `marker` (a value that is no
    mapping on the way is replaced whole)."""
    value = params
    for part in path:
        if not isinstance(value, dict):
            return _holds(value, marker)
        value = value.get(part)
    return _holds(value, marker)


def _holds(value: Any, marker: str) -> bool:
    """Whether `marker` is `value`, or in a string, list or mapping value within it."""
    if isinstance(value, str):
        return marker in value
    if isinstance(value, dict):
        return any(_holds(v, marker) for v in value.values())
    if isinstance(value, list | tuple):
        return any(_holds(v, marker) for v in value)
    return False


def _merged(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """`base` with the keys of `changes` set, mappings merged key by key (a --set mapping keeps the rest)."""
    out = dict(base)
    for key, value in changes.items():
        out[key] = _merged(out[key], value) if isinstance(out.get(key), dict) and isinstance(value, dict) else value
    return out


def with_external(launch: LaunchFile, names: Sequence[str]) -> LaunchFile:
    """`launch` with the nodes `names` marked ``external: true`` (``palpate launch --external``): wired and
    waited for, but started (and restarted) by a driver, not the launcher."""
    known = list(_named_nodes(launch))
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise LaunchError(f"--external: no node {unknown} in {_display(launch.path)}; its nodes: {sorted(known)}")
    nodes = [_external(entry) if entry.fields["name"] in names else entry for entry in launch.nodes]
    return replace(launch, nodes=nodes)


def _external(entry: NodeEntry) -> NodeEntry:
    """`entry` marked external; its driver, not the launcher, restarts it (its respawn settings go)."""
    kept = {k: v for k, v in entry.fields.items() if k not in ("respawn", "max_restarts")}
    return replace(entry, fields={**kept, "external": True})


def load_launch(path: str | Path, overrides: Mapping[str, Any] | None = None) -> LaunchFile:
    """Read a launch file, substitute arguments, and expand includes (depth-first, in order)."""
    try:
        return _load(Path(path), dict(overrides or {}), stack=(), sites={})
    except RecursionError:
        raise LaunchError(
            f"{_display(Path(path))}: nested too deeply to read (lists or mappings inside each other)"
        ) from None


def _load(path: Path, overrides: dict[str, Any], stack: tuple[Path, ...], sites: Mapping[str, Where]) -> LaunchFile:
    """`sites`: where an include set each of `overrides` (empty for the top file's)."""
    path = path.resolve()
    if path in stack:
        raise LaunchError(f"{path}: include cycle: {' -> '.join(str(p) for p in (*stack, path))}")
    name = _display(path)
    top = _top_items(_compose(path, name), name)
    args = _arguments(top, name, overrides, sites)

    def value(key: str, default: Any) -> Any:
        return _plain(top[key][1], name, args) if key in top else default

    mode, placement, seed = _settings(top, name, value)
    nodes = _included_nodes(top, name, args, path, stack)
    nodes.extend(_node_entry(entry, name, args) for entry in _sequence(top, "nodes", name))
    return LaunchFile(
        path=path,
        mode=mode,
        seed=seed,
        args=args,
        nodes=nodes,
        description=str(value("description", "")),
        placement=placement,
        mode_at=Where(name, next((top[k][0].start_mark.line + 1 for k in ("mode", "nodes") if k in top), 1)),
    )


def _compose(path: Path, name: str) -> yaml.Node | None:
    """The YAML node tree of the file (None when it is empty); every error names the file and line."""
    try:
        data = read_start(path, MAX_LAUNCH_BYTES + 1)
    except OSError as exc:
        raise LaunchError(f"{name}: cannot read launch file: {exc.strerror}") from exc
    if len(data) > MAX_LAUNCH_BYTES:
        raise LaunchError(f"{name}: larger than {MAX_LAUNCH_BYTES >> 20} MiB: not a launch file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise LaunchError(
            f"{name}:{line}: not UTF-8 text (byte {data[exc.start]:#04x}); save the file as UTF-8"
        ) from None
    try:
        return yaml.compose(text, Loader=YamlLoader)
    except yaml.MarkedYAMLError as exc:
        mark, context = exc.problem_mark, exc.context_mark
        around = f" ({exc.context} at line {context.line + 1})" if exc.context and context else ""
        line, column = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        raise LaunchError(f"{name}:{line}: invalid YAML: {exc.problem} at column {column}{around}") from exc
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow (a control character)
        line = text.count("\n", 0, exc.position) + 1
        char = chr(exc.character) if isinstance(exc.character, int) else exc.character
        raise LaunchError(f"{name}:{line}: invalid YAML: the character {char!r} is not allowed") from exc


def _top_items(root: yaml.Node | None, name: str) -> dict[str, tuple[yaml.Node, yaml.Node]]:
    """The file's top-level keys (only TOP_KEYS) -> (key node, value node)."""
    if root is None:
        raise LaunchError(f"{name}:1: empty launch file: it needs at least a 'nodes' list")
    if not isinstance(root, yaml.MappingNode):
        raise LaunchError(f"{name}:{root.start_mark.line + 1}: a launch file is a mapping with keys {sorted(TOP_KEYS)}")
    top = _mapping_items(root, name)
    for key, (knode, _) in top.items():
        if key not in TOP_KEYS:
            raise LaunchError(f"{name}:{knode.start_mark.line + 1}: unknown key {key!r}; allowed: {sorted(TOP_KEYS)}")
    return top


def _arguments(
    top: dict[str, tuple[yaml.Node, yaml.Node]], name: str, overrides: dict[str, Any], sites: Mapping[str, Where]
) -> dict[str, Any]:
    """The declared arguments with `overrides` applied; an override the file does not declare is an
    error at the include that set it (`sites`) or at the file's `args`."""
    try:
        declared = _plain(top["args"][1], name, {}) if "args" in top else {}
    except LaunchError as exc:  # `args: {a: "${b}"}`: "unknown argument ${b}; declared: []" said too little
        if "unknown argument ${" not in str(exc):
            raise
        where = str(exc).partition(": unknown argument")[0]
        raise LaunchError(
            f"{where}: an argument's default cannot use another argument (${{...}}); give a value"
        ) from None
    if not isinstance(declared, dict):
        raise LaunchError(f"{name}:{top['args'][1].start_mark.line + 1}: 'args' must be a mapping name: default")
    unknown_args = [k for k in overrides if k not in declared]
    if unknown_args and unknown_args[0] in sites:
        raise LaunchError(
            f"{sites[unknown_args[0]]}: {name} has no argument {unknown_args[0]!r}; it declares: {sorted(declared)}"
        )
    if unknown_args:
        args_line = top["args"][0].start_mark.line + 1 if "args" in top else 1
        raise LaunchError(
            f"{name}:{args_line}: unknown launch argument {unknown_args[0]!r}; declared: {sorted(declared)}"
        )
    return {**declared, **overrides}


def _settings(
    top: dict[str, tuple[yaml.Node, yaml.Node]], name: str, value: Callable[[str, Any], Any]
) -> tuple[str, str, int]:
    """(mode, placement, seed) of the file, checked."""
    mode = value("mode", "lockstep")
    if mode not in ("lockstep", "realtime"):
        raise LaunchError(
            f"{name}:{top['mode'][1].start_mark.line + 1}: mode must be 'lockstep' or 'realtime', got {mode!r}"
        )
    placement = value("placement", "os")
    if placement not in PLACEMENTS:
        line = top["placement"][1].start_mark.line + 1
        raise LaunchError(f"{name}:{line}: placement must be 'os' or 'loop', got {placement!r}")
    if placement == "loop" and mode != "lockstep":
        line = top["placement"][1].start_mark.line + 1
        raise LaunchError(
            f"{name}:{line}: placement 'loop' needs mode lockstep (mode is {mode}); give placement: os (the OS "
            "places the processes)"
        )
    seed = value("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise LaunchError(
            f"{name}:{top['seed'][1].start_mark.line + 1}: seed must be an integer >= 0 (NumPy's generators take "
            f"no negative seed), got {seed!r}"
        )
    return mode, placement, seed


def _included_nodes(
    top: dict[str, tuple[yaml.Node, yaml.Node]], name: str, args: Mapping[str, Any], path: Path, stack: tuple[Path, ...]
) -> list[NodeEntry]:
    """The nodes of the file's includes, in order, each include loaded with its own arguments."""
    nodes: list[NodeEntry] = []
    for include in _sequence(top, "include", name):
        items = _mapping_items(include, name)
        for key, (knode, _) in items.items():
            if key not in INCLUDE_KEYS:
                raise LaunchError(
                    f"{name}:{knode.start_mark.line + 1}: unknown include key {key!r}; allowed: {sorted(INCLUDE_KEYS)}"
                )
        if "file" not in items:
            raise LaunchError(f"{name}:{include.start_mark.line + 1}: include needs a 'file'")
        site = f"{name}:{items['file'][1].start_mark.line + 1}"
        given = _plain(items["file"][1], name, args)
        if not isinstance(given, str) or not given.strip():
            raise LaunchError(f"{site}: include 'file' must name a launch file, got {given!r}")
        try:
            target = (path.parent / given).resolve()
            is_file = target.is_file()
        except (OSError, ValueError) as exc:  # a NUL byte, a name longer than the system allows
            raise LaunchError(f"{site}: include file {given[:80]!r} is no usable path: {exc}") from None
        if target in (*stack, path):
            chain = " -> ".join(_display(p) for p in (*stack, path, target))
            raise LaunchError(f"{site}: include cycle: {chain}")
        if not is_file:
            what = "is a folder, not a launch file" if target.is_dir() else "does not exist"
            raise LaunchError(f"{site}: included launch file {_display(target)} {what}")
        include_args, include_sites = _include_args(items, name, args)
        nodes.extend(_load(target, include_args, (*stack, path), include_sites).nodes)
    return nodes


def _include_args(
    items: dict[str, tuple[yaml.Node, yaml.Node]], name: str, args: Mapping[str, Any]
) -> tuple[dict[str, Any], dict[str, Where]]:
    """The `args` of an include and the line of each."""
    if "args" not in items:
        return {}, {}
    node = items["args"][1]
    if not isinstance(node, yaml.MappingNode):
        raise LaunchError(f"{name}:{node.start_mark.line + 1}: an include's 'args' must be a mapping name: value")
    sites = {key: Where(name, knode.start_mark.line + 1) for key, (knode, _) in _mapping_items(node, name).items()}
    return _plain(node, name, args), sites


def _node_entry(node: yaml.Node, name: str, args: dict[str, Any]) -> NodeEntry:
    where = Where(name, node.start_mark.line + 1)
    items = _mapping_items(node, name)
    entry = NodeEntry(fields={}, where=where)
    for key, (knode, vnode) in items.items():
        line = Where(name, knode.start_mark.line + 1)
        if key not in NODE_KEYS:
            raise LaunchError(f"{line}: unknown node key {key!r}; allowed: {sorted(NODE_KEYS)}")
        entry.key_lines[key] = line
        entry.fields[key] = _plain(vnode, name, args)
        if key == "params":
            entry.param_lines = {path: Where(name, line) for path, line in key_lines(vnode).items()}
        if key == "remaps" and isinstance(vnode, yaml.MappingNode):
            for sub_key, (sub_knode, _) in _mapping_items(vnode, name).items():
                entry.remap_lines[sub_key] = Where(name, sub_knode.start_mark.line + 1)
    for required in ("name", "type"):
        if required not in entry.fields:
            raise LaunchError(f"{where}: node needs a {required!r}")
    return entry


def _mapping_items(node: yaml.Node, name: str) -> dict[str, tuple[yaml.Node, yaml.Node]]:
    if not isinstance(node, yaml.MappingNode):
        raise LaunchError(f"{name}:{node.start_mark.line + 1}: expected a mapping")
    items: dict[str, tuple[yaml.Node, yaml.Node]] = {}
    for knode, vnode in node.value:
        key = str(knode.value)
        if key in items:
            raise LaunchError(f"{name}:{knode.start_mark.line + 1}: duplicate key {key!r}")
        if key == "<<" and knode.tag == "tag:yaml.org,2002:merge":
            raise LaunchError(
                f"{name}:{knode.start_mark.line + 1}: a YAML merge key ('<<: *anchor') is not read in launch files "
                "(YAML 1.2 has none); write the keys out, or share a value through args and ${arg}"
            )
        items[key] = (knode, vnode)
    return items


def _sequence(top: dict[str, tuple[yaml.Node, yaml.Node]], key: str, name: str) -> list[yaml.Node]:
    if key not in top:
        return []
    node = top[key][1]
    if not isinstance(node, yaml.SequenceNode):
        raise LaunchError(f"{name}:{node.start_mark.line + 1}: {key!r} must be a list")
    return list(node.value)


@dataclass
class _Expansion:
    """What `_plain` has expanded so far: the collections it is inside (an alias may not repeat one of
    them) and how many values in all (aliases of aliases multiply them)."""

    inside: set[int] = field(default_factory=set)
    values: int = 0


def _plain(node: yaml.Node, name: str, args: Mapping[str, Any], seen: _Expansion | None = None) -> Any:
    """Construct Python data from a YAML node, substituting `${arg}` in strings."""
    seen = seen or _Expansion()
    seen.values += 1
    line = node.start_mark.line + 1
    if seen.values > MAX_VALUES:
        raise LaunchError(
            f"{name}:{line}: more than {MAX_VALUES:,} values once aliases are expanded (aliases of aliases?)"
        )
    if isinstance(node, yaml.MappingNode | yaml.SequenceNode):
        if id(node) in seen.inside:
            raise LaunchError(f"{name}:{line}: an alias inside the collection it names (a recursive anchor)")
        seen.inside.add(id(node))
        try:
            if isinstance(node, yaml.MappingNode):
                return {key: _plain(v, name, args, seen) for key, (_, v) in _mapping_items(node, name).items()}
            return [_plain(v, name, args, seen) for v in node.value]
        finally:
            seen.inside.discard(id(node))
    try:
        value = _CONSTRUCTOR.construct_object(node)
    except (yaml.YAMLError, *_CONSTRUCT_ERRORS) as exc:  # an unknown tag (`!foo x`), an impossible date
        problem = getattr(exc, "problem", None) or _construct_problem(exc, node.tag)
        raise LaunchError(f"{name}:{line}: cannot read {node.value!r}: {problem}") from exc
    if isinstance(value, str) and "${" in value:
        return _substitute(value, Where(name, line), args)
    return value


def _construct_problem(exc: BaseException, tag: str) -> str:
    """What a PyYAML constructor's error means: its own message for a ValueError (an impossible date),
    else that the value is not of the type its tag names (`!!bool maybe` raises a KeyError)."""
    if isinstance(exc, ValueError):
        return str(exc)
    return f"not a valid {tag.rsplit(':', 1)[-1]}" if tag else "not a value its tag allows"


def _substitute(text: str, where: Where, args: Mapping[str, Any]) -> Any:
    whole = _ARG.fullmatch(text)
    for match in _ARG.finditer(text):
        if match.group(1) not in args:
            raise LaunchError(f"{where}: unknown argument ${{{match.group(1)}}}; declared: {sorted(args)}")
    if whole:
        return args[whole.group(1)]
    return _ARG.sub(lambda m: str(args[m.group(1)]), text)


def _display(path: Path) -> str:
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)
