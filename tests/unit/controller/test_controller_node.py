"""Controller node in-process: a first approach that finds no surface stops the run with advice."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pytest

from palpate.errors import InputError
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import ContactSet, TouchTarget
from palpate.nodes.controller.contact_check import JUDGED_SETS
from palpate.nodes.controller.node import ControllerNode, ControllerNodeConfig
from palpate.nodes.controller.trajectory import ControllerConfig
from tests.unit.node_messages import no_contacts, pose

#: The probe's orientation in these tests: its poking axis along -z.
FACING_DOWN = (0.0, 1.0, 0.0, 0.0)


class FakeCtx:
    """What ControllerNode sees of the runtime."""

    def __init__(self) -> None:
        self.stamp_ns = 0
        self.metrics: dict[str, float] = {}
        self.published: list[tuple[str, Any]] = []
        self.stop_reason = ""
        self.stop_failed = False
        self.log = logging.getLogger("palpate.test.controller")

    def publish(self, port: str, message: Message) -> None:
        codec.validate(message)
        self.published.append((port, message))

    def request_stop(self, reason: str, *, failed: bool = False) -> None:
        self.stop_reason = self.stop_reason or reason
        self.stop_failed = self.stop_failed or failed


def approach_into_nothing(config: ControllerNodeConfig, start: list[float], ticks: int) -> tuple[FakeCtx, np.ndarray]:
    """Drive the node's first approach from `start`, facing down, without a contact, until it stops the
    run or `ticks` pass (the fingertip moves by each velocity command); returns the context and the
    fingertip's last position."""
    ctx = FakeCtx()
    node = ControllerNode(config, ctx)
    position, dt = np.array(start), 0.01
    node.on_contacts(no_contacts())
    for tick in range(ticks):
        node.on_pose(pose(position, FACING_DOWN, "probe"))
        node.on_tick(tick * 10_000_000)
        if ctx.stop_reason:
            break
        _, velocity = ctx.published[-1]
        position = position + dt * np.asarray(velocity.linear_m_s)
    return ctx, position


def test_initial_approach_that_finds_no_surface_stops_with_the_target_and_the_launch_arguments() -> None:
    # 5 cm + 1 cm miss distance at 5 cm/s: fails after about 1.2 s
    ctx, position = approach_into_nothing(ControllerNodeConfig(initial_target_m=(0.0, 0.0, 0.0)), [0.0, 0.0, 0.05], 200)
    assert "initial approach" in ctx.stop_reason and ctx.stop_failed
    assert "[0.0, 0.0, 0.0]" in ctx.stop_reason and "target:=" in ctx.stop_reason
    assert 0.059 < -position[2] + 0.05 < 0.062  # it went 1 cm past the target before giving up


def test_an_approach_along_the_poking_axis_that_finds_nothing_names_the_start_arguments() -> None:
    # no initial target: 0.5 m along the axis + 1 cm at 5 cm/s, fails after about 10.2 s
    ctx, position = approach_into_nothing(ControllerNodeConfig(), [0.01, 0.0, 0.0], 2000)
    assert "poking axis" in ctx.stop_reason and "start_quaternion:=" in ctx.stop_reason and ctx.stop_failed
    assert position[:2] == pytest.approx([0.01, 0.0]) and -position[2] == pytest.approx(0.51, abs=0.002)


def _target(
    position: list[float], normal: list[float], slide: bool = False, miss_distance_m: float = 0.0
) -> TouchTarget:
    return TouchTarget(
        stamp_ns=0,
        strategy="igef",
        position_m=np.array(position),
        normal=np.array(normal),
        predicted_contact_m=np.array(position),
        score=1.0,
        candidates_m=np.zeros((0, 3)),
        candidate_scores=np.zeros(0),
        slide=slide,
        miss_distance_m=miss_distance_m,
    )


def _contact(position: list[float]) -> ContactSet:
    return ContactSet(
        stamp_ns=0,
        positions_m=np.array([position]),
        local_positions_m=np.zeros((1, 3)),
        normals=np.array([[0.0, 0.0, 1.0]]),
        forces_n=np.ones(1),
        links=["probe"],
    )


@pytest.mark.parametrize(("slide", "kind"), [(False, "approach"), (True, "slide")])
def test_a_target_to_slide_to_is_published_as_a_slide_and_followed_along_the_surface(slide: bool, kind: str) -> None:
    ctx = FakeCtx()
    node = ControllerNode(ControllerNodeConfig(initial_target_m=(0.0, 0.0, -0.01)), ctx)
    centre = np.array([0.0, 0.0, 0.008])  # the fingertip resting on the plane z = 0 at the origin
    node.on_pose(pose(centre, FACING_DOWN, "probe"))
    node.on_contacts(_contact([0.0, 0.0, 0.0]))
    node.on_tick(0)
    assert [m for port, m in ctx.published if port == "touches"]  # the first touch
    node.on_target(_target([0.02, 0.0, 0.0], [0.0, 0.0, 1.0], slide=slide))
    [trajectory] = [m for port, m in ctx.published if port == "trajectory"]
    assert trajectory.kind == kind
    node.on_tick(10_000_000)
    velocity = ctx.published[-1][1].linear_m_s
    if slide:  # along the surface, pressing lightly
        np.testing.assert_allclose(velocity, [0.05, 0.0, -0.01])
    else:  # Eq. 15: up first
        assert velocity[2] > 0.0


def test_bad_poses_and_targets_are_refused_and_change_nothing() -> None:
    """The issue's crashes (a zero or 1e-200 quaternion, extreme targets) are InputErrors naming the field;
    a node that received them publishes exactly what a node that never did publishes."""
    config = ControllerNodeConfig(initial_target_m=(0.0, 0.0, 0.0))
    clean, fed = ControllerNode(config, FakeCtx()), ControllerNode(config, FakeCtx())
    bad_poses = [[0.0, 0.0, 0.0, 0.0], [1e-200, 0.0, 0.0, 0.0], [1e200, 0.0, 0.0, 0.0]]
    bad_targets = [([1e300, 0.0, 0.0], [0.0, 0.0, 1.0]), ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])]
    bad_targets.append(([999.0, 0.0, 0.0], [0.0, 0.0, 1.0]))  # within 1 km, but a 1.2 km approach: hours
    position = np.array([0.0, 0.0, 0.05])
    for tick in range(30):
        for node in (clean, fed):
            node.on_pose(pose(position, FACING_DOWN, "probe"))
            if tick == 10:
                node.on_target(_target([0.01, 0.0, 0.0], [0.0, 0.0, 1.0]))
        for q in bad_poses:
            bad = pose(position, FACING_DOWN, "probe")
            object.__setattr__(bad, "quaternion_wxyz", np.array(q))
            with pytest.raises(InputError, match=r"^quaternion_wxyz: norm"):
                fed.on_pose(bad)
        for p, n in bad_targets:
            with pytest.raises(InputError, match=r"^(position_m|normal): "):
                fed.on_target(_target(p, n))
        for miss in (-0.01, 1.0):  # a negative reach past the target, or one far beyond any object
            with pytest.raises(InputError, match=r"^miss_distance_m: "):
                fed.on_target(_target([0.01, 0.0, 0.0], [0.0, 0.0, 1.0], miss_distance_m=miss))
        for node in (clean, fed):
            node.on_tick(tick * 10_000_000)
        position = position + 0.01 * np.asarray(clean.ctx.published[-1][1].linear_m_s)
    assert len(clean.ctx.published) == len(fed.ctx.published) > 30
    for (port_a, a), (port_b, b) in zip(clean.ctx.published, fed.ctx.published, strict=True):
        assert port_a == port_b and a == b


def _contact_at(position_m: list[float]) -> ContactSet:
    p = np.array([position_m])
    return ContactSet(
        stamp_ns=0,
        positions_m=p,
        local_positions_m=p,
        normals=np.array([[0.0, 0.0, 1.0]]),
        forces_n=np.ones(1),
        links=["probe"],
    )


def test_a_contact_no_part_of_the_fingertip_can_make_is_refused() -> None:
    """A driver's contact in millimetres (25 m away) had sent the fingertip climbing for the rest of the run."""
    ctx = FakeCtx()
    node = ControllerNode(ControllerNodeConfig(initial_target_m=(0.0, 0.0, 0.0)), ctx)
    node.on_contacts(_contact_at([0.0, 0.0, 25.0]))  # before any pose: nothing to check it against, dropped
    assert len(node.contacts[0]) == 0
    node.on_pose(pose(np.array([0.0, 0.0, 0.025]), FACING_DOWN, "probe"))
    node.on_contacts(_contact_at([0.0, 0.0, 0.017]))  # on the fingertip's surface, 8 mm below its centre
    node.on_contacts(_contact_at([0.0, 0.0, 0.13]))  # 9.7 cm beyond it: far more than noise, still taken
    with pytest.raises(
        InputError, match=r"^positions_m: entry 0 lies 24.975 m from the fingertip at \[0.0, 0.0, 0.025\]"
    ):
        node.on_contacts(_contact_at([0.0, 0.0, 25.0]))
    np.testing.assert_array_equal(node.contacts[0], [[0.0, 0.0, 0.13]])  # the state before the refused set


@pytest.mark.parametrize(
    ("v0", "tick_ns", "stops"),
    [(0.05, 10_000_000, False), (0.8, 10_000_000, False), (100.0, 10_000_000, True), (0.05, 10_000_000_000, True)],
)
def test_a_tick_that_carries_the_fingertip_past_its_radius_stops_the_run_naming_both_knobs(
    v0: float, tick_ns: int, stops: bool
) -> None:
    ctx = FakeCtx()
    config = ControllerNodeConfig(controller=ControllerConfig(v0_m_s=v0))
    node = ControllerNode(config, ctx)
    node.on_contacts(no_contacts())
    for tick in range(3):
        node.on_pose(pose(np.array([0.0, 0.0, 0.05]), FACING_DOWN, "probe"))
        node.on_tick(tick * tick_ns)
    assert ctx.stop_failed == stops
    if stops:
        assert "v0_m_s" in ctx.stop_reason and "tick_period_s" in ctx.stop_reason and "8 mm radius" in ctx.stop_reason


def test_inward_normals_are_logged_once_by_the_node(caplog: pytest.LogCaptureFixture) -> None:
    ctx = FakeCtx()
    node = ControllerNode(ControllerNodeConfig(initial_target_m=(0.0, 0.0, 0.0)), ctx)
    node.on_pose(pose(np.array([0.0, 0.0, 0.025]), FACING_DOWN, "probe"))
    inward = _contact_at([0.0, 0.0, 0.017])
    inward.normals[:] = [0.0, 0.0, -1.0]  # the object lies below: its outward normal is +z
    with caplog.at_level(logging.WARNING):
        for _ in range(3 * JUDGED_SETS):
            node.on_contacts(inward)
    notes = [r.getMessage() for r in caplog.records if "point into the fingertip" in r.getMessage()]
    assert len(notes) == 1 and notes[0].startswith("controller: in 10 of the first 10 contact sets")
