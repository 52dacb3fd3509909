"""Sim node in-process: config validation, the ports of each scene, divergence without NaN messages,
and the launch validator keeping `truth/` topics away from non-evaluators."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.config import load
from palpate.errors import ConfigError, InputError, LaunchError, NonFiniteError, SimulationDivergedError
from palpate.launch.graph import Graph, resolve
from palpate.launch.loader import load_launch
from palpate.messages import codec, topics
from palpate.messages.base import Message
from palpate.messages.schemas import CartesianVelocityCommand, ContactSet, JointCommand, JointState, ObjectTruth, Pose
from palpate.nodes.sim.node import SPEC, SimNode, SimNodeConfig
from palpate.paths import REPO_ROOT

DATA = Path("tests/data/launch")  # relative: errors name files relative to the working directory
MARKER = "# <- error"


def _config(**params: Any) -> SimNodeConfig:
    return load(SimNodeConfig, params)


class FakeCtx:
    """What SimNode sees of the runtime; every published message goes through codec.validate."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.stamp_ns = 0
        self.metrics: dict[str, float] = {}
        self.counters: dict[str, int] = {}
        self.log = logging.getLogger("test.sim")
        self.published: list[tuple[str, Message]] = []
        self.stop_requested = ""

    def publish(self, port: str, message: Message) -> None:
        codec.validate(message)  # raises on NaN or a malformed array, as the real context does
        self.published.append((port, message))

    def request_stop(self, reason: str, *, failed: bool = False) -> None:
        self.stop_requested = reason

    def of(self, port: str) -> list[Any]:
        return [m for p, m in self.published if p == port]


@pytest.fixture(autouse=True)
def _isolated(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)  # MuJoCo writes MUJOCO_LOG.TXT into the working directory on divergence


def _run(node: SimNode) -> int:
    ticks = 0
    while node.step() is not None:
        ticks += 1
    return ticks


# --- config ----------------------------------------------------------------------------------------


def test_bad_scene_key_is_named_with_its_path() -> None:
    with pytest.raises(ConfigError, match=r"^params\.scene\.objekt: unknown key 'objekt'; known keys: contact_tol"):
        load(SimNodeConfig, {"scene": {"effector": "probe", "objekt": {"kind": "cube"}}}, "params")
    with pytest.raises(ConfigError, match=r"^params\.scene\.object\.kind: expected one of \['cube', "):
        load(SimNodeConfig, {"scene": {"effector": "probe", "object": {"kind": "cubee"}}}, "params")


@pytest.mark.parametrize("tick", [0.003, 0.001])
def test_tick_period_must_be_a_multiple_of_the_time_step(tick: float) -> None:
    with pytest.raises(
        ConfigError, match=rf"tick_period_s = {tick!r} must be a positive multiple of the scene's time step 0.002"
    ) as info:
        load(SimNodeConfig, {"tick_period_s": tick}, "params")
    assert info.value.path == ("tick_period_s",)  # so that a launch file error names the key's line
    assert SimNodeConfig(tick_period_s=0.006).tick_period_s == 0.006  # 3 steps of 2 ms
    faster = _config(tick_period_s=0.003, scene={"effector": "probe", "timestep_s": 0.001})
    assert faster.tick_period_s == 0.003


@pytest.mark.parametrize("key", ["tick_period_s", "duration_s"])
@pytest.mark.parametrize("value", [0.0, -0.01, math.nan])
def test_times_must_be_positive(key: str, value: float) -> None:
    with pytest.raises(ConfigError, match=rf"SimNodeConfig.{key}: expected a finite number > 0, got {value!r}"):
        SimNodeConfig(**{key: value})


# --- probe -----------------------------------------------------------------------------------------


def _probe_node(ctx: FakeCtx, duration_s: float = 0.1) -> SimNode:
    scene = {
        "effector": "probe",
        "object": {"kind": "cube", "size_m": [0.05]},
        "probe": {"start_position_m": [0, 0, 0.034]},
    }
    return SimNode(_config(scene=scene, duration_s=duration_s), ctx)


def test_probe_scene_publishes_pose_contacts_and_truth_but_no_joint_states() -> None:
    probe_spec = SPEC.with_params({"scene": {"effector": "probe"}})
    inputs, outputs = probe_spec.inputs, probe_spec.outputs
    assert set(inputs) == {"velocity"} and set(outputs) == {"pose", "contacts", "truth_object"}
    assert outputs["truth_object"].default_topic == topics.TRUTH_OBJECT
    ctx = FakeCtx()
    node = _probe_node(ctx)
    assert _run(node) == 11  # ticks 0..10 of 10 ms in 0.1 s, then None
    assert {port for port, _ in ctx.published} == {"pose", "contacts", "truth_object"}
    assert not any(isinstance(m, JointState) for _, m in ctx.published)
    truth = ctx.of("truth_object")
    assert len(truth) == 1 and isinstance(truth[0], ObjectTruth) and truth[0].stamp_ns == 0
    np.testing.assert_allclose(np.ptp(truth[0].vertices_m, axis=0), 0.05, atol=1e-12)
    poses, contacts = ctx.of("pose"), ctx.of("contacts")
    assert len(poses) == len(contacts) == 11 and all(isinstance(p, Pose) for p in poses)
    assert [p.stamp_ns for p in poses] == [k * 10_000_000 for k in range(11)]
    assert all(isinstance(c, ContactSet) and len(c.links) == 0 for c in contacts)  # 1 mm above the top face


def test_probe_pressed_down_reports_the_top_face_normal() -> None:
    ctx = FakeCtx()
    node = _probe_node(ctx)
    node.step()
    node.on_velocity(
        CartesianVelocityCommand(stamp_ns=0, linear_m_s=np.array([0.0, 0.0, -0.05]), angular_rad_s=np.zeros(3))
    )
    _run(node)
    last = ctx.of("contacts")[-1]
    assert last.links == ["probe"]
    np.testing.assert_allclose(last.normals[0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(last.positions_m[0, 2], 0.025, atol=1e-12)
    assert last.forces_n[0] == pytest.approx(50.0 * 0.05)  # force gain x commanded speed into the surface
    np.testing.assert_allclose(ctx.of("pose")[-1].position_m[2], 0.025 + 0.008, atol=1e-9)  # resting on it


def test_an_effector_sent_beyond_the_world_ends_the_run_naming_it() -> None:
    """An outside fuzzer held a 999 m/s command (within the input range) until the probe was kilometres
    away; every other node then refused every pose for good. The simulation ends the run instead."""
    ctx = FakeCtx()
    node = _probe_node(ctx, duration_s=2.0)
    node.step()
    node.on_velocity(
        CartesianVelocityCommand(stamp_ns=0, linear_m_s=np.array([0.0, 0.0, 999.0]), angular_rad_s=np.zeros(3))
    )
    while not ctx.stop_requested and node.step() is not None:
        pass
    assert "the effector left the world" in ctx.stop_requested and "beyond 1000 m" in ctx.stop_requested
    heights = [p.position_m[2] for p in ctx.of("pose")]
    assert heights[-2] <= 1e3 < heights[-1]  # it stops at the first pose beyond


# --- finger ----------------------------------------------------------------------------------------

FINGER = {"effector": "finger", "object": {"kind": "cube"}}


def test_finger_scene_publishes_joint_states_on_sensor_and_truth_topics(tmp_path: Path) -> None:
    path = tmp_path / "finger.yaml"
    path.write_text(
        "nodes:\n  - name: sim\n    type: sim\n    params:\n      scene: {effector: finger, object: {kind: cube}}\n"
        "  - name: noise\n    type: noise\n"
    )
    graph = resolve(load_launch(path), bus_dir=tmp_path / "bus")
    sim = graph.by_name["sim"]
    assert sim.publishes["joint_states"] == topics.JOINT_STATES == "sensors/joint_states"
    assert sim.publishes["truth_joint_states"] == topics.TRUTH_JOINT_STATES == "truth/joint_states"
    assert sim.subscribes == {}  # the scripted motion drives it
    assert graph.by_name["noise"].subscribes == {"joint_states": topics.JOINT_STATES}
    # without the scripted motion it takes joint commands
    assert set(SPEC.with_params({"scene": FINGER, "scripted_motion": False}).inputs) == {"joint_commands"}

    ctx = FakeCtx()
    node = SimNode(_config(scene=FINGER, duration_s=0.05, scripted_motion=False), ctx)
    names = list(node.sim.joint_names)
    assert len(names) == 4
    node.step()
    node.on_joint_commands(JointCommand(stamp_ns=0, names=names[::-1], positions_rad=np.array([0.0, 0.2, 0.3, 0.4])))
    _run(node)
    sensed, truth = ctx.of("joint_states"), ctx.of("truth_joint_states")
    assert len(sensed) == len(truth) == 6
    for a, b in zip(sensed, truth, strict=True):
        assert a.names == b.names == names
        np.testing.assert_array_equal(a.positions_rad, b.positions_rad)
    assert sensed[-1].positions_rad[0] > 0.05  # the reversed names were mapped: mcp flexion (0.4) moves
    with pytest.raises(InputError, match=r"names: lacks 2 of the 4 names needed: 'index_pip', 'index_dip'"):
        node.on_joint_commands(JointCommand(stamp_ns=0, names=names[:2], positions_rad=np.zeros(2)))


def test_huge_time_step_stops_the_node_naming_it_and_no_nan_is_published() -> None:
    scene = {"effector": "finger", "timestep_s": 0.5, "finger": {"kp_nm_per_rad": 1000.0}, "object": {"kind": "cube"}}
    ctx = FakeCtx()
    node = SimNode(_config(scene=scene, tick_period_s=0.5, duration_s=100.0, scripted_motion=False), ctx)
    node.step()
    names = list(node.sim.joint_names)
    node.on_joint_commands(JointCommand(stamp_ns=0, names=names, positions_rad=np.array([0.0, 1.2, 0.0, 0.0])))
    with pytest.raises(SimulationDivergedError) as info:
        for _ in range(100):
            node.step()
    message = str(info.value)
    assert "time step 0.5 s" in message and "timestep_s: 0.25" in message
    for _, published in ctx.published:  # every message was validated; check once more for NaN
        for value in vars(published).values():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                assert np.all(np.isfinite(value))


def test_the_fake_context_refuses_nan() -> None:
    """The divergence test above relies on publish() rejecting NaN."""
    nan_pose = Pose(
        stamp_ns=0,
        frame="fingertip",
        position_m=np.array([0.0, math.nan, 0.0]),
        quaternion_wxyz=np.array([1.0, 0, 0, 0]),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )
    with pytest.raises(NonFiniteError):
        FakeCtx().publish("pose", nan_pose)


# --- launch validation of truth topics --------------------------------------------------------------


def _marked_line(name: str) -> str:
    lines = (REPO_ROOT / DATA / name).read_text().splitlines()
    hits = [i + 1 for i, line in enumerate(lines) if MARKER in line]
    assert len(hits) == 1
    return f"{DATA / name}:{hits[0]}"


def _load_from_repo(path: Path, bus: Path, monkeypatch: pytest.MonkeyPatch) -> Graph:
    monkeypatch.chdir(REPO_ROOT)
    return resolve(load_launch(path), bus_dir=bus)


def test_truth_joint_states_into_a_non_evaluator_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    name = "sim_truth_to_noise.yaml"
    with pytest.raises(LaunchError) as info:
        _load_from_repo(DATA / name, tmp_path, monkeypatch)
    message = str(info.value)
    assert message.startswith(f"{_marked_line(name)}: "), message
    assert "node 'noise' reads ground truth 'truth/joint_states' on port 'joint_states'; only evaluators" in message
    assert "evaluator: true" in message  # says how to allow it


def test_truth_joint_states_into_an_evaluator_is_accepted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text = (REPO_ROOT / DATA / "sim_truth_to_noise.yaml").read_text()
    path = tmp_path / "evaluator.yaml"
    path.write_text(text.replace("    type: noise\n", "    type: noise\n    evaluator: true\n"))
    graph = _load_from_repo(path, tmp_path / "bus", monkeypatch)
    assert graph.by_name["noise"].evaluator
    assert graph.by_name["noise"].subscribes == {"joint_states": "truth/joint_states"}
