"""`palpate launch` and `palpate demo`."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from palpate.launch.graph import Graph, resolve
from palpate.launch.loader import load_launch, parse_cli_args
from palpate.launch.supervisor import Supervisor
from palpate.paths import REPO_ROOT
from palpate.runtime import bus

LAUNCH_DIR = REPO_ROOT / "launch"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("launch", help="run a node graph from a YAML launch file")
    p.add_argument("file", type=Path, help="launch file")
    p.add_argument("args", nargs="*", metavar="NAME:=VALUE", help="override launch arguments")
    p.add_argument("--dry-run", action="store_true", help="validate and print the resolved graph; start nothing")
    p.add_argument("--record", type=Path, metavar="OUT.mcap", help="record every topic of the run")
    p.add_argument(
        "--replay",
        type=Path,
        metavar="LOG.mcap",
        help="replace the publishers of the log's topics by the log",
    )
    p.add_argument("--bus", type=Path, help=f"bus directory (default ${bus.BUS_ENV} or a per-user temp dir)")
    p.set_defaults(func=run_launch)

    d = sub.add_parser("demo", help="run the built-in demo (launch/demo.yaml) headless and print a summary")
    d.add_argument("args", nargs="*", metavar="NAME:=VALUE", help="override launch arguments")
    d.set_defaults(func=run_demo)


def load_graph(path: Path, overrides: list[str], bus_dir: Path | None, replay: Path | None = None) -> Graph:
    launch = load_launch(path, parse_cli_args(overrides))
    if replay is not None:
        from palpate.record.launch_support import replace_publishers_with_log

        launch = replace_publishers_with_log(launch, replay)
    return resolve(launch, bus_dir=bus_dir)


def run_launch(args: argparse.Namespace) -> int:
    graph = load_graph(args.file, args.args, args.bus, args.replay)
    if args.dry_run:
        try:
            print(describe(graph))
        except BrokenPipeError:  # `palpate launch --dry-run FILE | head`
            sys.stderr.close()
        return 0
    return run_graph(graph, record=args.record)


def run_graph(graph: Graph, record: Path | None = None) -> int:
    """Start the graph's processes (and a recorder), supervise them, return the exit code."""
    specs = graph.process_specs(extra_subscribers=1 if record else 0)
    supervisor = Supervisor(graph, specs)
    recorder: subprocess.Popen[bytes] | None = None
    if record is not None:
        endpoints = [n.endpoint for n in graph.nodes]
        recorder = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "palpate.record.recorder",
                "-o",
                str(record),
                "--until-stop",
                "--bus",
                str(graph.bus_dir),
                "--connect",
                *endpoints,
            ]
        )
    try:
        code = supervisor.run()
    finally:
        if recorder is not None:
            try:
                recorder.wait(timeout=30)
            except subprocess.TimeoutExpired:
                recorder.terminate()
                recorder.wait()
    if recorder is not None and recorder.returncode != 0:
        print(f"[launch] recorder exited with code {recorder.returncode}", file=sys.stderr)
        code = code or 1
    return code


def run_demo(args: argparse.Namespace) -> int:
    return run_graph(load_graph(LAUNCH_DIR / "demo.yaml", args.args, None))


def describe(graph: Graph) -> str:
    """The resolved graph as text: nodes in lockstep order, then every topic with its type and peers."""
    lines = [
        f"launch {graph.source.path} (mode {graph.mode}, seed {graph.seed}, bus {graph.bus_dir})",
        "nodes:",
    ]
    for node in sorted(graph.nodes, key=lambda n: n.rank):
        flags = [
            f
            for f, on in (
                ("clock", node.spec.clock_source),
                ("external", node.external),
                ("evaluator", node.evaluator),
                ("respawn", node.respawn),
            )
            if on
        ]
        lines.append(
            f"  {node.rank}. {node.name} ({node.type}) {node.endpoint}" + (f" [{', '.join(flags)}]" if flags else "")
        )
    lines.append("topics:")
    types = graph.topic_types()
    for topic in sorted(types):
        pubs = ", ".join(n.name for n in graph.publishers(topic))
        subs = ", ".join(n.name for n in graph.nodes if topic in n.subscribes.values()) or "-"
        lines.append(f"  {topic} [{types[topic]}]: {pubs} -> {subs}")
    return "\n".join(lines)
