"""The controller node's decision: Algorithm 1's controller side (paper 002, lines 5-10 and 19-20).

``TouchLoop`` feeds the measured pose and contacts to a ``TrajectoryController`` (Algorithm 1's curve
follower, ``trajectory.py``), decides with ``TouchArming`` when a contact is a new touch (Alg. 1 lines
6-10, with re-arming rules not in the paper) and returns the velocity command and the touch, if any.
Not in the paper: where the next curve retracts (``retract_direction``) and slides along the surface
to a target (``Slide``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.config import NonNegativeFloat, PositiveFloat, Range, Validated
from palpate.errors import InputError
from palpate.geometry import rotations
from palpate.inputs import coordinates, unit_vectors
from palpate.messages.schemas import MAX_MISS_DISTANCE_M
from palpate.nodes.controller.trajectory import ControllerConfig, ControllerState, TrajectoryController

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
class TouchConfig(Validated):
    """When a contact is a new touch and where the next curve starts (TouchLoop, TouchArming)."""

    #: Radius of the fingertip sphere: the curve guides its centre, which touches a surface point
    #: t_p when it reaches t_p + radius t_n.
    tip_radius_m: NonNegativeFloat = 0.008
    #: A contact counts as a new touch once the fingertip has left the last one, or (not in the paper)
    #: once it has slid this far from the last touch while it stayed in contact, metres: both the
    #: fingertip (its pose) and the strongest contact point moved this far. The contact point alone
    #: is not enough: a noisy reading jumps by more than this without any motion, and counted one press
    #: as several touches; nor the fingertip alone, which rolls over an edge while the contact stays.
    #: Without it a curve that grazes the surface (retracting along a tangential v_n, or bending around
    #: an edge) slides along the object for ever without a touch event: measured on the YCB wood block.
    #: 3 mm is half the coverage radius, so such a touch still explores new surface. 0 disables it.
    rearm_distance_m: NonNegativeFloat = 0.003
    #: ... or once the fingertip has pushed against the surface (normal force > 0) without interruption
    #: for this long, seconds (not in the paper): a curve blocked by the object (under the lip of a cup)
    #: otherwise pushes in place for ever. So does a fingertip held in contact that moved less than
    #: HELD_M in that time, whatever the force of its strongest contact: wedged in a narrow gap, the
    #: contact that blocks it need not be the one reported (measured on the YCB large clamp, after a
    #: slide). 0 disables both.
    rearm_push_s: NonNegativeFloat = 0.1
    #: Not in the paper: the next curve retracts along -v_n (Eq. 15) only when v_n points into the
    #: surface, v_n . (-n) >= this cosine (n the measured contact normal); otherwise it retracts along
    #: n. A touch made while sliding (v_n tangential) would otherwise start the next curve along the
    #: surface, and the fingertip touches again a few millimetres on (measured: 600 contacts on 2 % of
    #: the YCB sponge with GP-V). 0.5 = 60 degrees; -1 keeps Eq. 15 as written.
    retract_min_cos: Annotated[float, Range(ge=-1.0, le=1.0)] = 0.5
    #: A slide (TouchTarget.slide, not in the paper) keeps the fingertip on the surface while it moves
    #: its contact point towards the target at v0, in the tangent plane of the strongest contact: it
    #: presses into the surface at this speed, m/s (the contact keeps it out), and ends with a touch
    #: once the contact point is within ``slide_arrive_m`` of the target in that plane (two control
    #: steps at v0), or has passed it by more than that, or the fingertip has moved twice as far as the
    #: slide's start was from the target plus ``slide_slack_m``, or for as long as that takes at v0
    #: (held by a wall). The contact point is placed by the fingertip's pose and the contact normal,
    #: fingertip centre - tip_radius_m n, not read: a noisy reading would end a slide at once. Where
    #: the fingertip loses the surface (an edge) it finishes along the Eq. 15 curve (see
    #: MIN_SLIDE_CURVE_M).
    slide_press_m_s: NonNegativeFloat = 0.01
    #: A slide ends with a touch once the placed contact point is within this of the target in the tangent
    #: plane, or has moved this much further from it than its closest, metres.
    slide_arrive_m: PositiveFloat = 0.001
    #: A slide also ends once the fingertip has moved twice its start's distance from the target plus this,
    #: metres, or after as long as that takes at v0.
    slide_slack_m: NonNegativeFloat = 0.01
    #: The normal a slide steers by: the new contact's with this weight, the slide's earlier ones with the
    #: rest (n <- normalise((1 - w) n + w n_new)). 1 (default): the latest normal. With noisy normals a
    #: tilt of theta moves the placed contact point by tip_radius_m theta (0.7 mm at 5 deg) and ends
    #: slides as "passed"; 0.3 averages the noise down (docs/exploration.md, "Under contact noise").
    slide_normal_weight: Annotated[float, Range(gt=0.0, le=1.0)] = 1.0


def retract_direction(v_n: ArrayLike, normal: ArrayLike, min_cos: float) -> FloatArray:
    """The v_n of the next Eq. 15 curve (not in the paper): the approach direction v_n (3,) when it
    points into the surface, v_n . (-normal) >= min_cos, else -normal (3,, the outward contact
    normal), so that the curve lifts the fingertip off the surface first."""
    v = np.asarray(v_n, dtype=np.float64)
    m = np.asarray(normal, dtype=np.float64)
    n = float(np.linalg.norm(m))
    if not n > 1e-12:  # no usable normal (also NaN): keep Eq. 15
        return v
    inward = -m / n
    return v if float(v @ inward) >= min_cos else inward


def _distance(a: FloatArray, b: FloatArray) -> float:
    d = a - b
    return math.sqrt(float(d @ d))


#: A fingertip in contact that stays within this distance of a point for rearm_push_s is held in place,
#: metres: a fifth of the way it moves at v0 = 5 cm/s in 0.1 s. Wedged in a gap it jumps between the
#: two surfaces that hold it, by 0.13-0.26 mm a tick (measured on the YCB large clamp).
HELD_M = 1e-3
#: A fingertip driven at v0 that touches nothing and stays within HELD_M this long is blocked, seconds:
#: at the default v0 of 5 cm/s it would have moved 25 cm.
BLOCKED_S = 5.0
#: Steps further apart than this (seconds of their stamps), or stamped earlier than the one before, start
#: the blocked watch again: no pose came between them (a real-time driver that paused, a clock set
#: forward), so nothing says the fingertip was held.
WATCH_GAP_S = 0.5


class TouchArming:
    """Whether a contact may count as a new touch (Alg. 1 line 6 with re-arming rules not in the paper).

    Armed at first. A new target disarms it: the next curve starts at the contact the fingertip is in.
    It re-arms when a tick has no contact (the fingertip left the surface) or, after the first touch,
    while the fingertip stays in contact: when both the fingertip and the strongest contact point are
    more than ``rearm_distance_m`` from where they were at the last touch, or when the strongest contact
    has pushed (force > 0) without interruption for ``rearm_push_s``, or the fingertip has been held
    in place (within HELD_M) that long (see TouchConfig).
    """

    def __init__(self, config: TouchConfig) -> None:
        self.config = config
        self.armed = True
        self.push_since_ns: int | None = None  # stamp since which the fingertip pushes without a touch
        self.held: tuple[int, FloatArray] | None = None  # since when, and where, it has not moved
        self.last_contact = np.zeros(3)  # position of the last touch (3,), metres
        self.last_fingertip = np.zeros(3)  # fingertip position at the last touch (3,), metres
        self.touches = 0

    def disarm(self) -> None:
        """A new target: the contact the fingertip is in is the last touch, not a new one."""
        self.armed = False
        self.held = None

    def update(self, stamp_ns: int, fingertip_m: FloatArray, positions_m: FloatArray, forces_n: FloatArray) -> bool:
        """Fold in one tick: the fingertip position (3,) m and its contacts (positions (n, 3) m, normal
        forces (n,) N); returns whether armed."""
        cfg = self.config
        if len(forces_n) == 0:
            self.armed = True
        elif not self.armed and self.touches > 0:
            strongest = int(np.argmax(forces_n))
            slid = min(
                _distance(fingertip_m, self.last_fingertip), _distance(positions_m[strongest], self.last_contact)
            )
            if cfg.rearm_distance_m > 0.0 and slid > cfg.rearm_distance_m:
                self.armed = True
            if forces_n[strongest] > 0.0:
                self.push_since_ns = stamp_ns if self.push_since_ns is None else self.push_since_ns
                if cfg.rearm_push_s > 0.0 and stamp_ns - self.push_since_ns >= cfg.rearm_push_s * 1e9:
                    self.armed = True
            else:
                self.push_since_ns = None
            if self.held is None or _distance(fingertip_m, self.held[1]) > HELD_M:
                self.held = (stamp_ns, np.array(fingertip_m))
            elif cfg.rearm_push_s > 0.0 and stamp_ns - self.held[0] >= cfg.rearm_push_s * 1e9:
                self.armed = True
        if self.armed:
            self.push_since_ns = None
            self.held = None
        return self.armed

    def touched(self, position_m: FloatArray, fingertip_m: FloatArray) -> None:
        """A touch at position_m (3,) m was announced, made with the fingertip at fingertip_m (3,) m."""
        self.last_contact = np.array(position_m)
        self.last_fingertip = np.array(fingertip_m)
        self.touches += 1


@dataclass(frozen=True)
class Touch:
    """A new touch, the contact that joins the set C (the fields of a TouchEvent).

    index: 0, 1, ... in order; position_m, normal: the strongest contact's point (3,) m and measured
    normal (3,); approach_direction: the v_n (3,) the next curve retracts along (see retract_direction);
    predicted_contact_m: where the target's estimate put the touch (3,), NaN before the first target;
    missed: a recovery curve ran since the last touch; travelled_m, rotation_deg: odometry so far.
    """

    index: int
    position_m: FloatArray
    normal: FloatArray
    approach_direction: FloatArray
    predicted_contact_m: FloatArray
    missed: bool
    travelled_m: float
    rotation_deg: float


@dataclass(frozen=True)
class ControlStep:
    """One control step: velocity command (linear (3,) m/s, angular (3,) rad/s, world frame), the touch
    made in this step if any, and whether the controller has failed (no surface where one was expected)."""

    linear_m_s: FloatArray
    angular_rad_s: FloatArray
    touch: Touch | None
    failed: bool


#: Closest the fingertip may start to the initial target and still have an approach direction, metres.
MIN_APPROACH_M = 1e-9

#: Without an initial target the first approach runs along the fingertip's poking axis (its local z)
#: for this far before it counts as finding no surface, metres.
AXIS_APPROACH_M = 0.5
#: A touch target farther than this from the fingertip is refused (metres): twice the largest object
#: palpate takes (the sim's MAX_EXTENT_M), an approach of 80 s at 5 cm/s.
MAX_TARGET_DISTANCE_M = 4.0


def tick_step_problem(v0_m_s: float, tick_s: float, tip_radius_m: float) -> str:
    """Why the fingertip cannot be controlled at this speed and tick ('' when it can): the controller
    sees a contact only at the next tick, so a tick's travel at v0 beyond the fingertip's radius can
    carry it into, or through, the surface before it reacts."""
    step_m = v0_m_s * tick_s
    if tip_radius_m <= 0.0 or step_m <= tip_radius_m:
        return ""
    return (
        f"controller: at v0 = {v0_m_s:g} m/s a tick of {tick_s:g} s moves the fingertip {step_m * 1e3:.4g} mm, "
        f"more than its {tip_radius_m * 1e3:g} mm radius, so it can pass through a surface before it sees the "
        f"contact; lower the controller's controller.v0_m_s or the sim's tick_period_s (v0 x tick at most "
        f"{tip_radius_m * 1e3:g} mm)"
    )


#: A slide that loses the surface finishes along the Eq. 15 curve to its target when the fingertip is
#: at least this far from its place there, metres (the planner's min_hop_m); nearer, the curve is too
#: short for the controller to follow (it looks ahead less than one control step), and the fingertip
#: goes straight back to the last point it touched.
MIN_SLIDE_CURVE_M = 0.006

#: A slide turns the fingertip towards the target's normal over the time left to get there, and no
#: faster than over this long, seconds (two control steps at 100 Hz).
MIN_SLIDE_TURN_S = 0.02


@dataclass
class Slide:
    """A slide in progress (TouchTarget.slide). target_m, normal: t_p (3,) m and t_n (3,); centre_m: the
    fingertip centre at the target; touched_m, fingertip_m, touched_normal: the strongest contact point,
    the fingertip centre and the contact normal of the last tick in contact (where the fingertip goes
    back to if it loses the surface); budget_m: how far the fingertip may move before the slide ends
    wherever it is (at v0 that also bounds its time, for a fingertip held in place); closest_m: the
    least distance from the contact point to the target in the contact's tangent plane so far;
    miss_distance_m: the target's Delta_m (0: the controller's own), for the curve or the straight move
    that follows where the fingertip loses the surface. The odometer reading and the stamp at which it
    ends are set at its first tick."""

    target_m: FloatArray
    normal: FloatArray
    centre_m: FloatArray
    touched_m: FloatArray
    fingertip_m: FloatArray
    touched_normal: FloatArray
    budget_m: float
    miss_distance_m: float = 0.0
    closest_m: float = math.inf
    end_travel_m: float = math.inf
    deadline_ns: int | None = None
    smoothed_normal: FloatArray | None = None


class TouchLoop:
    """Algorithm 1's controller side: approach the initial target (without one: move along the
    fingertip's poking axis, ``AXIS_APPROACH_M`` at most), follow the curve to each target (or slide to
    it along the surface, when the target says so), stop on a new touch and announce it. Feed it the
    fingertip pose and contacts once per tick."""

    def __init__(
        self, config: TouchConfig, controller_config: ControllerConfig, initial_target_m: ArrayLike | None = None
    ) -> None:
        self.config = config
        self.controller = TrajectoryController(controller_config)
        self.arming = TouchArming(config)
        # Alg. 1 line 2: a point inside the object; None: along the fingertip's poking axis from its start
        self.initial_target_m = None if initial_target_m is None else np.array(initial_target_m, dtype=np.float64)
        self.started = False
        self.missed_before = 0  # recoveries counted at the last touch
        self.retract_from = np.zeros(3)  # v_n of the next curve (Eq. 15), set at each touch
        self.predicted = np.full(3, np.nan)  # predicted contact of the current target
        self.slide: Slide | None = None  # the slide in progress
        self.in_contact = False  # the last tick had a contact
        self.last_normal = np.zeros(3)  # measured normal of the last touch
        self.slides = 0  # slides started
        self.still: tuple[int, FloatArray] | None = None  # since when, and where, it has not moved while driven
        self.watched_ns: int | None = None  # the stamp of the last step the blocked watch saw
        self.blocked = ""  # why the fingertip counts as blocked (the run then fails)

    @property
    def touches(self) -> int:
        """Touches announced so far."""
        return self.arming.touches

    @property
    def travelled_m(self) -> float:
        return self.controller.travelled_m

    @property
    def rotation_deg(self) -> float:
        return self.controller.rotation_deg

    def aim(
        self,
        r: ArrayLike,
        R: ArrayLike,
        target_m: ArrayLike,
        normal: ArrayLike,
        predicted_contact_m: ArrayLike,
        slide: bool = False,
        miss_distance_m: float = 0.0,
    ) -> FloatArray:
        """A new touch target (Alg. 1 lines 19-20): start its Eq. 15 curve from the fingertip at r (3,) m,
        orientation R (3, 3), to the target point t_p (3,) m with outward unit normal t_n (3,); the curve
        guides the fingertip centre to t_p + radius t_n. Returns the control points (4, 3).

        ``slide`` (not in the paper): while the fingertip is still in contact, slide along the surface
        to the target instead (the returned control points are then the straight line from r to the
        fingertip centre at the target, for display). A target beyond the sanity bounds of
        palpate.inputs or a normal that is not unit is an InputError naming the TouchTarget field; the
        loop then keeps its state."""
        target = coordinates(target_m, "position_m")
        normal = unit_vectors(normal, "normal")
        predicted = coordinates(predicted_contact_m, "predicted_contact_m")
        away = float(np.linalg.norm(target - np.asarray(r, dtype=np.float64)))
        if not away <= MAX_TARGET_DISTANCE_M:
            raise InputError(
                "position_m",
                f"lies {away:.6g} m from the fingertip, beyond the {MAX_TARGET_DISTANCE_M:g} m a touch may reach "
                "(twice the largest object palpate takes; at 1 km an approach ran for hours)",
            )
        miss = float(miss_distance_m)
        if not (math.isfinite(miss) and 0.0 <= miss <= MAX_MISS_DISTANCE_M):
            raise InputError(
                "miss_distance_m", f"is {miss!r}; give 0 (the controller's own) up to {MAX_MISS_DISTANCE_M} m"
            )
        centre_at_target = target + self.config.tip_radius_m * normal
        if slide and self.in_contact and self.controller.state is ControllerState.IDLE:
            start = np.array(coordinates(r, "r"))
            budget = 2.0 * float(np.linalg.norm(centre_at_target - start)) + self.config.slide_slack_m
            touched = (self.arming.last_contact.copy(), start.copy(), self.last_normal.copy())
            self.slide = Slide(np.array(target), np.array(normal), centre_at_target, *touched, budget, miss)
            self.slides += 1
            P = start + np.outer(np.arange(4) / 3.0, centre_at_target - start)
        else:
            P = self.controller.start(r, self.retract_from, R, centre_at_target, normal, miss_distance_m=miss)
            self.slide = None
        self.predicted = np.array(predicted)
        self.arming.disarm()
        return P

    def step(
        self,
        stamp_ns: int,
        r: FloatArray,
        R: FloatArray,
        positions_m: FloatArray,
        normals: FloatArray,
        forces_n: FloatArray,
    ) -> ControlStep:
        """One tick: fingertip position r (3,) m and orientation R (3, 3); this tick's contacts: positions
        (n, 3) m, measured normals (n, 3) and normal forces (n,) N (n = 0: no contact)."""
        if not self.started:
            # a fingertip reported at the initial target, or, without one, at the origin itself (an
            # uninitialised driver's zero pose) gives no approach to trust: wait for the next pose
            if self.initial_target_m is None:
                target, waiting = r + AXIS_APPROACH_M * R[:, 2], not r.any()
            else:
                target = self.initial_target_m
                waiting = float(np.linalg.norm(target - r)) < MIN_APPROACH_M
            if waiting:
                return ControlStep(np.zeros(3), np.zeros(3), None, failed=False)
            self.controller.initial_approach(r, target)
            self.started = True
        armed = self.arming.update(stamp_ns, r, positions_m, forces_n)
        self.in_contact = len(forces_n) > 0
        if self.slide is not None:
            return self._slide_step(stamp_ns, r, R, positions_m, normals, forces_n)
        touch = None
        if self.controller.moving and len(forces_n) > 0 and armed:
            touch = self._touch(r, R, positions_m, normals, forces_n)  # Alg. 1 lines 6-10: stop until the next target
            linear, angular = np.zeros(3), np.zeros(3)
        else:
            linear, angular = self.controller.command(r, R)
            self._watch_motion(stamp_ns, r, linear, len(forces_n) > 0)
        failed = self.controller.state is ControllerState.FAILED or bool(self.blocked)
        return ControlStep(linear, angular, touch, failed=failed)

    def _watch_motion(self, stamp_ns: int, r: FloatArray, linear: FloatArray, contact: bool) -> None:
        """Call the fingertip blocked (``blocked``) when, driven at v0 and touching nothing, it has stayed
        within HELD_M of one point for BLOCKED_S, over steps at most WATCH_GAP_S apart: something holds it
        that its contacts do not report (a sensor that fails, or contacts every one of which was refused)."""
        v0 = self.controller.config.v0_m_s
        before, self.watched_ns = self.watched_ns, stamp_ns
        gap = before is None or not 0 <= stamp_ns - before <= WATCH_GAP_S * 1e9
        if contact or not self.controller.moving or float(np.linalg.norm(linear)) < 0.5 * v0:
            self.still = None
        elif gap or self.still is None or _distance(r, self.still[1]) > HELD_M:
            self.still = (stamp_ns, np.array(r))
        elif stamp_ns - self.still[0] >= BLOCKED_S * 1e9 and not self.blocked:
            self.blocked = (
                f"controller: the fingertip has not moved for {BLOCKED_S:g} s while driven at {v0:g} m/s and touching "
                "nothing: something holds it that its contacts do not report (a sensor that fails, or contacts that "
                "were refused: see above)"
            )

    def _slide_step(
        self,
        stamp_ns: int,
        r: FloatArray,
        R: FloatArray,
        positions_m: FloatArray,
        normals: FloatArray,
        forces_n: FloatArray,
    ) -> ControlStep:
        """One tick of a slide: steer the strongest contact towards the target along the surface,
        pressing lightly; a touch where it ends (see TouchConfig.slide_press_m_s)."""
        slide = self.slide
        assert slide is not None
        cfg = self.config
        v0 = self.controller.config.v0_m_s
        if slide.deadline_ns is None:
            slide.end_travel_m = self.controller.travelled_m + slide.budget_m
            slide.deadline_ns = stamp_ns + int(1e9 * slide.budget_m / v0)
        if not len(forces_n):
            return self._leave_slide(slide, r, R)
        strongest = int(np.argmax(forces_n))
        normal = normals[strongest]
        if cfg.slide_normal_weight < 1.0 and slide.smoothed_normal is not None:
            mixed = (1.0 - cfg.slide_normal_weight) * slide.smoothed_normal + cfg.slide_normal_weight * normal
            length = float(np.linalg.norm(mixed))
            normal = mixed / length if length > 1e-6 else normal  # opposed normals: take the new one
        slide.touched_m = np.array(positions_m[strongest])
        slide.fingertip_m = np.array(r)
        slide.touched_normal = slide.smoothed_normal = np.array(normal)
        # the contact point as the fingertip's pose and the contact normal place it (the reported point
        # is as good without noise, and with noise would end a slide at its first ticks)
        to_target = slide.target_m - (r - cfg.tip_radius_m * normal)
        along = to_target - float(to_target @ normal) * normal  # the way there in the tangent plane
        distance = float(np.linalg.norm(along))
        ended = (
            distance <= cfg.slide_arrive_m
            or distance > slide.closest_m + cfg.slide_arrive_m  # passed it
            or self.controller.travelled_m >= slide.end_travel_m
            or stamp_ns >= slide.deadline_ns  # held in place (against a wall)
        )
        if ended:
            self.slide = None
            return ControlStep(np.zeros(3), np.zeros(3), self._touch(r, R, positions_m, normals, forces_n), False)
        slide.closest_m = min(slide.closest_m, distance)
        self.controller.observe(r, R)
        direction = along / distance
        self.controller.steer(direction)
        linear = v0 * direction - cfg.slide_press_m_s * normal
        # turn to face the target's normal by the time the fingertip gets there, as a curve does
        turn = R @ rotations.log_so3(R.T @ rotations.get_rotation(R, slide.normal))
        angular = turn / max(distance / v0, MIN_SLIDE_TURN_S)
        return ControlStep(linear, angular, None, failed=False)

    def _leave_slide(self, slide: Slide, r: FloatArray, R: FloatArray) -> ControlStep:
        """The surface fell away under a slide (an edge): the Eq. 15 curve to the target from here, leaving
        along the last contact's normal, its recovery aimed at the fingertip's last place in contact; or,
        nearer the target than MIN_SLIDE_CURVE_M, straight back to the last point touched."""
        self.slide = None
        if float(np.linalg.norm(slide.centre_m - r)) >= MIN_SLIDE_CURVE_M:
            self.controller.start(
                r, -slide.touched_normal, R, slide.centre_m, slide.normal, slide.fingertip_m, slide.miss_distance_m
            )
        else:
            self.controller.go_straight(r, slide.touched_m, slide.miss_distance_m)
        linear, angular = self.controller.command(r, R)
        return ControlStep(linear, angular, None, failed=self.controller.state is ControllerState.FAILED)

    def _touch(
        self, r: FloatArray, R: FloatArray, positions_m: FloatArray, normals: FloatArray, forces_n: FloatArray
    ) -> Touch:
        strongest = int(np.argmax(forces_n))
        normal = np.array(normals[strongest])
        self.last_normal = normal
        direction = retract_direction(self.controller.direction, normal, self.config.retract_min_cos)
        self.retract_from = direction
        self.controller.on_contact(r, R)
        position = np.array(positions_m[strongest])
        missed = self.controller.recoveries > self.missed_before
        self.missed_before = self.controller.recoveries
        touch = Touch(
            index=self.arming.touches,
            position_m=position,
            normal=normal,
            approach_direction=direction,
            predicted_contact_m=self.predicted,
            missed=missed,
            travelled_m=self.controller.travelled_m,
            rotation_deg=self.controller.rotation_deg,
        )
        self.arming.touched(position, r)
        return touch
