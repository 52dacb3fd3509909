"""Launch files: every shipped file validates, every bad file fails before any process starts with
`file:line: ... key`, and arguments, includes, namespaces and remaps resolve as documented."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from palpate.cli import main
from palpate.commands.launch import describe
from palpate.errors import ConfigError, LaunchError
from palpate.launch.graph import Graph, resolve
from palpate.launch.loader import apply_params, load_launch, parse_cli_args, parse_node_params, with_external
from palpate.paths import REPO_ROOT

LAUNCH_FILES = sorted((REPO_ROOT / "launch").glob("*.yaml"))
DATA = Path("tests/data/launch")  # relative: errors name files relative to the working directory
MARKER = "# <- error"


@pytest.fixture(autouse=True)
def _in_repo_root(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO_ROOT)


def load(path: Path | str, bus: Path, overrides: list[str] | None = None) -> Graph:
    return resolve(load_launch(path, parse_cli_args(overrides or [])), bus_dir=bus)


def marked_line(name: str) -> str:
    """`tests/data/launch/NAME:LINE` of the line that carries the error marker."""
    lines = (REPO_ROOT / DATA / name).read_text().splitlines()
    hits = [i + 1 for i, line in enumerate(lines) if MARKER in line]
    assert len(hits) == 1, f"{name} needs exactly one '{MARKER}' line"
    return f"{DATA / name}:{hits[0]}"


# --- every shipped launch file ---------------------------------------------------------------------------


def test_there_are_launch_files() -> None:
    assert LAUNCH_FILES, "launch/ holds no *.yaml"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_dry_run_succeeds_on_every_launch_file(path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["launch", "--dry-run", str(path), "--bus", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"launch {path}" in out and "\nnodes:\n" in out and "\ntopics:\n" in out
    graph = load(path, tmp_path)
    for node in graph.nodes:
        assert f". {node.name} ({node.type})" in out
    for topic, type_name in graph.topic_types().items():
        assert f"  {topic} [{type_name}]: " in out
    assert list(tmp_path.iterdir()) == []  # a dry run starts nothing and binds nothing


# --- bad launch files ---------------------------------------------------------------------------------------

BAD = [
    ("unknown_top_key.yaml", [], "unknown key 'nodez'"),
    ("unknown_node_key.yaml", [], "unknown node key 'respwan'"),
    ("unknown_param.yaml", [], "node 'cube': params.edge_mm: unknown key 'edge_mm'; known keys: contacts_per_tick,"),
    ("mistyped_param.yaml", [], "node 'cube': params.edge_m: expected a finite number > 0, got 'big'"),
    ("missing_param.yaml", [], "node 'sink': params: missing required key 'gain'"),
    (
        "no_publisher.yaml",
        [],
        "node 'stats' subscribes to 'sensors/contactz' (port 'contacts', ContactSet) but no node",
    ),
    (
        "type_mismatch.yaml",
        [],
        "type mismatch on 'sensors/contacts': cube publishes ContactSet, "
        "but node 'noise' port 'joint_states' expects JointState",
    ),
    ("truth_topic.yaml", [], "node 'stats' reads ground truth 'truth/contacts' on port 'contacts'; only evaluators"),
    ("duplicate_name.yaml", [], "node name 'stats' is already used at tests/data/launch/duplicate_name.yaml:5"),
    ("unknown_type.yaml", [], "unknown node type 'cube_contactz'"),
    ("two_publishers.yaml", [], "topic 'sensors/contacts' has two publishers (cube and cube2)"),
    ("bad_mode.yaml", [], "mode must be 'lockstep' or 'realtime', got 'fast'"),
    ("bad_placement.yaml", [], "placement must be 'os' or 'loop', got 'fastest'"),
    ("placement_realtime.yaml", [], "placement 'loop' needs mode lockstep (mode is realtime)"),
    ("bad_flag.yaml", [], "respawn must be true or false, got 'yes'"),
    ("unknown_substitution.yaml", [], "unknown argument ${edge}"),
    (
        "yaml_syntax.yaml",
        [],
        "invalid YAML: expected ',' or '}', but got ':' at column 12 (while parsing a flow mapping at line 5)",
    ),
    ("duplicate_param.yaml", [], "duplicate key 'effector'"),
    ("duplicate_arg.yaml", [], "duplicate key 'duration_s'"),
    ("with_args.yaml", ["x:=1"], "unknown launch argument 'x'"),
    ("include_missing.yaml", [], "included launch file tests/data/launch/does_not_exist.yaml does not exist"),
    ("include_cycle_a.yaml", [], "include cycle: tests/data/launch/include_cycle_a.yaml -> "),
    (
        "include_unknown_arg.yaml",
        [],
        "tests/data/launch/include_child.yaml has no argument 'reprot'; it declares: ['ns', 'report']",
    ),
    ("include_args_list.yaml", [], "an include's 'args' must be a mapping name: value"),
    (
        "mount_not_the_sims.yaml",
        [],
        "node 'mapper' (params.mount) and node 'sim' "
        "(params.scene.finger, tests/data/launch/mount_not_the_sims.yaml:7) "
        "disagree on hand_mount: "
        "base_position_m [-0.09662, 0.035, 0.0785] here, [-0.09312, 0.035, 0.075] there; make them the same, "
        "e.g. --set 'mapper.mount.base_position_m=[-0.09312,0.035,0.075]'",
    ),
    (
        "mount_other_finger.yaml",
        [],
        "disagree on hand_mount: finger 'index' here, 'ring' there; make them the same, e.g. --set "
        """'mapper.mount.finger="ring"'""",
    ),
    ("mount_object_missing.yaml", [], "node 'sim': does_not_exist.stl: mesh file not found"),
    ("mount_unknown_finger.yaml", [], "node 'mapper': params.mount.finger: expected one of ['index', 'middle', "),
    ("mount_thumb_on_finger.yaml", [], "params.mount: finger = 'thumb': the single-finger effector is a long finger"),
    ("mapper_not_a_mapping.yaml", [], "node 'mapper': params.mapper: expected a mapping of MapperConfig keys, got 3"),
    ("sim_scene_not_a_mapping.yaml", [], "node 'sim': params.scene: expected a mapping of SceneConfig keys, got [1]"),
]


def test_a_node_that_cannot_be_started_for_a_limit_is_named_with_the_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: under `ulimit -n 16` the launcher ended in Popen's OSError traceback."""
    import errno

    def no_files(*args: object, **kwargs: object) -> None:
        raise OSError(errno.EMFILE, "Too many open files")

    monkeypatch.setattr("palpate.launch.supervisor.subprocess.Popen", no_files)
    assert main(["launch", str(REPO_ROOT / "launch/demo_minimal.yaml"), "--bus", str(tmp_path / "bus")]) == 2
    said = capsys.readouterr().err
    assert "cannot start node 'cube': Too many open files (the limit of open files: raise it with `ulimit -n`" in said


def test_an_input_a_drivers_node_declares_and_nothing_feeds_is_not_told_to_be_external(tmp_path: Path) -> None:
    """An outside walkthrough: a glove driver's `type: sim` node without params (a probe scene, which takes
    velocity commands) was told to mark the hardware driver 'external: true', which it was."""
    path = tmp_path / "glove.yaml"
    path.write_text("nodes:\n  - name: glove\n    type: sim\n    external: true\n")
    with pytest.raises(LaunchError, match=r"no node publishes it; its params declare an input this graph does not"):
        resolve(load_launch(path), bus_dir=tmp_path)


def test_a_mount_that_a_drivers_sim_states_otherwise_is_set_on_the_driver(tmp_path: Path) -> None:
    """An outside walkthrough: a data glove's driver played the sim, and the mount check told to set the
    mapper (mounted where the real finger is) back to the fictional sim's mount."""
    text = (REPO_ROOT / "tests/data/launch/mount_not_the_sims.yaml").read_text()
    path = tmp_path / "glove.yaml"
    path.write_text(text.replace("    type: sim\n", "    type: sim\n    external: true\n", 1))
    with pytest.raises(LaunchError) as info:
        resolve(load_launch(path), bus_dir=tmp_path)
    said = str(info.value)
    assert "e.g. --set 'sim.scene.finger.base_position_m=[-0.09662,0.035,0.0785]'" in said
    assert said.endswith(
        "(node 'sim' is played by a driver: its params say what the hardware is, so give them the hardware's values)"
    )


@pytest.mark.parametrize(("name", "overrides", "expected"), BAD, ids=[b[0] + "".join(b[1]) for b in BAD])
def test_bad_launch_file_names_file_line_and_key(
    name: str, overrides: list[str], expected: str, tmp_path: Path
) -> None:
    where = marked_line("include_cycle_b.yaml" if name == "include_cycle_a.yaml" else name)
    with pytest.raises(LaunchError) as info:
        load(DATA / name, tmp_path, overrides)
    message = str(info.value)
    assert message.startswith(f"{where}: "), message
    assert expected in message, message


@pytest.mark.parametrize("name", ["mount_not_the_sims.yaml", "mount_other_finger.yaml"])
@pytest.mark.parametrize("mapper_first", [False, True])
def test_the_set_that_a_disagreement_proposes_makes_the_nodes_agree(
    name: str, mapper_first: bool, tmp_path: Path
) -> None:
    """Whichever node the file lists first: a set on the sim's scene (its `finger` is a mapping of the
    finger's settings, not a name) would not do, so the mapper's is proposed."""
    path = DATA / name
    if mapper_first:
        text = (REPO_ROOT / path).read_text()
        head, sim, mapper = re.split(r"(?=  - name: (?:sim|mapper)\n)", text)
        path = tmp_path / name
        path.write_text(head + mapper.rstrip("\n") + "\n" + sim)
    with pytest.raises(LaunchError) as info:
        load(path, tmp_path, [])
    proposed = shlex.split(str(info.value).split(", e.g. ")[1].split(" (with")[0])
    assert proposed[0] == "--set" and proposed[1].startswith("mapper.mount.") and len(proposed) == 2
    launch = load_launch(path, parse_cli_args([]))
    apply_params(launch, parse_node_params([proposed[1]]).items())
    resolve(launch, bus_dir=tmp_path)


def test_cli_reports_a_bad_file_and_starts_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    started: list[Any] = []

    class NoSupervisor:
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            started.append(args)

    monkeypatch.setattr("palpate.commands.launch.Supervisor", NoSupervisor)
    monkeypatch.setattr("subprocess.Popen", lambda *a, **k: started.append(a))
    code = main(["launch", str(DATA / "type_mismatch.yaml"), "--bus", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert f"palpate launch: {marked_line('type_mismatch.yaml')}: type mismatch on 'sensors/contacts'" in err
    assert started == []
    assert list(tmp_path.iterdir()) == []


def test_a_bus_that_is_a_file_is_refused_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("palpate.commands.launch.Supervisor", None)  # starting anything would fail
    file = tmp_path / "file"
    file.write_text("")
    for argv in (["launch", "--dry-run"], ["launch"]):
        assert main([*argv, str(DATA / "with_args.yaml"), "--bus", str(file)]) == 2
        assert f"palpate launch: bus directory {file} is not a directory; choose" in capsys.readouterr().err


def runtime_doc_examples() -> list[tuple[str, str]]:
    """The `$ palpate ...` examples of docs/runtime.md with the output the page shows."""
    text = (REPO_ROOT / "docs" / "runtime.md").read_text()
    blocks = re.findall(r"^```\n\$ (palpate [^\n]*)\n(.*?)```", text, re.M | re.S)
    return [(command, output) for command, output in blocks]


@pytest.mark.parametrize("command", [c for c, _ in runtime_doc_examples()])
def test_the_runtime_docs_examples_print_what_the_page_shows(command: str, tmp_path: Path) -> None:
    """Run with the installed `palpate` script from the repository root and no PYTHONPATH, as a reader would."""
    expected = dict(runtime_doc_examples())[command]
    script = Path(sys.executable).parent / "palpate"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PALPATE_BUS"] = str(tmp_path / "bus")  # a private bus: the examples print no bus directory of their own
    done = subprocess.run(
        [str(script), *shlex.split(command)[1:]], cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=60
    )
    printed = (done.stdout + done.stderr).replace(str(REPO_ROOT), "/path/to/palpate")
    assert printed == expected, f"exit code {done.returncode}"
    assert done.returncode == (2 if "palpate launch:" in expected else 0)


def test_errors_in_an_included_file_name_the_included_file(tmp_path: Path) -> None:
    child = tmp_path / "child.yaml"
    child.write_text("nodes:\n  - name: a\n    type: cube_contacts\n    colour: red\n")
    parent = tmp_path / "parent.yaml"
    parent.write_text("include:\n  - file: child.yaml\n")
    with pytest.raises(LaunchError, match=rf"^{child}:4: unknown node key 'colour'"):
        load(parent, tmp_path)


# --- arguments, includes, namespaces, remaps ------------------------------------------------------------


def test_argument_defaults(tmp_path: Path) -> None:
    graph = load(DATA / "with_args.yaml", tmp_path)
    cube, stats = graph.by_name["cube"], graph.by_name["stats"]
    assert cube.params == {"duration_s": 0.5, "edge_m": 0.05}
    assert graph.seed == 3
    assert stats.subscribes == {"contacts": "sensors/contacts"}  # an absolute remap ignores the namespace


def test_argument_overrides_from_the_command_line(tmp_path: Path) -> None:
    graph = load(DATA / "with_args.yaml", tmp_path, ["duration_s:=2.5", "seed:=9", "edge_m:=0.1"])
    assert graph.by_name["cube"].params == {"duration_s": 2.5, "edge_m": 0.1}
    assert graph.seed == 9
    specs = {s.name: s for s in graph.process_specs()}
    assert specs["cube"].params == {"duration_s": 2.5, "edge_m": 0.1}
    # node seeds derive from the launch seed, differ between nodes and do not depend on the process
    again = {s.name: s for s in load(DATA / "with_args.yaml", tmp_path, ["seed:=9"]).process_specs()}
    assert specs["cube"].seed == again["cube"].seed != specs["stats"].seed
    other = {s.name: s for s in load(DATA / "with_args.yaml", tmp_path, ["seed:=10"]).process_specs()}
    assert other["cube"].seed != specs["cube"].seed


def test_overridden_argument_values_are_validated(tmp_path: Path) -> None:
    with pytest.raises(
        LaunchError, match=r"with_args.yaml:14: node 'cube': params.edge_m: expected a finite number > 0, got 'wide'"
    ):
        load(DATA / "with_args.yaml", tmp_path, ["edge_m:=wide"])


def test_parse_cli_args() -> None:
    assert parse_cli_args(["a:=1", "b:=0.5", "c:=text", "d:=true", "e:="]) == {
        "a": 1,
        "b": 0.5,
        "c": "text",
        "d": True,
        "e": "",
    }
    with pytest.raises(LaunchError, match="must look like name:=value"):
        parse_cli_args(["a=1"])
    # YAML 1.2's floats too, which YAML 1.1 reads as text
    assert parse_cli_args(["a:=1e3", "b:=-2.5E-3", "c:=1.0e400"]) == {"a": 1000.0, "b": -0.0025, "c": float("inf")}
    # the last of two would win without a word (a launch file's keys may not repeat either)
    with pytest.raises(
        LaunchError, match=r"launch argument 'a' is given twice on the command line \('a:=1' and 'a:=2'\)"
    ):
        parse_cli_args(["a:=1", "b:=1", "a:=2"])
    with pytest.raises(LaunchError, match=r"--set 'sim.seed' is given twice on the command line"):
        parse_node_params(["sim.seed=1", "sim.seed=1"])
    with pytest.raises(ConfigError, match=r"--set 'gpis.gp.kernel': expected NODE.KEY=VALUE"):
        parse_node_params(["gpis.gp.kernel"])  # not "launch argument ... name=value": it is no launch argument


def test_a_bad_value_on_the_command_line_is_an_error_saying_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["launch", "--dry-run", str(DATA / "with_args.yaml"), "edge_m:=[", "--bus", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "launch argument 'edge_m:=[' from the command line: its value is not valid YAML" in err, err
    # a value that is YAML but wrong for the key: the error at the line of ${edge_m} names the override
    assert main(["launch", "--dry-run", str(DATA / "with_args.yaml"), "edge_m:=wide", "--bus", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "with_args.yaml:14: node 'cube': params.edge_m: expected a finite number > 0, got 'wide'" in err, err
    assert err.rstrip().endswith(" (from the command line: edge_m:=wide)"), err
    assert main(["launch", "--dry-run", str(DATA / "with_args.yaml"), "seed:=1e3", "--bus", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert (
        "with_args.yaml:8: seed must be an integer >= 0 (NumPy's generators take no negative seed), got 1000.0" in err
    )
    assert err.rstrip().endswith("(from the command line: seed:=1e3)"), err
    assert main(["launch", "--dry-run", str(DATA / "with_args.yaml"), "seed:=-300000", "--bus", str(tmp_path)]) == 2
    assert "with_args.yaml:8: seed must be an integer >= 0" in capsys.readouterr().err


def test_arguments_may_follow_options_in_any_order(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`palpate launch FILE --bus DIR NAME:=VALUE`: the order users type (issue 15)."""
    for argv in (
        ["launch", str(DATA / "with_args.yaml"), "--bus", str(tmp_path), "edge_m:=0.07", "--dry-run"],
        ["launch", "--dry-run", str(DATA / "with_args.yaml"), "edge_m:=0.07", "--bus", str(tmp_path)],
    ):
        assert main(argv) == 0
        out = capsys.readouterr().out
        assert f"bus {tmp_path})" in out
    # the late argument reaches the launch file: a bad value after --bus is the launch file's error
    assert main(["launch", str(DATA / "with_args.yaml"), "--bus", str(tmp_path), "edge_m:=wide", "--dry-run"]) == 2
    assert "params.edge_m: expected a finite number > 0, got 'wide'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["launch", str(DATA / "with_args.yaml"), "--bus", str(tmp_path), "edge_m:=0.07", "--nope"])
    assert exit_info.value.code == 2
    assert "unrecognized arguments: --nope" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a command without NAME:=VALUE arguments takes none after its options
        main(["topic", "list", "--bus", str(tmp_path), "edge_m:=0.07"])
    assert "unrecognized arguments: edge_m:=0.07" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # name=value after the options: it was "unrecognized arguments"
        main(["launch", str(DATA / "with_args.yaml"), "--bus", str(tmp_path), "edge_m=0.07"])
    assert "launch argument 'edge_m=0.07' must look like name:=value" in capsys.readouterr().err


def test_includes_bring_their_nodes_with_their_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    graph = load(DATA / "include_parent.yaml", tmp_path, ["duration_s:=0.3"])
    assert [n.name for n in graph.nodes] == ["left_stats", "right_stats", "cube"]
    assert graph.by_name["cube"].params == {"duration_s": 0.3}
    assert graph.by_name["left_stats"].params == {"report": True}  # the child's default
    assert graph.by_name["right_stats"].params == {"report": False}  # passed by the include
    assert graph.by_name["left_stats"].where.file == str(DATA / "include_child.yaml")
    assert graph.clock_source is graph.by_name["cube"]
    assert graph.by_name["cube"].rank == 0
    specs = {s.name: s for s in graph.process_specs()}
    assert specs["cube"].expected_subscribers == {
        "sensors/contacts": 2,
        "lockstep/ack": 2,
        "hello/left_stats": 1,
        "hello/right_stats": 1,
    }
    assert sorted(specs["cube"].lockstep_nodes) == ["left_stats", "right_stats"]
    recorded = {s.name: s for s in graph.process_specs(extra_subscribers=1)}
    assert recorded["cube"].expected_subscribers == {
        "sensors/contacts": 3,
        "lockstep/ack": 3,
        "hello/left_stats": 1,
        "hello/right_stats": 1,
    }
    assert main(["launch", "--dry-run", str(DATA / "include_parent.yaml"), "--bus", str(tmp_path)]) == 0
    assert "  sensors/contacts [ContactSet]: cube -> left_stats, right_stats" in capsys.readouterr().out


def test_namespaces_and_remaps_resolve_topics(tmp_path: Path) -> None:
    path = tmp_path / "ns.yaml"
    path.write_text(
        """
nodes:
  - name: cube
    type: cube_contacts
    namespace: /arm1/       # slashes around a namespace do not matter
  - name: plain
    type: contact_stats
    namespace: arm1         # default topic, prefixed: arm1/sensors/contacts
  - name: relative
    type: contact_stats
    namespace: arm1
    remaps: {contacts: sensors/contacts}   # a relative remap is prefixed too
  - name: absolute
    type: contact_stats
    namespace: other
    remaps: {contacts: /arm1/sensors/contacts}  # an absolute remap is taken as is
  - name: renamed
    type: contact_stats
    remaps: {contacts: arm1/sensors/contacts}   # no namespace: the remap is the topic
"""
    )
    graph = load(path, tmp_path)
    assert graph.by_name["cube"].publishes == {"contacts": "arm1/sensors/contacts"}
    for name in ("plain", "relative", "absolute", "renamed"):
        assert graph.by_name[name].subscribes == {"contacts": "arm1/sensors/contacts"}, name
    assert graph.topic_types() == {"arm1/sensors/contacts": "ContactSet"}


def test_remap_of_an_unknown_port(tmp_path: Path) -> None:
    path = tmp_path / "port.yaml"
    path.write_text("nodes:\n  - name: cube\n    type: cube_contacts\n    remaps:\n      contact: x\n")
    with pytest.raises(LaunchError, match=rf"^{path}:5: node 'cube' \(cube_contacts\) has no port 'contact'"):
        load(path, tmp_path)


def test_evaluator_may_read_truth(tmp_path: Path) -> None:
    text = (REPO_ROOT / DATA / "truth_topic.yaml").read_text().replace(MARKER, "")
    path = tmp_path / "truth.yaml"
    path.write_text(text.replace("    type: contact_stats\n", "    type: contact_stats\n    evaluator: true\n"))
    assert load(path, tmp_path).by_name["stats"].evaluator


def test_node_options(tmp_path: Path) -> None:
    path = tmp_path / "options.yaml"
    path.write_text(
        """
mode: realtime
nodes:
  - name: cube
    type: cube_contacts
    host: 127.0.0.1
    port: 47123
  - name: stats
    type: contact_stats
    respawn: true
    sigterm_timeout_s: 0.5
  - name: driver
    type: contact_stats
    external: true
  - name: sink
    type: contact_stats
    respawn: true
    max_restarts: 7
"""
    )
    graph = load(path, tmp_path)
    cube, stats, driver, sink = (graph.by_name[n] for n in ("cube", "stats", "driver", "sink"))
    assert cube.endpoint == "tcp://127.0.0.1:47123"
    assert stats.endpoint == f"ipc://{tmp_path}/stats.pub"
    assert (stats.respawn, stats.max_restarts, stats.sigterm_timeout_s) == (True, 3, 0.5)
    assert (driver.external, driver.respawn, sink.respawn, sink.max_restarts) == (True, False, True, 7)
    assert (cube.respawn, cube.max_restarts, cube.sigterm_timeout_s) == (False, 0, 5.0)
    assert graph.mode == "realtime"
    assert all(s.mode == "realtime" for s in graph.process_specs())


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("max_restarts: -1", "max_restarts must be finite, not negative and at most"),
        (
            "sigterm_timeout_s: .nan",
            "sigterm_timeout_s must be finite, not negative and at most 1,000,000,000, got nan",
        ),
        (
            "sigterm_timeout_s: .inf",
            "sigterm_timeout_s must be finite, not negative and at most 1,000,000,000, got inf",
        ),
        (
            "sigterm_timeout_s: 1e400",
            "sigterm_timeout_s must be finite, not negative and at most 1,000,000,000, got inf",
        ),
        ("max_restarts: 1.5", "max_restarts must be an integer"),
        ("sigterm_timeout_s: soon", "sigterm_timeout_s must be a number"),
        ("host: 7", "host must be a string"),
        ("port: 5601", "port needs a host; without one the node publishes over ipc"),
        ("host: 127.0.0.1\n    port: abc", "port must be an integer from 1 to 65535, got 'abc'"),
        ("host: 127.0.0.1\n    port: 70000", "port must be an integer from 1 to 65535, got 70000"),
        ("host: 127.0.0.1\n    port: 0", "port must be an integer from 1 to 65535, got 0"),
        ("curve_keys: /nonexistent/keys.json", "cannot read CurveZMQ key file"),
    ],
)
def test_bad_node_option_values(line: str, expected: str, tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(f"nodes:\n  - name: cube\n    type: cube_contacts\n    {line}\n")
    with pytest.raises(LaunchError, match=rf"^{path}:{3 + line.count(chr(10)) + 1}: {expected}"):
        load(path, tmp_path)


def test_two_nodes_cannot_bind_one_port(tmp_path: Path) -> None:
    path = tmp_path / "ports.yaml"
    path.write_text(
        "nodes:\n  - name: cube\n    type: cube_contacts\n    host: 127.0.0.1\n    port: 5999\n"
        "  - name: stats\n    type: contact_stats\n    host: 127.0.0.1\n    port: 5999\n"
    )
    expected = rf"^{path}:9: node 'stats' binds tcp://127.0.0.1:5999, the port node 'cube' \({path}:5\) binds at"
    with pytest.raises(LaunchError, match=expected):
        load(path, tmp_path)
    path.write_text(path.read_text().replace("    port: 5999\n", "", 1).replace("5999", "5600"))  # cube's default
    with pytest.raises(
        LaunchError, match=rf"^{path}:8: node 'stats' binds tcp://127.0.0.1:5600, the port node 'cube' \({path}:2\)"
    ):
        load(path, tmp_path)


@pytest.mark.parametrize(
    ("host_a", "host_b", "clash"),
    [
        ("localhost", "127.0.0.1", True),
        ("LOCALHOST", "localhost", True),
        ("0.0.0.0", "127.0.0.1", True),
        ("127.0.0.1", "*", True),
        ("127.0.0.1", "127.0.0.2", False),
    ],
)
def test_one_port_bound_under_two_names_of_one_interface_clashes(
    host_a: str, host_b: str, clash: bool, tmp_path: Path
) -> None:
    path = tmp_path / "ports.yaml"
    path.write_text(
        f"nodes:\n  - name: cube\n    type: cube_contacts\n    host: '{host_a}'\n    port: 5999\n"
        f"  - name: stats\n    type: contact_stats\n    host: '{host_b}'\n    port: 5999\n"
    )
    if clash:
        with pytest.raises(LaunchError, match=rf"^{path}:9: node 'stats' binds tcp://.*:5999, the port node 'cube'"):
            load(path, tmp_path)
    else:
        load(path, tmp_path)


def test_an_ipc_path_too_long_for_the_os_names_the_bus_option(tmp_path: Path) -> None:
    import zmq

    bus = tmp_path / ("b" * (zmq.IPC_PATH_MAX_LEN - len(f"{tmp_path}//stats.pub") + 1))
    with pytest.raises(LaunchError) as info:
        load(DATA / "with_args.yaml", bus)  # BUS/cube.pub is as long as the OS allows, BUS/stats.pub a byte longer
    message = str(info.value)
    where = f"{DATA / 'with_args.yaml'}:15"
    assert message.startswith(
        f"{where}: node 'stats': the socket path {bus}/stats.pub is {zmq.IPC_PATH_MAX_LEN + 1} bytes, "
    ), message
    assert "choose a shorter bus directory (--bus DIR or $PALPATE_BUS)" in message, message


@pytest.mark.parametrize("name", ["st/ats", "../stats", "", "-x", "a b", "stats.pub"])
def test_a_node_name_is_a_safe_file_name(name: str, tmp_path: Path) -> None:
    path = tmp_path / "name.yaml"
    path.write_text(f"nodes:\n  - type: cube_contacts\n    name: {name!r}\n")
    with pytest.raises(LaunchError, match=rf"^{path}:3: node name {re.escape(repr(name))} must be letters, digits"):
        load(path, tmp_path)
    assert list(tmp_path.iterdir()) == [path]


def test_lockstep_graph_needs_a_clock_source(tmp_path: Path) -> None:
    path = tmp_path / "noclock.yaml"
    path.write_text("# no clock\nnodes:\n  - name: sink\n    type: tests.integration.fake_nodes:CRASHER\n")
    with pytest.raises(LaunchError, match=rf"^{path}:2: a lockstep graph .* needs a clock source"):
        load(path, tmp_path)  # at the nodes key: the file has no mode key
    path.write_text("seed: 1\nmode: lockstep\n" + path.read_text())
    with pytest.raises(LaunchError, match=rf"^{path}:2: a lockstep graph"):
        load(path, tmp_path)  # at the mode key
    path.write_text(path.read_text().replace("mode: lockstep", "mode: realtime"))
    assert load(path, tmp_path).clock_source is None


def test_curve_keys_must_agree_across_links(tmp_path: Path) -> None:
    from palpate.commands.keys import write_keys
    from palpate.runtime.bus import make_curve_keys

    graph_key, other_key = tmp_path / "graph.key", tmp_path / "other.key"
    write_keys(graph_key, make_curve_keys())
    write_keys(other_key, make_curve_keys())

    def graph(cube_keys: Path | None, stats_keys: Path | None) -> Path:
        path = tmp_path / "curve.yaml"
        cube = f"\n    curve_keys: {cube_keys}" if cube_keys else ""
        stats = f"\n    curve_keys: {stats_keys}" if stats_keys else ""
        path.write_text(
            f"nodes:\n  - name: cube\n    type: cube_contacts\n    host: 127.0.0.1{cube}\n"
            f"  - name: stats\n    type: contact_stats\n    host: 127.0.0.1{stats}\n"
        )
        return path

    both = load(graph(graph_key, graph_key), tmp_path)
    assert both.by_name["cube"].curve == both.by_name["stats"].curve != {}
    with pytest.raises(LaunchError, match=r"curve.yaml:5: node 'cube' connects to 'stats', which has no CurveZMQ keys"):
        load(graph(graph_key, None), tmp_path)  # (the clock source connects to every node, for acknowledgements)
    with pytest.raises(LaunchError, match=r"curve.yaml:8: node 'stats' uses CurveZMQ keys but 'cube', which conn"):
        load(graph(None, graph_key), tmp_path)
    with pytest.raises(
        LaunchError, match=r"curve.yaml:5: node 'cube' connects to 'stats', which publishes with another"
    ):
        load(graph(graph_key, other_key), tmp_path)


def test_a_remote_nodes_spec_admits_the_recorder_the_launch_will_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--spec NAME --record` must list the recorder's public key that `launch --record` gives the
    recorder, or a keyed remote node refuses the recorder and never counts its subscriptions."""
    import zmq

    from palpate.commands.keys import write_keys
    from palpate.commands.launch import recorder_curve_keys
    from palpate.runtime.bus import make_curve_keys

    key = tmp_path / "graph.key"
    write_keys(key, make_curve_keys())
    path = tmp_path / "curve.yaml"
    path.write_text(
        f"nodes:\n  - name: cube\n    type: cube_contacts\n    host: 127.0.0.1\n    curve_keys: {key}\n"
        f"  - name: stats\n    type: contact_stats\n    host: 127.0.0.1\n    curve_keys: {key}\n    external: true\n"
    )
    recorder = recorder_curve_keys(load(path, tmp_path))
    assert recorder == recorder_curve_keys(load(path, tmp_path))  # the same in every process
    assert zmq.curve_public(recorder["secret"].encode()).decode() == recorder["public"]
    assert main(["launch", str(path), "--bus", str(tmp_path), "--spec", "stats", "--record", "x.mcap"]) == 0
    spec = json.loads(capsys.readouterr().out)
    assert recorder["public"] in spec["curve_clients"]
    assert main(["launch", str(path), "--bus", str(tmp_path), "--spec", "stats"]) == 0
    assert recorder["public"] not in json.loads(capsys.readouterr().out)["curve_clients"]
    key.unlink()
    write_keys(key, make_curve_keys())  # other graph keys, another recorder key
    assert recorder_curve_keys(load(path, tmp_path))["public"] != recorder["public"]


def test_launch_record_refuses_a_folder_or_an_existing_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    demo = str(REPO_ROOT / "launch" / "demo_minimal.yaml")
    assert main(["launch", demo, "--bus", str(tmp_path), "--record", str(tmp_path)]) == 2
    assert f"--record {tmp_path} is a directory; give a file name" in capsys.readouterr().err
    existing = tmp_path / "run.mcap"
    existing.write_bytes(b"precious")
    assert main(["launch", demo, "--bus", str(tmp_path), "--record", str(existing)]) == 2
    assert f"--record {existing} exists; pass --force" in capsys.readouterr().err
    assert existing.read_bytes() == b"precious"


def test_a_dry_run_checks_the_record_path_as_the_launch_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: `--dry-run --record EXISTING` said yes, and the launch then refused it."""
    demo = str(REPO_ROOT / "launch" / "demo_minimal.yaml")
    existing = tmp_path / "run.mcap"
    existing.write_bytes(b"precious")
    assert main(["launch", demo, "--bus", str(tmp_path), "--dry-run", "--record", str(existing)]) == 2
    assert f"--record {existing} exists; pass --force" in capsys.readouterr().err
    assert main(["launch", demo, "--bus", str(tmp_path), "--dry-run", "--record", str(existing), "--force"]) == 0
    inside_a_file = existing / "x.mcap"
    assert main(["launch", demo, "--bus", str(tmp_path), "--dry-run", "--record", str(inside_a_file)]) == 2
    assert f"--record {inside_a_file}: {existing} is not a folder" in capsys.readouterr().err
    later = tmp_path / "new" / "folder" / "run.mcap"
    assert main(["launch", demo, "--bus", str(tmp_path), "--dry-run", "--record", str(later)]) == 0
    assert not (tmp_path / "new").exists() and existing.read_bytes() == b"precious"  # a dry run makes nothing
    beside = tmp_path / "beside.mcap"
    assert main(["launch", demo, "--bus", str(tmp_path), "--dry-run", "--record", str(beside)]) == 0
    assert not beside.exists()


def test_a_repeated_external_option_adds_to_the_first(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An outside walkthrough: `--external sim --external noise` ran palpate's own sim (the second replaced
    the first), and the driver for the simulator waited for a spec that never came."""
    probe = str(REPO_ROOT / "launch" / "probe.yaml")
    assert main(["launch", probe, "--bus", str(tmp_path), "--dry-run", "--external", "sim", "--external", "noise"]) == 0
    out = capsys.readouterr().out
    assert "0. sim (sim)" in out and re.search(r"sim \(sim\) \S+ \[clock, external\]", out)
    assert re.search(r"noise \(noise\) \S+ \[external\]", out)


def test_a_relative_bus_directory_is_made_absolute(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An outside walkthrough: `--bus relbus` wrote ipc://relbus/... into an external node's spec, which a
    driver started in another folder could not reach."""
    monkeypatch.chdir(tmp_path)
    graph = load(REPO_ROOT / "launch" / "probe.yaml", Path("relbus"))
    assert graph.bus_dir == tmp_path / "relbus"
    assert all(spec.endpoint.startswith(f"ipc://{tmp_path}/relbus/") for spec in graph.process_specs())


def test_a_character_yaml_does_not_allow_is_named_with_file_and_line(tmp_path: Path) -> None:
    """A control character is a reader error, not a marked one: it escaped as a traceback naming
    '<unicode string>' (a review of the YAML-error commit)."""
    path = tmp_path / "ctrl.yaml"
    path.write_text("args:\n  a: 1\nnodes:\n  - name: x\x01\n")
    with pytest.raises(LaunchError, match=r"ctrl\.yaml:4: invalid YAML: the character '\\x01' is not allowed"):
        load_launch(path)


def test_output_piped_into_a_reader_that_stops_early_ends_quietly(monkeypatch: pytest.MonkeyPatch) -> None:
    """`palpate launch --dry-run F | head -1` and `palpate bag info LOG --json | head -c 10` ended with a
    BrokenPipeError traceback (an outside audit): palpate.cli ends them quietly, exit 0."""

    class ClosedPipe:
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self) -> None:
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.chdir(REPO_ROOT)
    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert main(["launch", "--dry-run", "launch/explore.yaml"]) == 0


def test_a_full_disk_ends_a_command_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: `eval explore --from-runs` onto a full disk ended in a matplotlib traceback
    whose last line was ENOSPC; any other OSError still raises."""
    import errno

    class FullDisk:
        def write(self, text: str) -> int:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "tables.md"))

        def flush(self) -> None:
            pass

    monkeypatch.chdir(REPO_ROOT)
    monkeypatch.setattr(sys, "stdout", FullDisk())
    assert main(["launch", "--dry-run", "launch/explore.yaml"]) == 1
    said = capsys.readouterr().err
    assert said.startswith("palpate launch: the disk is full (No space left on device writing ") and "--resume" in said

    class Denied(FullDisk):
        def write(self, text: str) -> int:
            raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(sys, "stdout", Denied())
    with pytest.raises(PermissionError):
        main(["launch", "--dry-run", "launch/explore.yaml"])


def test_a_yaml_merge_key_is_named_at_its_line(tmp_path: Path) -> None:
    path = tmp_path / "merge.yaml"
    path.write_text(
        "nodes:\n  - name: a\n    type: noise\n    params: &p\n      contacts: true\n"
        "  - name: b\n    type: noise\n    params:\n      <<: *p\n      joints: false\n"
    )
    with pytest.raises(LaunchError, match=rf"^{path}:9: a YAML merge key \('<<: \*anchor'\) is not read"):
        load(path, tmp_path)
    path.write_text(path.read_text().replace("<<: *p", "'<<': 1"))  # a quoted key is a plain (unknown) key
    with pytest.raises(LaunchError, match=r"params.<<: unknown key '<<'"):
        load(path, tmp_path)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (b"description: ok\nnodes: []\n\xff\xfe junk\n", r":3: not UTF-8 text \(byte 0xff\)"),
        (b"description: !!bool maybe\nnodes: []\n", r":1: cannot read 'maybe': not a valid bool"),
        (b"description: !!timestamp nope\nnodes: []\n", r":1: cannot read 'nope': not a valid timestamp"),
        (b"nodes: " + b"[" * 1000 + b"]" * 1000 + b"\n", r": nested too deeply to read"),
        (b"args:\n  a: &a [*a]\nnodes: []\n", r":2: an alias inside the collection it names"),
        (
            b"args:\n"
            + b"".join(f"  l{i}: &l{i} [{', '.join([f'*l{i - 1}' if i else 'lol'] * 10)}]\n".encode() for i in range(8))
            + b"nodes: []\n",
            r"more than 1,000,000 values once aliases are expanded",
        ),
        (b'include:\n  - file: "a\\0b"\nnodes: []\n', r":2: include file 'a\\x00b' is no usable path"),
        (b"include:\n  - file: " + b"x" * 5000 + b"\nnodes: []\n", r":2: include file 'x+' is no usable path"),
        (b"nodes:\n  - name: a\n    type: sim\n    max_restarts: " + b"9" * 400 + b"\n", r":4: max_restarts must be"),
        (b"nodes:\n  - name: a\n    type: '..:x'\n", r":3: node type '..:x': cannot import \.\."),
        (b"description: ok\nnodes:\n  - name: a\n    type: !!int\n", r":4: cannot read '': not a valid int"),
        (
            b"nodes:\n  - name: sim\n    type: sim\n    params: {tick_period_s: 1.0e+308}\n",
            r":4: node 'sim': params: tick_period_s = 1e\+308 must be a positive multiple",
        ),
    ],
    ids=[
        "binary",
        "bool-tag",
        "timestamp-tag",
        "deep",
        "recursive-alias",
        "alias-bomb",
        "nul-include",
        "long-include",
        "huge-int",
        "relative-type",
        "empty-int-tag",
        "huge-tick",
    ],
)
def test_a_fuzzed_launch_file_is_a_launch_error_never_a_traceback(text: bytes, expected: str, tmp_path: Path) -> None:
    """A fuzzer's finds: each raised a Python exception (or, the alias bomb, ran for minutes)."""
    path = tmp_path / "fuzzed.yaml"
    path.write_bytes(text)
    with pytest.raises(LaunchError, match=expected):
        load(path, tmp_path)


@pytest.mark.parametrize("value", ["2001-13-45", "!!bool maybe", "!!timestamp nope", "!!float x", "!!int"])
def test_a_fuzzed_command_line_value_is_a_launch_error(value: str) -> None:
    with pytest.raises(LaunchError, match=r"from the command line: its value is not valid YAML"):
        parse_cli_args([f"seed:={value}"])


def test_a_command_line_value_nested_too_deeply_is_a_launch_error() -> None:
    """A fuzzer's find: a RecursionError traceback."""
    with pytest.raises(LaunchError, match=r"^launch argument 'seed:=\[+' from the command line: nested too deeply"):
        parse_cli_args(["seed:=" + "[" * 5000])


@pytest.mark.parametrize(
    ("node", "expected"),
    [
        ("  - name: a\n    type: noise\n    params: 3\n", r":5: params must be a mapping$"),
        ("  - name: [a]\n    type: noise\n", r":3: name must be a string, got \['a'\]$"),
        ("  - name: 5\n    type: noise\n", r":3: name must be a string, got 5$"),
    ],
    ids=["params-not-a-mapping", "name-a-list", "name-a-number"],
)
def test_set_and_external_on_a_node_entry_of_the_wrong_shape_name_its_line(
    node: str, expected: str, tmp_path: Path
) -> None:
    """A fuzzer's finds: --set (and --external) on such a file raised AttributeError or TypeError."""
    path = tmp_path / "shape.yaml"
    path.write_text("mode: realtime\nnodes:\n" + node + "  - name: b\n    type: noise\n")
    named = "name must" in expected  # a bad name fails whichever node --set names; bad params only their node's
    for dotted in ("a.contacts", "b.contacts", "nobody.contacts") if named else ("a.contacts",):
        with pytest.raises(LaunchError, match=rf"^{re.escape(str(path))}{expected}"):
            apply_params(load_launch(path), [(dotted, True)])
    if named:
        with pytest.raises(LaunchError, match=rf"^{re.escape(str(path))}{expected}"):
            with_external(load_launch(path), ["b"])


def test_set_on_a_node_whose_params_have_no_value_sets_the_parameter(tmp_path: Path) -> None:
    path = tmp_path / "empty_params.yaml"
    path.write_text("nodes:\n  - name: a\n    type: cube_contacts\n    params:\n")
    launch = load_launch(path)
    apply_params(launch, [("a.edge_m", 0.1)])
    assert resolve(launch, bus_dir=tmp_path).by_name["a"].config.edge_m == 0.1


def test_external_on_the_command_line_marks_nodes_as_the_file_key_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    explore = REPO_ROOT / "launch" / "explore.yaml"
    assert main(["launch", "--dry-run", str(explore), "--external", "noise", "--bus", str(tmp_path)]) == 0
    marked = [line for line in capsys.readouterr().out.splitlines() if "[external]" in line]
    assert len(marked) == 1 and " noise (noise) " in marked[0], marked
    assert main(["launch", str(explore), "--external", "noise,planr", "--bus", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--external: no node ['planr'] in launch/explore.yaml; its nodes: ['controller', 'eval'," in err, err
    # the specs follow: probe.yaml's clock source lets its noise node trail, but never an external one
    probe = REPO_ROOT / "launch" / "probe.yaml"
    for external, trailing in (([], ["noise"]), (["--external", "noise"], [])):
        assert main(["launch", str(probe), *external, "--spec", "sim", "--bus", str(tmp_path)]) == 0
        assert json.loads(capsys.readouterr().out)["trailing_nodes"] == trailing


def test_a_planner_rating_by_the_variance_needs_a_gpis_node_that_gives_it(tmp_path: Path) -> None:
    explore = REPO_ROOT / "launch" / "explore.yaml"
    both = r"node 'planner' \(params.strategy\) and node 'gpis' \(params.vertex_variance"
    with pytest.raises(LaunchError, match=both):
        load(explore, tmp_path, ["strategy:=gpv", "variance:=none"])
    load(explore, tmp_path, ["strategy:=igef", "variance:=none"])  # IGEF needs none, and may have it
    load(explore, tmp_path, ["strategy:=igef"])
    launch = load_launch(explore, parse_cli_args(["strategy:=gpv"]))
    planner = next(entry for entry in launch.nodes if entry.fields["name"] == "planner")
    planner.fields["params"]["candidate_step_m"] = 0.004  # GP-V's candidates 4 mm apart, the variance's 5 mm
    with pytest.raises(LaunchError, match=r"disagree on surface/mesh:candidate_step_m: 0.004 here, 0.005 there"):
        resolve(launch, bus_dir=tmp_path)
    # a second GPIS node without the variance, on a topic no planner reads, is no disagreement
    two = tmp_path / "two_gpis.yaml"
    two.write_text(
        f"include:\n  - file: {explore}\n    args: {{strategy: gpv}}\nnodes:\n  - name: gpis_fast\n    type: gpis\n"
        "    params: {vertex_variance: none}\n    remaps: {surface: surface/mesh_fast}\n"
    )
    assert "gpis_fast" in [node.name for node in load(two, tmp_path).nodes]


def test_a_gpis_node_left_to_the_graph_gives_the_variance_only_to_a_planner_that_rates_by_it(tmp_path: Path) -> None:
    explore = REPO_ROOT / "launch" / "explore.yaml"

    def variance(graph: Graph, name: str = "gpis") -> str:
        node = graph.by_name[name]
        spec = next(s for s in graph.process_specs() if s.name == name)
        assert spec.params["vertex_variance"] == node.config.vertex_variance  # what the node process gets
        return str(node.config.vertex_variance)

    assert variance(load(explore, tmp_path)) == "none"  # IGEF, the launch file's default strategy
    assert "     vertex_variance: auto -> none (set by the graph)" in describe(load(explore, tmp_path)).splitlines()
    assert variance(load(explore, tmp_path, ["strategy:=gpv"])) == "candidates"
    assert variance(load(explore, tmp_path, ["strategy:=tour"])) == "none"
    assert variance(load(explore, tmp_path, ["strategy:=igef", "variance:=all"])) == "all"  # set, not left
    # a second GPIS node left to the graph, on a topic no planner reads, gives none
    two = tmp_path / "two_gpis.yaml"
    two.write_text(
        f"include:\n  - file: {explore}\n    args: {{strategy: gpv}}\nnodes:\n  - name: gpis_fast\n    type: gpis\n"
        "    params: {vertex_variance: auto}\n    remaps: {surface: surface/mesh_fast}\n"
    )
    graph = load(two, tmp_path)
    assert variance(graph) == "candidates" and variance(graph, "gpis_fast") == "none"


def test_set_overrides_a_node_parameter_and_the_log_keeps_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`palpate launch --set node.key=value`, as the evaluations take it: a GPIS knob that is no launch
    argument needed a copy of the launch file."""
    from palpate.commands.launch import launch_about, load_graph

    explore = REPO_ROOT / "launch" / "explore.yaml"
    graph = load_graph(explore, [], tmp_path, sets=["gpis.gp.kernel=gaussian", "noise.position_sigma_m=0.001"])
    assert graph.by_name["gpis"].config.gp.kernel == "gaussian"
    assert graph.by_name["noise"].config.position_sigma_m == 0.001
    about = launch_about(graph)
    assert json.loads(about["params"]) == {"gpis.gp.kernel": "gaussian", "noise.position_sigma_m": 0.001}
    assert "params" not in launch_about(load_graph(explore, [], tmp_path))  # nothing set, nothing said
    # an outside driver's log did not say that a driver played a node
    assert launch_about(load_graph(explore, [], tmp_path, external=["noise"]))["external"] == "noise"
    assert "external" not in about
    assert main(["launch", str(explore), "--set", "gpis.gp.kernl=gaussian", "--dry-run", "--bus", str(tmp_path)]) == 2
    assert "unknown key 'kernl'" in (err := capsys.readouterr().err) and "(with --set gpis.gp.kernl=gaussian)" in err
    # a mapping merges into the file's (mode and the region stay); an error names only the --set of its node
    fastslam = REPO_ROOT / "launch" / "fastslam.yaml"
    mapper = load_graph(fastslam, [], tmp_path, sets=["mapper.mapper={n_particles: 10}"]).by_name["mapper"]
    assert mapper.config.mapper.n_particles == 10 and mapper.config.mapper.mode == "fastslam"
    with pytest.raises(LaunchError) as info:
        load_graph(explore, ["object:=bogus"], tmp_path, sets=["gpis.gp.kernel=gaussian"])
    assert "--set" not in str(info.value)
    # the node a replay stands in for takes no --set: its data is the log's
    from palpate.record.mcap_io import LogWriter, schema_bytes

    log = tmp_path / "explore.mcap"
    with LogWriter(log) as writer:  # channels only: what replacing reads
        for topic, type_name in load_graph(explore, [], tmp_path).topic_types().items():
            writer.channel(topic, type_name, schema_bytes(type_name, 1))
    with pytest.raises(LaunchError, match=r"--set sim.tick_period_s: --replay stands in for that node"):
        load_graph(explore, [], tmp_path, replay=log, sets=["sim.tick_period_s=0.02"])


def test_a_mesh_file_that_is_not_there_is_named_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """It was named only by the simulator's process, after the launch had started the others."""
    explore = REPO_ROOT / "launch" / "explore.yaml"
    missing = ["object:=mesh", "mesh:=no_such_mesh.stl"]
    with pytest.raises(
        LaunchError, match=r"explore\.yaml:\d+: node 'sim' \(params\.scene\.object\.path\): no_such_mesh\.stl"
    ):
        load(explore, tmp_path, missing)
    assert main(["launch", str(explore), *missing, "--dry-run", "--bus", str(tmp_path)]) == 2
    assert "no_such_mesh.stl does not exist (resolved from " in capsys.readouterr().err
    # a node on another host may see another filesystem: an external simulator's mesh is its own
    assert main(["launch", str(explore), *missing, "--external", "sim", "--dry-run", "--bus", str(tmp_path)]) == 0
    capsys.readouterr()
    mesh = tmp_path / "cube.stl"
    mesh.write_text("solid cube\nendsolid cube\n")  # present: the simulator reads it at its start
    load(explore, tmp_path, ["object:=mesh", f"mesh:={mesh}"])
    monkeypatch.setenv("PALPATE_YCB_DIR", str(tmp_path / "no_folder"))
    with pytest.raises(LaunchError, match=r"node 'sim': ycb:011_banana: the YCB mesh folder was not found"):
        load(explore, tmp_path, ["object:=mesh", "mesh:=ycb:011_banana"])


def test_a_set_and_an_argument_on_one_parameter_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An outside walkthrough: `--set planner.strategy=gpv strategy:=igef` ran GP-V without a word."""
    from palpate.launch.loader import arguments_set_at

    explore = REPO_ROOT / "launch" / "explore.yaml"
    args = {"strategy": "igef", "object": "sphere", "seed": 3}
    assert arguments_set_at(explore, args, {"planner.strategy": "gpv"}) == {"planner.strategy": ["strategy"]}
    assert arguments_set_at(explore, args, {"sim.scene.object.kind": "cube"}) == {"sim.scene.object.kind": ["object"]}
    assert arguments_set_at(explore, args, {"sim.scene": {"object": {"kind": "cube"}}}) == {"sim.scene": ["object"]}
    # a mapping is merged key by key: the argument's value below it stays, so nothing is overruled
    assert arguments_set_at(explore, args, {"sim.scene": {"effector": "probe"}}) == {}
    assert arguments_set_at(explore, args, {"gpis.gp.R_m": 1.0, "planner.tour_sites": 6}) == {}
    assert main(["launch", str(explore), "strategy:=igef", "--set", "planner.strategy=gpv", "--dry-run"]) == 2
    assert "--set planner.strategy='gpv' and strategy:='igef' set the same parameter" in capsys.readouterr().err
    assert main(["launch", str(explore), "seed:=3", "--set", "planner.tour_sites=6", "--dry-run"]) == 0


def test_a_mesh_at_an_absurd_scale_is_named_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A part drawn in millimetres, read as metres: named by the simulator's process only, after the launch
    had started the others, although runtime.md says the launch checks everything first."""
    import trimesh

    explore = REPO_ROOT / "launch" / "explore.yaml"
    mesh = tmp_path / "part.stl"
    trimesh.creation.box(extents=[40.0, 30.0, 20.0]).export(mesh)  # 40 mm drawn as 40 m
    given = ["object:=mesh", f"mesh:={mesh}"]
    assert main(["launch", str(explore), *given, "--dry-run", "--bus", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert re.search(r"explore\.yaml:\d+: node 'sim' \(params\.scene\.object\.path\): .*part\.stl: absurd scale", err)
    assert "0.001 for millimetres (4 cm across), 0.01 for centimetres (40 cm across)" in err and "scale:=0.001" in err
    assert main(["launch", str(explore), *given, "scale:=0.001", "--dry-run", "--bus", str(tmp_path)]) == 0
    capsys.readouterr()
    # an external simulator reads its own files
    assert main(["launch", str(explore), *given, "--external", "sim", "--dry-run", "--bus", str(tmp_path)]) == 0


# --- more faults named at their file, line and key -------------------------------------------------------


def assert_refused(tmp_path: Path, name: str, text: str, at: str) -> None:
    """`text`, written as the launch file `name`, is a LaunchError that starts with its path and then
    matches `at` (a pattern: ':LINE: message')."""
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(LaunchError, match=rf"^{re.escape(str(path))}{at}"):
        load(path, tmp_path)


def test_a_seed_of_true_is_no_integer(tmp_path: Path) -> None:
    assert_refused(
        tmp_path,
        "seed.yaml",
        "seed: true\nnodes:\n  - name: cube\n    type: cube_contacts\n",
        r":1: seed must be an integer >= 0 .*, got True$",
    )


def test_a_node_without_a_type_is_named_at_its_entry(tmp_path: Path) -> None:
    assert_refused(
        tmp_path,
        "untyped.yaml",
        "mode: realtime\nnodes:\n  - name: cube\n    params: {}\n",
        r":3: node needs a 'type'$",
    )


def test_an_include_error_is_named_at_the_line_of_its_file_key(tmp_path: Path) -> None:
    assert_refused(
        tmp_path,
        "parent.yaml",
        "include:\n  - args: {report: true}\n    file: missing.yaml\nnodes: []\n",
        r":3: included launch file .*missing.yaml does not",
    )


def test_a_file_that_includes_itself_is_named_at_the_include(tmp_path: Path) -> None:
    path = tmp_path / "self.yaml"
    path.write_text("include:\n  - file: self.yaml\nnodes: []\n")
    where = re.escape(str(path))
    with pytest.raises(LaunchError, match=rf"^{where}:2: include cycle: {where} -> {where}$"):
        load(path, tmp_path)


def test_an_impossible_date_says_what_is_wrong_with_it(tmp_path: Path) -> None:
    assert_refused(
        tmp_path,
        "date.yaml",
        "description: ok\nnodes: []\nmode: 2001-13-45\n",
        r":3: cannot read '2001-13-45': month must be in",
    )


@pytest.mark.parametrize(("port", "ok"), [(65535, True), (65536, False), (1, True)])
def test_the_highest_port_is_65535(port: int, ok: bool, tmp_path: Path) -> None:
    path = tmp_path / "port.yaml"
    path.write_text(
        f"mode: realtime\nnodes:\n  - name: cube\n    type: cube_contacts\n    host: 127.0.0.1\n    port: {port}\n"
    )
    if ok:
        assert load(path, tmp_path).by_name["cube"].endpoint == f"tcp://127.0.0.1:{port}"
        return
    with pytest.raises(LaunchError, match=rf"^{re.escape(str(path))}:6: port must be an integer from 1 to 65535, got"):
        load(path, tmp_path)


def test_respawn_needs_realtime(tmp_path: Path) -> None:
    assert_refused(
        tmp_path,
        "respawn.yaml",
        "nodes:\n  - name: cube\n    type: cube_contacts\n"
        "  - name: stats\n    type: contact_stats\n    respawn: true\n",
        r":6: node 'stats': respawn needs 'mode: realtime'",
    )


def test_a_graph_has_one_clock_source(tmp_path: Path) -> None:
    assert_refused(
        tmp_path,
        "clocks.yaml",
        "nodes:\n  - name: cube\n    type: cube_contacts\n"
        "  - name: cube2\n    type: cube_contacts\n    remaps: {contacts: other/contacts}\n",
        r":4: two clock sources \(cube, cube2\); keep one$",
    )


def test_a_missing_file_a_node_reads_is_named_at_its_key(tmp_path: Path) -> None:
    path = tmp_path / "mesh.yaml"
    path.write_text(
        "nodes:\n  - name: sim\n    type: sim\n    params:\n      scene:\n        object:\n"
        "          kind: mesh\n          path: no_such_mesh.stl\n"
    )
    with pytest.raises(
        LaunchError, match=rf"^{re.escape(str(path))}:8: node 'sim' \(params.scene.object.path\): no_such_mesh.stl does"
    ):
        load(path, tmp_path)


@pytest.mark.parametrize("item", [":=3", "seed"])
def test_a_command_line_argument_needs_a_name_and_a_value(item: str) -> None:
    with pytest.raises(LaunchError, match=rf"^launch argument '{item}' must look like name:=value$"):
        parse_cli_args([item])


def test_a_set_parameter_names_node_and_key() -> None:
    assert parse_node_params(["cube.edge_m=0.1"]) == {"cube.edge_m": 0.1}
    with pytest.raises(ConfigError, match=r"^--set 'seed': expected NODE.KEY=VALUE"):
        parse_node_params(["seed=3"])
    launch = load_launch(DATA / "with_args.yaml")
    for dotted in ("cube.", "nobody.edge_m"):
        with pytest.raises(ConfigError, match=rf"^parameter override '{dotted}': expected node.key with node one of"):
            apply_params(launch, [(dotted, 1)])


@pytest.mark.parametrize("topic", ["''", "/", "null", "5", "[a]"])
def test_a_remap_to_no_topic_is_named_at_its_line(topic: str, tmp_path: Path) -> None:
    """A fuzzer's finds: '' and '/' subscribed to every topic (a ZeroMQ prefix), null became the topic 'None'."""
    assert_refused(
        tmp_path,
        "remap.yaml",
        "nodes:\n  - name: cube\n    type: cube_contacts\n  - name: estimator\n    type: bbox_estimator\n"
        f"    remaps:\n      mesh: {topic}\n",
        r":7: node 'estimator' remaps port 'mesh' to .*; a topic is a non-empty string$",
    )


@pytest.mark.parametrize("topic", ["clock", "/status", "graph/control", "lockstep/ack", "hello/cube"])
def test_a_remap_onto_the_runtimes_own_topics_is_named_at_its_line(topic: str, tmp_path: Path) -> None:
    """A port remapped onto a topic the runtime publishes on (a mesh on `clock`) passed --dry-run."""
    assert_refused(
        tmp_path,
        "remap.yaml",
        "nodes:\n  - name: cube\n    type: cube_contacts\n  - name: estimator\n    type: bbox_estimator\n"
        f"    remaps:\n      mesh: {topic}\n",
        r":7: node 'estimator' remaps port 'mesh' to the runtime's own topic",
    )


def test_an_error_that_echoes_a_huge_value_prints_its_start_and_end(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A launch fuzzer's find: an undeclared argument name of 200,000 characters made a 200 kB error line."""
    path = tmp_path / "huge.yaml"
    path.write_text("nodes:\n  - name: cube\n    type: cube_contacts\n")
    name = "x" * 200_000
    assert main(["launch", str(path), "--dry-run", f"{name}:=1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("palpate launch: ") and len(err) < 4100
    assert "characters left out" in err


def test_a_launch_file_that_never_ends_is_refused_unread() -> None:
    with pytest.raises(LaunchError, match=r"/dev/zero: larger than 16 MiB: not a launch file"):
        load_launch("/dev/zero")  # read to its end: MemoryError, or the kernel's OOM killer


GRAPH_OF_TWO = (
    "mode: realtime\nnodes:\n  - name: cube\n    type: cube_contacts\n{cube}  - name: stats\n    type: contact_stats\n"
)


def test_respawn_on_an_external_node_is_refused_at_its_line(tmp_path: Path) -> None:
    """An outside walkthrough: it was accepted (`[external, respawn]` in --dry-run) and did nothing."""
    path = tmp_path / "g.yaml"
    path.write_text(GRAPH_OF_TWO.format(cube="    external: true\n    respawn: true\n"))
    expected = "node 'cube' is external: its driver starts it, and restarts it"
    with pytest.raises(LaunchError, match=f"^{re.escape(str(path))}:6: {re.escape(expected)}"):
        load(path, tmp_path)


def test_external_on_the_command_line_leaves_restarts_to_the_driver(tmp_path: Path) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(GRAPH_OF_TWO.format(cube="    respawn: true\n"))
    graph = resolve(with_external(load_launch(path), ["cube"]), bus_dir=tmp_path)
    cube = next(n for n in graph.nodes if n.name == "cube")
    assert cube.external and not cube.respawn


@pytest.mark.parametrize(("text", "expected"), [("010", "'010'"), ("1:30", "'1:30'"), ("1:30.5", "'1:30.5'")])
def test_yaml_1_1_octal_and_base_60_numbers_are_text_a_number_refuses(text: str, expected: str, tmp_path: Path) -> None:
    """An outside walkthrough: `duration_s: 1:30` ran 90 s and `seed:=010` seed 8 (YAML 1.1's base 60 and octal)."""
    assert parse_cli_args([f"x:={text}"]) == {"x": text}
    with pytest.raises(
        LaunchError, match=f"params.duration_s: expected a finite number > 0, got {re.escape(expected)}"
    ):
        load(REPO_ROOT / "launch" / "probe.yaml", tmp_path, [f"duration_s:={text}"])
    assert parse_cli_args(["a:=10", "b:=0x10", "c:=1_000", "d:=0", "e:=1e3", "f:=010.5"]) == {
        "a": 10,
        "b": 16,
        "c": 1000,
        "d": 0,
        "e": 1000.0,
        "f": 10.5,
    }


@pytest.mark.parametrize(
    ("file", "expected"),
    [("", "include 'file' must name a launch file, got None"), (".", "is a folder, not a launch file")],
)
def test_an_include_without_a_file_name_says_so(file: str, expected: str, tmp_path: Path) -> None:
    path = tmp_path / "a.yaml"
    path.write_text(f"include:\n  - file: {file}\n")
    with pytest.raises(LaunchError, match=f"^{re.escape(str(path))}:2: .*{re.escape(expected)}"):
        load_launch(path)


def test_a_bad_command_line_value_passed_on_by_an_include_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    """An outside walkthrough: the '(from the command line: ...)' note was only for errors in the top file."""
    assert main(["launch", "--dry-run", "launch/demo.yaml", "strategy:=bogus"]) == 2
    err = capsys.readouterr().err
    assert "launch/explore.yaml:" in err and "got 'bogus' (from the command line: strategy:=bogus)" in err


def test_record_to_the_log_being_replayed_is_refused_under_any_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: `--replay same.mcap --record same.mcap --force` emptied the log it replayed."""
    demo = str(REPO_ROOT / "launch" / "demo_minimal.yaml")
    log = tmp_path / "run.mcap"
    log.write_bytes(b"precious")
    (tmp_path / "hard.mcap").hardlink_to(log)
    (tmp_path / "soft.mcap").symlink_to(log)
    for name in ("run.mcap", "hard.mcap", "soft.mcap"):
        args = ["launch", demo, "--bus", str(tmp_path), "--replay", str(log), "--record", str(tmp_path / name)]
        assert main([*args, "--force"]) == 2
        assert "is the log --replay reads" in capsys.readouterr().err
    assert log.read_bytes() == b"precious"


def test_a_ctrl_c_that_a_library_swallows_while_the_graph_loads_still_ends_the_launch(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An outside walkthrough: Ctrl-C while trimesh was imported (its optional imports catch BaseException)
    was lost, and the launch ran the whole graph and exited 0."""
    import signal

    from palpate.commands import launch

    original = launch._load_graph

    def load_swallowing(*args: Any, **kwargs: Any) -> Any:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler runs between two bytecodes of this loop
                pass
        except BaseException:
            pass
        return original(*args, **kwargs)

    def must_not_run(*args: Any, **kwargs: Any) -> int:
        raise AssertionError("the graph started after Ctrl-C")

    monkeypatch.setattr(launch, "_load_graph", load_swallowing)
    monkeypatch.setattr(launch, "run_graph", must_not_run)
    assert main(["launch", "launch/probe.yaml"]) == 130
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_commands_that_no_node_reads_are_refused(tmp_path: Path) -> None:
    """An outside walkthrough: launch/explore.yaml with `effector: hand` ran to its end (exit 0) while the
    planner and controller steered nothing: the scripted hand reads no velocity commands."""
    text = (REPO_ROOT / "launch" / "explore.yaml").read_text()
    path = tmp_path / "explore_hand.yaml"
    path.write_text(re.sub(r"\n\s*probe:.*", "", text.replace("effector: probe", "effector: hand")))
    with pytest.raises(LaunchError, match=r"node 'controller' commands on 'commands/velocity' .*which no node reads"):
        load(path, tmp_path)
    load(REPO_ROOT / "launch" / "explore.yaml", tmp_path)  # the probe reads them


def test_a_dry_run_refuses_an_object_the_scripted_finger_cannot_reach(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: --dry-run passed a 3 mm cube under the finger, and the run's sim then
    failed at its start."""
    args = ["launch", "--dry-run", "launch/map_known.yaml", "--bus", str(tmp_path)]
    small = ["--set", "sim.scene.object={kind: cube, size_m: 0.003}"]
    mount = ["--set", "mapper.mount.base_position_m=[-0.06962,0.035,0.0515]"]  # where the sim puts the finger
    assert main([*args, *small, *mount]) == 2
    err = capsys.readouterr().err
    assert "map_known.yaml:18: node 'sim' (params.scene): the finger's fingertip cannot reach the object" in err
    assert "(3 mm across)" in err and "finger_mcp_offset_m=[0,0.01,0.05]" in err
    offset = [
        "--set",
        "sim.scene.finger_mcp_offset_m=[0,0.01,0.05]",
        "--set",
        "mapper.mount.base_position_m=[-0.06962,0.01,0.0515]",
    ]
    assert main([*args, *small, *offset]) == 0, capsys.readouterr().err


def test_an_argument_default_that_uses_another_argument_says_so(tmp_path: Path) -> None:
    """An outside walkthrough: `args: {a: "${b}", b: 1}` said "unknown argument ${b}; declared: []"."""
    path = tmp_path / "args.yaml"
    path.write_text('args: {a: "${b}", b: 1}\nnodes: []\n')
    with pytest.raises(LaunchError, match=r"args\.yaml:1: an argument's default cannot use another argument"):
        load_launch(path)
