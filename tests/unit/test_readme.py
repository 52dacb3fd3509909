"""The README matches the code: its graphs are the resolved launch files, its commands parse and name them all."""

from __future__ import annotations

import argparse
import itertools
import re
import shlex
from pathlib import Path

import pytest

from palpate import cli
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.paths import REPO_ROOT

README = (REPO_ROOT / "README.md").read_text()
#: `publisher ── topic (Type) ──> reader, reader  (a note)`
EDGE = re.compile(r"^(?P<publisher>\w+)\s+── (?P<topic>\S+) \((?P<type>\w+)\) ─+> (?P<readers>.*)$")
Edge = tuple[str, str, str, frozenset[str]]


def graph_blocks() -> dict[str, list[str]]:
    """Launch file -> the lines of the code block under the README heading that names its dry run."""
    found = {}
    for match in re.finditer(r"^### [^\n]*`palpate launch --dry-run (\S+)`\)\n\n```\n(.*?)```", README, re.M | re.S):
        found[match.group(1)] = match.group(2).splitlines()
    return found


def drawn_edges(lines: list[str]) -> list[Edge]:
    edges = []
    for line in lines:
        match = EDGE.match(line)
        assert match, f"README graph line not in the form 'publisher ── topic (Type) ──> readers': {line!r}"
        readers = re.sub(r"\([^)]*\)", "", match["readers"])  # notes in parentheses are not readers
        names = frozenset(r.strip() for r in readers.split(",") if r.strip())
        edges.append((match["publisher"], match["topic"], match["type"], names))
    return edges


def resolved_edges(launch_file: str) -> dict[str, Edge]:
    graph = resolve(load_launch(REPO_ROOT / launch_file), bus_dir=Path("/nonexistent-bus"))
    types = graph.topic_types()
    edges = {}
    for topic, type_name in types.items():
        (publisher,) = graph.publishers(topic)
        readers = frozenset(n.name for n in graph.nodes if topic in n.subscribes.values())
        edges[topic] = (publisher.name, topic, type_name, readers)
    return edges


def test_the_readme_draws_the_two_graphs() -> None:
    assert set(graph_blocks()) == {"launch/explore.yaml", "launch/fastslam.yaml"}


@pytest.mark.parametrize("launch_file", sorted(graph_blocks()))
def test_every_drawn_edge_is_in_the_resolved_graph_and_none_is_missing(launch_file: str) -> None:
    drawn = drawn_edges(graph_blocks()[launch_file])
    resolved = resolved_edges(launch_file)
    for publisher, topic, type_name, readers in drawn:
        assert topic in resolved, f"README draws {topic!r}, which {launch_file} does not have"
        assert (publisher, topic, type_name, readers) == resolved[topic], f"README's {topic!r} differs from the graph"
    assert len({e[1] for e in drawn}) == len(drawn), "a topic drawn twice"
    wired = {t for t, e in resolved.items() if e[3]}
    assert wired <= {e[1] for e in drawn}, f"topics read by a node but not drawn: {wired - {e[1] for e in drawn}}"


def command_lines() -> list[list[str]]:
    """The `$P ...` invocations of the README's command list, as words (several per line, split at `;`)."""
    block = re.search(r"^## Commands\n\n```sh\n(.*?)```", README, re.M | re.S)
    assert block, "README has no ## Commands block"
    out = []
    for line in block.group(1).splitlines():
        words = shlex.split(line, comments=True)
        for is_separator, part in itertools.groupby(words, key=lambda w: w == ";"):
            command = list(part)
            if not is_separator and command[0] == "$P":
                out.append(command[1:])
    return out


def expand(command: list[str]) -> list[list[str]]:
    """The argument lists a README command stands for: `a|b` gives each choice, `[--x]` with and without it."""
    choices: list[list[str | None]] = []
    for word in command:
        if word.startswith("[") and word.endswith("]"):
            choices.append([word[1:-1], None])
        else:
            choices.append(list(word.split("|")))
    return [[w for w in combo if w is not None] for combo in itertools.product(*choices)]


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def test_every_readme_command_parses() -> None:
    parser = cli.build_parser()
    for command in command_lines():
        for argv in expand(command):
            try:
                cli.parse(parser, argv)
            except SystemExit:
                pytest.fail(f"README command `palpate {' '.join(argv)}` does not parse")


def test_the_readme_names_every_command() -> None:
    named = {tuple(argv[:2]) for command in command_lines() for argv in expand(command)}
    named_first = {n[0] for n in named}
    missing = []
    for name, sub in _subcommands(cli.build_parser()).items():
        if name not in named_first:
            missing.append(name)
        missing.extend(f"{name} {child}" for child in _subcommands(sub) if (name, child) not in named)
    assert not missing, f"commands of the CLI that the README's command list does not show: {missing}"
