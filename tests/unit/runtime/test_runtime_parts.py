"""Socket-free parts of the runtime: node-type registry, manifests, subscription counting."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.config import Validated
from palpate.errors import BusError, ConfigError, EstimationError, LaunchError
from palpate.launch.node_types import NODE_TYPES, load_node_type
from palpate.launch.supervisor import external_spec_path, write_external_spec
from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import ContactSet, LockstepAck, TouchEvent
from palpate.runtime import bus
from palpate.runtime.node import _latest_state_messages
from palpate.runtime.spec import NodeProcessSpec, NodeSpec


@pytest.fixture(autouse=True)
def _signal_handlers_kept() -> Iterator[None]:
    """A NodeRunner installs its SIGINT and SIGTERM handlers in this process: put pytest's back after."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, handler in previous.items():
        signal.signal(s, handler)


def test_registry_resolves_builtin_and_module_attribute_types() -> None:
    assert load_node_type("cube_contacts").clock_source
    spec = load_node_type("tests.integration.fake_nodes:CRASHER")
    assert isinstance(spec, NodeSpec) and spec.name == "crasher"
    assert "cube_contacts" in NODE_TYPES


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("no_such_type", "unknown node type 'no_such_type'"),
        ("no.such.module:SPEC", "cannot import no.such.module"),
        ("tests.integration.fake_nodes:NOTHING", "has no NodeSpec named NOTHING"),
        ("tests.integration.fake_nodes:CrasherConfig", "has no NodeSpec named CrasherConfig"),
    ],
)
def test_registry_errors(name: str, message: str) -> None:
    with pytest.raises(LaunchError, match=message):
        load_node_type(name)


def test_process_spec_json_round_trip() -> None:
    spec = NodeProcessSpec(
        name="stats",
        type="contact_stats",
        node_spec="palpate.nodes.demo.node:CONTACT_STATS",
        params={"report": False},
        bus_dir="/tmp/bus",
        endpoint="ipc:///tmp/bus/stats.pub",
        publishes={},
        subscribes={"contacts": "sensors/contacts"},
        connect=["ipc:///tmp/bus/cube.pub"],
        expected_subscribers={"lockstep/ack": 1},
        forward_upstream=["a"],
        curve={"public": "p", "secret": "s", "server_public": "q"},
    )
    assert NodeProcessSpec.from_json(spec.to_json()) == spec
    assert json.loads(spec.to_json())["mode"] == "lockstep"


def test_an_external_spec_with_its_secret_key_is_readable_by_its_owner_only(tmp_path: Path) -> None:
    spec = NodeProcessSpec(
        name="noise",
        type="noise",
        node_spec="palpate.nodes.noise.node:SPEC",
        params={},
        bus_dir=str(tmp_path),
        endpoint="tcp://127.0.0.1:5555",
        publishes={},
        subscribes={},
        connect=[],
        expected_subscribers={},
        curve={"public": "p", "secret": "s", "server_public": "q"},
    )
    path = write_external_spec(tmp_path, spec)
    assert path == external_spec_path(tmp_path, "noise") and NodeProcessSpec.from_json(path.read_text()) == spec
    assert (path.stat().st_mode & 0o777, path.parent.stat().st_mode & 0o777) == (0o600, 0o700)
    write_external_spec(tmp_path, spec)  # a second launch replaces it
    assert path.stat().st_mode & 0o777 == 0o600


def test_manifests_list_live_publishers_only(tmp_path: Path) -> None:
    live = bus.Manifest("cube", "ipc://x", os.getpid(), {"sensors/contacts": "ContactSet"}, {})
    live.write(tmp_path)
    dead = bus.Manifest("ghost", "ipc://y", 2**22 + 12345, {"sensors/contacts": "ContactSet"}, {})  # no such pid
    dead.write(tmp_path)
    (tmp_path / "garbage.json").write_text("{not json")
    assert bus.read_manifests(tmp_path) == [live]
    assert bus.publishers_of(tmp_path) == {"sensors/contacts": [live]}
    assert bus.publishers_of(tmp_path, ["status"]) == {}
    assert not list(tmp_path.glob("*.tmp"))  # written atomically


def test_default_bus_dir_follows_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(bus.BUS_ENV, str(tmp_path / "bus"))
    assert bus.default_bus_dir() == tmp_path / "bus"
    assert (tmp_path / "bus").is_dir()
    assert bus.ipc_endpoint(tmp_path, "cube") == f"ipc://{tmp_path}/cube.pub"


def test_a_file_where_the_bus_directory_should_be_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    file = tmp_path / "file"
    file.write_text("")
    assert bus.usable_dir(tmp_path / "new" / "bus") == tmp_path / "new" / "bus"
    with pytest.raises(BusError, match=rf"^bus directory {file} is not a directory; choose a bus directory with --bus"):
        bus.usable_dir(file)
    with pytest.raises(BusError, match=rf"^bus directory {file}/bus: {file} is not a directory"):
        bus.usable_dir(file / "bus")
    monkeypatch.setenv(bus.BUS_ENV, str(file))
    with pytest.raises(BusError, match=rf"^bus directory {file} is not a directory"):
        bus.default_bus_dir()
    bus.remove_ipc_file(bus.ipc_endpoint(file, "cube"))  # nothing to remove: no error either


def test_default_bus_dir_is_private_in_the_runtime_dir_or_the_temp_dir(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(bus.BUS_ENV, raising=False)
    runtime = tmp_path / "run-user"
    runtime.mkdir(mode=0o700)
    monkeypatch.setenv(bus.RUNTIME_DIR_ENV, str(runtime))
    assert bus.default_bus_dir() == runtime / "palpate" / "default"
    assert stat.S_IMODE((runtime / "palpate").stat().st_mode) == 0o700
    monkeypatch.delenv(bus.RUNTIME_DIR_ENV)  # no runtime dir (a container, cron): a 0700 dir in the temp dir
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    base = tmp_path / f"palpate-{os.getuid()}"
    assert bus.default_bus_dir() == base / "default"
    assert stat.S_IMODE(base.stat().st_mode) == 0o700 and base.stat().st_uid == os.getuid()
    assert bus.default_bus_dir() == base / "default"  # an existing private directory is fine


def test_an_unsafe_bus_directory_is_refused_or_closed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    open_dir = tmp_path / "open"  # yours but open, as an older palpate made it: closed, not refused
    open_dir.mkdir()
    open_dir.chmod(0o755)
    assert bus.private_dir(open_dir) == open_dir and stat.S_IMODE(open_dir.stat().st_mode) == 0o700
    target = tmp_path / "elsewhere"
    target.mkdir(mode=0o700)
    planted = tmp_path / "planted"
    planted.symlink_to(target)
    with pytest.raises(BusError, match="not a directory but a symlink"):
        bus.private_dir(planted)
    (tmp_path / "file").write_text("")
    with pytest.raises(BusError, match="not a directory but a file"):
        bus.private_dir(tmp_path / "file")
    if os.geteuid() == 0:  # only root can give a directory to someone else
        theirs = tmp_path / "theirs"
        theirs.mkdir(mode=0o700)
        os.chown(theirs, 12345, 12345)
        with pytest.raises(BusError, match="belongs to uid 12345"):
            bus.private_dir(theirs)
    monkeypatch.delenv(bus.BUS_ENV, raising=False)
    monkeypatch.delenv(bus.RUNTIME_DIR_ENV, raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    (tmp_path / f"palpate-{os.getuid()}").symlink_to(target)  # planted before the user's first run
    with pytest.raises(BusError, match="symlink"):
        bus.default_bus_dir()


def test_subscription_counter() -> None:
    counter = bus.SubscriptionCounter()
    expected = {"sensors/contacts": 2, "lockstep/ack": 1}
    assert counter.missing(expected) == expected
    for frame in (b"\x01sensors/contacts", b"\x01sensors/contacts", b"\x01lockstep/ack", b"\x00lockstep/ack", b""):
        counter.feed(frame)
    assert not counter.satisfied(expected)
    assert counter.missing(expected) == {"lockstep/ack": 1}
    counter.feed(b"\x01lockstep/ack")
    assert counter.satisfied(expected)


def _contacts(stamp: int) -> bytes:
    return codec.encode(
        ContactSet(
            stamp_ns=stamp,
            positions_m=np.zeros((1, 3)),
            local_positions_m=np.zeros((1, 3)),
            normals=np.zeros((1, 3)),
            forces_n=np.zeros(1),
            links=["tip"],
        )
    )


def test_realtime_keeps_only_the_latest_state_message_but_every_event() -> None:
    types = {"sensors/contacts": ContactSet, "controller/events": TouchEvent}
    batch = [
        (0, 0, 1, "sensors/contacts", _contacts(1)),
        (0, 0, 2, "controller/events", b"e1"),
        (0, 0, 3, "sensors/contacts", _contacts(2)),
        (0, 0, 4, "controller/events", b"e2"),
        (0, 0, 5, "sensors/contacts", _contacts(3)),
    ]
    kept = _latest_state_messages(batch, types)  # type: ignore[arg-type]
    assert [seq for _, _, seq, _, _ in kept] == [2, 4, 5]


@pytest.mark.parametrize("failed", [False, True])
def test_in_process_graph_keeps_the_stop_reason_and_whether_it_was_a_failure(tmp_path: Path, failed: bool) -> None:
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.paths import LAUNCH_DIR
    from palpate.runtime.inprocess import InProcessGraph

    launch = tmp_path / "quits.yaml"
    launch.write_text(
        (LAUNCH_DIR / "demo_minimal.yaml").read_text()
        + "  - name: quitter\n    type: tests.integration.fake_nodes:QUITTER\n"
        f"    params: {{after_ticks: 3, failed: {str(failed).lower()}}}\n"
    )
    graph = InProcessGraph(resolve(load_launch(launch), bus_dir=tmp_path / "bus").in_process_members())
    assert graph.run(max_ticks=50) == 3
    assert graph.stop_reason == "quitter: done after 3 ticks"
    assert graph.failure == (graph.stop_reason if failed else "")


def test_in_process_graph_ends_as_a_failure_when_the_clock_goes_back(tmp_path: Path) -> None:
    """As the process runtime: a lockstep clock runs forward (a log's clock that went back, replayed)."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.runtime.inprocess import InProcessGraph

    launch = tmp_path / "back.yaml"
    launch.write_text(
        "nodes:\n  - name: clock\n    type: tests.integration.fake_nodes:FAILING_CLOCK\n"
        "    params: {after_ticks: 1000, back_at_tick: 4}\n"
        "  - name: quitter\n    type: tests.integration.fake_nodes:QUITTER\n    params: {after_ticks: 1000}\n"
    )
    graph = InProcessGraph(resolve(load_launch(launch), bus_dir=tmp_path / "bus").in_process_members())
    assert graph.run(max_ticks=50) == 3
    assert (
        graph.failure
        == graph.stop_reason
        == (
            "clock: the clock's stamp at tick 3 is 0 ns, before tick 2's 30000000 ns: a lockstep clock runs forward "
            "(a log recorded in real time whose clock went back replays with mode:=realtime)"
        )
    )


def test_in_process_graph_refuses_nodes_out_of_rank_order(tmp_path: Path) -> None:
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.paths import LAUNCH_DIR
    from palpate.runtime.inprocess import InProcessGraph

    members = resolve(load_launch(LAUNCH_DIR / "demo_minimal.yaml"), bus_dir=tmp_path).in_process_members()
    assert InProcessGraph(members).run(max_ticks=2) == 2
    with pytest.raises(ValueError, match="rank order"):
        InProcessGraph(members[::-1])


@dataclasses.dataclass(frozen=True, kw_only=True)
class NoParams(Validated):
    """No parameters."""


def refuse_to_start(config: NoParams, ctx: Any) -> Any:
    raise EstimationError("this node cannot start")


def recorded_transfers(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The messages the in-process executor transfers from now on (codec.transfer still does the work),
    in order."""
    from palpate.runtime import inprocess

    recorded: list[Any] = []
    real = codec.transfer

    def recording(message: Any) -> Any:
        recorded.append(message)
        return real(message)

    monkeypatch.setattr(inprocess.codec, "transfer", recording)
    return recorded


def bare_process(bus_dir: Path, name: str, **fields: Any) -> NodeProcessSpec:
    """The process spec of a real-time node `name` that publishes and reads nothing, on `bus_dir`."""
    return NodeProcessSpec(
        name=name,
        type=name,
        node_spec="tests:unused",
        params={},
        bus_dir=str(bus_dir),
        endpoint=f"ipc://{bus_dir}/{name}.pub",
        publishes={},
        subscribes={},
        connect=[],
        mode="realtime",
        **fields,
    )


def test_a_node_that_fails_to_start_leaves_no_socket_file(tmp_path: Path) -> None:
    from palpate.runtime.node import NodeRunner

    process = bare_process(tmp_path, "refuser")
    spec = NodeSpec(name="refuser", config=NoParams, factory=refuse_to_start)
    with pytest.raises(EstimationError, match="cannot start"):
        NodeRunner(spec, process)
    assert not (tmp_path / "refuser.pub").exists()
    with pytest.raises(ConfigError, match="unknown key 'speed'"):  # checked before any socket is bound
        NodeRunner(spec, dataclasses.replace(process, params={"speed": 1}))
    assert not (tmp_path / "refuser.pub").exists()


def test_nodes_that_may_trail_and_feed_nothing_back_trail_the_clock(tmp_path: Path) -> None:
    """Trailing nodes: not external, NodeSpec.may_trail, and no chain of topics from them to the clock source;
    lockstep only. The clock source's process spec lists them with TRAIL_TICKS."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch, parse_cli_args
    from palpate.paths import LAUNCH_DIR
    from palpate.runtime.spec import TRAIL_TICKS

    def trailing(name: str, *args: str) -> list[str]:
        graph = resolve(load_launch(LAUNCH_DIR / name, parse_cli_args(list(args))), bus_dir=tmp_path)
        names = [n.name for n in graph.trailing_nodes()]
        clock = next(p for p in graph.process_specs() if p.clock_source)
        assert clock.trailing_nodes == names and clock.trail_ticks == (TRAIL_TICKS if names else 0)
        return names

    assert trailing("probe.yaml") == ["noise"]  # the driver closes the loop; nothing reads the noisy contacts
    assert trailing("fastslam.yaml") == ["noise", "mapper"]
    assert trailing("explore.yaml") == []  # the noisy contacts feed the controller, which commands the sim
    launch = tmp_path / "graph.yaml"
    text = (LAUNCH_DIR / "probe.yaml").read_text()
    launch.write_text(text.replace("    type: noise\n", "    type: noise\n    external: true\n"))
    assert trailing(str(launch)) == []  # a driver speaks the plain protocol
    launch.write_text(text.replace("mode: lockstep", "mode: realtime"))
    assert trailing(str(launch), "placement:=os") == []  # (placement loop is for lockstep only)


def test_a_node_that_may_trail_cannot_stop_the_run() -> None:
    """may_trail promises that the node never ends a run (the clock may be ticks ahead of it): asking is a bug."""
    from palpate.runtime.node import NodeContext

    ctx = NodeContext("sink", 0, lambda topic, message: None, {}, may_stop=False)
    with pytest.raises(RuntimeError, match=r"node 'sink' asked to stop the run \(done\).*may_trail"):
        ctx.request_stop("done")
    assert ctx.stop_requested == ""


def test_in_process_a_message_on_a_second_topic_nobody_reads_is_not_checked_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The finger sim publishes each JointState on joint_states (read by the noise node: transferred, so
    checked) and then on truth/joint_states (read by no node): the executor does not validate it again."""
    from palpate.bench.sim import FALLBACK_OBJECT, SimBenchConfig, scene_launch
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch, parse_cli_args
    from palpate.messages import codec
    from palpate.runtime import inprocess

    validated: list[str] = []
    real = codec.validate

    def counting(message: Any) -> None:
        validated.append(message.TYPE)
        real(message)

    monkeypatch.setattr(inprocess.codec, "validate", counting)
    launch, args = scene_launch("finger", FALLBACK_OBJECT, SimBenchConfig(duration_s=0.05), tmp_path)
    graph = resolve(load_launch(launch, parse_cli_args(args)), bus_dir=tmp_path / "bus")
    runner = inprocess.InProcessGraph(graph.in_process_members())
    assert runner.run(max_ticks=3) == 3
    sim = runner.members[[m.process.name for m in runner.members].index("sim")]
    assert sim.ctx.counters["messages_out"] >= 3 * 4  # pose, contacts, joint states twice per tick
    assert "JointState" not in validated


def test_in_process_messages_nobody_reads_are_validated_not_transferred(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """demo_minimal's estimator publishes surface/mesh, which no node reads: without a listener the
    executor only validates it (counted in messages_out all the same); with one, it is transferred."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.paths import LAUNCH_DIR
    from palpate.runtime import inprocess

    transferred = recorded_transfers(monkeypatch)
    members = resolve(load_launch(LAUNCH_DIR / "demo_minimal.yaml"), bus_dir=tmp_path).in_process_members()
    graph = inprocess.InProcessGraph(members)
    graph.run(max_ticks=5)
    types = [message.TYPE for message in transferred]
    assert "SurfaceMesh" not in types and "ContactSet" in types
    assert graph.members[[m.process.name for m in graph.members].index("estimator")].ctx.counters["messages_out"] == 5
    transferred.clear()
    heard: list[str] = []
    inprocess.InProcessGraph(members, listener=lambda tick, node, topic, message: heard.append(topic)).run(max_ticks=5)
    assert "SurfaceMesh" in [message.TYPE for message in transferred] and "surface/mesh" in heard


def test_a_stuck_tick_names_the_node_that_holds_it_up_not_those_waiting_for_it(tmp_path: Path) -> None:
    """The exploration graph with its noise node silent at tick 50: the controller, GPIS, planner and
    evaluator wait for it (directly or not), so only the noise node is named (an outside driver's audit
    saw all five). The clock source's spec gives every node's upstream, and each spec its topics' types."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch, parse_cli_args
    from palpate.paths import LAUNCH_DIR
    from palpate.runtime.node import holding_up

    graph = resolve(load_launch(LAUNCH_DIR / "explore.yaml", parse_cli_args([])), bus_dir=tmp_path)
    specs = {p.name: p for p in graph.process_specs()}
    clock = specs["sim"]
    assert clock.lockstep_upstream["controller"] == {"forward": ["noise"], "backward": ["planner"]}
    assert clock.lockstep_upstream["noise"] == {"forward": [], "backward": []}  # the sim is never listed
    assert specs["noise"].topic_types == {"sensors/contacts": "ContactSet", "sensors/contacts_noisy": "ContactSet"}
    everyone = dict.fromkeys(clock.lockstep_nodes, 49)
    assert holding_up(everyone, 50, clock) == ["noise"]
    assert holding_up({**everyone, "noise": 50}, 50, clock) == ["controller"]
    assert holding_up({**everyone, "noise": 50, "controller": 50}, 50, clock) == ["gpis"]
    assert holding_up({**everyone, "eval": 50}, 50, clock) == ["noise"]
    assert holding_up({"noise": -1}, -1, clock) == [n for n in clock.lockstep_nodes if n != "noise"]  # start-up
    # probe.yaml: the clock waits for the driver at tick 50 while the trailing noise node may lag 3 ticks
    probe = {p.name: p for p in resolve(load_launch(LAUNCH_DIR / "probe.yaml"), bus_dir=tmp_path).process_specs()}
    sim = probe["sim"]
    assert sim.trailing_nodes == ["noise"] and sim.lockstep_nodes == ["driver", "noise"]
    assert holding_up({"driver": 49, "noise": 47}, 50, sim, ["driver"]) == ["driver"]


def test_a_publisher_that_cannot_bind_names_the_endpoint_and_what_to_change() -> None:
    """An outside audit: docker.yaml on a machine without its container addresses ended each node with a
    ZMQError traceback ('Cannot assign requested address')."""
    import zmq

    from palpate.errors import BusError

    ctx = zmq.Context()
    try:
        with pytest.raises(BusError, match=r"cannot bind tcp://192\.0\.2\.1:5999: .*an address of this machine"):
            bus.make_publisher(ctx, "tcp://192.0.2.1:5999", lockstep=True)  # TEST-NET-1: never local
    finally:
        ctx.term()


def test_a_node_name_is_claimed_on_a_bus_directory_until_released(tmp_path: Path) -> None:
    first = bus.NameClaim(tmp_path, ["sim", "gpis"])
    with pytest.raises(
        BusError, match=rf"node name 'gpis' is in use on the bus directory {tmp_path} .*process {os.getpid()}"
    ):
        bus.NameClaim(tmp_path, ["gpis", "planner"])
    other = bus.NameClaim(tmp_path, ["planner"])  # the failed claim kept nothing
    first.release()
    second = bus.NameClaim(tmp_path, ["sim", "gpis"])
    second.release()
    other.release()


def test_a_signal_tells_the_nodes_close_that_the_run_was_ended() -> None:
    """A node stopped by its own SIGTERM (Ctrl-C on the launch) reports the run as stopped, not finished:
    an evaluator's close() reads run_stopped_by (it said `finished: clock`)."""
    import signal
    from types import SimpleNamespace

    from palpate.runtime.node import _install_signal_handlers

    runner = SimpleNamespace(interrupted=False, stop_reason="", ctx=SimpleNamespace(run_stopped_by=""))
    previous = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        _install_signal_handlers(runner)  # type: ignore[arg-type]
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler)
        handler(signal.SIGTERM, None)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    assert runner.interrupted and runner.stop_reason == "interrupted by SIGTERM"
    assert runner.ctx.run_stopped_by == "interrupted by SIGTERM"


class Idle:
    """A node that does nothing."""


class ContactsReader(Idle):
    """A node that takes every contact set and does nothing with it."""

    def on_contacts(self, message: ContactSet) -> None:
        pass


def runner_of(process: NodeProcessSpec, node: type[Idle] = Idle) -> Any:
    """A NodeRunner of ``process`` (its inputs on sensors/contacts, when it subscribes any) running ``node``;
    close its sockets after (``_close_sockets``)."""
    from palpate.runtime.node import NodeRunner
    from palpate.runtime.spec import Port

    inputs = {"contacts": Port(ContactSet)} if process.subscribes else {}
    spec = NodeSpec(name=process.name, config=NoParams, factory=lambda c, ctx: node(), inputs=inputs)
    return NodeRunner(spec, process)


def frame_to(runner: Any, topic: str, message: Message) -> None:
    """Hand ``message`` on ``topic`` to ``runner`` as its subscriber would (the two frames off the bus)."""
    import zmq

    runner._on_frames([zmq.Frame(topic.encode()), zmq.Frame(codec.encode(message))])


def test_a_start_up_without_a_peer_names_it_as_perhaps_an_external_node(tmp_path: Path) -> None:
    from palpate.runtime.node import NodeRunner

    process = bare_process(tmp_path, "waiter", expected_subscribers={"hello/noise": 1, "graph/control": 1})
    runner = NodeRunner(
        NodeSpec(name="waiter", config=NoParams, factory=lambda c, ctx: Idle()), process, start_timeout_s=0.2
    )
    try:
        with pytest.raises(
            TimeoutError,
            match=r"not connected: noise \(an external node's driver not started, or not subscribed to hello/noise\?\)",
        ):
            runner._start_up()
    finally:
        runner._close_sockets(linger_ms=0)


def test_unused_input_warning_counts_apart_what_a_real_time_node_never_read(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """In real time a burst of state messages is read newest first: the two older ones are replaced
    unread, the newest is refused, and the warning says so instead of "all 1 were refused"."""
    process = dataclasses.replace(bare_process(tmp_path, "reader"), subscribes={"contacts": "sensors/contacts"})
    runner = runner_of(process)
    try:
        for i in range(3):
            runner.buffer.append((-1, 0, i, "sensors/contacts", b"not msgpack"))
        runner.dispatch(latest_only=True)
        with caplog.at_level("WARNING"):
            runner._note_refused_inputs()
    finally:
        runner._close_sockets(linger_ms=0)
    assert runner.ctx.counters["decode_errors"] == 1
    assert caplog.messages[-1] == (
        "node reader used no message on sensors/contacts: 1 were refused (1 did not decode, 0 were unusable), "
        "2 more were replaced by newer ones unread"
    )


def test_a_real_time_node_counts_and_says_the_state_messages_it_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An outside walkthrough: a real-time mapper slower than a glove's readings made 914 updates for 1001
    ticks, and nothing counted or said the readings it skipped."""
    process = dataclasses.replace(bare_process(tmp_path, "reader"), subscribes={"contacts": "sensors/contacts"})
    runner = runner_of(process, ContactsReader)
    try:
        for i in range(3):
            runner.buffer.append((-1, 0, i, "sensors/contacts", _contacts(i)))
        runner.dispatch(latest_only=True)
        with caplog.at_level("WARNING"):
            runner._note_refused_inputs()
    finally:
        runner._close_sockets(linger_ms=0)
    assert runner.ctx.counters["superseded"] == 2 and runner.ctx.counters["messages_in"] == 1
    assert caplog.messages[-1] == (
        "node reader skipped 2 message(s) on sensors/contacts in this run: newer ones replaced them before it "
        "read them (real time: it handles the newest of a burst; counter superseded)"
    )


def test_a_bus_directory_that_cannot_be_written_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An outside walkthrough: a bus directory of another user, or on a full disk, ended the launch (and each
    node writing its manifest) in a PermissionError or ENOSPC traceback."""
    import errno

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(bus.locks, "hold", full)
    with pytest.raises(BusError, match=r"cannot write the bus directory .* \(No space left on device\); give one"):
        bus.NameClaim(tmp_path / "bus", ["sim"])
    monkeypatch.setattr(Path, "write_text", full)
    manifest = bus.Manifest(node="sim", pid=os.getpid(), publishes={}, endpoint="ipc:///x", subscribes={})
    with pytest.raises(BusError, match=r"cannot write the bus directory .* \(No space left on device\)"):
        manifest.write(tmp_path / "bus")
    assert not list((tmp_path / "bus").glob("*.tmp"))


def test_a_node_says_at_the_end_how_many_messages_of_a_topic_it_refused(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An outside fuzzer: the counts of refused messages showed only in NodeStatus; the first ten are
    logged, and the run's output now ends with how many there were on each topic."""
    from tests.unit.node_messages import no_contacts

    process = dataclasses.replace(bare_process(tmp_path, "reader"), subscribes={"contacts": "sensors/contacts"})
    runner = runner_of(process, ContactsReader)
    try:
        for i in range(12):
            runner.buffer.append((-1, 0, i, "sensors/contacts", b"not msgpack"))
        runner.buffer.append((-1, 0, 12, "sensors/contacts", codec.encode(no_contacts())))
        runner.dispatch()
        with caplog.at_level("WARNING"):
            runner._note_refused_inputs()
    finally:
        runner._close_sockets(linger_ms=0)
    assert caplog.messages[-1] == (
        "node reader refused 12 message(s) on sensors/contacts in this run (12 did not decode, 0 were unusable)"
    )


def test_a_warning_in_a_node_process_is_one_log_line(caplog: pytest.LogCaptureFixture) -> None:
    """Python's own format adds the source line that warned (`local = read_mesh_file(...)`)."""
    import warnings

    from palpate.errors import MeshWarning
    from palpate.runtime import node

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = node._log_warning  # as the node process's main sets it
        with caplog.at_level("WARNING"):
            warnings.warn("two.stl: the mesh holds 2 separate bodies", MeshWarning, stacklevel=1)
    assert caplog.messages == ["MeshWarning: two.stl: the mesh holds 2 separate bodies"]


# --- InProcessGraph on hand-made nodes: delivery order, stops, transfers ----------------------------


@dataclasses.dataclass(frozen=True, kw_only=True)
class TalkerParams(Validated):
    """When a hand-made node asks to stop (0: never), and whether as a failure."""

    stop_at: int = 0
    failed: bool = False


class Talker:
    """Publishes one Pose (frame: its name, x: the tick) on each output port per tick, from one object it
    changes in place; asks to stop at tick ``stop_at``; records what it hears (frame, x) on any input.
    As the clock source (``step``) it runs three ticks."""

    def __init__(self, config: TalkerParams, ctx: Any) -> None:
        from palpate.messages.schemas import Pose

        self.config, self.ctx = config, ctx
        self.pose = Pose(
            stamp_ns=0,
            frame=ctx.name,
            position_m=np.zeros(3),
            quaternion_wxyz=np.array([1.0, 0.0, 0.0, 0.0]),
            linear_velocity_m_s=np.zeros(3),
            angular_velocity_rad_s=np.zeros(3),
        )
        self.heard: list[tuple[str, float]] = []
        self.ticks = 0

    def __getattr__(self, name: str) -> Any:
        if name.startswith("on_") and name != "on_tick":  # any input port
            return lambda message: self.heard.append((message.frame, float(message.position_m[0])))
        raise AttributeError(name)

    def _talk(self) -> None:
        self.ticks += 1
        self.pose.position_m[0] = self.ticks  # the same object, changed in place
        for port in sorted(self.ctx.outputs):
            self.ctx.publish(port, self.pose)
        if self.ticks == self.config.stop_at:
            self.ctx.request_stop(f"{self.ctx.name} stops", failed=self.config.failed)

    def step(self) -> int | None:
        if self.ticks == 3:
            return None
        self._talk()
        return self.ticks * 1000

    def on_tick(self, stamp_ns: int) -> None:
        self._talk()


def _talkers(tmp_path: Path, wiring: list[tuple[str, list[str], list[str]]], **params: dict[str, Any]) -> Any:
    """An InProcessGraph of Talkers in rank order, the first the clock source: (name, topics it
    publishes, topics it reads) each."""
    from palpate.runtime.inprocess import InProcessGraph

    spec = NodeSpec(name="talker", config=TalkerParams, factory=Talker)
    clock = NodeSpec(name="talker", config=TalkerParams, factory=Talker, clock_source=True)
    members = []
    for rank, (name, out, read) in enumerate(wiring):
        process = NodeProcessSpec(
            name=name,
            type="talker",
            node_spec="tests:unused",
            params=params.get(name, {}),
            bus_dir=str(tmp_path),
            endpoint=f"ipc://{tmp_path}/{name}.pub",
            publishes={topic.replace("/", "_"): topic for topic in out},
            subscribes={topic.replace("/", "_"): topic for topic in read},
            connect=[],
            clock_source=rank == 0,
        )
        members.append((clock if rank == 0 else spec, process))
    return InProcessGraph(members)


def test_in_process_inputs_are_handled_by_publisher_rank_then_publish_order(tmp_path: Path) -> None:
    """The reader (rank 2) gets the later-ranked node's message of tick t - 1 (a feedback edge) before the
    clock's and the earlier node's of tick t, yet handles them by rank: clock, early (two topics, in the
    order published), late."""
    graph = _talkers(
        tmp_path,
        [
            ("clock", ["t/clock"], []),
            ("early", ["t/early_a", "t/early_b"], []),
            ("reader", [], ["t/late", "t/early_b", "t/clock", "t/early_a"]),
            ("late", ["t/late"], []),
        ],
    )
    assert graph.run() == 3
    heard = graph.node("reader").heard
    assert heard == [
        ("clock", 1.0), ("early", 1.0), ("early", 1.0),
        ("clock", 2.0), ("early", 2.0), ("early", 2.0), ("late", 1.0),
        ("clock", 3.0), ("early", 3.0), ("early", 3.0), ("late", 2.0),
    ]  # fmt: skip


def test_in_process_a_message_is_transferred_once_per_tick_it_is_sent_in(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The early node sends one Pose object on two topics each tick, changed in place between ticks: one
    transfer per tick, and each tick's subscribers see that tick's value."""
    transfers = recorded_transfers(monkeypatch)
    graph = _talkers(tmp_path, [("clock", [], []), ("early", ["t/a", "t/b"], []), ("reader", [], ["t/a", "t/b"])])
    assert graph.run() == 3
    assert [message.frame for message in transfers] == ["early"] * 3
    assert graph.node("reader").heard == [("early", x) for x in (1.0, 1.0, 2.0, 2.0, 3.0, 3.0)]


def test_in_process_the_first_stop_and_the_first_failure_by_rank_end_the_run(tmp_path: Path) -> None:
    wiring: list[tuple[str, list[str], list[str]]] = [("clock", [], []), ("one", [], []), ("two", [], [])]
    both = {"one": {"stop_at": 2, "failed": True}, "two": {"stop_at": 2, "failed": True}}
    graph = _talkers(tmp_path, wiring, **both)
    assert graph.run() == 2
    assert graph.stop_reason == "one stops" and graph.failure == "one stops"
    assert graph.members[2].ctx.run_stopped_by == "one stops"  # two asked too, for another reason
    assert graph.members[1].ctx.run_stopped_by == ""  # its own stop
    assert graph.members[0].ctx.run_stopped_by == "one stops"
    clock = _talkers(tmp_path, wiring, clock={"stop_at": 1})
    assert clock.run() == 1 and clock.stop_reason == "clock stops"  # the clock source's own stop counts too


def test_the_clock_source_names_a_restarted_node_and_a_refused_acknowledgement_at_once(tmp_path: Path) -> None:
    """An outside driver in C: a driver restarted mid-run acknowledged the start (tick -1) again and the
    run waited 120 s, ending with "no acknowledgement of tick 50"; an acknowledgement that was refused
    was not mentioned when the wait ran out."""
    from palpate.runtime.node import PeerLostError

    process = dataclasses.replace(
        bare_process(tmp_path, "clock"), mode="lockstep", clock_source=True, lockstep_nodes=["noise", "stats"]
    )
    runner = runner_of(process)

    def ack(node: str, tick: int) -> None:
        frame_to(runner, topics.LOCKSTEP_ACK, LockstepAck(stamp_ns=0, node=node, tick=tick))

    try:
        runner.last_clock = 50
        for node in ("noise", "stats"):
            ack(node, 49)
        ack("noise", -1)  # its driver, started again, says it is ready
        with pytest.raises(PeerLostError) as info:
            runner._wait_for_acks(["noise", "stats"], 50)
        assert str(info.value) == (
            "no acknowledgement of tick 50: 'noise' started again after tick 49 (it acknowledged the start anew); "
            "a lockstep node cannot rejoin a run: start a new launch"
        )
        ack("stats", 1000)  # refused: ahead of the clock
        runner.ack_timeout_s = 0.2
        with pytest.raises(TimeoutError) as timeout:
            runner._wait_for_acks(["stats"], 50)
        assert str(timeout.value) == (
            "no acknowledgement of tick 50 from ['stats'] in 0 s; stats sent an acknowledgement that was refused: "
            "LockstepAck of tick 1000 from 'stats' is ahead of the clock (last tick 50)"
        )
        # an outside driver's acknowledgement without its node field: the timeout said nothing of it
        import msgpack
        import zmq

        header, buffer = msgpack.unpackb(codec.encode(LockstepAck(stamp_ns=0, node="noise", tick=50)))
        del header["fields"]["node"]
        runner._on_frames([zmq.Frame(topics.LOCKSTEP_ACK.encode()), zmq.Frame(msgpack.packb([header, buffer]))])
        with pytest.raises(TimeoutError) as timeout:
            runner._wait_for_acks(["late"], 50)
        assert str(timeout.value) == (
            "no acknowledgement of tick 50 from ['late'] in 0 s; 1 acknowledgement(s) did not decode (logged above)"
        )
    finally:
        runner._close_sockets(linger_ms=0)


def test_a_lockstep_clock_stamped_before_the_last_or_the_start_is_refused(tmp_path: Path) -> None:
    """An outside audit: only a Clock's tick was checked; a stamp going back turned the nodes' watchdogs
    off, and one of -5 ns was taken."""
    from palpate.messages.schemas import Clock

    runner = runner_of(dataclasses.replace(bare_process(tmp_path, "follower"), mode="lockstep"))

    def clock(tick: int, stamp_ns: int) -> None:
        frame_to(runner, topics.CLOCK, Clock(stamp_ns=stamp_ns, tick=tick, period_ns=10_000_000, lockstep=True))

    try:
        clock(0, -5)
        clock(0, 0)
        clock(1, 20_000_000)
        clock(2, 10_000_000)  # before tick 1's
        clock(2, 20_000_000)  # the same time again: taken (a clock source may hold its time)
    finally:
        runner._close_sockets(linger_ms=0)
    assert [c.tick for c in runner.clock_ticks] == [0, 1, 2]
    assert runner.ctx.counters["decode_errors"] == 2


def test_a_real_time_clock_that_goes_back_repeats_or_jumps_is_taken_counted_and_said_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An outside walkthrough: a real-time driver's restart (stamps and ticks from 0 again) and a 6 s pause
    passed without a word, and the controller then blamed the contact sensor, the evaluator the odometer."""
    from palpate.messages.schemas import Clock

    runner = runner_of(dataclasses.replace(bare_process(tmp_path, "follower"), mode="realtime", clock_name="rig"))

    def clock(tick: int, stamp_ns: int) -> None:
        frame_to(runner, topics.CLOCK, Clock(stamp_ns=stamp_ns, tick=tick, period_ns=10_000_000, lockstep=False))

    try:
        with caplog.at_level(logging.WARNING):
            clock(0, 0)
            clock(1, 10_000_000)
            clock(2, 6_010_000_000)  # a 6 s pause
            clock(3, 6_020_000_000)
            clock(0, 0)  # the driver started again from 0
            clock(1, 10_000_000)
            clock(1, 20_000_000)  # a tick repeated
            clock(9, 7_000_000_000)  # another jump: counted, not said again
    finally:
        runner._close_sockets(linger_ms=0)
    assert [c.tick for c in runner.clock_ticks] == [0, 1, 2, 3, 0, 1, 1, 9]  # real time takes them all
    counters = runner.ctx.counters
    assert (counters["clock_jumped"], counters["clock_went_back"], counters["clock_tick_repeated"]) == (2, 1, 1)
    said = [r.getMessage() for r in caplog.records if "taken as it comes in real time" in r.getMessage()]
    assert len(said) == 3
    assert "Clock tick 2 (from tick 1) is stamped 6 s after the one before" in said[0]
    assert "stamped 6.02 s before the one before" in said[1] and "a restarted 'rig' continues" in said[1]
    assert "Clock tick 1 (from tick 1) is no later than the tick before" in said[2]
    assert counters["decode_errors"] == 0


def test_a_real_time_follower_says_when_inputs_come_but_no_clock(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An outside real-time driver that sent poses and contacts but no Clock: the graph did nothing for 45 s,
    said nothing, and the launch exited 0."""
    from palpate.messages.schemas import Clock

    runner = runner_of(dataclasses.replace(bare_process(tmp_path, "follower"), mode="realtime", clock_name="rig"))
    clockless = runner_of(dataclasses.replace(bare_process(tmp_path, "other"), mode="realtime"))
    try:
        clockless.ctx.counters["messages_in"] = 5
        assert not clockless._said_no_clock(60.0, 30.0)  # a real-time graph without a clock source
        with caplog.at_level(logging.WARNING):
            assert not runner._said_no_clock(60.0, 30.0)  # nothing arrived yet: a slow start
            runner.ctx.counters["messages_in"] = 5
            assert not runner._said_no_clock(29.0, 30.0)
            assert runner._said_no_clock(31.0, 30.0)
            frame_to(runner, topics.CLOCK, Clock(stamp_ns=0, tick=0, period_ns=10_000_000, lockstep=False))
            assert not runner._said_no_clock(90.0, 30.0)  # a Clock came
    finally:
        runner._close_sockets(linger_ms=0)
        clockless._close_sockets(linger_ms=0)
    said = [r.getMessage() for r in caplog.records]
    assert said == [
        "node follower: inputs arrive but no Clock came in 31 s: in real time a node acts on each Clock of the "
        "clock source (a driver that plays it publishes Clock on topic clock)"
    ]


def test_a_follower_names_a_restarted_clock_source_a_refused_clock_and_gives_up_after_the_timeout(
    tmp_path: Path,
) -> None:
    """An outside clock-source driver in C: one restarted within the 2 s grace left the graph saying "hung"
    for 120 s and more; a refused Clock (a skipped tick) was not named in the wait's note; a hung one was
    waited for until Ctrl-C."""
    from palpate.messages.schemas import Clock

    runner = runner_of(dataclasses.replace(bare_process(tmp_path, "follower"), mode="lockstep", clock_name="sim"))

    def clock(tick: int) -> None:
        frame_to(
            runner, topics.CLOCK, Clock(stamp_ns=tick * 10_000_000, tick=tick, period_ns=10_000_000, lockstep=True)
        )

    runner.counter.counts["hello/sim"] = 1  # the clock source is connected
    try:
        for tick in range(4):
            clock(tick)
        runner.clock_ticks.clear()  # ticks 0..3 ran
        clock(5)  # refused: skips ahead
        assert runner._clock_lost("sim", True, 4, 1.0) == ""
        assert runner._awaited(4).endswith(
            "slow; this node refused its last Clock: Clock tick 5 skips ahead of tick 4; a lockstep clock source "
            "sends every tick in turn from 0 (only it, 'sim', publishes on this topic))"
        )
        runner.ack_timeout_s = 60.0  # a slow node's tick can keep the graph still that long, twice in a row
        assert runner._clock_lost("sim", True, 4, 119.0) == ""
        assert runner._clock_lost("sim", True, 4, 121.0).startswith(
            "nothing moved in the graph for 121 s (no Clock, no acknowledgement): waited for tick 4 from"
        )
        clock(4)  # taken: the refused one is forgotten
        assert "refused" not in runner._awaited(5)
        clock(0)  # its process started again
        assert runner._clock_lost("sim", True, 5, 1.0) == (
            "the clock source sim started again after tick 4 (a Clock of tick 0 came); a lockstep run cannot go on "
            "with it: start a new launch"
        )
    finally:
        runner._close_sockets(linger_ms=0)
