"""Scripted exploration of an object with one finger (hand and finger scenes, paper 000).

The fingertip taps and slides over every face of the object it can reach. At construction the
finger's reachable touch configurations are found by sampling joint space and projecting each
sample onto the touch surface {q : d(c(q)) = r} with Newton steps (c = fingertip cap centre,
d = exact signed distance to the object, r = segment radius); configurations where another part of
the hand would hit the object are dropped. The motion is then a sequence of strokes drawn with the
injected rng:

- tap: move above a touch point (``hover_m`` along its normal), press ``press_m`` into the surface,
  hold, lift;
- slide: press at one touch point and slide to another one on the same face, keeping the press.

Transits between strokes follow straight joint-space lines when those stay clear of the object,
else go through the straight finger (all joints 0). Waypoints are joined by cosine ramps, so the
targets are smooth. The k-th stroke depends only on the seed, never on when ``targets`` is called.

``python -m palpate.nodes.sim.motion`` runs 100 s of exploration of the Rubik's cube with the finger
and with the hand and prints contacts per second and the fraction of the reachable surface touched
after 10 s and 100 s.
"""

from __future__ import annotations

import argparse
import bisect
import math
import time
from dataclasses import dataclass
from typing import Annotated

import mujoco
import numpy as np

from palpate.config import Fraction, NonNegativeFloat, PositiveFloat, PositiveInt, Range, Validated
from palpate.errors import ConfigError
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.jsonio import dumps as json_dumps
from palpate.nodes.sim import capsule_kernels
from palpate.nodes.sim.capsules import capsule_spheres, sphere_centres
from palpate.nodes.sim.core import Simulation
from palpate.nodes.sim.effectors import LONG_FINGERS, FingerConfig, HandConfig, finger_joint_names
from palpate.nodes.sim.objects import ObjectModel, load_object, sample_surface
from palpate.nodes.sim.scene import OBJECT_BODY, SceneConfig, build_model


@dataclass(frozen=True, kw_only=True)
class MotionConfig(Validated):
    """Parameters of the scripted exploration."""

    #: Joint-space samples drawn to find touch configurations.
    candidate_samples: PositiveInt = 1500
    #: Newton iterations projecting a sample onto the touch surface, and the accepted residual.
    newton_iterations: Annotated[int, Range(ge=0)] = 6
    touch_tolerance_m: PositiveFloat = 3e-4
    #: Hover height above a touch point before pressing, and the press depth into the surface.
    hover_m: NonNegativeFloat = 0.012
    press_m: NonNegativeFloat = 0.004
    #: Minimum distance kept between the object and the parts that must not touch it.
    clearance_m: NonNegativeFloat = 0.001
    approach_s: PositiveFloat = 0.2
    hold_s: NonNegativeFloat = 0.06
    retract_s: PositiveFloat = 0.1
    #: Joint speed of transits between strokes.
    transit_speed_rad_s: PositiveFloat = 4.0
    slide_probability: Annotated[float, Fraction] = 0.5
    #: Slide length range and speed along the surface.
    slide_length_m: tuple[NonNegativeFloat, NonNegativeFloat] = (0.01, 0.035)
    slide_speed_m_s: PositiveFloat = 0.06
    #: Slides stay on one face: the end normals differ by less than this angle.
    slide_max_turn_deg: NonNegativeFloat = 10.0


@dataclass(frozen=True)
class TouchSet:
    """Reachable touch configurations of the exploring finger.

    q_touch, q_hover, q_press: (n, J) full joint vectors (hand: all 21 joints), radians.
    points_m: (n, 3) touched surface points; normals: (n, 3) outward surface normals.
    """

    q_touch: np.ndarray
    q_hover: np.ndarray
    q_press: np.ndarray
    points_m: np.ndarray
    normals: np.ndarray


class FingerKinematics:
    """Forward kinematics of the scene's effector on a scratch MjData (contacts are not simulated)."""

    def __init__(self, scene: SceneConfig, obj: ObjectModel) -> None:
        if scene.effector not in ("hand", "finger"):
            raise ValueError(f"exploration motion needs a hand or finger scene, not {scene.effector!r}")
        self.model = build_model(scene, obj)
        self.data = mujoco.MjData(self.model)
        m = self.model
        cfg = scene.effector_config()
        assert isinstance(cfg, HandConfig | FingerConfig)
        if isinstance(cfg, HandConfig):
            finger = cfg.pose_finger if cfg.pose_finger in LONG_FINGERS else "index"
        else:
            finger = cfg.finger
        self.finger = finger
        self.joint_names = [m.joint(i).name for i in range(m.njnt)]
        self.limits = np.array(m.jnt_range, dtype=np.float64)
        #: Indices (4,) of the exploring finger's joints in the full joint vector.
        self.active = np.array([self.joint_names.index(n) for n in finger_joint_names(finger)])
        self.site = m.site(f"{finger}_tip").id
        self.radius = cfg.radius_m
        object_body = m.body(OBJECT_BODY).id
        effector = np.ones(m.nbody, dtype=bool)
        effector[[0, object_body]] = False
        geoms, offsets, radii, runs = capsule_spheres(m, effector)
        # The distal phalanx of the exploring finger may touch; everything else must stay clear.
        distal = m.body(f"{finger}_distal").id
        self.sph_geoms, self.sph_offsets, self.sph_radii = geoms, offsets, radii
        self.sph_may_touch = m.geom_bodyid[geoms] == distal
        del runs

    def forward(self, q: np.ndarray) -> None:
        """Kinematics of the full joint vector q (J,)."""
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def tip(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fingertip cap centre (3,) and its Jacobian (3, 4) over the exploring finger's joints."""
        self.forward(q)
        jacp = np.zeros((3, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jacp, None, self.site)
        return self.data.site_xpos[self.site].copy(), jacp[:, self.active]

    def spheres(self, q: np.ndarray) -> np.ndarray:
        """Centres (K, 3) of the spheres covering the effector's capsules at q."""
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)  # the geom frames (forward's mj_comPos adds nothing here)
        if not capsule_kernels.matches_numpy():
            return sphere_centres(self.data, self.sph_geoms, self.sph_offsets)
        centres = np.empty((len(self.sph_geoms), 3))
        capsule_kernels.place_all(self.data.geom_xpos, self.data.geom_xmat, self.sph_geoms, self.sph_offsets, centres)
        return centres


def _dls(J: np.ndarray, x: np.ndarray, damping: float = 1e-3) -> np.ndarray:
    """Damped least-squares solution of J dq = x: J^T (J J^T + lambda^2 I)^-1 x."""
    return np.asarray(J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(J.shape[0]), x))


#: Below this size (mm) the default placement's sideways offset puts the finger beside an object.
SMALL_OBJECT_MM = 40.0


class ExplorationMotion:
    """Joint targets over time that make the fingertip tap and slide over the object's faces."""

    def __init__(
        self,
        scene: SceneConfig,
        rng: np.random.Generator,
        config: MotionConfig | None = None,
        obj: ObjectModel | None = None,
    ) -> None:
        self.scene = scene
        self.config = MotionConfig() if config is None else config
        self.object = load_object(scene.object) if obj is None else obj
        self.kin = FingerKinematics(scene, self.object)
        self.sensor = ExactContactSensor(self.object.mesh)
        vertices = np.asarray(self.object.mesh.vertices, dtype=np.float64)
        self._box = (vertices.min(axis=0), vertices.max(axis=0))
        self.joint_names = self.kin.joint_names
        self._rng = rng
        self.q_rest = np.clip(np.zeros(len(self.joint_names)), self.kin.limits[:, 0], self.kin.limits[:, 1])
        self.touches = self.find_touches(self.config.candidate_samples, rng)
        if len(self.touches.q_touch) == 0:
            size_mm = 1e3 * float(np.max(self._box[1] - self._box[0]))
            offset = [float(v) for v in scene.finger_mcp_offset_m]
            hint = (
                "a small object needs a smaller offset (its y puts the finger beside it), e.g. --set "
                "'sim.scene.finger_mcp_offset_m=[0,0.01,0.05]'"
                if size_mm < SMALL_OBJECT_MM
                else "on a large object the finger reaches only near that edge: move the base over the object "
                "(a larger x) or nearer its top (a smaller z)"
            )
            raise ConfigError(
                f"the {scene.effector}'s fingertip cannot reach the object {self.object.name!r} ({size_mm:.4g} mm "
                f"across) from this placement: move the effector base (finger_mcp_offset_m or base_position_m) "
                f"closer to the object, or turn scripted_motion off. The finger's base sits finger_mcp_offset_m = "
                f"{offset} m from the object's -x face, y centre and top; {hint}",
                ("scene",),
            )
        # Waypoints from the kept history's start on (``targets`` drops those older than HISTORY_S).
        self._times: list[float] = [0.0]
        self._points: list[np.ndarray] = [self.q_rest.copy()]
        self._latest_s = 0.0

    # --- touch configurations ----------------------------------------------------------------------
    def _clear(self, qs: np.ndarray, allow_tip: bool) -> np.ndarray:
        """Which configurations (n, J) keep the effector clear of the object -> (n,) bool.

        With ``allow_tip`` the exploring distal phalanx may touch (down to r - 1 mm); all other
        spheres must stay ``clearance_m`` away.
        """
        if len(qs) == 0:
            return np.zeros(0, dtype=bool)
        centres = np.stack([self.kin.spheres(q) for q in qs])  # (n, K, 3)
        n, K, _ = centres.shape
        need = self.kin.sph_radii + self.config.clearance_m
        need = np.broadcast_to(need, (n, K)).copy()
        if allow_tip:
            need[:, self.kin.sph_may_touch] = self.kin.sph_radii[self.kin.sph_may_touch] - 1e-3
        dist = self._distances_below(centres.reshape(-1, 3), need.ravel()).reshape(n, K)
        return np.all(dist >= need, axis=1)

    def _distances_below(self, points: np.ndarray, need: np.ndarray) -> np.ndarray:
        """Signed distances (n,) of points (n, 3) to the object where they may be below ``need`` (n,);
        elsewhere the distance to the object's bounding box, a lower bound above ``need`` (outside the
        box the surface is at least that far, and the sign test of a closed, outward-wound mesh says
        outside). The sensor answers the others; a few of them take its scalar path, whose distances may
        differ from its batch path's in the last bits (about 1e-17 m), so a decision at exactly the
        clearance could differ: none did in the first 150 strokes of the finger and the hand on the
        Rubik's cube, the banana and a cup.
        """
        lo, hi = self._box
        box = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)
        ask = ~(box > need + 1e-9)  # margin over the rounding of the sensor's closest points
        dist = box
        if ask.any():
            dist[ask] = self.sensor.closest(points[ask]).distance_m
        return dist

    def _project(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Newton-project configurations (n, J) onto d(c(q)) = r.

        Returns the projected configurations (n, J), residuals (n,) m, surface points (n, 3) and
        contact normals (n, 3) (from the surface point to the cap centre).
        """
        kin, cfg = self.kin, self.config
        qs = qs.copy()
        lo, hi = kin.limits[kin.active, 0], kin.limits[kin.active, 1]
        residual = np.full(len(qs), np.inf)
        points = np.zeros((len(qs), 3))
        normals = np.zeros((len(qs), 3))
        todo = np.arange(len(qs))
        for iteration in range(cfg.newton_iterations + 1):
            tips, jacs = [], []
            for q in qs[todo]:
                c, J = kin.tip(q)
                tips.append(c)
                jacs.append(J)
            if not tips:
                break
            c = np.array(tips)
            hit = self.sensor.closest(c)
            d = np.asarray(hit.distance_m, dtype=np.float64)
            p = np.asarray(hit.points_m, dtype=np.float64)
            offset = c - p
            length = np.linalg.norm(offset, axis=1)
            n = np.where((d > 1e-9)[:, None], offset / np.maximum(length, 1e-12)[:, None], np.asarray(hit.normals))
            residual[todo], points[todo], normals[todo] = d - kin.radius, p, n
            if iteration == cfg.newton_iterations:
                break
            move = np.abs(residual[todo]) >= 0.1 * cfg.touch_tolerance_m  # converged ones stay put
            G = np.einsum("kij,ki->kj", np.array(jacs)[move], n[move])  # d(distance)/dq, (k, 4)
            gg = np.maximum(np.einsum("kj,kj->k", G, G), 1e-12)
            todo = todo[move]
            step = -(residual[todo] / gg)[:, None] * G
            active = qs[np.ix_(todo, kin.active)]
            qs[np.ix_(todo, kin.active)] = np.minimum(np.maximum(active + step, lo), hi)
        return qs, np.abs(residual), points, normals

    def _offset_along_normal(self, qs: np.ndarray, normals: np.ndarray, distance_m: float) -> np.ndarray:
        """Configurations that move the cap centre ``distance_m`` along each normal (n, J)."""
        kin = self.kin
        out = qs.copy()
        lo, hi = kin.limits[kin.active, 0], kin.limits[kin.active, 1]
        for i, q in enumerate(qs):
            _, J = kin.tip(q)
            out[i, kin.active] = np.clip(q[kin.active] + _dls(J, distance_m * normals[i]), lo, hi)
        return out

    def find_touches(self, samples: int, rng: np.random.Generator) -> TouchSet:
        """Sample joint space and keep the reachable, collision-free touch configurations."""
        kin, cfg = self.kin, self.config
        lo, hi = kin.limits[kin.active, 0], kin.limits[kin.active, 1]
        qs = np.repeat(self.q_rest[None, :], samples, axis=0)
        qs[:, kin.active] = lo + (hi - lo) * rng.random((samples, len(kin.active)))
        # keep samples whose cap is within 2 cm of the touch surface before projecting
        c = np.array([kin.tip(q)[0] for q in qs])
        d = np.asarray(self.sensor.closest(c).distance_m)
        qs = qs[np.abs(d - kin.radius) < 0.02]
        qs, residual, points, normals = self._project(qs)
        ok = residual < cfg.touch_tolerance_m
        qs, points, normals = qs[ok], points[ok], normals[ok]
        ok = self._clear(qs, allow_tip=True)
        qs, points, normals = qs[ok], points[ok], normals[ok]
        hover = self._offset_along_normal(qs, normals, cfg.hover_m)
        ok = self._clear(hover, allow_tip=False)
        qs, points, normals, hover = qs[ok], points[ok], normals[ok], hover[ok]
        press = self._offset_along_normal(qs, normals, -cfg.press_m)
        return TouchSet(q_touch=qs, q_hover=hover, q_press=press, points_m=points, normals=normals)

    # --- strokes -----------------------------------------------------------------------------------
    #: Simulated seconds of past waypoints ``targets`` keeps behind the latest time asked.
    HISTORY_S = 60.0
    #: ``_forget_before`` trims once this many waypoints are forgettable (amortised: no per-tick copy).
    _TRIM_AT = 1024

    def _forget_before(self, time_s: float) -> None:
        """Drop the waypoints of segments that end before ``time_s``, in batches of at least _TRIM_AT."""
        k = bisect.bisect_right(self._times, time_s) - 1  # the segment holding time_s starts at k
        if k >= self._TRIM_AT:
            del self._times[:k]
            del self._points[:k]

    def _add(self, q: np.ndarray, duration_s: float) -> None:
        self._times.append(self._times[-1] + max(duration_s, 1e-3))
        self._points.append(q.copy())

    def _transit_time(self, a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(b - a).max()) / self.config.transit_speed_rad_s + 0.02

    def _path_clear(self, a: np.ndarray, b: np.ndarray) -> bool:
        alphas = np.linspace(0.0, 1.0, 9)[1:-1]
        return bool(np.all(self._clear(a[None, :] + alphas[:, None] * (b - a)[None, :], allow_tip=False)))

    def _transit(self, target: np.ndarray) -> bool:
        """Append a collision-free transit to ``target``; False if none was found."""
        start = self._points[-1]
        if self._path_clear(start, target):
            self._add(target, self._transit_time(start, target))
            return True
        safe = self.q_rest
        if self._path_clear(start, safe) and self._path_clear(safe, target):
            self._add(safe, self._transit_time(start, safe))
            self._add(target, self._transit_time(safe, target))
            return True
        return False

    def _slide_end(self, i: int) -> tuple[int, float] | None:
        """A random neighbour of touch i on the same face to slide to, and its distance."""
        t, cfg = self.touches, self.config
        dist = np.linalg.norm(t.points_m - t.points_m[i], axis=1)
        same_face = t.normals @ t.normals[i] > math.cos(math.radians(cfg.slide_max_turn_deg))
        lo, hi = cfg.slide_length_m
        options = np.flatnonzero(same_face & (dist >= lo) & (dist <= hi))
        if len(options) == 0:
            return None
        j = int(options[self._rng.integers(len(options))])
        return j, float(dist[j])

    def _slide_path(self, i: int, j: int, length_m: float) -> np.ndarray | None:
        """Pressed configurations (m, J) sliding from touch i to touch j, ``length_m`` away."""
        t, cfg = self.touches, self.config
        steps = max(2, math.ceil(length_m / 0.004))
        alphas = np.linspace(0.0, 1.0, steps + 1)
        line = t.q_touch[i][None, :] + alphas[:, None] * (t.q_touch[j] - t.q_touch[i])[None, :]
        line, residual, _, normals = self._project(line)
        if np.any(residual > 2 * cfg.touch_tolerance_m) or not np.all(self._clear(line, allow_tip=True)):
            return None
        return self._offset_along_normal(line, normals, -cfg.press_m)

    def _next_stroke(self) -> None:
        t, cfg = self.touches, self.config
        for _ in range(20):
            i = int(self._rng.integers(len(t.q_touch)))
            end = self._slide_end(i) if self._rng.random() < cfg.slide_probability else None
            if not self._transit(t.q_hover[i]):
                continue
            slide = self._slide_path(i, *end) if end is not None else None  # draws nothing: planned once reached
            self._add(t.q_press[i], cfg.approach_s)
            self._add(t.q_press[i], cfg.hold_s)
            if slide is not None:
                step_s = 0.004 / cfg.slide_speed_m_s
                for q in slide[1:]:
                    self._add(q, step_s)
                # lift along the surface normal at the end of the slide
                last = slide[-1:]
                n = np.asarray(self.sensor.closest(self.kin.tip(last[0])[0][None, :]).normals, dtype=np.float64)
                self._add(self._offset_along_normal(last, n, cfg.press_m + cfg.hover_m)[0], cfg.retract_s)
            else:
                self._add(t.q_hover[i], cfg.retract_s)
            return
        # no stroke could be reached this time: rest briefly, then try again
        self._transit(self.q_rest)
        self._add(self.q_rest, 0.1)

    def targets(self, time_s: float) -> np.ndarray:
        """Joint targets (J,) in radians at simulated time ``time_s`` (full joint vector).

        Any time from HISTORY_S before the latest one asked on may be asked (a long run keeps a bounded
        number of waypoints)."""
        if not math.isfinite(time_s) or time_s < 0:
            raise ValueError(f"time_s must be finite and >= 0, got {time_s!r}")
        if time_s < self._times[0]:
            raise ValueError(
                f"time_s {time_s!r} is more than {self.HISTORY_S:g} s before the latest time asked "
                f"({self._latest_s!r} s): the motion keeps only that much of its past"
            )
        while self._times[-1] <= time_s:
            self._next_stroke()
        if time_s > self._latest_s:
            self._latest_s = time_s
            self._forget_before(time_s - self.HISTORY_S)
        k = bisect.bisect_right(self._times, time_s) - 1  # np.searchsorted(side="right") without the array
        t0, t1 = self._times[k], self._times[k + 1]
        s = (time_s - t0) / (t1 - t0)
        ramp = 0.5 - 0.5 * math.cos(math.pi * s)  # smooth start and stop of every segment
        return np.asarray(self._points[k] + ramp * (self._points[k + 1] - self._points[k]))


# --- measurement -----------------------------------------------------------------------------------


def reachable_surface(
    motion: ExplorationMotion, rng: np.random.Generator, samples: int = 20000, surface_points: int = 6000
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface samples of the object and which ones the fingertip can reach.

    Returns points (m, 3), outward normals (m, 3) and reachable (m,) bool: a surface sample is
    reachable when a touch configuration of a dense joint-space sample (``samples``) touches the
    surface within 3 mm of it.
    """
    touches = motion.find_touches(samples, rng)
    points, normals = sample_surface(motion.object.mesh, surface_points, rng)
    reachable = _within(points, touches.points_m, 0.003)
    return points, normals, reachable


def _within(points: np.ndarray, targets: np.ndarray, radius_m: float) -> np.ndarray:
    """(m,) bool: each point has a target within radius_m."""
    if len(targets) == 0:
        return np.zeros(len(points), dtype=bool)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(targets).query(points, k=1, distance_upper_bound=radius_m)
    return np.asarray(np.isfinite(dist))


def explore(
    scene: SceneConfig, seed: int, seconds: float, sample_hz: float = 100.0
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Run the scripted exploration in the simulation.

    Returns contact positions (n, 3) and sample times (n,) of every contact reported at
    ``sample_hz``, and the number of touch onsets (no contact -> contact) per whole second.
    """
    sim = Simulation(scene)
    motion = ExplorationMotion(scene, np.random.default_rng(seed), obj=sim.object)
    per_sample = max(1, round(1.0 / (sample_hz * sim.timestep_s)))
    positions: list[np.ndarray] = []
    times: list[np.ndarray] = []
    onsets = [0] * math.ceil(seconds)
    touching = False
    while sim.time_s < seconds - 1e-9:
        sim.set_joint_targets(motion.targets(sim.time_s))
        sim.step(per_sample)
        c = sim.contacts()
        if len(c):
            positions.append(c.positions_m)
            times.append(np.full(len(c), sim.time_s))
            if not touching:
                onsets[min(int(sim.time_s), len(onsets) - 1)] += 1
        touching = len(c) > 0
    if positions:
        return np.concatenate(positions), np.concatenate(times), onsets
    return np.zeros((0, 3)), np.zeros(0), onsets


def exploration_report(
    effector: str = "finger",
    seed: int = 0,
    seconds: tuple[float, ...] = (10.0, 100.0),
    coverage_radius_m: float = 0.005,
) -> dict[str, object]:
    """Contacts per second and the fraction of the reachable cube surface touched after each duration.

    A reachable surface sample counts as touched when a reported contact lies within
    ``coverage_radius_m`` of it. Per face: the face's share of reachable samples and of those touched.
    """
    scene = SceneConfig(effector=effector)
    start = time.perf_counter()
    positions, times, onsets = explore(scene, seed, max(seconds))
    wall = time.perf_counter() - start
    motion = ExplorationMotion(scene, np.random.default_rng(seed))
    points, normals, reachable = reachable_surface(motion, np.random.default_rng(seed + 1))
    face = np.argmax(np.abs(normals), axis=1) * 2 + (
        normals[np.arange(len(normals)), np.argmax(np.abs(normals), axis=1)] > 0
    )
    names = ["-x", "+x", "-y", "+y", "-z", "+z"]
    report: dict[str, object] = {
        "effector": effector,
        "object": scene.object.kind,
        "seed": seed,
        "wall_s_for_sim_s": {"wall_s": round(wall, 2), "sim_s": max(seconds)},
        "reachable_fraction_of_surface": round(float(reachable.mean()), 3),
        "reachable_faces": {names[f]: round(float(reachable[face == f].mean()), 3) for f in range(6)},
    }
    for duration in seconds:
        keep = times <= duration
        touched = _within(points, positions[keep], coverage_radius_m) & reachable
        report[f"after_{duration:g}s"] = {
            "contact_samples_per_s": round(float(keep.sum()) / duration, 1),
            "touches_per_s": round(sum(onsets[: int(duration)]) / duration, 2),
            "touched_fraction_of_reachable": round(float(touched.sum()) / max(1, int(reachable.sum())), 3),
            "touched_fraction_per_face": {
                names[f]: round(float(touched[face == f].sum()) / max(1, int(reachable[face == f].sum())), 3)
                for f in range(6)
                if reachable[face == f].any()
            },
        }
    return report


def main(argv: list[str] | None = None) -> None:
    """Print the exploration report for the finger and hand scenes on the Rubik's cube."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--effector", choices=["finger", "hand", "both"], default="both")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seconds", type=float, nargs="+", default=[10.0, 100.0])
    args = parser.parse_args(argv)
    effectors = ["finger", "hand"] if args.effector == "both" else [args.effector]
    for effector in effectors:
        print(json_dumps(exploration_report(effector, args.seed, tuple(args.seconds))))


if __name__ == "__main__":
    main()
