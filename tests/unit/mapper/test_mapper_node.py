"""Mapper node: a joint reading without the finger's joints (the issue's subset, duplicated, unknown, empty
or 50,000-joint readings) is refused naming the field, and the map is then exactly that of a clean run."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pytest

from palpate.config import load
from palpate.errors import InputError
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.messages.base import Message
from palpate.messages.schemas import ContactSet, JointState
from palpate.nodes.mapper.node import MapperNode, MapperNodeConfig
from palpate.paths import LAUNCH_DIR
from palpate.runtime.node import NodeContext


def mapper(file: str) -> tuple[MapperNode, list[tuple[str, Message]]]:
    process = next(p for p in resolve(load_launch(LAUNCH_DIR / file)).process_specs() if p.type == "mapper")
    sent: list[tuple[str, Message]] = []
    ctx = NodeContext("mapper", 1, lambda topic, message: sent.append((topic, message)), dict(process.publishes))
    config: Any = load(MapperNodeConfig, process.params)
    return MapperNode(config, ctx), sent


def reading(names: list[str], q: np.ndarray, stamp_ns: int) -> JointState:
    return JointState(stamp_ns=stamp_ns, names=names, positions_rad=q, velocities_rad_s=np.zeros(len(names)))


def contacts(links: list[str], local: np.ndarray, stamp_ns: int) -> ContactSet:
    n = len(links)
    return ContactSet(
        stamp_ns=stamp_ns,
        positions_m=np.zeros((n, 3)),
        local_positions_m=local,
        normals=np.tile([0.0, 0.0, 1.0], (n, 1)),
        forces_n=np.ones(n),
        links=links,
    )


@pytest.mark.parametrize("file", ["map_known.yaml", "fastslam.yaml"])
def test_readings_without_the_joints_are_refused_and_change_nothing(file: str) -> None:
    clean, clean_out = mapper(file)
    fed, fed_out = mapper(file)
    joints = list(clean.chain.joint_names)
    tip = clean.chain.link_names[-1]
    bad = [
        ([], "lacks 4 of the 4"),
        (joints[:2], "lacks 2 of the 4"),
        ([*joints, joints[0]], "repeats needed name"),
        (["", "", "", ""], "lacks 4 of the 4"),
        ([f"joint_{i}" for i in range(50_000)], "lacks 4 of the 4"),
    ]
    rng = np.random.default_rng(0)
    for tick in range(20):
        stamp = tick * 10_000_000
        q = np.radians([0.0, 20.0, 30.0, 10.0]) + 0.01 * rng.standard_normal(4)
        touch = contacts([tip], np.array([[0.0, 0.0, -0.008]]), stamp)
        for node in (clean, fed):
            node.on_joint_states(reading(joints[::-1], q[::-1], stamp))  # any order: the names say which is which
            node.on_contacts(touch)
        for names, reason in bad:
            with pytest.raises(InputError, match=rf"^names: {reason}"):
                fed.on_joint_states(reading(names, np.zeros(len(names)), stamp))
        with pytest.raises(InputError, match=r"^local_positions_m: coordinate 1e\+300 m"):
            fed.on_contacts(contacts([tip], np.array([[0.0, 1e300, 0.0]]), stamp))
        for node in (clean, fed):
            node.on_tick(stamp)
    assert clean.core.counters.updates == fed.core.counters.updates == 20
    assert clean.core.counters.contacts == 20
    assert len(clean_out) == len(fed_out) > 0
    for (topic_a, a), (topic_b, b) in zip(clean_out, fed_out, strict=True):
        assert topic_a == topic_b and a == b


@pytest.mark.parametrize("file", ["map_known.yaml", "fastslam.yaml"])
def test_a_region_that_misses_every_contact_is_said_once(file: str) -> None:
    """An outside audit: a region beside the object mapped nothing, exit 0, no line in the log; the counts
    were kept in the core only."""
    process = next(p for p in resolve(load_launch(LAUNCH_DIR / file)).process_specs() if p.type == "mapper")
    params = {**process.params, "mapper": {**process.params["mapper"]}}
    params["mapper"].update(region_min_m=[1.0, 1.0, 1.0], region_max_m=[1.1, 1.1, 1.1])
    ctx = NodeContext("mapper", 1, lambda topic, message: None, dict(process.publishes))
    node = MapperNode(load(MapperNodeConfig, params), ctx)
    said: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: said.append(record.getMessage())  # type: ignore[method-assign]
    ctx.log.addHandler(handler)
    joints, tip = list(node.chain.joint_names), node.chain.link_names[-1]
    for tick in range(30):
        stamp = tick * 10_000_000
        node.on_joint_states(reading(joints, np.radians([0.0, 20.0, 30.0, 10.0]), stamp))
        node.on_contacts(contacts([tip], np.array([[0.0, 0.0, -0.008]]), stamp))
        node.on_tick(stamp)
    assert ctx.counters["contacts_outside"] == node.core.grids.n_maps * 30
    ctx.log.removeHandler(handler)
    said = [m for m in said if "outside the mapped region" in m]
    assert len(said) == 1 and "the first 10 contacts" in said[0]
    assert "give the contacts' local_positions_m in metres" in said[0]  # contacts in millimetres lie far out


def test_a_run_that_ends_between_two_publications_publishes_its_last_maps_at_the_end() -> None:
    """An outside walkthrough: map_known.yaml with duration_s:=2.5 recorded no map after 2.0 s, and
    slam_eval.yaml launched for 5 s (10 s period) none after 0 s."""
    node, sent = mapper("map_known.yaml")
    joints = list(node.chain.joint_names)
    for tick in range(251):  # 0 .. 2.5 s; maps at 0, 1 and 2 s
        node.on_joint_states(reading(joints, np.radians([0.0, 20.0, 30.0, 10.0]), tick * 10_000_000))
        node.on_tick(tick * 10_000_000)
    stamps = [m.stamp_ns for topic, m in sent if topic == "map/occupancy"]
    assert stamps == [0, 1_000_000_000, 2_000_000_000]
    node.ctx.failure = "controller: lost"  # a failed run's state is not published as its last maps
    node.close()
    assert [m.stamp_ns for topic, m in sent if topic == "map/occupancy"] == stamps
    node.ctx.failure = ""
    node.close()
    node.close()  # once: the last maps are then the newest
    assert [m.stamp_ns for topic, m in sent if topic == "map/occupancy"][3:] == [2_500_000_000]


def test_maps_are_published_again_after_a_real_time_clock_went_back() -> None:
    """An outside walkthrough: a real-time glove driver restarted with stamps from 0, and the mapper
    published no map for the rest of the run (its next publication stayed at the old clock's time)."""
    node, sent = mapper("map_known.yaml")
    joints = list(node.chain.joint_names)
    stamps = [tick * 10_000_000 for tick in range(301)] + [tick * 10_000_000 for tick in range(151)]  # 0..3 s, 0..1.5 s
    for stamp in stamps:
        node.on_joint_states(reading(joints, np.radians([0.0, 20.0, 30.0, 10.0]), stamp))
        node.on_tick(stamp)
    published = [m.stamp_ns for topic, m in sent if topic == "map/occupancy"]
    assert published == [0, 1_000_000_000, 2_000_000_000, 3_000_000_000, 0, 1_000_000_000]


def test_contacts_of_a_driver_s_former_run_are_dropped_when_its_clock_goes_back() -> None:
    """The review: contacts stamped 1.01 s before a driver's restart stayed pending and, at the new run's
    1.01 s, won over that run's own contacts."""
    node, _ = mapper("map_known.yaml")
    joints, tip = list(node.chain.joint_names), node.chain.link_names[-1]
    q = np.radians([0.0, 20.0, 30.0, 10.0])
    for tick in range(101):  # 0 .. 1.0 s; then the driver sends contacts at 1.01 s and dies
        node.on_joint_states(reading(joints, q, tick * 10_000_000))
        node.on_tick(tick * 10_000_000)
    node.on_contacts(contacts([tip], np.array([[0.0, 0.0, -0.008]]), 1_010_000_000))
    node.on_joint_states(reading(joints, q, 0))  # restarted from 0
    node.on_tick(0)
    assert node.session.contacts_unmatched == 1 and node.session.last_unmatched == (1_010_000_000, 0)
    for tick in range(1, 102):  # the new run's own contacts at 1.01 s take its reading of that stamp
        stamp = tick * 10_000_000
        node.on_joint_states(reading(joints, q, stamp))
        if tick == 101:
            node.on_contacts(contacts([tip], np.array([[0.0, 0.0, -0.008]]), stamp))
        node.on_tick(stamp)
    assert node.session.contacts_unmatched == 1 and node.core.counters.contacts == 1


def test_contacts_stamped_apart_are_not_blamed_on_a_reading_refused_earlier(caplog: pytest.LogCaptureFixture) -> None:
    """The review: one reading refused early made every later unmatched contact "refused"."""
    from palpate.errors import InputError

    node, _ = mapper("map_known.yaml")
    joints, tip = list(node.chain.joint_names), node.chain.link_names[-1]
    with pytest.raises(InputError):
        node.on_joint_states(reading(joints, np.array([0.0, 20.0, 30.0, 10.0]), 10_000_000))  # degrees
    with caplog.at_level(logging.WARNING):
        for tick in range(2, 5):
            node.on_joint_states(reading(joints, np.zeros(4), tick * 10_000_000))
            node.on_contacts(contacts([tip], np.array([[0.0, 0.0, 0.01]]), tick * 10_000_000 + 1))
            node.on_tick(tick * 10_000_000)
    assert node.ctx.counters["contacts_unmatched"] == 2
    assert "slower than the tick" in caplog.text and "were refused" not in caplog.text


def test_contacts_on_another_finger_are_counted_and_said_once() -> None:
    """An outside walkthrough: a hand scene tapping with the index finger and a mapper of the ring finger
    mapped nothing, without a count or a word."""
    node, _ = mapper("map_known.yaml")
    said: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: said.append(record.getMessage())  # type: ignore[method-assign]
    node.ctx.log.addHandler(handler)
    joints = list(node.chain.joint_names)
    try:
        for tick in range(12):
            stamp = tick * 10_000_000
            node.on_joint_states(reading(joints, np.radians([0.0, 20.0, 30.0, 10.0]), stamp))
            node.on_contacts(contacts(["ring_distal"], np.array([[0.0, 0.0, -0.008]]), stamp))
            node.on_tick(stamp)
    finally:
        node.ctx.log.removeHandler(handler)
    assert node.ctx.counters["contacts_off_finger"] == 12
    finger = [m for m in said if "another finger" in m]
    assert len(finger) == 1 and "the first 10 contacts all lie on links its index finger does not have" in finger[0]
    # an outside walkthrough: a driver's name that is no link of the hand was told to set mount.finger only
    assert "('ring_distal', where its links are index_" in finger[0] and "no link of the hand description" in finger[0]


def test_contacts_whose_joint_readings_were_refused_are_said_so(caplog: pytest.LogCaptureFixture) -> None:
    """An outside walkthrough: a glove sending degrees had its readings refused, and the contacts left
    without a reading were blamed on a mapper slower than the tick, in a lockstep run."""
    from palpate.errors import InputError

    node, _ = mapper("map_known.yaml")
    joints, tip = list(node.chain.joint_names), node.chain.link_names[-1]
    with caplog.at_level(logging.WARNING):
        for tick in range(1, 4):
            with pytest.raises(InputError, match="more than a full turn: degrees sent as radians"):
                node.on_joint_states(reading(joints, np.array([0.0, 20.0, 30.0, 10.0]), tick * 10_000_000))
            node.on_contacts(contacts([tip], np.array([[0.0, 0.0, 0.01]]), tick * 10_000_000))
            node.on_tick(tick * 10_000_000)
        node.on_joint_states(reading(joints, np.radians([0.0, 20.0, 30.0, 10.0]), 40_000_000))  # in radians
        node.on_tick(40_000_000)
    assert node.session.readings_refused == 3 and node.ctx.counters["contacts_unmatched"] == 3
    assert "joint readings were refused (said above; 3 so far), and their contacts with them" in caplog.text
    assert "slower than the tick" not in caplog.text


def test_a_contact_outside_the_region_among_others_inside_is_said_once() -> None:
    """An outside walkthrough: on the YCB banana 18 contacts fell outside the region, counted in the
    status only; the maps left them out without a word."""
    node, _ = mapper("map_known.yaml")
    said: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: said.append(record.getMessage())  # type: ignore[method-assign]
    node.ctx.log.addHandler(handler)
    joints, tip = list(node.chain.joint_names), node.chain.link_names[-1]
    try:
        for tick in range(20):
            stamp = tick * 10_000_000
            node.on_joint_states(reading(joints, np.radians([0.0, 20.0, 30.0, 10.0]), stamp))
            away = 0.5 if tick % 4 == 3 else 0.0  # every fourth contact half a metre off the fingertip
            node.on_contacts(contacts([tip], np.array([[away, 0.0, -0.008]]), stamp))
            node.on_tick(stamp)
    finally:
        node.ctx.log.removeHandler(handler)
    assert node.ctx.counters["contacts_outside"] == 5  # the others lie in the region
    outside = [m for m in said if "outside the mapped region" in m]
    assert len(outside) == 1 and outside[0].startswith("mapper: a contact lies outside the mapped region")


def test_contacts_stamped_apart_from_the_readings_are_counted_and_said_once(caplog: pytest.LogCaptureFixture) -> None:
    node, _ = mapper("map_known.yaml")
    joints, tip = list(node.chain.joint_names), node.chain.link_names[-1]
    with caplog.at_level(logging.WARNING):
        for tick in range(1, 4):
            node.on_joint_states(reading(joints, np.zeros(4), tick * 10_000_000))
            node.on_contacts(contacts([tip], np.array([[0.0, 0.0, 0.01]]), tick * 10_000_000 + 1))
            node.on_tick(tick * 10_000_000)
    assert node.ctx.counters["contacts_unmatched"] == 2  # the third may still meet a reading of its stamp
    assert caplog.text.count("mapper: contacts found no joint reading stamped within stamp_tolerance_s (0 s)") == 1


def test_a_free_volume_without_points_and_a_one_cell_map_are_said() -> None:
    """An outside walkthrough: 8 mm cells cleared nothing without a word, and resolution_m:=2 (millimetres
    meant) mapped one 2 m cell."""
    from palpate.errors import ConfigError
    from palpate.nodes.mapper.core import MapperConfig

    region = {"region_min_m": (-0.045, -0.045, -0.045), "region_max_m": (0.045, 0.045, 0.045)}
    with pytest.raises(ConfigError, match=r"resolution_m 2 leaves fewer than 2 cells across .*2 mm is 0\.002"):
        MapperConfig(**region, resolution_m=2.0)
    ctx = NodeContext("mapper", 1, lambda topic, message: None, {})
    node = MapperNode(MapperNodeConfig(mapper=MapperConfig(**region, resolution_m=0.008)), ctx)
    assert node.core.free_volume.n_points == 0 and "no free volume" in node._warned
    node = MapperNode(MapperNodeConfig(mapper=MapperConfig(**region, resolution_m=0.002)), ctx)
    assert "no free volume" not in node._warned


@pytest.mark.parametrize(
    ("resolution_m", "margin_m"), [(0.002, 0.0005), (0.004, 0.0025), (0.001, 0.0015), (0.003, 0.003)]
)
@pytest.mark.parametrize("file", ["map_known.yaml", "fastslam.yaml"])
def test_the_slam_launch_files_take_the_free_margin_measured_for_their_cells(
    file: str, resolution_m: float, margin_m: float
) -> None:
    """Two outside walkthroughs: `resolution_m:=0.004` kept the 2 mm cells' 0.5 mm margin, and the known-pose
    map scored rmse 0.209 instead of 0.018."""
    graph = resolve(load_launch(LAUNCH_DIR / file, {"resolution_m": resolution_m}))
    process = next(p for p in graph.process_specs() if p.type == "mapper")
    config: Any = load(MapperNodeConfig, process.params)
    assert config.mapper.free_margin_m == "auto"
    assert config.mapper.free_lattice() == pytest.approx((resolution_m, margin_m))


def test_a_mapper_whose_updates_will_be_slow_says_so_at_start(caplog: pytest.LogCaptureFixture) -> None:
    """An outside audit: particles:=100000 advanced fastslam.yaml 0.27 s in 5 minutes, and only the clock
    source's wait notes spoke (of the clock source)."""
    from palpate.nodes.mapper import node as node_module
    from palpate.nodes.mapper.core import MapperConfig

    region = {"region_min_m": (-0.045, -0.045, -0.045), "region_max_m": (0.045, 0.045, 0.045)}
    ctx = NodeContext("mapper", 1, lambda topic, message: None, {})
    with caplog.at_level(logging.WARNING):
        paper = MapperNode(MapperNodeConfig(mapper=MapperConfig(**region, n_particles=100)), ctx)
        points = paper.core.free_volume.n_points
        assert "costly updates" not in paper._warned and points * 100 < node_module.COSTLY_POINT_UPDATES
        many = -(-node_module.COSTLY_POINT_UPDATES // points) + 1  # just over the line
        costly = MapperNode(MapperNodeConfig(mapper=MapperConfig(**region, n_particles=many)), ctx)
    assert "costly updates" in costly._warned
    assert f"updates {points} free-volume points in each of {many} maps" in caplog.text
    assert "fewer particles" in caplog.text
