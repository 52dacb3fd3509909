"""`palpate launch` and `palpate demo`."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from types import FrameType
from typing import Any

from palpate import jsonio
from palpate.argtypes import path_arg
from palpate.errors import LaunchError
from palpate.launch import placement
from palpate.launch.graph import Graph, check_file_contents, resolve
from palpate.launch.loader import (
    apply_params,
    arguments_set_at,
    load_launch,
    parse_cli_args,
    parse_node_params,
    with_external,
)
from palpate.launch.supervisor import Supervisor
from palpate.paths import LAUNCH_DIR, REPO_ROOT, output_path_problem, same_file, why_not
from palpate.runtime import bus


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("launch", help="run a node graph from a YAML launch file")
    p.add_argument("file", type=path_arg, help="launch file")
    p.add_argument("args", nargs="*", metavar="NAME:=VALUE", help="override launch arguments")
    p.add_argument("--dry-run", action="store_true", help="validate and print the resolved graph; start nothing")
    p.add_argument("--record", type=path_arg, metavar="OUT.mcap", help="record every topic of the run")
    p.add_argument("--force", action="store_true", help="let --record replace an existing log")
    p.add_argument(
        "--replay",
        type=path_arg,
        metavar="LOG.mcap",
        help="replay the log's sensor data (the clock source's topics); every other node re-runs",
    )
    p.add_argument(
        "--replay-nodes",
        type=_names,
        action="extend",
        metavar="A,B",
        help="with --replay: the nodes the log stands in for (default: the clock source); repeatable",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NODE.KEY=VALUE",
        help="override a node parameter the launch file sets or not (e.g. gpis.gp.kernel=gaussian); repeatable",
    )
    p.add_argument(
        "--external",
        type=_names,
        action="extend",
        metavar="A,B",
        help="start these nodes not here but from a driver (as `external: true` in the launch file would); repeatable",
    )
    p.add_argument("--bus", type=path_arg, help=f"bus directory (default ${bus.BUS_ENV} or a per-user temp dir)")
    p.add_argument(
        "--spec",
        metavar="NODE",
        help="print the process spec of NODE as JSON (what an external node's driver needs) and start nothing",
    )
    p.set_defaults(func=run_launch)

    d = sub.add_parser(
        "demo", help="IGEF explores a torus through the full node graph (launch/demo.yaml); records MCAP, PNG"
    )
    d.add_argument("args", nargs="*", metavar="NAME:=VALUE", help="override launch arguments")
    d.add_argument("--out", type=path_arg, default=Path("out/demo"), help="folder for the MCAP log, JSON and PNG")
    d.set_defaults(func=run_demo)


def _names(text: str) -> list[str]:
    """Comma-separated node names, at least one."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r} names no node; give A,B")
    return names


def load_graph(*args: Any, **kwargs: Any) -> Graph:
    """`_load_graph(...)`, with a Ctrl-C while it runs raised after it: the node types it imports pull in
    trimesh, whose optional imports catch BaseException and would swallow the KeyboardInterrupt (the
    launch then ran the whole graph)."""
    interrupted = False

    def note(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupted
        interrupted = True
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, note)
    try:
        graph = _load_graph(*args, **kwargs)
    finally:
        signal.signal(signal.SIGINT, previous)
    if interrupted:
        raise KeyboardInterrupt
    return graph


def _load_graph(
    path: Path,
    overrides: list[str],
    bus_dir: Path | None,
    replay: Path | None = None,
    replay_nodes: list[str] | None = None,
    external: list[str] | None = None,
    sets: list[str] | None = None,
) -> Graph:
    try:
        arguments = parse_cli_args(overrides)
        launch = load_launch(path, arguments)
        if sets:
            params = parse_node_params(sets)
            _refuse_set_over_arguments(path, arguments, params)
            apply_params(launch, params.items())
        if external:
            launch = with_external(launch, external)
        if replay is not None:
            from palpate.record.launch_support import replace_publishers_with_log, replay_note

            note = replay_note(launch, replay, replay_nodes)
            if note:
                print(note, file=sys.stderr)
            notes: list[str] = []
            replayed = replace_publishers_with_log(launch, replay, replay_nodes, notes)
            for line in notes:
                print(line, file=sys.stderr)
            kept = {entry.fields["name"] for entry in replayed.nodes}
            if gone := sorted(set(external or ()) - kept):
                raise LaunchError(f"--external {','.join(gone)}: --replay stands in for {gone}; name other nodes")
            if lost := sorted(key for key in launch.overrides if key.partition(".")[0] not in kept):
                raise LaunchError(f"--set {', '.join(lost)}: --replay stands in for that node; its data is the log's")
            launch = replayed
        graph = resolve(launch, bus_dir=bus_dir)
        check_file_contents(graph)
        return graph
    except LaunchError as exc:
        named = _from_the_command_line(exc, path, overrides)
        relevant = [item for item in sets or () if f"node '{item.partition('.')[0]}'" in str(named)]
        raise LaunchError(f"{named} (with --set {' --set '.join(relevant)})") if relevant else named from exc


def _refuse_set_over_arguments(path: Path, arguments: dict[str, Any], params: dict[str, Any]) -> None:
    """LaunchError where a --set key and a name:=value of the command line set the same parameter (the
    --set would win without a word)."""
    for key, names in arguments_set_at(path, arguments, params).items():
        given = ", ".join(f"{name}:={arguments[name]!r}" for name in names)
        raise LaunchError(
            f"--set {key}={params[key]!r} and {given} set the same parameter ({path} puts "
            f"{', '.join(names)} in {key}); give one of them"
        )


def _from_the_command_line(exc: LaunchError, path: Path, overrides: list[str]) -> LaunchError:
    """`exc`, saying which `name:=value` of the command line the line it names substitutes, if any: a line
    of `path`, or of a file it includes (where an argument of the same name is most often passed on)."""
    file, _, line = str(exc).partition(": ")[0].rpartition(":")
    if not line.isdigit() or not file or not overrides or not Path(file).is_file():
        return exc
    lines = Path(file).read_text(errors="replace").splitlines()
    text = lines[int(line) - 1] if int(line) <= len(lines) else ""  # (an empty file's error names line 1)
    included = Path(file).resolve() != path.resolve()
    top = path.read_text(errors="replace") if included else ""  # an include passes the argument on as ${name}
    used = [
        item
        for item in overrides
        if (name := f"${{{item.partition(':=')[0]}}}") in text and (not included or name in top)
    ]
    return LaunchError(f"{exc} (from the command line: {', '.join(used)})") if used else exc


def run_launch(args: argparse.Namespace) -> int:
    if args.replay_nodes and args.replay is None:
        raise LaunchError("--replay-nodes needs --replay LOG.mcap")
    if args.record is not None and args.replay is not None and same_file(args.record, args.replay):
        raise LaunchError(f"--record {args.record} is the log --replay reads (--force or not); record to another file")
    graph = load_graph(args.file, args.args, args.bus, args.replay, args.replay_nodes, args.external, args.set)
    if args.spec is not None:
        recorder_keys = recorder_curve_keys(graph) if args.record else {}
        specs = {
            s.name: s
            for s in graph.process_specs(
                extra_subscribers=1 if args.record else 0,
                extra_curve_clients=[recorder_keys["public"]] if recorder_keys else [],
            )
        }
        if args.spec not in specs:
            raise LaunchError(f"no node {args.spec!r} in {args.file}; nodes: {', '.join(sorted(specs))}")
        print(json.dumps(json.loads(specs[args.spec].to_json()), indent=1, sort_keys=True))
        return 0
    if args.dry_run:
        if args.record is not None:
            check_record_path(args.record, overwrite=args.force, create=False)
        print(describe(graph))  # a reader that stops early (| head) is no error: palpate.cli says so
        return 0
    return run_graph(graph, record=args.record, overwrite=args.force)


def recorder_curve_keys(graph: Graph) -> dict[str, str]:
    """The recorder's own key pair in a keyed graph ({} otherwise), which every keyed publisher admits:
    derived from the graph's secret keys, so `--spec NAME --record` gives a remote node the same one."""
    if not graph.keyed:
        return {}
    return bus.derived_curve_keys("palpate recorder", [n.curve["secret"] for n in graph.nodes if n.curve.get("secret")])


def check_record_path(path: Path, *, overwrite: bool, create: bool = True) -> None:
    """Refuse a `--record` path the recorder could not write, or an existing log without `overwrite`;
    with `create`, makes its folder, as the recorder would, and tries to create the file itself (then
    removes it again); without (--dry-run), makes nothing."""
    if problem := output_path_problem(path, "run.mcap"):
        raise LaunchError(f"--record {problem}")
    if path.exists() and not overwrite:
        raise LaunchError(f"--record {path} exists; pass --force to replace it, or choose another file")
    if path.exists() and not os.access(path, os.W_OK):
        raise LaunchError(f"--record {path} exists and cannot be replaced (not writable)")
    if not create:  # --dry-run: nothing made on disk
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LaunchError(f"--record {path}: cannot create its folder: {exc}") from exc
    try:  # access() says yes to root in /proc, and to any user on some file systems that refuse files
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except FileExistsError:
        return
    except OSError as exc:
        raise LaunchError(f"--record {path}: cannot create the file: {exc.strerror}") from exc
    path.unlink()


def launch_about(graph: Graph) -> dict[str, str]:
    """What a log records about the launch that made it: its file, resolved arguments and seed, and the
    nodes that drivers played (``external``)."""
    source = graph.source
    path = source.path.resolve()
    shown = path.relative_to(REPO_ROOT) if path.is_relative_to(REPO_ROOT) else path  # the same in every clone
    about = {
        "launch_file": str(shown),
        "args": jsonio.dumps(source.args, sort_keys=True, default=str),
        "seed": str(source.seed),
    }
    if source.overrides:  # --set
        about["params"] = jsonio.dumps(source.overrides, sort_keys=True, default=str)
    if external := sorted(node.name for node in graph.nodes if node.external):  # played by drivers, not palpate
        about["external"] = ",".join(external)
    return about


#: After a failed run the recorder gets this long (seconds) to finish on its own before it is told to.
RECORDER_GRACE_S = 3.0


def run_graph(graph: Graph, record: Path | None = None, *, overwrite: bool = False) -> int:
    """Start the graph's processes (and a recorder), supervise them, return the exit code.

    `overwrite`: the recorder may replace an existing `record` file."""
    if record is not None:
        check_record_path(record, overwrite=overwrite)
    recorder_keys = recorder_curve_keys(graph) if record is not None else {}
    specs = graph.process_specs(
        extra_subscribers=1 if record else 0,
        extra_curve_clients=[recorder_keys["public"]] if recorder_keys else [],
    )
    where = placement.graph_placement(graph)
    if where:
        print(f"[launch] placement {graph.source.placement}: {placement.describe(where)}", flush=True)
    elif graph.source.placement != "os" and not placement.supported():
        print(
            f"[launch] placement {graph.source.placement}: this system cannot place processes (no Linux CPU "
            "affinity); the OS places them",
            flush=True,
        )
    supervisor = Supervisor(graph, specs, placement=where)
    recorder: subprocess.Popen[bytes] | None = None
    if record is not None:
        endpoints = [n.endpoint for n in graph.nodes]
        server_keys = {n.endpoint: n.curve["public"] for n in graph.nodes if n.curve.get("public")}
        key_args = []
        if recorder_keys:
            key_args = ["--curve-keys", str(supervisor.write_secret("recorder.key", recorder_keys))]
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
                "--curve-servers",
                json.dumps(server_keys),
                "--about",
                jsonio.dumps(launch_about(graph)),
                *key_args,
                "--connect",
                *endpoints,
            ]
        )
        supervisor.watch("recorder", recorder)
    code = 1
    try:
        code = supervisor.run()
    finally:
        if recorder is not None:
            if code != 0:
                # a failed run may never send the stop the recorder waits for (no tick was made): after a
                # grace to take what is on its way, it closes its log on SIGINT with everything so far
                with contextlib.suppress(subprocess.TimeoutExpired):
                    recorder.wait(timeout=RECORDER_GRACE_S)
                if recorder.poll() is None:
                    recorder.send_signal(signal.SIGINT)
            try:
                recorder.wait(timeout=30)
            except subprocess.TimeoutExpired:
                recorder.terminate()
                recorder.wait()
    if recorder is not None and recorder.returncode != 0:
        # its death was said when it stopped the launch: here only what it means for the log
        how = "" if "recorder" in supervisor.helpers_died else f"the recorder exited with code {recorder.returncode}: "
        print(
            f"[launch] {how}{record} may lack the end of the run; "
            f"`palpate bag recover {record}` rewrites what it holds into a complete log",
            file=sys.stderr,
        )
        code = code or 1
    return code


def make_folder(path: Path, option: str) -> None:
    """Create the folder `path` (and its parents) or raise LaunchError naming `option` and why not."""
    try:
        if path.exists() and not path.is_dir():
            raise LaunchError(f"{option} {path} is a file, not a folder; give a folder")
        path.mkdir(parents=True, exist_ok=True)
    except (OSError, RecursionError) as exc:  # (RecursionError: pathlib's mkdir of a path of 1,000s of parts)
        why = why_not(exc)
        raise LaunchError(f"{option} {path}: cannot create the folder: {why}") from None


def run_demo(args: argparse.Namespace) -> int:
    """launch/demo.yaml through the full node graph, recorded to OUT/explore.mcap; prints the metrics."""
    import json

    out: Path = args.out.resolve()
    make_folder(out, "--out")
    given = {item.partition(":=")[0] for item in args.args}
    defaults = {"results": out / "explore.json", "plot": out / "explore.png"}
    overrides = [*args.args, *(f"{k}:={v}" for k, v in defaults.items() if k not in given)]
    results = Path(parse_cli_args(overrides)["results"])
    record = out / "explore.mcap"
    results.unlink(missing_ok=True)
    import tempfile

    with tempfile.TemporaryDirectory(prefix="palpate-demo-") as bus_dir:  # a private bus: no clash with other graphs
        graph = load_graph(LAUNCH_DIR / "demo.yaml", overrides, Path(bus_dir))
        code = run_graph(graph, record=record, overwrite=True)  # the demo's folder is its own, as are its results
    if not results.is_file():
        print(f"[demo] the evaluator wrote no results ({results}); exit code {code}", file=sys.stderr)
        return code or 1
    print(demo_summary(json.loads(results.read_text())))
    print(f"[demo] log {record}, picture {parse_cli_args(overrides)['plot']}, results {results}")
    return code


def demo_summary(result: dict[str, Any]) -> str:
    """The metrics of an exploration run (the evaluator's results JSON) as a few lines of text."""
    milestones = result.get("milestones", {})
    area, vertices = 100 * float(result.get("coverage", 0.0)), 100 * float(result.get("vertex_coverage", 0.0))
    lines = [
        f"[demo] {result.get('object')}: {result.get('contacts')} contacts, coverage {area:.1f} % (by area; "
        f"{vertices:.1f} % of vertices), finished: {result.get('finished')}"
    ]
    for percent in ("50", "80"):
        m = milestones.get(percent)
        if not isinstance(m, dict):
            continue
        state = "reached" if m.get("reached") else "NOT reached (figures at the end of the run)"
        lines.append(
            f"[demo] {percent} % coverage {state}: {m['contacts']} contacts, travel {m['travel_cm']:.1f} cm, "
            f"rotation {m['rotation_deg']:.0f} deg, surface RMSE {_mm(m.get('rmse_mm'))} over the confident "
            f"{_pct(m.get('confident_fraction'))} of the estimate (whole estimate: estimate->truth "
            f"{_mm(m.get('rmse_estimate_to_truth_mm'))}, truth->estimate {_mm(m.get('rmse_truth_to_estimate_mm'))}), "
            f"prediction miss {_mm(m.get('prediction_miss_mm'))}, fingertip-normal angle {_deg(m.get('angle_deg'))}"
        )
    return "\n".join(lines)


def _pct(value: object) -> str:
    return "n/a" if value is None or value != value else f"{100 * float(value):.0f} %"  # type: ignore[arg-type]


def _deg(value: object) -> str:
    return "n/a" if value is None or value != value else f"{float(value):.1f} deg"  # type: ignore[arg-type]


def _mm(value: object) -> str:
    return "n/a" if value is None or value != value else f"{float(value):.2f} mm"  # type: ignore[arg-type]


def describe(graph: Graph) -> str:
    """The resolved graph as text: nodes in lockstep order, then every topic with its type and peers."""
    lines = [
        f"launch {graph.source.path} (mode {graph.mode}, seed {graph.seed}, bus {graph.bus_dir})",
        "nodes:",
    ]
    trailing = {n.name for n in graph.trailing_nodes()}
    for node in sorted(graph.nodes, key=lambda n: n.rank):
        flags = [
            f
            for f, on in (
                ("clock", node.spec.clock_source),
                ("trails", node.name in trailing),
                ("external", node.external),
                ("evaluator", node.evaluator),
                ("respawn", node.respawn),
            )
            if on
        ]
        lines.append(
            f"  {node.rank}. {node.name} ({node.type}) {node.endpoint}" + (f" [{', '.join(flags)}]" if flags else "")
        )
        for path, (given, value) in node.settled.items():
            lines.append(f"     {'.'.join(map(str, path))}: {given} -> {value} (set by the graph)")
    lines.append("topics:")
    types = graph.topic_types()
    for topic in sorted(types):
        pubs = ", ".join(n.name for n in graph.publishers(topic))
        subs = ", ".join(n.name for n in graph.nodes if topic in n.subscribes.values()) or "-"
        lines.append(f"  {topic} [{types[topic]}]: {pubs} -> {subs}")
    return "\n".join(lines)
