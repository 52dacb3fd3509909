"""The Haptic SLAM graphs: map_known.yaml and fastslam.yaml run as processes and start only what they
need; at sigma 0 the evaluation graph's FastSLAM map is the known-pose map; a mapper process fed a
NaN joint angle rejects it, counts it and keeps mapping."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.description import load_hand
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.messages import codec, topics
from palpate.messages.schemas import ContactSet, JointState, OccupancyGrid
from palpate.paths import REPO_ROOT
from palpate.runtime.inprocess import InProcessGraph
from tests.integration.launch_helpers import launched, node_pids, text
from tests.integration.test_bad_input import Harness, counters, node_process

LAUNCH = REPO_ROOT / "launch"


# --- launch files --------------------------------------------------------------------------------------
def test_map_known_starts_sim_and_a_known_pose_mapper_only() -> None:
    graph = resolve(load_launch(LAUNCH / "map_known.yaml"))
    assert sorted((n.name, n.type) for n in graph.nodes) == [("mapper", "mapper"), ("sim", "sim")]
    (mapper,) = [p for p in graph.process_specs() if p.name == "mapper"]
    assert mapper.params["mapper"]["mode"] == "known"
    assert mapper.subscribes["joint_states"] == topics.JOINT_STATES  # the simulator's noise-free joint sensor
    assert "particles" not in mapper.publishes and "weighted_map" not in mapper.publishes


def test_fastslam_starts_sim_noise_and_a_fastslam_mapper_on_the_noisy_angles() -> None:
    graph = resolve(load_launch(LAUNCH / "fastslam.yaml"))
    assert sorted((n.name, n.type) for n in graph.nodes) == [("mapper", "mapper"), ("noise", "noise"), ("sim", "sim")]
    (mapper,) = [p for p in graph.process_specs() if p.name == "mapper"]
    assert mapper.params["mapper"]["mode"] == "fastslam"
    assert mapper.subscribes["joint_states"] == topics.NOISY_JOINT_STATES
    assert {"map", "weighted_map", "particles"} <= set(mapper.publishes)


def test_dry_run_of_map_known_lists_no_noise_node() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "palpate.cli", "launch", str(LAUNCH / "map_known.yaml"), "--dry-run"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout
    assert "sim (sim)" in out and "mapper (mapper)" in out
    assert "noise" not in out and "joint_states_noisy" not in out


def test_slam_eval_graph_has_three_mappers_on_distinct_map_topics() -> None:
    graph = resolve(load_launch(LAUNCH / "slam_eval.yaml"))
    specs = {p.name: p for p in graph.process_specs()}
    assert {specs[n].publishes["map"] for n in ("mapper_known", "mapper_dead_reckoning", "mapper_fastslam")} == {
        "map/known",
        "map/dead_reckoning",
        "map/fastslam",
    }
    assert specs["mapper_known"].subscribes["joint_states"] == topics.JOINT_STATES
    assert specs["mapper_dead_reckoning"].subscribes["joint_states"] == topics.NOISY_JOINT_STATES
    assert specs["mapper_fastslam"].params["mapper"]["mode"] == "fastslam"
    assert specs["mapper_dead_reckoning"].params["mapper"]["mode"] == "known"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["map_known.yaml", "fastslam.yaml"])
def test_slam_launch_file_runs_to_completion(tmp_path: Path, name: str) -> None:
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    args = ["duration_s:=1"] + (["particles:=10"] if name == "fastslam.yaml" else [])
    with launched(LAUNCH / name, bus_dir, log, *args) as proc:
        assert proc.wait(timeout=90) == 0, text(log)
    assert node_pids(bus_dir) == {}  # every node exited and removed its manifest


# --- sigma 0 through the graph ---------------------------------------------------------------------------
@pytest.mark.slow
def test_at_sigma_zero_the_fastslam_map_is_the_known_pose_map() -> None:
    maps: dict[str, OccupancyGrid] = {}

    def listen(tick: int, node: str, topic: str, message: Any) -> None:
        if topic in ("map/known", "map/dead_reckoning", "map/fastslam"):
            maps[topic] = message  # the last one wins: the map after the last update

    args = {"duration_s": 1.5, "sigma_deg": 0.0, "particles": 5, "publish_period_s": 0.5}
    graph = InProcessGraph(resolve(load_launch(LAUNCH / "slam_eval.yaml", args)).in_process_members(), listener=listen)
    assert graph.run() == 151
    known = maps["map/known"]
    assert known.stamp_ns == 1_500_000_000 and int(np.count_nonzero(known.log_odds > 0)) > 0  # it touched the cube
    for topic in ("map/dead_reckoning", "map/fastslam"):
        np.testing.assert_array_equal(maps[topic].cell_indices, known.cell_indices)
        np.testing.assert_array_equal(maps[topic].log_odds, known.log_odds)
    core = graph.node("mapper_fastslam").core
    for k in range(5):  # every particle, not only the best
        m = core.grids.to_sparse(k)
        np.testing.assert_array_equal(m.flat, known.cell_indices)
        np.testing.assert_array_equal(m.log_odds, known.log_odds)


@pytest.mark.parametrize("name", ["map_known", "fastslam", "slam_eval"])
def test_every_mapper_models_the_simulators_finger(name: str) -> None:
    """The mapper's chain (hand description at its mount) is the simulator's model of the finger, bit for bit."""
    from palpate.nodes.mapper.kinematics import KinematicChain
    from palpate.nodes.sim.scene import build_model

    graph = resolve(load_launch(LAUNCH / f"{name}.yaml"))
    scene = graph.by_name["sim"].config.scene
    mappers = [n for n in graph.nodes if n.type == "mapper"]
    assert mappers
    q = np.random.default_rng(0).uniform(-1.5, 1.5, size=(20, 4))
    for mapper in mappers:
        chain = KinematicChain.from_description(load_hand(), mapper.config.mount)
        assert (mapper.config.mount.finger, mapper.config.mount.effector) == (scene.finger_config().finger, "finger")
        truth = KinematicChain.from_model(build_model(scene), chain.joint_names)
        for got, expected in zip(chain.forward(q), truth.forward(q), strict=True):
            np.testing.assert_array_equal(got, expected)


# --- NaN in a joint reading ---------------------------------------------------------------------------
@contextmanager
def mapper_node(tmp_path: Path) -> Iterator[Harness]:
    """A known-pose mapper node process in lockstep mode, fed by the test's own publisher."""
    with node_process(
        tmp_path,
        name="mapper",
        node_type="mapper",
        params={
            "mapper": {"mode": "known", "region_min_m": [-0.045] * 3, "region_max_m": [0.045] * 3},
        },
        publishes={"map": topics.OCCUPANCY_GRID},
        subscribes={"joint_states": topics.JOINT_STATES, "contacts": topics.CONTACTS},
        wanted={topics.JOINT_STATES: 1, topics.CONTACTS: 1, topics.CLOCK: 1, topics.GRAPH_CONTROL: 1},
        timeout_s=60.0,  # the mapper builds its finger model at start-up
    ) as harness:
        yield harness


def _reading(tick: int, names: list[str], nan: bool = False) -> bytes:
    q = np.radians([0.0, 20.0, 30.0, 20.0])[: len(names)]
    if nan:
        q[1] = np.nan
    state = JointState(stamp_ns=tick * 10_000_000, names=names, positions_rad=q, velocities_rad_s=np.zeros(len(q)))
    return codec.encode(state)  # encode() does not validate: the NaN reaches the wire


def _no_contacts(tick: int) -> bytes:
    empty = np.zeros((0, 3))
    return codec.encode(
        ContactSet(
            stamp_ns=tick * 10_000_000,
            positions_m=empty,
            local_positions_m=empty,
            normals=empty,
            forces_n=np.zeros(0),
            links=[],
        )
    )


def test_a_nan_joint_angle_is_rejected_counted_and_the_mapper_goes_on(tmp_path: Path) -> None:
    names = load_hand().digit("index").joint_names()
    with mapper_node(tmp_path) as node:
        node.send(topics.JOINT_STATES, _reading(0, names, nan=True))
        node.send(topics.CONTACTS, _no_contacts(0))
        node.tick(0)
        assert node.proc.poll() is None, "the mapper died of a NaN joint angle"
        for tick in (1, 2):
            node.send(topics.JOINT_STATES, _reading(tick, names))
            node.send(topics.CONTACTS, _no_contacts(tick))
            node.tick(tick)
        time.sleep(0.1)
        assert node.stop() == 0, text(node.log)
    finished = node.statuses[-1]
    assert (finished.node, finished.state) == ("mapper", "finished")
    assert counters(finished)["decode_errors"] == 1  # the NaN reading, refused by the codec
    assert counters(finished)["messages_in"] == 5  # the other five messages
    metrics = dict(zip(finished.metric_names, finished.metric_values.tolist(), strict=True))
    assert metrics["updates"] == 2.0  # both good readings were mapped
    assert "JointState.positions_rad must be finite" in text(node.log)
