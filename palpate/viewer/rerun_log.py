"""Pure mapping from palpate messages to viewer log calls (no rerun import).

`SceneLogger.log_message(logger, topic, message)` turns one decoded message into calls on a
`Logger`: `logger.set_time_ns(stamp_ns)` (the sim-time timeline) then `logger.log(path, kind, **arrays)`
where `kind` names a rerun archetype (`Mesh3D`, `Points3D`, `Arrows3D`, `LineStrips3D`, `Boxes3D`,
`Scalars`) and the keyword arguments are that archetype's constructor arguments. The real adapter
(`palpate.viewer.sink.RerunLogger`) forwards them to rerun; tests use a recording fake.

Entity paths are `world/<topic>/...`, so remapped topics (or two planners) show side by side:

| message (default topic)            | entities                                                         |
|------------------------------------|------------------------------------------------------------------|
| ObjectTruth (truth/object)         | `world/truth/object` Mesh3D, static                              |
| ContactSet (sensors/contacts)      | `world/<topic>` Points3D, `world/<topic>/normals` Arrows3D       |
| TouchEvent (controller/events)     | `.../contacts` Points3D, `.../normals` Arrows3D (all so far),    |
|                                    | `.../prediction_miss` LineStrips3D, `metrics/...` Scalars        |
| SurfaceMesh (surface/mesh)         | `world/<topic>/<region>` Mesh3D coloured by GP variance          |
| TouchTarget (planner/target)       | `.../candidates` Points3D coloured by score, `.../chosen` Points3D,|
|                                    | `.../normal` Arrows3D, `.../predicted_contact` Points3D          |
| Trajectory (controller/trajectory) | `.../curve` LineStrips3D (sampled Bezier), `.../control_points`  |
| Pose (sensors/effector_pose)       | `.../trail/<k>` LineStrips3D chunks, `.../tip` Points3D,         |
|                                    | `.../axis` Arrows3D (the body's z axis, the poking axis)         |
| OccupancyGrid (map/occupancy)      | `world/<topic>/<map_kind>` Boxes3D of the occupied cells         |

Other message types are ignored (`log_message` returns False).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from palpate.geometry.bezier import bezier_point
from palpate.geometry.rotations import quat_to_matrix
from palpate.inputs import per_vertex
from palpate.messages.base import Message
from palpate.messages.schemas import (
    ContactSet,
    ObjectTruth,
    OccupancyGrid,
    Pose,
    SurfaceMesh,
    TouchEvent,
    TouchTarget,
    Trajectory,
)

#: Name of the rerun timeline that carries `stamp_ns` (simulated time, a duration since the start).
TIMELINE = "sim_time"
#: Archetype names a `Logger` must understand.
KINDS = ("Mesh3D", "Points3D", "Arrows3D", "LineStrips3D", "Boxes3D", "Scalars")
#: Message types the viewer shows.
SHOWN_TYPES: tuple[type[Message], ...] = (
    ObjectTruth,
    ContactSet,
    TouchEvent,
    SurfaceMesh,
    TouchTarget,
    Trajectory,
    Pose,
    OccupancyGrid,
)
SHOWN_TYPE_NAMES = frozenset(cls.TYPE for cls in SHOWN_TYPES)

# RGBA colours, uint8
TRUTH_RGBA = (170, 170, 180, 255)
CONTACT_RGBA = (40, 200, 60, 255)
MISSED_RGBA = (255, 140, 0, 255)
NORMAL_RGBA = (60, 120, 255, 255)
TARGET_RGBA = (230, 30, 30, 255)
PREDICTED_RGBA = (250, 220, 30, 255)
CURVE_RGBA = (255, 80, 200, 255)
TRAIL_RGBA = (90, 90, 90, 255)


class Logger(Protocol):
    """What the mapping needs from a viewer: a sim-time cursor and archetype logging."""

    def set_time_ns(self, stamp_ns: int) -> None:
        """Place the following `log` calls at simulated time `stamp_ns` on the `TIMELINE`."""

    def log(self, path: str, kind: str, *, static: bool = False, **arrays: Any) -> None:
        """Log archetype `kind` (one of KINDS) built from `arrays` at entity `path`."""


@dataclass(frozen=True, kw_only=True)
class ViewConfig:
    """Sizes and sampling of the drawn items."""

    point_radius_m: float = 1.5e-3  # contacts, target, tip
    candidate_radius_m: float = 0.8e-3
    normal_length_m: float = 1.0e-2  # drawn length of unit normals and of the fingertip axis
    line_radius_m: float = 0.4e-3  # curve, trail, prediction-miss segments
    curve_samples: int = 64  # points of the sampled Bezier curve
    trail_step_m: float = 1.0e-3  # a pose joins the trail when it moved this far from the last trail point
    trail_chunk_points: int = 256  # trail points per entity; finished chunks are never re-logged
    occupied_log_odds: float = 0.0  # a cell is drawn when its log-odds exceed this
    colormap: str = "viridis"


# --- pure helpers --------------------------------------------------------------------------------


def entity_root(topic: str) -> str:
    """`world/<topic>` without leading or doubled slashes."""
    parts = [p for p in topic.split("/") if p]
    return "/".join(["world", *parts])


def colorize(
    values: np.ndarray, colormap: str = "viridis", *, vmin: float | None = None, vmax: float | None = None
) -> np.ndarray:
    """RGBA uint8 (n, 4) of `values` (n,) scaled linearly from vmin to vmax (default: their finite min and
    max), clipped; NaN and infinity are grey."""
    from matplotlib import colormaps  # lazy: matplotlib's import is slow and only the viewer needs it

    v = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(v)
    out = np.empty((v.size, 4), dtype=np.uint8)
    out[:] = (128, 128, 128, 255)
    if finite.any():
        lo = float(v[finite].min()) if vmin is None else vmin
        hi = float(v[finite].max()) if vmax is None else vmax
        scaled = np.clip((v[finite] - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(int(finite.sum()), 0.5)
        out[finite] = colormaps[colormap](scaled, bytes=True)
    return out


def variance_per_vertex(m: SurfaceMesh) -> np.ndarray:
    """A SurfaceMesh's GP variance at every vertex (v,), NaN (grey in ``colorize``) where it carries none."""
    return per_vertex(m.vertex_variance, m.variance_vertices, len(m.vertices_m), "variance_vertices")


def vertex_normals(vertices_m: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (v, 3) of a triangle mesh (zero for unused vertices)."""
    v = np.asarray(vertices_m, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    normals = np.zeros_like(v)
    if len(f):
        face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # |n| = 2 * area
        for k in range(3):
            np.add.at(normals, f[:, k], face_n)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 0)


def occupied_cells(grid: OccupancyGrid, threshold_log_odds: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Centres (k, 3) m and log-odds (k,) of the cells whose log-odds exceed the threshold.

    Centre = origin_m + (index + 0.5) * resolution_m, with the flat C-order index unravelled by `shape`.
    """
    keep = np.asarray(grid.log_odds) > threshold_log_odds
    flat = np.asarray(grid.cell_indices, dtype=np.int64)[keep]
    ijk = np.stack(np.unravel_index(flat, tuple(int(n) for n in grid.shape)), axis=1).astype(np.float64)
    centres = np.asarray(grid.origin_m, dtype=np.float64) + (ijk + 0.5) * grid.resolution_m
    return centres.reshape(-1, 3), np.asarray(grid.log_odds, dtype=np.float64)[keep]


def _rgba(rgba: tuple[int, int, int, int], n: int) -> np.ndarray:
    return np.tile(np.asarray(rgba, dtype=np.uint8), (n, 1))


# --- the stateful mapping ------------------------------------------------------------------------


@dataclass
class _Trail:
    chunk: int = 0
    points: list[np.ndarray] = field(default_factory=list)


@dataclass
class _Touches:
    positions: list[np.ndarray] = field(default_factory=list)
    normals: list[np.ndarray] = field(default_factory=list)
    missed: list[bool] = field(default_factory=list)
    misses: list[np.ndarray] = field(default_factory=list)  # (2, 3) segments predicted -> actual


class SceneLogger:
    """Turns messages into log calls, keeping what accumulates (contacts so far, the fingertip trail)."""

    def __init__(self, config: ViewConfig | None = None):
        self.config = config or ViewConfig()
        self._trails: dict[str, _Trail] = {}
        self._touches: dict[str, _Touches] = {}
        self._contacts_shown: dict[str, int] = {}

    def log_message(self, logger: Logger, topic: str, message: Message) -> bool:
        """Log one message received on `topic`; False when the viewer does not show its type."""
        handler = _HANDLERS.get(type(message))
        if handler is None:
            return False
        logger.set_time_ns(int(message.stamp_ns))
        handler(self, logger, entity_root(topic), topic, message)
        return True

    # --- per type --------------------------------------------------------------------------------

    def _object_truth(self, logger: Logger, root: str, topic: str, m: ObjectTruth) -> None:
        logger.log(
            root,
            "Mesh3D",
            static=True,
            vertex_positions=np.asarray(m.vertices_m, dtype=np.float64),
            triangle_indices=np.asarray(m.faces, dtype=np.uint32),
            vertex_normals=vertex_normals(m.vertices_m, m.faces),
            albedo_factor=np.asarray(TRUTH_RGBA, dtype=np.uint8),
        )

    def _contact_set(self, logger: Logger, root: str, topic: str, m: ContactSet) -> None:
        n = len(m.positions_m)
        if n == 0 and self._contacts_shown.get(topic, 0) == 0:
            return  # nothing shown and nothing to clear
        self._contacts_shown[topic] = n
        c = self.config
        positions = np.asarray(m.positions_m, dtype=np.float64)
        logger.log(
            root, "Points3D", positions=positions, radii=np.full(n, c.point_radius_m), colors=_rgba(CONTACT_RGBA, n)
        )
        logger.log(
            f"{root}/normals",
            "Arrows3D",
            origins=positions,
            vectors=np.asarray(m.normals, dtype=np.float64) * c.normal_length_m,
            colors=_rgba(NORMAL_RGBA, n),
        )

    def _touch_event(self, logger: Logger, root: str, topic: str, m: TouchEvent) -> None:
        c = self.config
        t = self._touches.setdefault(topic, _Touches())
        t.positions.append(np.asarray(m.position_m, dtype=np.float64))
        t.normals.append(np.asarray(m.normal, dtype=np.float64))
        t.missed.append(bool(m.missed))
        predicted = np.asarray(m.predicted_contact_m, dtype=np.float64)
        miss_mm = float("nan")
        if np.isfinite(predicted).all():
            t.misses.append(np.stack([predicted, t.positions[-1]]))
            miss_mm = float(np.linalg.norm(t.positions[-1] - predicted)) * 1e3
        n = len(t.positions)
        positions = np.stack(t.positions)
        colors = np.where(np.asarray(t.missed)[:, None], np.asarray(MISSED_RGBA), np.asarray(CONTACT_RGBA))
        logger.log(
            f"{root}/contacts",
            "Points3D",
            positions=positions,
            radii=np.full(n, c.point_radius_m),
            colors=colors.astype(np.uint8),
        )
        logger.log(
            f"{root}/normals",
            "Arrows3D",
            origins=positions,
            vectors=np.stack(t.normals) * c.normal_length_m,
            colors=_rgba(NORMAL_RGBA, n),
        )
        if t.misses:
            logger.log(
                f"{root}/prediction_miss",
                "LineStrips3D",
                strips=np.stack(t.misses),
                radii=np.full(len(t.misses), c.line_radius_m),
                colors=_rgba(PREDICTED_RGBA, len(t.misses)),
            )
        logger.log(f"metrics/{topic.strip('/')}/travelled_m", "Scalars", scalars=float(m.travelled_m))
        logger.log(f"metrics/{topic.strip('/')}/rotation_deg", "Scalars", scalars=float(m.rotation_deg))
        if np.isfinite(miss_mm):
            logger.log(f"metrics/{topic.strip('/')}/prediction_miss_mm", "Scalars", scalars=miss_mm)

    def _surface_mesh(self, logger: Logger, root: str, topic: str, m: SurfaceMesh) -> None:
        logger.log(
            f"{root}/{m.region or 'surface'}",
            "Mesh3D",
            vertex_positions=np.asarray(m.vertices_m, dtype=np.float64),
            triangle_indices=np.asarray(m.faces, dtype=np.uint32),
            vertex_normals=np.asarray(m.vertex_normals, dtype=np.float64),
            vertex_colors=colorize(variance_per_vertex(m), self.config.colormap),
        )

    def _touch_target(self, logger: Logger, root: str, topic: str, m: TouchTarget) -> None:
        c = self.config
        k = len(m.candidates_m)
        position = np.asarray(m.position_m, dtype=np.float64)[None]
        logger.log(
            f"{root}/candidates",
            "Points3D",
            positions=np.asarray(m.candidates_m, dtype=np.float64),
            radii=np.full(k, c.candidate_radius_m),
            colors=colorize(m.candidate_scores, c.colormap),
        )
        logger.log(
            f"{root}/chosen",
            "Points3D",
            positions=position,
            radii=np.full(1, 1.5 * c.point_radius_m),
            colors=_rgba(TARGET_RGBA, 1),
            labels=[f"{m.strategy} {m.score:.3g}"],
        )
        logger.log(
            f"{root}/normal",
            "Arrows3D",
            origins=position,
            vectors=np.asarray(m.normal, dtype=np.float64)[None] * c.normal_length_m,
            colors=_rgba(TARGET_RGBA, 1),
        )
        logger.log(
            f"{root}/predicted_contact",
            "Points3D",
            positions=np.asarray(m.predicted_contact_m, dtype=np.float64)[None],
            radii=np.full(1, c.point_radius_m),
            colors=_rgba(PREDICTED_RGBA, 1),
        )

    def _trajectory(self, logger: Logger, root: str, topic: str, m: Trajectory) -> None:
        c = self.config
        control = np.asarray(m.control_points_m, dtype=np.float64)
        logger.log(
            f"{root}/curve",
            "LineStrips3D",
            strips=bezier_point(control, np.linspace(0.0, 1.0, max(2, c.curve_samples)))[None],
            radii=np.full(1, c.line_radius_m),
            colors=_rgba(CURVE_RGBA, 1),
            labels=[m.kind],
        )
        logger.log(
            f"{root}/control_points",
            "Points3D",
            positions=control,
            radii=np.full(4, 0.5 * c.point_radius_m),
            colors=_rgba(CURVE_RGBA, 4),
        )

    def _pose(self, logger: Logger, root: str, topic: str, m: Pose) -> None:
        c = self.config
        trail = self._trails.setdefault(topic, _Trail())
        p = np.asarray(m.position_m, dtype=np.float64)
        if trail.points and float(np.linalg.norm(p - trail.points[-1])) < c.trail_step_m:
            return
        if len(trail.points) >= c.trail_chunk_points:
            # start the next chunk at the last point so the drawn trail has no gap
            trail.chunk, trail.points = trail.chunk + 1, trail.points[-1:]
        trail.points.append(p)
        if len(trail.points) >= 2:
            logger.log(
                f"{root}/trail/{trail.chunk:05d}",
                "LineStrips3D",
                strips=np.stack(trail.points)[None],
                radii=np.full(1, c.line_radius_m),
                colors=_rgba(TRAIL_RGBA, 1),
            )
        logger.log(
            f"{root}/tip",
            "Points3D",
            positions=p[None],
            radii=np.full(1, c.point_radius_m),
            colors=_rgba(TRAIL_RGBA, 1),
        )
        logger.log(
            f"{root}/axis",
            "Arrows3D",
            origins=p[None],
            vectors=quat_to_matrix(m.quaternion_wxyz)[:, 2][None] * c.normal_length_m,
            colors=_rgba(TRAIL_RGBA, 1),
        )

    def _occupancy_grid(self, logger: Logger, root: str, topic: str, m: OccupancyGrid) -> None:
        centres, log_odds = occupied_cells(m, self.config.occupied_log_odds)
        k = len(centres)
        probability = 1.0 / (1.0 + np.exp(-log_odds))  # p = 1 - 1 / (1 + exp(l))
        colors = colorize(probability, self.config.colormap, vmin=0.5, vmax=1.0)
        logger.log(
            f"{root}/{m.map_kind or 'grid'}",
            "Boxes3D",
            centers=centres,
            half_sizes=np.full((k, 3), 0.5 * m.resolution_m),
            colors=colors,
            fill_mode="solid",
        )


_HANDLERS: dict[type[Message], Any] = {
    ObjectTruth: SceneLogger._object_truth,
    ContactSet: SceneLogger._contact_set,
    TouchEvent: SceneLogger._touch_event,
    SurfaceMesh: SceneLogger._surface_mesh,
    TouchTarget: SceneLogger._touch_target,
    Trajectory: SceneLogger._trajectory,
    Pose: SceneLogger._pose,
    OccupancyGrid: SceneLogger._occupancy_grid,
}
assert set(_HANDLERS) == set(SHOWN_TYPES)
