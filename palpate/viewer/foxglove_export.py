"""`palpate bag export --foxglove`: a palpate log rewritten with Foxglove's own schemas.

A palpate log carries msgpack payloads that Foxglove cannot decode. The export turns each shown
message into Foxglove's message types, encoded as protobuf by foxglove-sdk (the optional extra
``pip install 'palpate[foxglove]'``), with each channel's schema the FileDescriptorSet the SDK ships,
so Foxglove (or any MCAP reader with protobuf) decodes it without palpate:

- ObjectTruth (`truth/object`): `foxglove.SceneUpdate`, entity `truth`, a TriangleListPrimitive (grey);
- SurfaceMesh (`surface/mesh`): SceneUpdate, entity `<region>`, a TriangleListPrimitive coloured per
  vertex by GP variance;
- ContactSet (`sensors/contacts`): SceneUpdate, entity `contacts`, spheres and normal arrows;
- TouchEvent (`controller/events`): SceneUpdate, entity `touches`, every touch so far (spheres, normal
  arrows, prediction-miss lines); and JSON `palpate.TouchMetrics` on `<topic>/metrics`;
- TouchTarget (`planner/target`): SceneUpdate, entity `target`, the candidates coloured by score, the
  target, its normal, the predicted contact and a label;
- Trajectory (`controller/trajectory`): SceneUpdate, entity `curve`, the sampled Bezier curve and its
  control points;
- Pose (`sensors/effector_pose`): `foxglove.FrameTransforms`, `world` -> the pose's frame (`fingertip`);
- OccupancyGrid (`map/occupancy`): SceneUpdate, entity `<map_kind>`, a cube per cell with log-odds > 0,
  coloured by occupancy probability;
- NodeStatus (`status`): JSON `palpate.NodeStatus`, node, state, and each counter and metric as a number.

Each goes out on the topic it came from. Every entity is in frame `world`; log and publish time
are the message's ``stamp_ns`` (simulated time), as in the palpate log. Sizes and colours are the
viewer's (`rerun_log.ViewConfig`). Metrics are JSON messages with a JSON Schema, which Foxglove's Plot
panel reads (``controller/events/metrics.travelled_m``, ``status{node=="mapper"}.n_eff``); NaN values
are left out (JSON has no NaN).
"""

from __future__ import annotations

import importlib
import math
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from palpate import jsonio
from palpate.errors import InputError, MessageError, RecordError
from palpate.geometry.bezier import bezier_point
from palpate.geometry.rotations import align_axis, matrix_to_quat
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import (
    ContactSet,
    NodeStatus,
    ObjectTruth,
    OccupancyGrid,
    Pose,
    SurfaceMesh,
    TouchEvent,
    TouchTarget,
    Trajectory,
)
from palpate.record.mcap_io import LogWriter, output_file, read_messages
from palpate.viewer.rerun_log import (
    CONTACT_RGBA,
    CURVE_RGBA,
    MISSED_RGBA,
    NORMAL_RGBA,
    PREDICTED_RGBA,
    TARGET_RGBA,
    TRUTH_RGBA,
    ViewConfig,
    colorize,
    occupied_cells,
    variance_per_vertex,
)

FOXGLOVE_HINT = "palpate bag export --foxglove needs the foxglove extra: pip install 'palpate[foxglove]'"
#: Frame of every exported entity, and the parent of the exported transforms.
WORLD_FRAME = "world"
EXPORTED_TYPES: tuple[type[Message], ...] = (
    ObjectTruth,
    SurfaceMesh,
    ContactSet,
    TouchEvent,
    TouchTarget,
    Trajectory,
    Pose,
    OccupancyGrid,
    NodeStatus,
)
EXPORTED_TYPE_NAMES = frozenset(cls.TYPE for cls in EXPORTED_TYPES)

_TOUCH_METRICS_SCHEMA = {
    "title": "palpate.TouchMetrics",
    "description": "Figures of one touch (TouchEvent): travel and rotation so far, prediction miss",
    "type": "object",
    "properties": {
        "index": {"type": "integer", "description": "contact number, 0 for the first touch"},
        "missed": {"type": "boolean", "description": "the curve ended without contact (recovery)"},
        "travelled_m": {"type": "number", "description": "fingertip path length since the start, m"},
        "rotation_deg": {"type": "number", "description": "accumulated fingertip rotation, deg"},
        "prediction_miss_mm": {"type": "number", "description": "predicted to actual contact, mm (absent: none)"},
    },
    "required": ["index", "missed", "travelled_m", "rotation_deg"],
}
_STATUS_SCHEMA = {
    "title": "palpate.NodeStatus",
    "description": "A node's status: its counters and metrics as numbers (names carry units; NaN left out)",
    "type": "object",
    "properties": {
        "node": {"type": "string"},
        "state": {"type": "string", "description": "'running', 'finished' or 'error'"},
        "message": {"type": "string"},
    },
    "additionalProperties": {"type": "number"},
    "required": ["node", "state", "message"],
}


def require_foxglove() -> ModuleType:
    """`foxglove.messages` (foxglove-sdk), or RecordError saying how to install it."""
    try:
        return importlib.import_module("foxglove.messages")
    except ImportError as exc:
        raise RecordError(f"{FOXGLOVE_HINT} ({exc})") from exc


class Schema(NamedTuple):
    """An output channel's schema and message encoding."""

    name: str
    encoding: str  # "protobuf" or "jsonschema"
    data: bytes
    message_encoding: str  # "protobuf" or "json"


class Exported(NamedTuple):
    """One exported message: its topic, schema and encoded bytes."""

    topic: str
    schema: Schema
    data: bytes


def _json(name: str, document: dict[str, Any]) -> Schema:
    return Schema(name, "jsonschema", jsonio.dumps(document, sort_keys=True).encode(), "json")


TOUCH_METRICS = _json("palpate.TouchMetrics", _TOUCH_METRICS_SCHEMA)
STATUS = _json("palpate.NodeStatus", _STATUS_SCHEMA)


def _encode_json(values: dict[str, Any]) -> bytes:
    return jsonio.dumps(values, sort_keys=True).encode()


def _finite(names: Iterable[str], values: Iterable[float]) -> dict[str, float]:
    return {n: v for n, v in zip(names, values, strict=True) if math.isfinite(v)}


def arrow_quaternions_xyzw(directions: np.ndarray) -> np.ndarray:
    """Orientations (n, 4) x, y, z, w that turn +x (a Foxglove arrow's axis) onto each direction (n, 3)."""
    out = np.empty((len(directions), 4))
    for i, d in enumerate(np.asarray(directions, dtype=np.float64).reshape(-1, 3)):
        w, x, y, z = matrix_to_quat(align_axis([1.0, 0.0, 0.0], d)) if np.linalg.norm(d) > 0 else (1, 0, 0, 0)
        out[i] = (x, y, z, w)
    return out


@dataclass
class _Touches:
    positions: list[np.ndarray] = field(default_factory=list)
    normals: list[np.ndarray] = field(default_factory=list)
    missed: list[bool] = field(default_factory=list)
    misses: list[np.ndarray] = field(default_factory=list)  # (2, 3) predicted -> actual


class FoxgloveScene:
    """Turns palpate messages into Foxglove messages, keeping what accumulates (the touches so far)."""

    def __init__(self, config: ViewConfig | None = None):
        self.fg = require_foxglove()
        self.config = config or ViewConfig()
        self._touches: dict[str, _Touches] = {}
        self._schemas: dict[str, Schema] = {}

    def convert(self, topic: str, message: Message) -> list[Exported]:
        """The Foxglove messages of one palpate message received on `topic` ([] for other types)."""
        handler = _HANDLERS.get(type(message))
        return [] if handler is None else handler(self, topic, message)

    # --- building blocks -------------------------------------------------------------------------
    def _schema(self, cls: Any) -> Schema:
        schema = self._schemas.get(cls.__name__)
        if schema is None:
            s = cls.get_schema()
            schema = self._schemas[cls.__name__] = Schema(s.name, s.encoding, bytes(s.data), s.encoding)
        return schema

    def _timestamp(self, stamp_ns: int) -> Any:
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        return self.fg.Timestamp(sec, nsec)

    def _color(self, rgba: Iterable[float]) -> Any:
        r, g, b, a = (float(c) / 255.0 for c in rgba)
        return self.fg.Color(r=r, g=g, b=b, a=a)

    def _points(self, xyz: np.ndarray) -> list[Any]:
        return [self.fg.Point3(x=x, y=y, z=z) for x, y, z in np.asarray(xyz, dtype=np.float64).reshape(-1, 3).tolist()]

    def _pose(self, position: Iterable[float], quaternion_xyzw: Iterable[float] = (0.0, 0.0, 0.0, 1.0)) -> Any:
        px, py, pz = (float(v) for v in position)
        qx, qy, qz, qw = (float(v) for v in quaternion_xyzw)
        return self.fg.Pose(
            position=self.fg.Vector3(x=px, y=py, z=pz), orientation=self.fg.Quaternion(x=qx, y=qy, z=qz, w=qw)
        )

    def _spheres(self, positions: np.ndarray, diameter_m: float, colors: np.ndarray) -> list[Any]:
        size = self.fg.Vector3(x=diameter_m, y=diameter_m, z=diameter_m)
        return [
            self.fg.SpherePrimitive(pose=self._pose(p), size=size, color=self._color(c))
            for p, c in zip(np.asarray(positions).reshape(-1, 3), np.asarray(colors).reshape(-1, 4), strict=True)
        ]

    def _arrows(self, origins: np.ndarray, directions: np.ndarray, rgba: tuple[int, int, int, int]) -> list[Any]:
        length = self.config.normal_length_m
        color = self._color(rgba)
        quats = arrow_quaternions_xyzw(directions)
        return [
            self.fg.ArrowPrimitive(
                pose=self._pose(o, q),
                shaft_length=0.75 * length,
                shaft_diameter=0.08 * length,
                head_length=0.25 * length,
                head_diameter=0.2 * length,
                color=color,
            )
            for o, q in zip(np.asarray(origins).reshape(-1, 3), quats, strict=True)
        ]

    def _mesh(self, vertices_m: np.ndarray, faces: np.ndarray, *, rgba: Any = None, colors: Any = None) -> Any:
        return self.fg.TriangleListPrimitive(
            pose=self._pose((0.0, 0.0, 0.0)),
            points=self._points(vertices_m),
            color=self._color(rgba) if rgba is not None else None,
            colors=[self._color(c) for c in colors] if colors is not None else None,
            indices=np.asarray(faces, dtype=np.int64).reshape(-1).tolist(),
        )

    def _scene(self, topic: str, stamp_ns: int, entity_id: str, **primitives: Any) -> Exported:
        entity = self.fg.SceneEntity(
            timestamp=self._timestamp(stamp_ns), frame_id=WORLD_FRAME, id=entity_id, **primitives
        )
        update = self.fg.SceneUpdate(entities=[entity])
        return Exported(topic, self._schema(self.fg.SceneUpdate), update.encode())

    # --- per type --------------------------------------------------------------------------------
    def _object_truth(self, topic: str, m: ObjectTruth) -> list[Exported]:
        return [self._scene(topic, m.stamp_ns, "truth", triangles=[self._mesh(m.vertices_m, m.faces, rgba=TRUTH_RGBA)])]

    def _surface_mesh(self, topic: str, m: SurfaceMesh) -> list[Exported]:
        colors = colorize(variance_per_vertex(m), self.config.colormap)
        mesh = self._mesh(m.vertices_m, m.faces, colors=colors)
        return [self._scene(topic, m.stamp_ns, m.region or "surface", triangles=[mesh])]

    def _contact_set(self, topic: str, m: ContactSet) -> list[Exported]:
        n, c = len(m.positions_m), self.config
        spheres = self._spheres(m.positions_m, 2 * c.point_radius_m, np.tile(CONTACT_RGBA, (n, 1)))
        arrows = self._arrows(m.positions_m, m.normals, NORMAL_RGBA)
        return [self._scene(topic, m.stamp_ns, "contacts", spheres=spheres, arrows=arrows)]

    def _touch_event(self, topic: str, m: TouchEvent) -> list[Exported]:
        c = self.config
        t = self._touches.setdefault(topic, _Touches())
        position = np.asarray(m.position_m, dtype=np.float64)
        t.positions.append(position)
        t.normals.append(np.asarray(m.normal, dtype=np.float64))
        t.missed.append(bool(m.missed))
        predicted = np.asarray(m.predicted_contact_m, dtype=np.float64)
        metrics: dict[str, Any] = {
            "index": int(m.index),
            "missed": bool(m.missed),
            "travelled_m": float(m.travelled_m),
            "rotation_deg": float(m.rotation_deg),
        }
        if np.isfinite(predicted).all():
            t.misses.append(np.stack([predicted, position]))
            metrics["prediction_miss_mm"] = float(np.linalg.norm(position - predicted)) * 1e3
        positions = np.stack(t.positions)
        colors = np.where(np.asarray(t.missed)[:, None], np.asarray(MISSED_RGBA), np.asarray(CONTACT_RGBA))
        lines = []
        if t.misses:
            lines.append(
                self.fg.LinePrimitive(
                    type=self.fg.LinePrimitiveLineType.LineList,
                    pose=self._pose((0.0, 0.0, 0.0)),
                    thickness=2 * c.line_radius_m,
                    points=self._points(np.concatenate(t.misses)),
                    color=self._color(PREDICTED_RGBA),
                )
            )
        scene = self._scene(
            topic,
            m.stamp_ns,
            "touches",
            spheres=self._spheres(positions, 2 * c.point_radius_m, colors),
            arrows=self._arrows(positions, np.stack(t.normals), NORMAL_RGBA),
            lines=lines,
        )
        return [scene, Exported(f"{topic.rstrip('/')}/metrics", TOUCH_METRICS, _encode_json(metrics))]

    def _touch_target(self, topic: str, m: TouchTarget) -> list[Exported]:
        c = self.config
        candidates = self._spheres(m.candidates_m, 2 * c.candidate_radius_m, colorize(m.candidate_scores, c.colormap))
        marks = self._spheres(
            np.stack([m.position_m, m.predicted_contact_m]),
            3 * c.point_radius_m,
            np.array([TARGET_RGBA, PREDICTED_RGBA]),
        )
        label = self.fg.TextPrimitive(
            pose=self._pose(np.asarray(m.position_m) + 0.5 * c.normal_length_m * np.asarray(m.normal)),
            billboard=True,
            font_size=12.0,
            scale_invariant=True,
            color=self._color(TARGET_RGBA),
            text=f"{m.strategy} {m.score:.3g}",
        )
        arrows = self._arrows(np.asarray(m.position_m)[None], np.asarray(m.normal)[None], TARGET_RGBA)
        return [self._scene(topic, m.stamp_ns, "target", spheres=candidates + marks, arrows=arrows, texts=[label])]

    def _trajectory(self, topic: str, m: Trajectory) -> list[Exported]:
        c = self.config
        control = np.asarray(m.control_points_m, dtype=np.float64)
        curve = self.fg.LinePrimitive(
            type=self.fg.LinePrimitiveLineType.LineStrip,
            pose=self._pose((0.0, 0.0, 0.0)),
            thickness=2 * c.line_radius_m,
            points=self._points(bezier_point(control, np.linspace(0.0, 1.0, max(2, c.curve_samples)))),
            color=self._color(CURVE_RGBA),
        )
        spheres = self._spheres(control, c.point_radius_m, np.tile(CURVE_RGBA, (4, 1)))
        return [self._scene(topic, m.stamp_ns, "curve", lines=[curve], spheres=spheres)]

    def _effector_pose(self, topic: str, m: Pose) -> list[Exported]:
        w, x, y, z = (float(v) for v in m.quaternion_wxyz)
        px, py, pz = (float(v) for v in m.position_m)
        transform = self.fg.FrameTransform(
            timestamp=self._timestamp(m.stamp_ns),
            parent_frame_id=WORLD_FRAME,
            child_frame_id=m.frame or "effector",
            translation=self.fg.Vector3(x=px, y=py, z=pz),
            rotation=self.fg.Quaternion(x=x, y=y, z=z, w=w),
        )
        transforms = self.fg.FrameTransforms(transforms=[transform])
        return [Exported(topic, self._schema(self.fg.FrameTransforms), transforms.encode())]

    def _occupancy_grid(self, topic: str, m: OccupancyGrid) -> list[Exported]:
        centres, log_odds = occupied_cells(m, self.config.occupied_log_odds)
        probability = 1.0 / (1.0 + np.exp(-log_odds))  # p = 1 - 1 / (1 + exp(l))
        colors = colorize(probability, self.config.colormap, vmin=0.5, vmax=1.0)
        size = self.fg.Vector3(x=m.resolution_m, y=m.resolution_m, z=m.resolution_m)
        cubes = [
            self.fg.CubePrimitive(pose=self._pose(p), size=size, color=self._color(rgba))
            for p, rgba in zip(centres, colors, strict=True)
        ]
        return [self._scene(topic, m.stamp_ns, m.map_kind or "grid", cubes=cubes)]

    def _node_status(self, topic: str, m: NodeStatus) -> list[Exported]:
        values: dict[str, Any] = {
            **_finite(m.counter_names, np.asarray(m.counter_values, dtype=np.float64).tolist()),
            **_finite(m.metric_names, np.asarray(m.metric_values, dtype=np.float64).tolist()),
        }
        values.update(node=m.node, state=m.state, message=m.message)
        return [Exported(topic, STATUS, _encode_json(values))]


_HANDLERS: dict[type[Message], Any] = {
    ObjectTruth: FoxgloveScene._object_truth,
    SurfaceMesh: FoxgloveScene._surface_mesh,
    ContactSet: FoxgloveScene._contact_set,
    TouchEvent: FoxgloveScene._touch_event,
    TouchTarget: FoxgloveScene._touch_target,
    Trajectory: FoxgloveScene._trajectory,
    Pose: FoxgloveScene._effector_pose,
    OccupancyGrid: FoxgloveScene._occupancy_grid,
    NodeStatus: FoxgloveScene._node_status,
}
assert set(_HANDLERS) == set(EXPORTED_TYPES)


@dataclass
class ExportReport:
    """What an export read and wrote: messages per output (topic, schema name)."""

    read: int = 0
    converted: int = 0
    undecodable: int = 0
    #: Messages that decode but hold values the export cannot draw (a mesh naming vertices it lacks),
    #: skipped as the nodes skip them; the last one's topic, time and reason.
    unusable: int = 0
    last_unusable: str = ""
    written: Counter[tuple[str, str]] = field(default_factory=Counter)


def _decoded(path: Path, topics: list[str] | None, report: ExportReport) -> Iterator[tuple[str, int, Message]]:
    for logged in read_messages(path, topics):
        report.read += 1
        if logged.type not in EXPORTED_TYPE_NAMES:
            continue
        try:
            message: Message = codec.decode(logged.data)
        except MessageError:
            report.undecodable += 1
            continue
        yield logged.topic, logged.sequence, message


def export_foxglove(src: Path, dst: Path, topics: list[str] | None = None, *, overwrite: bool = True) -> ExportReport:
    """Write the exported messages of the palpate log `src` (optionally only `topics`) to `dst`; a
    failure leaves no output (and an existing `dst` as it was), which only `overwrite` lets it replace.

    Nothing in the output depends on wall time: the same log exports to the same bytes.
    """
    scene = FoxgloveScene()
    report = ExportReport()
    with output_file(src, dst, "export", overwrite) as partial, LogWriter(partial, profile="") as writer:
        for topic, sequence, message in _decoded(Path(src), topics, report):
            try:
                converted = scene.convert(topic, message)
            except InputError as exc:
                report.unusable += 1
                report.last_unusable = f"{topic} at {message.stamp_ns} ns: {exc}"
                continue
            report.converted += 1
            for out in converted:
                s = out.schema
                channel = writer.channel(
                    out.topic, s.name, s.data, encoding=s.encoding, message_encoding=s.message_encoding
                )
                writer.add(channel, int(message.stamp_ns), out.data, sequence)
                report.written[(out.topic, s.name)] += 1
        if not report.written:
            raise RecordError(
                f"{src}: nothing to export (of {report.read} messages, none of a type the export knows); wrote nothing"
            )
    return report
