"""Small valid messages of every type the viewer shows, and an MCAP log of them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import Writer

from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import (
    Clock,
    ContactSet,
    ObjectTruth,
    OccupancyGrid,
    Pose,
    SurfaceMesh,
    TouchEvent,
    TouchTarget,
    Trajectory,
)

TETRA_V = np.array([[0, 0, 0], [0.02, 0, 0], [0, 0.02, 0], [0, 0, 0.02]], dtype=np.float64)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)


def truth(stamp_ns: int = 0) -> ObjectTruth:
    return ObjectTruth(
        stamp_ns=stamp_ns,
        name="tetra",
        source="primitive",
        position_m=np.zeros(3),
        quaternion_wxyz=np.array([1.0, 0, 0, 0]),
        vertices_m=TETRA_V,
        faces=TETRA_F,
    )


def contacts(stamp_ns: int, n: int) -> ContactSet:
    rng = np.random.default_rng(n)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return ContactSet(
        stamp_ns=stamp_ns,
        positions_m=rng.normal(size=(n, 3)) * 0.01,
        local_positions_m=np.zeros((n, 3)),
        normals=normals,
        forces_n=np.ones(n),
        links=["tip"] * n,
    )


def touch(stamp_ns: int, index: int, position: Any, predicted: Any, *, missed: bool = False) -> TouchEvent:
    return TouchEvent(
        stamp_ns=stamp_ns,
        index=index,
        position_m=np.asarray(position, dtype=np.float64),
        normal=np.array([0.0, 0.0, 1.0]),
        approach_direction=np.array([0.0, 0.0, -1.0]),
        predicted_contact_m=np.asarray(predicted, dtype=np.float64),
        missed=missed,
        travelled_m=0.1 * (index + 1),
        rotation_deg=5.0 * index,
    )


def surface(stamp_ns: int, region: str = "local") -> SurfaceMesh:
    normals = TETRA_V - TETRA_V.mean(axis=0)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return SurfaceMesh(
        stamp_ns=stamp_ns,
        region=region,
        num_contacts=3,
        vertices_m=TETRA_V,
        faces=TETRA_F,
        vertex_normals=normals,
        variance_vertices=np.arange(4, dtype=np.int32),
        vertex_variance=np.array([1e-6, 4e-6, 2e-6, 3e-6]),
    )


def target(stamp_ns: int) -> TouchTarget:
    candidates = np.array([[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01], [0.01, 0.01, 0], [0, 0.01, 0.01]])
    return TouchTarget(
        stamp_ns=stamp_ns,
        strategy="igef",
        position_m=candidates[3],
        normal=np.array([0, 0, 1.0]),
        predicted_contact_m=candidates[3] - [0, 0, 0.001],
        score=0.9,
        candidates_m=candidates,
        candidate_scores=np.array([0.1, 0.5, 0.2, 0.9, 0.3]),
    )


def trajectory(stamp_ns: int) -> Trajectory:
    control = np.array([[0, 0, 0.05], [0, 0, 0.08], [0.03, 0, 0.08], [0.03, 0, 0.05]])
    return Trajectory(
        stamp_ns=stamp_ns,
        kind="approach",
        control_points_m=control,
        start_quaternion_wxyz=np.array([1.0, 0, 0, 0]),
        end_quaternion_wxyz=np.array([1.0, 0, 0, 0]),
        length_m=0.08,
    )


def pose(stamp_ns: int, position: Any, quaternion_wxyz: Any = (1.0, 0, 0, 0)) -> Pose:
    return Pose(
        stamp_ns=stamp_ns,
        frame="fingertip",
        position_m=np.asarray(position, dtype=np.float64),
        quaternion_wxyz=np.asarray(quaternion_wxyz, dtype=np.float64),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )


def grid(stamp_ns: int) -> OccupancyGrid:
    shape = np.array([4, 5, 6], dtype=np.int64)
    return OccupancyGrid(
        stamp_ns=stamp_ns,
        map_kind="best",
        origin_m=np.array([-0.1, 0.0, 0.2]),
        resolution_m=0.01,
        shape=shape,
        cell_indices=np.array([0, 7, 31, 119, 64], dtype=np.int64),
        log_odds=np.array([0.5, -1.0, 2.0, 0.0, 3.0], dtype=np.float32),
    )


def clock(stamp_ns: int, tick: int) -> Clock:
    return Clock(stamp_ns=stamp_ns, tick=tick, period_ns=1_000_000, lockstep=True)


def session() -> list[tuple[str, Message]]:
    """A short exploration: every shown type, in sim-time order, with clocks between ticks."""
    ms = 1_000_000
    out: list[tuple[str, Message]] = [("truth/object", truth()), ("clock", clock(0, 0))]
    for k in range(6):
        out.append(("sensors/effector_pose", pose(k * ms, [0.002 * k, 0, 0.05])))
    out += [
        ("sensors/contacts", contacts(6 * ms, 2)),
        ("controller/events", touch(6 * ms, 0, [0.01, 0, 0.02], [np.nan] * 3)),
        ("surface/mesh", surface(7 * ms)),
        ("planner/target", target(8 * ms)),
        ("controller/trajectory", trajectory(8 * ms)),
        ("map/occupancy", grid(9 * ms)),
        ("controller/events", touch(10 * ms, 1, [0.02, 0, 0.02], [0.02, 0.001, 0.02])),
        ("clock", clock(10 * ms, 10)),
    ]
    return out


def write_mcap(path: Path, messages: list[tuple[str, Message]]) -> None:
    """A palpate-style log: channel per topic, msgpack encoding, schema name = type, log_time = stamp_ns."""
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="palpate", library="test")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, message in messages:
            type_name = type(message).TYPE
            if type_name not in schemas:
                schemas[type_name] = writer.register_schema(type_name, "jsonschema", b"{}")
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "msgpack", schemas[type_name])
            writer.add_message(channels[topic], message.stamp_ns, codec.encode(message), message.stamp_ns)
        writer.finish()
