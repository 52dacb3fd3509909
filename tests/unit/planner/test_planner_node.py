"""Planner node: a touch, pose or surface it cannot use is refused naming the field, before the planner
changes (a refused surface does not use up the plan of its contact)."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.errors import InputError
from palpate.messages.base import Message
from palpate.messages.schemas import Pose, SurfaceMesh, TouchEvent, TouchTarget
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.node import PlannerNode
from palpate.runtime.node import NodeContext


def touch(position: list[float], approach: list[float]) -> TouchEvent:
    return TouchEvent(
        stamp_ns=0,
        index=0,
        position_m=np.array(position),
        normal=np.array([0.0, 0.0, 1.0]),
        approach_direction=np.array(approach),
        predicted_contact_m=np.full(3, np.nan),
        missed=False,
        travelled_m=0.0,
        rotation_deg=0.0,
    )


def pose(q: list[float]) -> Pose:
    return Pose(
        stamp_ns=0,
        frame="fingertip",
        position_m=np.array([0.0, 0.0, 0.008]),
        quaternion_wxyz=np.array(q),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )


def plane(variance: float) -> SurfaceMesh:
    """The plane z = 0 within 5 cm of the origin, 2.5 mm apart, normals +z."""
    x = np.arange(-0.05, 0.0501, 0.0025)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    n = len(x)
    quads = [(i * n + j, (i + 1) * n + j, i * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
    return SurfaceMesh(
        stamp_ns=0,
        region="local",
        num_contacts=1,
        vertices_m=V,
        faces=np.array(quads, dtype=np.int32),
        vertex_normals=np.tile([0.0, 0.0, 1.0], (len(V), 1)),
        variance_vertices=np.arange(len(V), dtype=np.int32),
        vertex_variance=np.full(len(V), variance),
    )


def test_unusable_inputs_are_refused_and_the_plan_still_comes() -> None:
    sent: list[Message] = []
    ctx = NodeContext("planner", 0, lambda topic, message: sent.append(message), {"target": "planner/target"})
    node = PlannerNode(PlannerConfig(strategy="gpv"), ctx)
    with pytest.raises(InputError, match=r"^approach_direction: norm 2, neither 0 nor 1 \(\+-0.01\)"):
        node.on_touches(touch([0.0, 0.0, 0.0], [0.0, 0.0, -2.0]))
    with pytest.raises(InputError, match=r"^approach_direction: norm 1.73205, neither 0 nor 1"):
        node.on_touches(touch([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]))  # each component within [-1, 1]
    with pytest.raises(InputError, match=r"^position_m: coordinate"):
        node.on_touches(touch([0.0, -1e30, 0.0], [0.0, 0.0, -1.0]))
    assert node.core.contacts == []
    node.on_touches(touch([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]))
    with pytest.raises(InputError, match=r"^quaternion_wxyz: norm 0 is not that of a unit quaternion"):
        node.on_pose(pose([0.0, 0.0, 0.0, 0.0]))
    node.on_pose(pose([0.0, 1.0, 0.0, 0.0]))
    with pytest.raises(InputError, match=r"^vertex_variance: value -1 m\^2 is outside \[0, 1e\+06\] m\^2"):
        node.on_surface(plane(-1.0))
    assert not sent and node.core.planned_for == 0
    node.on_surface(plane(1e-6))
    [target] = sent
    assert isinstance(target, TouchTarget) and target.strategy == "gpv"
    assert target.position_m[2] == 0.0 and np.all(np.abs(target.position_m) <= 0.05)  # a vertex of the plane


def test_a_touch_without_a_unit_normal_is_refused_as_the_gpis_node_refuses_it() -> None:
    """An outside audit: the planner took a zero normal ("unknown") that the GPIS node refused, so its
    count of contacts stayed one ahead of every surface's and it never planned again."""
    ctx = NodeContext("planner", 0, lambda topic, message: None, {"target": "planner/target"})
    node = PlannerNode(PlannerConfig(strategy="gpv"), ctx)
    event = touch([0.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    object.__setattr__(event, "normal", np.zeros(3))
    with pytest.raises(InputError, match=r"^normal: norm 0"):
        node.on_touches(event)
    assert node.core.contacts == []


def test_a_contact_that_cannot_be_planned_for_ends_the_run_with_the_reason() -> None:
    """No surface near the last contact: the contact's one plan is used up, so the node does not wait
    for ever (the run would stall) but asks the graph to stop, naming why, and counts it."""
    sent: list[Message] = []
    ctx = NodeContext("planner", 0, lambda topic, message: sent.append(message), {"target": "planner/target"})
    node = PlannerNode(PlannerConfig(strategy="igef"), ctx)
    node.on_touches(touch([1.0, 1.0, 0.0], [0.0, 0.0, -1.0]))  # 1.4 m from every vertex of the plane
    node.on_pose(pose([0.0, 1.0, 0.0, 0.0]))
    node.on_surface(plane(1e-6))
    assert not sent and ctx.counters["planning_failed"] == 1
    assert ctx.stop_requested.startswith("planner: no vertex of the local surface of 1 contacts lies within 0.05 m")
    assert "the nearest is 1.34 m away" in ctx.stop_requested  # what is wrong: the plane's corner (1 - 0.05) * sqrt 2
    assert ctx.failure == ctx.stop_requested  # a failure: palpate launch exits 1


@pytest.mark.parametrize(("reach_m", "slide"), [(0.0, False), (0.06, True)])
def test_the_target_says_whether_to_slide_to_it(reach_m: float, slide: bool) -> None:
    sent: list[Message] = []
    ctx = NodeContext("planner", 0, lambda topic, message: sent.append(message), {"target": "planner/target"})
    node = PlannerNode(PlannerConfig(strategy="tour", tour_slide_max_m=reach_m), ctx)
    node.on_touches(touch([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]))  # the touch's normal: +z, as the plane's
    node.on_pose(pose([0.0, 1.0, 0.0, 0.0]))
    node.on_surface(plane(1e-6))
    [target] = sent
    assert isinstance(target, TouchTarget) and target.slide is slide


@pytest.mark.parametrize(
    ("config", "miss_m"),
    [
        (PlannerConfig(strategy="tour"), 0.03),
        (PlannerConfig(strategy="igef"), 0.0),  # the controller's own Delta_m, as in the paper
        (PlannerConfig(strategy="igef", miss_distance_m=0.02), 0.02),
        (PlannerConfig(strategy="tour", tour_miss_distance_m=0.0, miss_distance_m=0.02), 0.02),
    ],
)
def test_the_target_says_how_far_past_it_the_fingertip_may_go(config: PlannerConfig, miss_m: float) -> None:
    sent: list[Message] = []
    ctx = NodeContext("planner", 0, lambda topic, message: sent.append(message), {"target": "planner/target"})
    node = PlannerNode(config, ctx)
    node.on_touches(touch([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]))
    node.on_pose(pose([0.0, 1.0, 0.0, 0.0]))
    node.on_surface(plane(1e-6))
    [target] = sent
    assert isinstance(target, TouchTarget) and target.miss_distance_m == miss_m


def test_a_surface_of_no_known_region_is_refused_and_one_of_other_contacts_is_said(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """An outside driver author: a gpis driver's meshes of region 'regoin', or one contact off, were skipped
    without a word and the run ended 'stalled' with exit 0."""
    from dataclasses import replace

    sent: list[Message] = []
    ctx = NodeContext("planner", 0, lambda topic, message: sent.append(message), {"target": "planner/target"})
    node = PlannerNode(PlannerConfig(strategy="gpv"), ctx)
    node.on_touches(touch([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]))
    node.on_pose(pose([0.0, 1.0, 0.0, 0.0]))
    with pytest.raises(InputError, match=r"^region: 'regoin' is no region of a surface: 'local' .* or 'global'"):
        node.on_surface(replace(plane(1e-6), region="regoin"))
    with caplog.at_level("WARNING"):
        for _ in range(2):
            node.on_surface(replace(plane(1e-6), num_contacts=2))
    assert not sent and node.core.take_counts() == {"surface_not_matching": 2}
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "a local surface of 2 contacts (SurfaceMesh.num_contacts) came after 1 touch" in said[0]
    node.on_surface(plane(1e-6))  # the touch's own surface: planned on
    assert len(sent) == 1
    node.on_touches(touch([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]))
    empty = np.zeros((0, 3))
    no_vertex = replace(
        plane(1e-6), num_contacts=2, vertices_m=empty, vertex_normals=empty, faces=np.zeros((0, 3), np.int32)
    )
    node.on_surface(replace(no_vertex, variance_vertices=np.zeros(0, np.int32), vertex_variance=np.zeros(0)))
    assert ctx.stop_requested == "planner: the local surface of 2 contacts holds no vertex: nothing to plan on"
