"""The pure message -> log-call mapping, checked with a recording fake logger (rerun not needed)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from matplotlib import colormaps

from palpate.messages.base import Message
from palpate.viewer.rerun_log import (
    KINDS,
    SceneLogger,
    ViewConfig,
    colorize,
    entity_root,
    occupied_cells,
    vertex_normals,
)
from tests.unit.viewer.viewer_messages import (
    clock,
    contacts,
    grid,
    pose,
    session,
    surface,
    target,
    touch,
    trajectory,
    truth,
)


@dataclass
class Call:
    path: str
    kind: str
    static: bool
    time_ns: int | None
    arrays: dict[str, Any]


class FakeLogger:
    """Records every call; checks that each is a known archetype kind."""

    def __init__(self) -> None:
        self.calls: list[Call] = []
        self.time_ns: int | None = None

    def set_time_ns(self, stamp_ns: int) -> None:
        self.time_ns = stamp_ns

    def log(self, path: str, kind: str, *, static: bool = False, **arrays: Any) -> None:
        assert kind in KINDS
        self.calls.append(Call(path, kind, static, self.time_ns, arrays))

    def by_path(self) -> dict[str, Call]:
        """The last call of each path."""
        return {c.path: c for c in self.calls}


def _log(messages: list[tuple[str, Message]], config: ViewConfig | None = None) -> FakeLogger:
    fake, scene = FakeLogger(), SceneLogger(config)
    for topic, message in messages:
        scene.log_message(fake, topic, message)
    return fake


def test_entity_root_strips_slashes() -> None:
    assert entity_root("surface/mesh") == "world/surface/mesh"
    assert entity_root("/robot2//planner/target/") == "world/robot2/planner/target"


def test_unshown_types_log_nothing() -> None:
    fake, scene = FakeLogger(), SceneLogger()
    assert scene.log_message(fake, "clock", clock(5, 1)) is False
    assert fake.calls == [] and fake.time_ns is None


def test_truth_mesh_is_static_with_unit_normals() -> None:
    fake = _log([("truth/object", truth(123))])
    (call,) = fake.calls
    assert (call.path, call.kind, call.static) == ("world/truth/object", "Mesh3D", True)
    np.testing.assert_array_equal(call.arrays["vertex_positions"], truth().vertices_m)
    np.testing.assert_array_equal(call.arrays["triangle_indices"], truth().faces)
    assert call.arrays["triangle_indices"].dtype == np.uint32
    np.testing.assert_allclose(np.linalg.norm(call.arrays["vertex_normals"], axis=1), 1.0, atol=1e-12)


def test_vertex_normals_point_out_of_a_ccw_tetrahedron() -> None:
    v, f = truth().vertices_m, truth().faces
    n = vertex_normals(v, f)
    outward = v - v.mean(axis=0)
    assert np.all(np.sum(n * outward, axis=1) > 0)
    # the apex (0, 0, 0.02) touches faces with normals -x, -y, +(1,1,1)/sqrt3 weighted by twice their areas
    a = 0.02**2
    expected = np.array([-a, -a, 0.0]) + np.array([a, a, a])
    np.testing.assert_allclose(n[3], expected / np.linalg.norm(expected), atol=1e-12)


def test_contact_set_points_and_normal_arrows_and_clearing() -> None:
    c2 = contacts(5, 2)
    fake = _log(
        [
            ("sensors/contacts", contacts(1, 0)),
            ("sensors/contacts", c2),
            ("sensors/contacts", contacts(9, 0)),
            ("sensors/contacts", contacts(10, 0)),
        ]
    )
    # the first empty set is skipped, the second empty one clears, the third is skipped again
    assert [(c.path, c.time_ns) for c in fake.calls] == [
        ("world/sensors/contacts", 5),
        ("world/sensors/contacts/normals", 5),
        ("world/sensors/contacts", 9),
        ("world/sensors/contacts/normals", 9),
    ]
    points, arrows = fake.calls[0].arrays, fake.calls[1].arrays
    np.testing.assert_array_equal(points["positions"], c2.positions_m)
    assert points["colors"].shape == (2, 4) and points["radii"].shape == (2,)
    np.testing.assert_array_equal(arrows["origins"], c2.positions_m)
    np.testing.assert_allclose(arrows["vectors"], c2.normals * ViewConfig().normal_length_m, rtol=1e-15)
    assert fake.calls[2].arrays["positions"].shape == (0, 3)


def test_touch_events_accumulate_and_draw_prediction_misses() -> None:
    first = touch(10, 0, [0.01, 0, 0], [np.nan] * 3)
    second = touch(20, 1, [0.02, 0, 0], [0.02, 0.003, 0.004], missed=True)
    fake = _log([("controller/events", first)])
    assert "world/controller/events/prediction_miss" not in fake.by_path()
    assert "metrics/controller/events/prediction_miss_mm" not in fake.by_path()
    fake = _log([("controller/events", first), ("controller/events", second)])
    last = fake.by_path()
    pts = last["world/controller/events/contacts"]
    assert pts.time_ns == 20 and pts.kind == "Points3D"
    np.testing.assert_array_equal(pts.arrays["positions"], [[0.01, 0, 0], [0.02, 0, 0]])
    assert pts.arrays["colors"].dtype == np.uint8 and pts.arrays["colors"].shape == (2, 4)
    assert not np.array_equal(pts.arrays["colors"][0], pts.arrays["colors"][1])  # the missed one differs
    assert last["world/controller/events/normals"].arrays["vectors"].shape == (2, 3)
    miss = last["world/controller/events/prediction_miss"]
    assert miss.kind == "LineStrips3D"
    np.testing.assert_array_equal(miss.arrays["strips"], [[[0.02, 0.003, 0.004], [0.02, 0, 0]]])
    assert last["metrics/controller/events/prediction_miss_mm"].arrays["scalars"] == pytest.approx(5.0, rel=1e-12)
    assert last["metrics/controller/events/travelled_m"].arrays["scalars"] == pytest.approx(0.2)


def test_surface_mesh_coloured_by_variance_per_region() -> None:
    fake = _log([("surface/mesh", surface(7, "local")), ("surface/mesh", surface(8, "global"))])
    paths = fake.by_path()
    assert set(paths) == {"world/surface/mesh/local", "world/surface/mesh/global"}
    call = paths["world/surface/mesh/local"]
    assert call.kind == "Mesh3D" and call.time_ns == 7
    colors = call.arrays["vertex_colors"]
    assert colors.shape == (4, 4) and colors.dtype == np.uint8
    viridis = colormaps["viridis"]
    np.testing.assert_array_equal(colors[0], viridis(0.0, bytes=True))  # smallest variance
    np.testing.assert_array_equal(colors[1], viridis(1.0, bytes=True))  # largest variance
    np.testing.assert_array_equal(colors[2], viridis(1.0 / 3.0, bytes=True))
    assert call.arrays["triangle_indices"].shape == (4, 3)


def test_colorize_handles_constant_nan_and_fixed_range() -> None:
    assert colorize(np.zeros(0)).shape == (0, 4)
    flat = colorize(np.full(3, 2.0))
    assert np.all(flat == flat[0])
    with_nan = colorize(np.array([0.0, np.nan, 1.0]))
    np.testing.assert_array_equal(with_nan[1], [128, 128, 128, 255])
    clipped = colorize(np.array([0.2, 0.75, 2.0]), vmin=0.5, vmax=1.0)
    viridis = colormaps["viridis"]
    np.testing.assert_array_equal(clipped, np.stack([viridis(x, bytes=True) for x in (0.0, 0.5, 1.0)]))


def test_touch_target_candidates_coloured_by_score() -> None:
    msg = target(30)
    paths = _log([("planner/target", msg)]).by_path()
    cand = paths["world/planner/target/candidates"]
    np.testing.assert_array_equal(cand.arrays["positions"], msg.candidates_m)
    assert cand.arrays["colors"].shape == (5, 4)
    np.testing.assert_array_equal(cand.arrays["colors"][3], colormaps["viridis"](1.0, bytes=True))  # best score
    np.testing.assert_array_equal(paths["world/planner/target/chosen"].arrays["positions"], msg.position_m[None])
    assert paths["world/planner/target/normal"].arrays["vectors"].shape == (1, 3)
    assert paths["world/planner/target/predicted_contact"].arrays["positions"].shape == (1, 3)


def test_trajectory_curve_strip() -> None:
    msg = trajectory(40)
    paths = _log([("controller/trajectory", msg)], ViewConfig(curve_samples=17)).by_path()
    curve = paths["world/controller/trajectory/curve"]
    assert curve.kind == "LineStrips3D" and curve.arrays["strips"].shape == (1, 17, 3)
    np.testing.assert_allclose(curve.arrays["strips"][0, [0, -1]], msg.control_points_m[[0, 3]], atol=1e-15)
    np.testing.assert_array_equal(
        paths["world/controller/trajectory/control_points"].arrays["positions"], msg.control_points_m
    )


def test_pose_trail_decimates_and_chunks_without_gaps() -> None:
    config = ViewConfig(trail_step_m=1e-3, trail_chunk_points=4)
    steps = [0.0, 0.0005, 0.002, 0.004, 0.0042, 0.006, 0.008, 0.010, 0.012, 0.014]
    fake = _log([("sensors/effector_pose", pose(k, [x, 0, 0])) for k, x in enumerate(steps)], config)
    kept = [0.0, 0.002, 0.004, 0.006, 0.008, 0.010, 0.012, 0.014]  # 0.0005 and 0.0042 are within a step
    tips = [c for c in fake.calls if c.path.endswith("/tip")]
    np.testing.assert_allclose([c.arrays["positions"][0, 0] for c in tips], kept, atol=1e-15)
    chunks = {c.path: c.arrays["strips"][0] for c in fake.calls if "/trail/" in c.path}
    assert sorted(chunks) == [f"world/sensors/effector_pose/trail/{k:05d}" for k in range(3)]
    strips = [chunks[k] for k in sorted(chunks)]
    assert [len(s) for s in strips] == [4, 4, 2]
    for a, b in itertools.pairwise(strips):
        np.testing.assert_array_equal(a[-1], b[0])  # each chunk starts where the last ended
    joined = np.concatenate([strips[0], *(s[1:] for s in strips[1:])])
    np.testing.assert_allclose(joined[:, 0], kept, atol=1e-15)


def test_pose_axis_is_the_body_z_axis() -> None:
    axis = _log([("sensors/effector_pose", pose(0, [0, 0, 0], [np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0]))])
    np.testing.assert_allclose(
        axis.by_path()["world/sensors/effector_pose/axis"].arrays["vectors"][0],
        [0, -ViewConfig().normal_length_m, 0],
        atol=1e-15,
    )


def test_occupied_cells_match_a_loop_reference() -> None:
    g = grid(50)
    centres, log_odds = occupied_cells(g)
    expected = []
    _nx, ny, nz = (int(n) for n in g.shape)
    for flat, lo in zip(g.cell_indices, g.log_odds, strict=True):
        if lo > 0:
            i, rest = divmod(int(flat), ny * nz)
            j, k = divmod(rest, nz)
            expected.append(g.origin_m + (np.array([i, j, k]) + 0.5) * g.resolution_m)
    np.testing.assert_allclose(centres, np.array(expected), atol=1e-15)
    np.testing.assert_allclose(log_odds, [0.5, 2.0, 3.0])
    boxes = _log([("map/occupancy", g)]).by_path()["world/map/occupancy/best"]
    assert boxes.kind == "Boxes3D" and boxes.time_ns == 50
    assert boxes.arrays["centers"].shape == (3, 3) and boxes.arrays["colors"].shape == (3, 4)
    np.testing.assert_allclose(boxes.arrays["half_sizes"], np.full((3, 3), 0.005))


def test_session_times_and_paths() -> None:
    messages = session()
    fake = _log(messages)
    paths = {c.path for c in fake.calls}
    for expected in (
        "world/truth/object",
        "world/sensors/contacts",
        "world/controller/events/contacts",
        "world/surface/mesh/local",
        "world/planner/target/candidates",
        "world/controller/trajectory/curve",
        "world/sensors/effector_pose/trail/00000",
        "world/map/occupancy/best",
    ):
        assert expected in paths
    stamps = {m.stamp_ns for _, m in messages}
    assert all(c.time_ns in stamps for c in fake.calls)
    times = [c.time_ns for c in fake.calls if c.time_ns is not None]
    assert times == sorted(times)
