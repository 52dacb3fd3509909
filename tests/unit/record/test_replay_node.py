"""The replay node and `launch --replay`: ports from the log, one recorded tick per step, node replacement."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import msgpack
import numpy as np
import pytest
from mcap.writer import Writer as McapWriter

from palpate.errors import LaunchError
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.launch.node_types import load_node_type
from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import ContactSet, JointState
from palpate.paths import REPO_ROOT
from palpate.record import mcap_io
from palpate.record.launch_support import replace_publishers_with_log
from palpate.record.mcap_io import LogWriter
from palpate.record.replay_node import ReplayConfig, ReplayNode, ports_from_config
from tests.unit.record.synthetic import PERIOD_NS, canonical_log, lockstep_streams, mesh, write_log

DEMO = REPO_ROOT / "launch" / "demo_minimal.yaml"
MAP_KNOWN = REPO_ROOT / "launch" / "map_known.yaml"


class FakeContext:
    """What the replay node sees of the runtime: its outputs, publish, counters and a logger."""

    def __init__(self, outputs: dict[str, str]):
        self.outputs = outputs
        self.sent: list[tuple[str, bytes]] = []
        self.counters: dict[str, int] = {}
        self.log = logging.getLogger("test.replay")
        self.stop: tuple[str, bool] | None = None

    def publish(self, port: str, message: Message) -> None:
        codec.validate(message)
        self.sent.append((self.outputs[port], codec.encode(message)))

    def count(self, name: str, n: int = 1) -> None:
        self.counters[name] = self.counters.get(name, 0) + n

    def request_stop(self, reason: str, *, failed: bool = False) -> None:
        self.stop = (reason, failed)


@pytest.fixture
def log_path(tmp_path: Path) -> Path:
    path = tmp_path / "run.mcap"
    write_log(path, canonical_log(4))
    return path


def test_ports_are_the_logs_data_topics(log_path: Path) -> None:
    inputs, outputs = ports_from_config(ReplayConfig(path=str(log_path)))
    assert inputs == {} and set(outputs) == {topics.CONTACTS, topics.SURFACE_MESH}
    assert outputs[topics.CONTACTS].message is ContactSet and outputs[topics.CONTACTS].topic == topics.CONTACTS
    _, only = ports_from_config(ReplayConfig(path=str(log_path), topics=(topics.CONTACTS,)))
    assert set(only) == {topics.CONTACTS}
    with pytest.raises(LaunchError, match="no topic 'nope'"):
        ports_from_config(ReplayConfig(path=str(log_path), topics=("nope",)))
    with pytest.raises(LaunchError, match="cannot open log"):
        ports_from_config(ReplayConfig(path=str(log_path.with_name("missing.mcap"))))


def test_each_step_publishes_one_recorded_tick_and_returns_its_stamp(log_path: Path) -> None:
    spec = load_node_type("replay").with_params({"path": str(log_path), "topics": [topics.CONTACTS]})
    assert spec.clock_source and set(spec.outputs) == {topics.CONTACTS}
    ctx = FakeContext({topics.CONTACTS: "remapped/contacts"})
    node = ReplayNode(ReplayConfig(path=str(log_path), topics=(topics.CONTACTS,)), ctx)
    assert node.period_ns == PERIOD_NS
    recorded = [codec.encode(m) for t, m in lockstep_streams(4)["cube"] if t == topics.CONTACTS]
    stamps = []
    while (stamp := node.step()) is not None:
        stamps.append(stamp)
        assert ctx.sent[-1] == ("remapped/contacts", recorded[len(stamps) - 1])  # byte for byte
    assert stamps == [t * PERIOD_NS for t in range(4)] and len(ctx.sent) == 4


def test_launch_replay_replaces_the_clock_source_and_reruns_the_rest(tmp_path: Path, log_path: Path) -> None:
    sensors = tmp_path / "sensors.mcap"
    write_log(sensors, [(t, m) for t, m in canonical_log(3) if t != topics.SURFACE_MESH])
    launch = replace_publishers_with_log(load_launch(DEMO), sensors)
    names = [e.fields["name"] for e in launch.nodes]
    assert names == ["replay", "stats", "estimator"]  # cube replaced; the estimator re-runs
    graph = resolve(launch, bus_dir=tmp_path)
    replay = graph.by_name["replay"]
    assert replay.spec.clock_source and replay.publishes == {topics.CONTACTS: topics.CONTACTS}
    assert replay.params["order"] == {topics.CONTACTS: 0}
    # a full recording re-runs the estimator too (it replaced every node before: nothing re-ran) ...
    full = replace_publishers_with_log(load_launch(DEMO), log_path)
    assert [e.fields["name"] for e in full.nodes] == ["replay", "stats", "estimator"]
    # ... unless the estimator is named: then the log's meshes stand in for it
    both = replace_publishers_with_log(load_launch(DEMO), log_path, ["cube", "estimator"])
    assert [e.fields["name"] for e in both.nodes] == ["replay", "stats"]


def test_launch_replay_needs_the_topics_of_the_nodes_it_replaces(tmp_path: Path, log_path: Path) -> None:
    meshes = tmp_path / "meshes.mcap"
    write_log(meshes, [(t, m) for t, m in canonical_log(2) if t == topics.SURFACE_MESH])
    with pytest.raises(LaunchError, match=r"the log lacks \['sensors/contacts'\] of node 'cube'"):
        replace_publishers_with_log(load_launch(DEMO), meshes)
    with pytest.raises(LaunchError, match="the clock source 'cube' must be among them"):
        replace_publishers_with_log(load_launch(DEMO), log_path, ["estimator"])
    with pytest.raises(LaunchError, match=r"no node \['nope'\] in the graph"):
        replace_publishers_with_log(load_launch(DEMO), log_path, ["cube", "nope"])
    with pytest.raises(LaunchError, match="has nothing to publish for node 'stats'"):
        replace_publishers_with_log(load_launch(DEMO), log_path, ["cube", "stats"])


def test_launch_replay_needs_only_the_topics_that_nodes_which_re_run_read(tmp_path: Path) -> None:
    """An outside walkthrough: a data glove's driver had stood in for the sim of map_known.yaml and
    published only what the mapper reads; its recording was refused for lacking the sim's other topics
    (truth/object, truth/joint_states, sensors/effector_pose), which no node of the graph reads."""
    glove = tmp_path / "glove.mcap"
    names = ["index_mcp_abd", "index_mcp_flex", "index_pip", "index_dip"]  # the mapper's finger's
    states = [
        JointState(stamp_ns=t * PERIOD_NS, names=names, positions_rad=np.zeros(4), velocities_rad_s=np.zeros(4))
        for t in range(3)
    ]
    sensors = [(t, m) for t, m in canonical_log(3) if t == topics.CONTACTS]
    readings = [(topics.JOINT_STATES, s) for s in states]
    write_log(glove, [item for pair in zip(sensors, readings, strict=True) for item in pair])
    notes: list[str] = []
    launch = replace_publishers_with_log(load_launch(MAP_KNOWN), glove, notes=notes)
    assert [e.fields["name"] for e in launch.nodes] == ["replay", "mapper"]
    assert notes == [
        "note: the log holds no ['sensors/effector_pose', 'truth/joint_states', 'truth/object'], which no node that "
        "re-runs reads; the replay goes without them (a recording of it, or a viewer, lacks them too)"
    ]
    replay = resolve(launch, bus_dir=tmp_path).by_name["replay"]
    assert sorted(replay.publishes) == [topics.CONTACTS, topics.JOINT_STATES]
    assert set(replay.params["order"]) == {topics.CONTACTS, topics.JOINT_STATES}
    write_log(glove, sensors)  # without the joint readings the mapper reads, the log cannot stand in
    with pytest.raises(LaunchError, match=rf"the log lacks \['{topics.JOINT_STATES}'\] of node 'sim'"):
        replace_publishers_with_log(load_launch(MAP_KNOWN), glove)


def _write_versioned(path: Path, *, schema: int, payload: int) -> None:
    """canonical_log(3) with ContactSet recorded as schema version `schema` and payload version `payload`."""
    with LogWriter(path) as writer:
        for seq, (topic, message) in enumerate(canonical_log(3)):
            data, info = codec.encode(message), mcap_io.peek(codec.encode(message))
            if info.type == ContactSet.TYPE:
                header, blob = msgpack.unpackb(data, raw=False)
                data = msgpack.packb([{**header, "version": payload}, blob], use_bin_type=True)
                info = info._replace(version=schema)
            writer.write(topic, data, info, seq)


def test_a_log_of_another_message_version_is_refused_before_the_run(tmp_path: Path) -> None:
    path = tmp_path / "v99.mcap"
    _write_versioned(path, schema=99, payload=99)
    with pytest.raises(LaunchError, match=f"'{topics.CONTACTS}' carries ContactSet version 99; this build speaks "):
        ports_from_config(ReplayConfig(path=str(path)))


def test_the_bus_player_refuses_another_version_or_encoding_as_launch_replay_does(tmp_path: Path) -> None:
    """An outside audit: `palpate replay` put a log of a newer ContactSet, and one in JSON, on the bus with
    exit 0, where every node would refuse each message."""
    from palpate.errors import RecordError
    from palpate.record.bag import Player, PlayOptions

    path = tmp_path / "v99.mcap"
    _write_versioned(path, schema=99, payload=99)
    with pytest.raises(RecordError, match=f"'{topics.CONTACTS}' carries ContactSet version 99; this build speaks "):
        Player(path, tmp_path / "bus", PlayOptions())
    assert Player(path, tmp_path / "bus", PlayOptions(topics=[topics.CLOCK])).types == {topics.CLOCK: "Clock"}
    foreign = tmp_path / "json.mcap"
    with foreign.open("wb") as stream:
        writer = McapWriter(stream)
        writer.start()
        schema = writer.register_schema(name="Clock", encoding="jsonschema", data=b"{}")
        channel = writer.register_channel(topic=topics.CLOCK, message_encoding="json", schema_id=schema)
        writer.add_message(channel_id=channel, log_time=0, data=b'{"tick": 0}', publish_time=0)
        writer.finish()
    with pytest.raises(RecordError, match=r"topic 'clock' is encoded as 'json', not msgpack"):
        Player(foreign, tmp_path / "bus", PlayOptions())


def test_ticks_a_recovered_log_lacks_are_counted_and_logged(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """An outside audit: a recovered log (one damaged chunk skipped: ticks 198 to 209) replayed without a
    word, with other results than the recorded run."""
    lost = {2 * PERIOD_NS, 3 * PERIOD_NS}
    path = tmp_path / "recovered.mcap"
    write_log(path, [(t, m) for t, m in canonical_log(6) if m.stamp_ns not in lost or t == topics.NODE_STATUS])
    ctx = FakeContext({topics.CONTACTS: topics.CONTACTS})
    node = ReplayNode(ReplayConfig(path=str(path), topics=(topics.CONTACTS,)), ctx)
    with caplog.at_level(logging.WARNING, logger="test.replay"):
        stamps = []
        while (stamp := node.step()) is not None:
            stamps.append(stamp)
    assert stamps == [0, PERIOD_NS, 4 * PERIOD_NS, 5 * PERIOD_NS]
    assert ctx.counters == {"replay_ticks_missing": 2}
    assert "replay: the log holds no ticks 2 to 3 (2 missing: a recovered log" in caplog.text
    # a review: ticks lost at the start were not counted
    path = tmp_path / "late.mcap"
    write_log(path, [(t, m) for t, m in canonical_log(4) if m.stamp_ns != 0 or t == topics.NODE_STATUS])
    ctx = FakeContext({topics.CONTACTS: topics.CONTACTS})
    node = ReplayNode(ReplayConfig(path=str(path), topics=(topics.CONTACTS,)), ctx)
    while node.step() is not None:
        pass
    assert ctx.counters == {"replay_ticks_missing": 1} and "the log holds no tick 0 (1 missing" in caplog.text


def test_a_recorded_message_that_does_not_decode_fails_the_run(tmp_path: Path) -> None:
    path = tmp_path / "forged.mcap"  # the schema says this build's version, the payloads another
    _write_versioned(path, schema=ContactSet.VERSION, payload=99)
    ctx = FakeContext({topics.CONTACTS: topics.CONTACTS})
    node = ReplayNode(ReplayConfig(path=str(path), topics=(topics.CONTACTS,)), ctx)
    assert node.step() is None and ctx.sent == []
    assert ctx.stop is not None and ctx.stop[1], ctx.stop
    assert f"recorded {topics.CONTACTS} message at 0.000 s cannot be replayed" in ctx.stop[0]
    assert "version 99" in ctx.stop[0]


def test_a_replay_notes_a_log_of_another_launch_file_or_other_arguments(tmp_path: Path) -> None:
    from palpate.record.launch_support import replay_note
    from palpate.record.mcap_io import LAUNCH_METADATA, LogWriter, launch_info

    def log_of(name: str, about: dict[str, str]) -> Path:
        path = tmp_path / name
        with LogWriter(path) as writer:
            if about:
                writer.metadata(LAUNCH_METADATA, about)
        return path

    launch = load_launch(DEMO)
    same = {"launch_file": f"launch/{DEMO.name}", "args": json.dumps(launch.args), "seed": "0"}
    assert launch_info(log_of("same.mcap", same)) == same
    assert replay_note(launch, log_of("same.mcap", same)) is None
    assert replay_note(launch, log_of("bare.mcap", {})) is None  # palpate record says nothing of a launch
    other = log_of("other.mcap", {**same, "launch_file": "launch/map_known.yaml"})
    assert f"was recorded from launch/map_known.yaml, not {DEMO.name}" in (replay_note(launch, other) or "")
    name, value = next(iter(launch.args.items()))
    changed = log_of("changed.mcap", {**same, "args": json.dumps({**launch.args, name: f"{value}x"})})
    assert f"was recorded with {name}:='{value}x'" in (replay_note(launch, changed) or "")
    assert f"(here {value!r})" in (replay_note(launch, changed) or "")
    reseeded = log_of("reseeded.mcap", {**same, "seed": "7"})
    assert "was recorded with seed 7 (here 0)" in (replay_note(launch, reseeded) or "")
    # an outside walkthrough: a node a driver played was re-run by palpate's own without a word
    driven = log_of("driven.mcap", {**same, "external": "estimator"})
    assert replay_note(launch, driven) == (
        "note: estimator played by a driver in the recorded run, palpate's own node here, so its outputs need not "
        "be the recorded ones (--replay-nodes estimator replays them as recorded; --external estimator with the "
        "driver started again re-runs it)"
    )
    assert replay_note(launch, driven, ["cube", "estimator"]) is None  # replayed as recorded


def test_a_replayed_node_that_reads_a_node_which_re_runs_is_refused(tmp_path: Path) -> None:
    """The replay node publishes with the clock: a recorded GPIS mesh would reach the planner before the
    re-run controller's touch it answers (the planner then never planned)."""
    from palpate.record.mcap_io import LogWriter, schema_bytes

    explore = load_launch(REPO_ROOT / "launch" / "explore.yaml")
    graph = resolve(explore, bus_dir=tmp_path)
    log = tmp_path / "explore.mcap"
    with LogWriter(log) as writer:  # channels only: what replacing reads
        for topic, type_name in graph.topic_types().items():
            writer.channel(topic, type_name, schema_bytes(type_name, 1))
    with pytest.raises(LaunchError, match=r"node 'gpis' reads controller/events of 'controller'.*those nodes re-run"):
        replace_publishers_with_log(explore, log, ["sim", "gpis"])
    sim_noise = replace_publishers_with_log(explore, log, ["sim", "noise"])  # noise reads only the sim: fine
    assert "noise" not in [e.fields["name"] for e in sim_noise.nodes]


def test_a_replay_note_leaves_out_arguments_that_do_not_set_the_replaced_nodes(tmp_path: Path) -> None:
    from palpate.record.launch_support import replay_note
    from palpate.record.mcap_io import LAUNCH_METADATA, LogWriter

    explore = load_launch(REPO_ROOT / "launch" / "explore.yaml")

    def note(params: dict[str, object] | None = None, **changed: object) -> str | None:
        path = tmp_path / "explore.mcap"
        about = {"launch_file": "launch/explore.yaml", "args": json.dumps({**explore.args, **changed}), "seed": "0"}
        if params:
            about["params"] = json.dumps(params)
        with LogWriter(path) as writer:
            writer.metadata(LAUNCH_METADATA, about)
        return replay_note(explore, path)

    assert note(results="out/run.json", plot="out/run.png") is None  # the evaluator's outputs only
    assert "object:='sphere' (here 'torus')" in (note(object="sphere") or "")  # the simulator's object
    # the planner and the controller steered the recorded motion: another strategy is noted as such
    steered = note(strategy="tour") or ""
    assert steered.startswith(  # the node it changes, among every node whose outputs reach the simulator
        "note: strategy:='tour' (here 'igef') changes planner: nodes whose outputs steered the recorded motion "
        "(of controller, gpis, noise, planner); the replay does not follow them"
    ), steered
    # parameters set with --set are compared too, by the node they set
    tour_sites = note({"planner.tour_sites": 6}) or ""
    assert tour_sites.startswith("note: --set {'planner.tour_sites': 6} (here nothing) changes planner: nodes whose"), (
        tour_sites
    )
    assert "sensor data" not in tour_sites  # the planner is not replayed
    assert "was recorded with --set {'sim.tick_period_s': 0.02} (here nothing); the replayed sensor data" in (
        note({"sim.tick_period_s": 0.02}) or ""
    )
    assert note({"eval.report": True}) is None  # the evaluator observes


def test_a_step_publishes_by_the_recorded_publishers_rank_with_the_start_ups_messages_first(tmp_path: Path) -> None:
    """The estimator (ranked before the contacts' publisher in `order`) published a mesh at start-up
    (tick -1, no clock stamp) and one in tick 0: the first step sends both, in that order, then the
    contacts the clock source recorded first."""
    streams = lockstep_streams(1)
    startup = mesh(0, size_m=0.005)
    cube, est = streams["cube"][:2], [(topics.SURFACE_MESH, startup), *streams["est"][:3]]  # est: ack -1 after it
    path = tmp_path / "run.mcap"
    write_log(path, [est[0], est[1], *cube, est[2], est[3]])
    wanted = (topics.CONTACTS, topics.SURFACE_MESH)
    ctx = FakeContext({t: t for t in wanted})
    node = ReplayNode(
        ReplayConfig(path=str(path), topics=wanted, order={topics.SURFACE_MESH: 1, topics.CONTACTS: 2}), ctx
    )
    assert node.step() == 0
    expected = [(topics.SURFACE_MESH, startup), est[2], cube[0]]
    assert ctx.sent == [(t, codec.encode(m)) for t, m in expected]


def test_a_replay_into_a_graph_whose_mapper_is_mounted_for_another_scene_is_refused(tmp_path: Path) -> None:
    """An outside walkthrough: a cube log replayed into a sphere's launch file (its mapper mounted for the
    sphere) mapped the recorded contacts 1.5 mm off without a word; the check of the mount compared the
    mapper with the sphere's sim, which the replay replaces."""
    from palpate.launch.loader import apply_params
    from palpate.record.launch_support import replay_note
    from palpate.record.mcap_io import LAUNCH_METADATA, LogWriter, schema_bytes

    stock = REPO_ROOT / "launch" / "map_known.yaml"
    cube = load_launch(stock)
    log = tmp_path / "cube.mcap"
    with LogWriter(log) as writer:
        about = {"launch_file": "launch/map_known.yaml", "args": json.dumps(cube.args), "seed": "0"}  # as recorded
        writer.metadata(LAUNCH_METADATA, about)
        for topic, type_name in resolve(cube, bus_dir=tmp_path).topic_types().items():
            writer.channel(topic, type_name, schema_bytes(type_name, 1))
    sphere = load_launch(stock)
    apply_params(
        sphere, [("sim.scene.object.kind", "sphere"), ("mapper.mount.base_position_m", [-0.09812, 0.035, 0.08])]
    )
    with pytest.raises(LaunchError) as refused:
        replace_publishers_with_log(sphere, log)
    assert "node 'mapper' (params.mount) and node 'sim' of the recorded run (" in str(refused.value)
    assert "disagree on hand_mount: base_position_m [-0.09812, 0.035, 0.08] here, [-0.09662, 0.035, 0.0785]" in str(
        refused.value
    )
    assert "--set 'mapper.mount.base_position_m=[-0.09662,0.035,0.0785]'" in str(refused.value)
    replace_publishers_with_log(cube, log)  # the recorded scene's mount: replayed
    # the hint taken: the sphere's own sim, which the replay replaces, no longer has a say (a review: it did)
    apply_params(sphere, [("mapper.mount.base_position_m", [-0.09662, 0.035, 0.0785])])
    replay_note(sphere, log)
    replace_publishers_with_log(sphere, log)
    # a log that names no launch file: the nodes of the file must agree among themselves, as in a launch
    bare = tmp_path / "bare.mcap"
    with LogWriter(bare) as writer:
        for topic, type_name in resolve(cube, bus_dir=tmp_path).topic_types().items():
            writer.channel(topic, type_name, schema_bytes(type_name, 1))
    with pytest.raises(LaunchError, match=r"node 'mapper' \(params.mount\) and node 'sim' \(params.scene"):
        replace_publishers_with_log(sphere, bare)
