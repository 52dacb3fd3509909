"""Metrics of one exploration run, as paper 002 defines them (Section 3.2), updated per touch.

Coverage: the true surface sampled uniformly by area; a sample is explored once a contact lies within
6 mm. A run is complete at 80 % coverage (figures also at 50 %); a run that cannot get there stops at a
budget (contacts or travel) and is reported as incomplete with the coverage it reached.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Annotated, Any

import numpy as np

from palpate.config import NonNegativeFloat, NonNegativeInt, PositiveFloat, PositiveInt, Range, Validated
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.metrics.exploration import (
    CoverageTracker,
    RmseScorer,
    SurfaceRmse,
    angle_to_normal_deg,
    confident_faces,
    covering_bound_contacts,
    triangle_areas,
)
from palpate.metrics.shape import ShapeScorer

#: How the evaluator's stop request begins ("exploration finished: goal", ...): any other reason to end
#: a run came from another node.
FINISHED_PREFIX = "exploration finished"


def milestone_key(fraction: float) -> str:
    """A milestone's key in a run's summary: its percent, "50" for 0.5, "0.5" for 0.005."""
    return f"{round(100 * fraction, 6):g}"


@dataclass(frozen=True, kw_only=True)
class EvalConfig(Validated):
    """Goal, milestones and budgets of a run."""

    #: The run ends as complete once this fraction of the true surface is explored (paper: 80 %).
    coverage_goal: Annotated[float, Range(gt=0.0, le=1.0)] = 0.8
    #: Coverage fractions at which the run's figures (contacts, travel, surface RMSE) are recorded; one not
    #: reached is recorded at the end as not reached. The coverage goal is always one (``recorded``).
    milestones: tuple[Annotated[float, Range(gt=0.0, le=1.0)], ...] = (0.5, 0.8)
    #: A point of the true surface counts as explored once a contact lies within this distance, metres.
    radius_m: PositiveFloat = 0.006
    #: Points drawn uniformly by area on the true surface to measure coverage (standard error about
    #: sqrt(p (1 - p) / samples)).
    coverage_samples: PositiveInt = 20000
    #: Budgets: a run that has not reached the coverage goal after this many contacts or this much
    #: travel ends as incomplete. Chosen for time (issue 5: the 180-run YCB evaluation within 2 hours on 2
    #: cores): a run then costs at most ~60 s CPU. About twice the covering bound of most large YCB
    #: objects (block of wood 360 contacts; the master chef can's 531 gets more from contacts_per_bound);
    #: IGEF needs 1.5-2.5 times the bound (its hops overlap), and GP-V covered only 48-77 % of the large
    #: YCB cups within 15 m.
    max_contacts: PositiveInt = 800
    #: The travel budget: fingertip path, metres (see max_contacts).
    max_travel_m: PositiveFloat = 20.0
    #: Budgets that fit the object: at least this many contacts, and this much travel, per contact of
    #: the object's covering bound (``covering_bound_contacts`` at the goal), so that a large object (a
    #: coffee can's bound is about 530 contacts) is not cut off by budgets sized for the others
    #: (IGEF needs 1.5-2.5 times the bound). 0 keeps the fixed budgets above.
    contacts_per_bound: NonNegativeFloat = 2.5
    #: Travel budget per contact of the covering bound, metres (as contacts_per_bound; 0 keeps max_travel_m).
    travel_per_bound_m: NonNegativeFloat = 0.05
    #: Simulated time without a touch after which the run ends as stalled (the fingertip stuck against
    #: the object without a touch event, or a planner error), seconds; counted from the first touch (a
    #: start 1.7 m away took 34 s to reach the object and ended as stalled with no contact).
    max_idle_s: PositiveFloat = 30.0
    #: Touches in a row that add no coverage after which the run ends as "no progress" (a planner that
    #: keeps aiming at what it cannot reach: an outside audit saw 720 such touches on a 1 mm needle and
    #: 400 on a mesh of two bodies, until the contact budget); 0: never. On the 30 shared objects x 3
    #: starts a run that reached the goal went at most 128 touches without a gain (IGEF).
    max_touches_without_gain: NonNegativeInt = 200
    #: Time the run waits for the whole-object surface it asked for at the end; then it ends without it
    #: (its last milestones keep no RMSE) instead of running on until the clock, seconds. Lockstep runs
    #: get it the next tick; 30 s leaves a real-time GPIS node time for a large object's mesh.
    surface_wait_s: PositiveFloat = 30.0
    #: Points drawn uniformly by area on each surface, true and estimated, for the surface RMSE.
    rmse_samples: PositiveInt = 20000
    #: The headline surface RMSE is taken over the part of the estimate whose GP standard deviation is
    #: at most this, metres: the surface the estimate claims to know (see ``Milestone``).
    confident_sigma_m: PositiveFloat = 0.001
    #: Whole-shape scores (Chamfer distance, F-scores, palpate.metrics.shape) of the whole estimate
    #: every this many contacts, at each milestone and at the end; 0: only at milestones and the end.
    shape_every_contacts: NonNegativeInt = 10
    #: At most this many shape checkpoints per covering bound of contacts: a large object's run (a 0.6 x
    #: 0.4 x 0.3 m box: a bound of 9,238 contacts) spaces them wider than shape_every_contacts, so its
    #: whole-object meshes (seconds each there) do not outweigh the run. Every 10 contacts for any
    #: object with a bound up to 600 (all 30 shared YCB objects). 0: always shape_every_contacts.
    shape_checkpoints_per_bound: NonNegativeFloat = 60.0
    #: Points drawn uniformly by area on each surface, true and estimated, for the whole-shape scores.
    shape_samples: PositiveInt = 5000

    @property
    def recorded(self) -> tuple[float, ...]:
        """The milestones and the coverage goal, in order: a goal that is no milestone was reached without
        its figures and the run said complete: false beside finished: goal."""
        return tuple(sorted({*self.milestones, self.coverage_goal}))

    def covering_bound(self, area_m2: float) -> float:
        """The fewest discs of radius_m that cover coverage_goal of a surface of area_m2 (contacts)."""
        return covering_bound_contacts(area_m2, self.coverage_goal, self.radius_m)

    def shape_interval(self, bound: float) -> int:
        """Contacts between shape checkpoints: shape_every_contacts, or more for a large covering bound
        (bound / shape_checkpoints_per_bound, rounded up); 0 when the checkpoints are off."""
        every = self.shape_every_contacts
        if every == 0 or self.shape_checkpoints_per_bound == 0:
            return every
        return max(every, math.ceil(bound / self.shape_checkpoints_per_bound))

    def contact_budget(self, bound: float) -> int:
        """max(max_contacts, contacts_per_bound * covering bound)."""
        return max(self.max_contacts, math.ceil(self.contacts_per_bound * bound))

    def travel_budget_m(self, bound: float) -> float:
        """max(max_travel_m, travel_per_bound_m * covering bound), metres."""
        return max(self.max_travel_m, self.travel_per_bound_m * bound)


@dataclass
class Milestone:
    """Figures when coverage first reached `fraction` (or at the end of an incomplete run)."""

    fraction: float
    reached: bool
    contacts: int
    travel_cm: float
    rotation_deg: float
    prediction_miss_mm: float
    angle_deg: float
    coverage: float
    vertex_coverage: float
    #: Headline surface RMSE: one-sided, from the confident estimate (GP std <= confident_sigma_m) to
    #: the true mesh; how wrong the surface is where the estimate says it knows it.
    rmse_mm: float = math.nan
    #: Area fraction of the estimated mesh that is confident.
    confident_fraction: float = math.nan
    #: Over the whole estimated mesh: symmetric, and one-sided each way (truth -> estimate also charges
    #: the unexplored part of the object, where the estimate is only the GP's extrapolation).
    rmse_symmetric_mm: float = math.nan
    rmse_estimate_to_truth_mm: float = math.nan
    rmse_truth_to_estimate_mm: float = math.nan
    #: Whole-shape scores of the same estimate (palpate.metrics.shape).
    chamfer_mm: float = math.nan
    fscore_2mm: float = math.nan


@dataclass
class ShapePoint:
    """Whole-shape scores of the estimate after ``contacts`` contacts and ``travel_cm`` of travel."""

    contacts: int
    travel_cm: float
    coverage: float
    chamfer_mm: float
    accuracy_mm: float
    completeness_mm: float
    fscore_1mm: float
    fscore_2mm: float
    fscore_5mm: float
    fscore_10mm: float


@dataclass(frozen=True)
class SurfaceScores:
    """Surface RMSE of an estimate over the whole mesh and over its confident part, and the area
    fraction of the estimate that is confident."""

    whole: SurfaceRmse
    confident: SurfaceRmse
    confident_fraction: float


@dataclass
class TouchRecord:
    """One touch as the evaluator saw it."""

    index: int
    position_m: list[float]
    travel_cm: float
    rotation_deg: float
    coverage: float
    vertex_coverage: float
    prediction_miss_mm: float
    angle_deg: float
    missed: bool
    #: The measured outward unit normal (as the estimator got it), or None when not given.
    normal: list[float] | None = None


@dataclass(frozen=True)
class SurfaceAsk:
    """One request for the whole-object surface: the touch count when it was made, the milestones its
    surface scores, and whether it is the run's last."""

    contacts: int
    milestones: tuple[float, ...]
    final: bool


class RunControl:
    """When an evaluated run asks for the whole-object surface, which milestones that surface scores,
    and when the run ends (around an ExplorationEvaluator).

    A touch that reaches milestones, finishes the run (goal or budget) or is a shape checkpoint (every
    ``EvalConfig.shape_interval`` contacts for the object's covering bound) asks for the surface. The
    surfaces answer the requests in order (the estimator answers each once, first come first served),
    and a surface also answers the later requests that its contact count covers, so that a request
    never answered does not hold up the rest (see ``surface``): it gets its shape scores at the touch
    count of the newest request it answers, scores their milestones and, when it answers the
    finishing touch's request, ends the run; a surface that answers no request is ignored. So a
    surface that comes late (a slow estimator, off lockstep) is neither scored as a later one nor
    ends the run early; off lockstep it may also hold touches made after its request. A run with no
    touch for EvalConfig.max_idle_s of simulated time after its last one finishes as "stalled" (the
    first approach has no limit: a start far away takes long, and the controller ends a run whose
    first approach finds no surface; its last surface is
    scored the same way). A run whose last surface does not come within EvalConfig.surface_wait_s is
    ``overdue``: it ends without it.
    """

    def __init__(self, evaluator: ExplorationEvaluator) -> None:
        self.evaluator = evaluator
        self.asks: deque[SurfaceAsk] = deque()  # requests not yet answered, oldest first
        self.final_requested = False
        self.final_requested_ns = 0
        self.final_received = False
        self.overdue_reported = False
        self.last_touch_ns = 0

    def touch(
        self,
        stamp_ns: int,
        position_m: np.ndarray,
        predicted_m: np.ndarray,
        travel_m: float,
        rotation_deg: float,
        fingertip_axis: np.ndarray | None,
        missed: bool,
        normal: np.ndarray | None = None,
    ) -> bool:
        """Fold in a touch (see ExplorationEvaluator.add_touch; no fingertip axis: -z); True when the
        whole-object surface must be requested. Touches after the finishing one are ignored."""
        if self.final_requested:
            return False
        ev = self.evaluator
        self.last_touch_ns = stamp_ns
        axis = np.array([0.0, 0.0, -1.0]) if fingertip_axis is None else fingertip_axis
        reached = ev.add_touch(position_m, predicted_m, travel_m, rotation_deg, axis, missed, normal)
        every = ev.shape_interval
        checkpoint = every > 0 and len(ev.touches) % every == 0
        if reached or ev.finished or checkpoint:
            self._ask(stamp_ns, tuple(reached), final=bool(ev.finished))
            return True
        return False

    def _ask(self, stamp_ns: int, milestones: tuple[float, ...], final: bool) -> None:
        self.asks.append(SurfaceAsk(len(self.evaluator.touches), milestones, final))
        if final:
            self.final_requested = True
            self.final_requested_ns = stamp_ns

    @property
    def needs_variance(self) -> bool:
        """Whether the whole-object surface just asked for must carry the GP variance: only the
        milestones' confident RMSE reads it (the shape checkpoints do not), and Eq. 6 at every vertex of
        the whole object costs the GPIS node more than its mesh."""
        return bool(self.asks and self.asks[-1].milestones)

    def surface(
        self, vertices_m: np.ndarray, faces: np.ndarray, vertex_variance: np.ndarray, num_contacts: int | None = None
    ) -> bool:
        """A whole-object estimate of ``num_contacts`` contacts arrived (vertices (v, 3) m, faces (f, 3), GP
        variance (v,) m^2): it answers the oldest open request and every later one that its contacts
        cover (a request whose answer never came: the estimator refused it, or a reply was lost), and
        gets the shape scores at the newest of them and their milestones. True when the run is over (it
        answers the run's last request). An estimator that holds fewer contacts than touches (it refused
        some) is answered in order."""
        if not self.asks:
            return False
        answered = [self.asks.popleft()]
        while self.asks and num_contacts is not None and self.asks[0].contacts <= num_contacts:
            answered.append(self.asks.popleft())
        newest = answered[-1]
        shape = self.evaluator.shape(vertices_m, faces, newest.contacts)
        milestones = [fraction for ask in answered for fraction in ask.milestones]
        if milestones:
            rmse = self.evaluator.rmse(vertices_m, faces, vertex_variance)
            for fraction in milestones:
                self.evaluator.set_rmse(fraction, rmse, shape)
        self.final_received = newest.final
        return newest.final

    def tick(self, stamp_ns: int) -> bool:
        """Watchdog: True (once) when the run has made no touch for max_idle_s and has just finished as
        stalled; the whole-object surface must then be requested (the end's estimate is scored too)."""
        if self.final_requested or not self.evaluator.touches:  # the first approach may be long: no limit
            return False
        if stamp_ns - self.last_touch_ns <= self.evaluator.config.max_idle_s * 1e9:
            return False
        self.evaluator.finished = "stalled"
        self._ask(stamp_ns, (), final=True)
        return True

    def overdue(self, stamp_ns: int) -> bool:
        """True (once) when the surface asked for at the end has not come within surface_wait_s of
        simulated time (the GPIS node refused the request, or there is none): the run ends without it."""
        if not self.final_requested or self.final_received or self.overdue_reported:
            return False
        if stamp_ns - self.final_requested_ns <= self.evaluator.config.surface_wait_s * 1e9:
            return False
        self.overdue_reported = True
        return True


@dataclass
class ExplorationEvaluator:
    """Accumulates touches on a known true mesh and reports the paper's metrics."""

    vertices_m: np.ndarray
    faces: np.ndarray
    config: EvalConfig = field(default_factory=EvalConfig)
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def __post_init__(self) -> None:
        mesh = (self.vertices_m, self.faces)
        self.tracker = CoverageTracker(mesh, self.config.radius_m, self.config.coverage_samples, self.rng)
        self.sensor = _sensor(self.vertices_m, self.faces)
        self._rmse_scorer: RmseScorer | None = None
        self.touches: list[TouchRecord] = []
        self.milestones: dict[float, Milestone] = {}
        self.shape_series: list[ShapePoint] = []
        self._shape_scorer: ShapeScorer | None = None  # built on the first estimate
        self.finished = ""
        self._touches_without_gain = 0

    @property
    def area_m2(self) -> float:
        return self.tracker.area_m2

    @property
    def covering_bound(self) -> float:
        """The fewest 6 mm discs that cover the goal's share of the true surface (contacts)."""
        return self.config.covering_bound(self.area_m2)

    @property
    def shape_interval(self) -> int:
        """EvalConfig.shape_interval of this object (contacts between shape checkpoints)."""
        return self.config.shape_interval(self.covering_bound)

    @property
    def contact_budget(self) -> int:
        """EvalConfig.contact_budget of this object."""
        return self.config.contact_budget(self.covering_bound)

    @property
    def travel_budget_m(self) -> float:
        """EvalConfig.travel_budget_m of this object, metres."""
        return self.config.travel_budget_m(self.covering_bound)

    def add_touch(
        self,
        position_m: np.ndarray,
        predicted_m: np.ndarray,
        travel_m: float,
        rotation_deg: float,
        fingertip_axis: np.ndarray,
        missed: bool = False,
        normal: np.ndarray | None = None,
    ) -> list[float]:
        """Fold in one touch (``normal``, the measured one, is only recorded); returns the milestones
        (fractions) this touch reached."""
        self.tracker.add_contact(position_m)
        true_normal = self.sensor.closest(np.asarray(position_m, dtype=np.float64)[None]).normals[0]
        miss = float(np.linalg.norm(predicted_m - position_m)) if np.all(np.isfinite(predicted_m)) else math.nan
        record = TouchRecord(
            index=len(self.touches),
            position_m=[float(v) for v in position_m],
            travel_cm=100.0 * travel_m,
            rotation_deg=float(rotation_deg),
            coverage=self.tracker.coverage,
            vertex_coverage=self.tracker.vertex_coverage,
            prediction_miss_mm=1000.0 * miss,
            angle_deg=float(angle_to_normal_deg(fingertip_axis, true_normal)[0]),
            missed=missed,
            normal=None if normal is None else [float(v) for v in normal],
        )
        gained = not self.touches or record.coverage > self.touches[-1].coverage
        self._touches_without_gain = 0 if gained else self._touches_without_gain + 1
        self.touches.append(record)
        reached = []
        for fraction in self.config.recorded:
            if fraction not in self.milestones and record.coverage >= fraction:
                self.milestones[fraction] = self._milestone(fraction, reached=True)
                reached.append(fraction)
        if record.coverage >= self.config.coverage_goal:
            self.finished = "goal"
        elif len(self.touches) >= self.contact_budget:
            self.finished = "contact budget"
        elif travel_m >= self.travel_budget_m:
            self.finished = "travel budget"
        elif 0 < self.config.max_touches_without_gain <= self._touches_without_gain:
            self.finished = "no progress"
        return reached

    def close_incomplete(self) -> None:
        """Record the end of a run that stopped before a milestone, with what it reached."""
        for fraction in self.config.recorded:
            if fraction not in self.milestones:
                self.milestones[fraction] = self._milestone(fraction, reached=False)

    def _milestone(self, fraction: float, reached: bool) -> Milestone:
        touches = self.touches
        misses = [t.prediction_miss_mm for t in touches if math.isfinite(t.prediction_miss_mm)]
        last = touches[-1] if touches else None
        return Milestone(
            fraction=fraction,
            reached=reached,
            contacts=len(touches),
            travel_cm=last.travel_cm if last else 0.0,
            rotation_deg=last.rotation_deg if last else 0.0,
            prediction_miss_mm=float(np.mean(misses)) if misses else math.nan,
            angle_deg=_mean_defined([t.angle_deg for t in touches]),
            coverage=self.tracker.coverage,
            vertex_coverage=self.tracker.vertex_coverage,
        )

    def shape(self, vertices_m: np.ndarray, faces: np.ndarray, contacts: int | None = None) -> ShapePoint:
        """Whole-shape scores of an estimated mesh (vertices (v, 3) m, faces (f, 3)) after ``contacts``
        touches (None: all so far): appended to ``shape_series`` (once per contact count) and returned."""
        if self._shape_scorer is None:
            truth = (self.vertices_m, self.faces)
            self._shape_scorer = ShapeScorer(truth, self.config.shape_samples, rng=np.random.default_rng(0))
        scores = self._shape_scorer.score((vertices_m, faces)).as_dict()  # ShapePoint's score fields
        count = len(self.touches) if contacts is None else contacts
        last = self.touches[count - 1] if count > 0 else None
        point = ShapePoint(
            contacts=count,
            travel_cm=last.travel_cm if last else 0.0,
            coverage=last.coverage if last else 0.0,
            **scores,
        )
        if self.shape_series and self.shape_series[-1].contacts == point.contacts:
            self.shape_series[-1] = point
        else:
            self.shape_series.append(point)
        return point

    def set_rmse(self, fraction: float, scores: SurfaceScores, shape: ShapePoint | None = None) -> None:
        """Attach the surface scores of the estimate published when `fraction` was reached."""
        m = self.milestones[fraction]
        if shape is not None:
            m.chamfer_mm, m.fscore_2mm = shape.chamfer_mm, shape.fscore_2mm
        for key, value in surface_fields(scores).items():
            setattr(m, key, value)

    def rmse(self, vertices_m: np.ndarray, faces: np.ndarray, vertex_variance: np.ndarray) -> SurfaceScores:
        """Surface RMSE between an estimated mesh (vertices (v, 3) m, faces (f, 3), GP variance (v,) m^2)
        and the true mesh: over the whole estimate and over its confident part."""
        whole = self._rmse(vertices_m, faces)
        sure = confident_faces(faces, vertex_variance, self.config.confident_sigma_m)
        area = triangle_areas(vertices_m, np.asarray(faces, dtype=np.int64)).sum() if len(faces) else 0.0
        fraction = float(triangle_areas(vertices_m, sure).sum() / area) if area > 0 else math.nan
        return SurfaceScores(whole=whole, confident=self._rmse(vertices_m, sure), confident_fraction=fraction)

    def _rmse(self, vertices_m: np.ndarray, faces: np.ndarray) -> SurfaceRmse:
        """NaN for an estimate without surface (no faces, or all of zero area: the shape scores call it
        infinitely far, ``shape``); otherwise ``surface_rmse``'s figures."""
        if len(faces) == 0 or not triangle_areas(vertices_m, np.asarray(faces, dtype=np.int64)).sum() > 0:
            nan = math.nan
            return SurfaceRmse(estimate_to_truth_m=nan, truth_to_estimate_m=nan, symmetric_m=nan)
        if self._rmse_scorer is None:  # the true mesh's samples and distance field, once per run
            self._rmse_scorer = RmseScorer((self.vertices_m, self.faces), self.config.rmse_samples, seed=0)
        return self._rmse_scorer.score((vertices_m, faces))

    def summary(self) -> dict[str, Any]:
        """Everything about the run as plain data (JSON-ready)."""
        goal = self.config.coverage_goal
        return {
            "complete": goal in self.milestones and self.milestones[goal].reached,
            "finished": self.finished or "clock",
            "contacts": len(self.touches),
            "coverage": self.tracker.coverage,
            "vertex_coverage": self.tracker.vertex_coverage,
            "area_m2": self.area_m2,
            "covering_bound_contacts": self.covering_bound,
            "contact_budget": self.contact_budget,
            "travel_budget_m": self.travel_budget_m,
            "milestones": {milestone_key(f): asdict(m) for f, m in sorted(self.milestones.items())},
            "shape": [asdict(p) for p in self.shape_series],
            "touches": [asdict(t) for t in self.touches],
        }


def surface_fields(scores: SurfaceScores) -> dict[str, float]:
    """A milestone's surface figures (Milestone fields, mm) from an estimate's scores."""
    return {
        "rmse_mm": 1000.0 * scores.confident.estimate_to_truth_m,
        "confident_fraction": scores.confident_fraction,
        "rmse_symmetric_mm": 1000.0 * scores.whole.symmetric_m,
        "rmse_estimate_to_truth_mm": 1000.0 * scores.whole.estimate_to_truth_m,
        "rmse_truth_to_estimate_mm": 1000.0 * scores.whole.truth_to_estimate_m,
    }


def _sensor(vertices_m: np.ndarray, faces: np.ndarray) -> ExactContactSensor:
    import trimesh

    return ExactContactSensor(trimesh.Trimesh(vertices_m, faces, process=False))


def _mean_defined(values: list[float]) -> float:
    """The mean of the values that are not NaN (an angle at a zero-length normal), NaN without any."""
    defined = [v for v in values if not math.isnan(v)]
    return float(np.mean(defined)) if defined else math.nan


#: Below this covering bound (contacts) coverage is reached by a touch or two.
FEW_TOUCHES = 3.0
#: ... or so large that a run to the goal takes more touches than this (about 4x the covering bound of the
#: largest YCB object, the master chef can's 531), hours of simulated exploration.
MANY_TOUCHES = 2000.0


def size_note(name: str, area_m2: float, bound: float, config: EvalConfig, caps: str) -> str:
    """What to know of an object (area m^2, covering bound in contacts) so small that a touch or two may
    reach the coverage goal (its run then ends early, and only its shape scores, F-score and Chamfer,
    tell how well it was learnt), or so large that its run takes hours (with the budgets it gets and,
    in ``caps``, how to cap them and to give the mesh's unit), or whose contact budget ends every run
    short of the goal; "" for any other object."""
    goal, radius_m = config.coverage_goal, config.radius_m
    if bound < FEW_TOUCHES:
        return (
            f"{name} has {area_m2 * 1e4:.3g} cm^2 of surface: {bound:.2g} touches of {radius_m * 1e3:g} mm "
            f"cover {goal:.0%} of it at best, so its run may end within a few touches (more on a thin or long "
            "object, where a touch covers less); its F-score and Chamfer distance tell how well it was learnt"
        )
    if bound <= MANY_TOUCHES:
        return ""
    contacts, travel_m = config.contact_budget(bound), config.travel_budget_m(bound)
    unit = caps.rsplit("; ", 1)[-1]
    if contacts < bound:  # the budget ends every run first: no hours, and no goal
        return (
            f"{name} has {area_m2:.3g} m^2 of surface: {bound:,.0f} touches of {radius_m * 1e3:g} mm cover "
            f"{goal:.0%} of it at best, more than its budget of {contacts:,.0f} contacts, so its runs end at "
            f"the budget short of that coverage ({unit} if the mesh is not in metres)"
        )
    return (
        f"{name} has {area_m2:.3g} m^2 of surface: {bound:,.0f} touches of {radius_m * 1e3:g} mm cover "
        f"{goal:.0%} of it, so its runs may take hours; their budgets are {contacts:,.0f} contacts and "
        f"{travel_m:,.0f} m of travel ({caps} if the mesh is not in metres)"
    )
