"""Cartesian velocity controller that follows Bezier trajectories (paper 002, Algorithm 1 lines 1-4, 19-41).

``TrajectoryController`` is a pure state machine driven by whoever owns the clock (the simulation or
the node): call ``initial_approach`` or ``start``, then ``command(r, R)`` once per control step with
the measured fingertip pose, apply the returned velocities, and call ``on_contact()`` when the
fingertip touches. It never sleeps and keeps no time; it only needs the poses it is given.

Frames and units: positions in metres (world frame), linear velocity in m/s and angular velocity in
rad/s, both in the world frame. The fingertip's local z axis ``R[:, 2]`` is the direction it pokes; it
faces a surface with outward normal n when ``R[:, 2] = -n`` (see ``palpate.geometry.rotations.get_rotation``).

States: IDLE (stopped, zero command) -> DIRECT (initial straight approach, Alg. 1 lines 1-4) or
APPROACH (Eq. 15 curve to the target) -> RECOVERY (Eq. 17 curve back to the last contact after a
missed prediction, Alg. 1 lines 26-34) -> DIRECT again, straight back to the last contact, when the
recovery misses too (not in the paper, ``return_after_recovery``) -> IDLE on contact, or FAILED (zero
command) when a direct motion runs out without a contact.

``TouchLoop`` is the controller node's whole decision: it feeds the measured pose and contacts to a
``TrajectoryController``, decides with ``TouchArming`` when a contact is a new touch (Alg. 1 lines
6-10, with re-arming rules not in the paper) and returns the velocity command and the touch, if any.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.config import NonNegativeFloat, PositiveFloat, Range, Validated
from palpate.errors import InputError, PlanningError
from palpate.geometry import rotations
from palpate.geometry.bezier import Cubic, approach_curve, recovery_curve
from palpate.geometry.rotations import dot3
from palpate.inputs import coordinates, unit_vectors
from palpate.messages.schemas import MAX_MISS_DISTANCE_M

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
    slide_arrive_m: PositiveFloat = 0.001
    slide_slack_m: NonNegativeFloat = 0.01
    #: The normal a slide steers by: the new contact's with this weight, the slide's earlier ones with the
    #: rest (n <- normalise((1 - w) n + w n_new)). 1 (default): the latest normal. With noisy normals a
    #: tilt of theta moves the placed contact point by tip_radius_m theta (0.7 mm at 5 deg) and ends
    #: slides as "passed"; 0.3 averages the noise down (docs/exploration.md, "Under contact noise").
    slide_normal_weight: Annotated[float, Range(gt=0.0, le=1.0)] = 1.0


@dataclass(frozen=True, kw_only=True)
class ControllerConfig(Validated):
    """Parameters of the trajectory controller. The paper gives no values for v0 or Delta_m."""

    #: v0, desired fingertip speed (Table 1). Paper silent; 5 cm/s is a gentle tactile approach speed.
    v0_m_s: PositiveFloat = 0.05
    #: Delta_m, how far past the end of the curve (from T(1)) the fingertip may get without a contact
    #: before the prediction counts as missed (Alg. 1 line 26). Paper silent; 1 cm is about twice the
    #: IGEF prediction miss the paper reports (5 mm), so ordinary prediction errors still end in a
    #: contact and only real misses (an edge) start the recovery curve.
    miss_distance_m: PositiveFloat = 0.01
    #: Proportional gain on the orientation error R^-1 T_R(tau) (Alg. 1 line 38), 1/s.
    angular_gain_1_s: NonNegativeFloat = 5.0
    #: Add the slerp's own rate (axis * angle * dtau/dt) to the angular velocity, so the fingertip
    #: faces the target normal at tau = 1 instead of lagging behind by rate / gain. Not in the paper.
    orientation_feedforward: bool = True
    #: Delta tau, the look-ahead on the curve parameter for the velocity direction (Alg. 1 line 35).
    d_tau: PositiveFloat = 0.02
    #: Not in the paper: look ahead on the curve at least as far as the fingertip moved in the last
    #: control step (Delta tau grows to that length / |T'(tau)|, at most MAX_LOOKAHEAD_TAU). On a short
    #: curve Delta tau alone looks ahead less than one step (0.02 of a 5 mm curve is 0.1 mm; a step is
    #: 0.5 mm at 5 cm/s and 100 Hz): the fingertip overshoots the look-ahead point every tick and
    #: zigzags about the curve (measured: 1.15 cm of travel along a 0.6 cm curve, arriving 70 degrees
    #: off the target's normal). With it the fingertip lands on the look-ahead point every step.
    #: False keeps Alg. 1's Delta tau alone.
    lookahead_one_step: bool = True
    #: Floor on |c_p - t_p| for the control-point scaling beta, metres (a target at the start point).
    min_chord_m: PositiveFloat = 1e-4
    #: Samples of the closest-point search on [tau, tau_max] before Newton refinement.
    closest_samples: Annotated[int, Range(ge=3)] = 33
    #: Not in the paper: when the recovery curve (Eq. 17) misses too, go straight back to the last
    #: contact (the fingertip centre where it touched, so the line ends in a contact) instead of
    #: failing. The recovery arrives at the last contact along the missed target's normal, and where
    #: that contact lies on a rim it can pass it by: GP-V on YCB cups stopped there in 4 of 90 runs
    #: (controller state FAILED, "the fingertip found no surface"). Algorithm 1 would start another
    #: recovery curve; False fails instead (the controller's first behaviour).
    return_after_recovery: bool = True


#: The look-ahead of ``lookahead_one_step`` reaches at most this far on the curve parameter: its
#: first-order length estimate fails where |T'| is small, at a sharp turn (the doubling of Delta tau
#: then takes over), and on a curve shorter than about four control steps (2 mm) it then looks ahead
#: less than one step.
MAX_LOOKAHEAD_TAU = 0.25


class ControllerState(enum.Enum):
    """What the controller is doing."""

    IDLE = "idle"
    DIRECT = "direct"
    APPROACH = "approach"
    RECOVERY = "recovery"
    FAILED = "failed"


def _vector(name: str, value: ArrayLike) -> FloatArray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not all(map(math.isfinite, v.tolist())):
        raise PlanningError(f"{name} must be a finite 3-vector, got {value!r}")
    return v


def _miss(value: float, config: ControllerConfig) -> float:
    """Delta_m for one motion: ``value`` (m), or the config's for 0."""
    if not (math.isfinite(value) and value >= 0.0):
        raise PlanningError(f"miss_distance_m must be finite and >= 0 (0: the config's), got {value!r}")
    return value if value > 0.0 else config.miss_distance_m


def _unit(name: str, value: ArrayLike, *, allow_zero: bool = False) -> FloatArray:
    v = _vector(name, value)
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        if allow_zero:
            return np.zeros(3)
        raise PlanningError(f"{name} has zero length ({value!r}); pass a unit direction")
    return v / n


def _rotation(name: str, value: ArrayLike) -> FloatArray:
    R = np.asarray(value, dtype=np.float64)
    if R.shape != (3, 3):
        raise PlanningError(f"{name} must be a 3x3 rotation matrix, got shape {R.shape}")
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()  # plain floats: this runs every control step
    # |R^T R - I|, entry by entry over the upper triangle (columns (a, d, g), (b, e, h), (c, f, i))
    gram_err = max(
        abs(a * a + d * d + g * g - 1.0),
        abs(a * b + d * e + g * h),
        abs(a * c + d * f + g * i),
        abs(b * b + e * e + h * h - 1.0),
        abs(b * c + e * f + h * i),
        abs(c * c + f * f + i * i - 1.0),
    )
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if not (gram_err <= 1e-6 and det > 0.0):  # also false for NaN
        raise PlanningError(f"{name} is not a finite rotation matrix (|R^T R - I| = {gram_err:.3g}, det = {det:.3g})")
    return R


def _minus(a: list[float], b: list[float]) -> list[float]:
    """a - b of two 3-vectors given as floats."""
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


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


class TrajectoryController:
    """Algorithm 1's Cartesian velocity controller as a pure state machine (see the module doc)."""

    def __init__(self, config: ControllerConfig | None = None) -> None:
        self.config = config or ControllerConfig()
        self._state = ControllerState.IDLE
        self._curve: Cubic | None = None  # T_p
        self._tau = 0.0
        self._tau_max = 1.0
        self._R0 = np.eye(3)
        self._w01 = np.zeros(3)  # log(R0^T R1): slerp rotation vector in the R0 frame
        self._last_contact = np.zeros(3)
        self._target_p = np.zeros(3)
        self._target_n = np.zeros(3)
        self._direction = np.zeros(3)  # unit direction of the last commanded velocity (v_n)
        self._direct_start = np.zeros(3)
        self._direct_budget_m = 0.0
        self._miss_m = self.config.miss_distance_m  # Delta_m of the motion under way
        self._recoveries = 0
        self._straight_returns = 0
        self._R0_w01 = np.zeros(3)  # R0 w01: the slerp's rotation vector in the world frame
        # Odometry: the initial approach is kept apart from the exploratory actions.
        self._prev_r: list[float] | None = None
        self._prev_R: FloatArray | None = None
        self._last_step_m = 0.0  # |r_k - r_{k-1}| of the last two poses seen (the look-ahead's floor)
        self._exploring = False
        self._travelled = {False: 0.0, True: 0.0}
        self._rotated_rad = {False: 0.0, True: 0.0}

    # --- state -----------------------------------------------------------------------------------
    @property
    def state(self) -> ControllerState:
        return self._state

    @property
    def moving(self) -> bool:
        """True while following a motion (DIRECT, APPROACH or RECOVERY): a contact then stops it."""
        return self._state in (ControllerState.DIRECT, ControllerState.APPROACH, ControllerState.RECOVERY)

    @property
    def curve(self) -> FloatArray | None:
        """Control points (4, 3) of the curve being followed, None during the direct approach."""
        return None if self._curve is None else self._curve.P.copy()

    @property
    def tau(self) -> float:
        """Progress on the current curve (may exceed 1 on the straight continuation)."""
        return self._tau

    @property
    def direction(self) -> FloatArray:
        """Unit direction of the last commanded velocity (v_n of Alg. 1 line 9); zeros before any."""
        return self._direction.copy()

    @property
    def target(self) -> tuple[FloatArray, FloatArray]:
        """(t_p, t_n) of the current trajectory."""
        return self._target_p.copy(), self._target_n.copy()

    @property
    def recoveries(self) -> int:
        """Number of missed predictions (recovery curves started) since the controller was built."""
        return self._recoveries

    @property
    def straight_returns(self) -> int:
        """Number of straight returns to the last contact started (each after a missed recovery)."""
        return self._straight_returns

    # --- odometry --------------------------------------------------------------------------------
    @property
    def travelled_m(self) -> float:
        """Path length of the fingertip during exploratory actions (after the first contact), metres."""
        return self._travelled[True]

    @property
    def rotation_deg(self) -> float:
        """Accumulated rotation angle of the fingertip during exploratory actions, degrees."""
        return math.degrees(self._rotated_rad[True])

    @property
    def initial_travelled_m(self) -> float:
        """Path length of the initial direct approach (before the first contact), metres."""
        return self._travelled[False]

    @property
    def initial_rotation_deg(self) -> float:
        """Rotation during the initial direct approach, degrees."""
        return math.degrees(self._rotated_rad[False])

    def observe(self, r: ArrayLike, R: ArrayLike) -> None:
        """Accumulate travelled distance |r_k - r_{k-1}| and rotation angle(R_{k-1}^T R_k).

        ``command`` calls this; call it directly for poses seen while no command is needed.
        """
        r_ = _vector("r", r).tolist()
        R_ = _rotation("R", R)
        if self._prev_r is not None and self._prev_R is not None:
            step = _minus(r_, self._prev_r)
            self._last_step_m = math.sqrt(dot3(step, step))
            self._travelled[self._exploring] += self._last_step_m
            self._rotated_rad[self._exploring] += rotations.rotation_angle_3x3(self._prev_R.T @ R_)
        self._prev_r, self._prev_R = r_, R_

    # --- commands --------------------------------------------------------------------------------
    def initial_approach(self, start_r: ArrayLike, target_p: ArrayLike) -> None:
        """Alg. 1 lines 1-4: move straight from start_r towards target_p (a point inside the object).

        Fails (state FAILED) if the fingertip gets more than Delta_m beyond target_p without contact.
        """
        self.go_straight(start_r, target_p)  # v_n = (t_p - r)/|t_p - r|
        self._exploring = False

    def start(
        self,
        c_p: ArrayLike,
        v_n: ArrayLike,
        R0: ArrayLike,
        target_p: ArrayLike,
        target_n: ArrayLike,
        touched_m: ArrayLike | None = None,
        miss_distance_m: float = 0.0,
    ) -> FloatArray:
        """Alg. 1 lines 19-24: the Eq. 15 curve from the last contact c_p to the target.

        c_p: last contact (3,) m, also the curve start; v_n: velocity direction just before that contact
        (normalised here; zero means no retraction); R0: current orientation (3, 3); target_p, target_n:
        target position (m) and outward unit normal; touched_m: where the fingertip last touched, the
        recovery's target, when the curve does not start there (a slide that lost the surface; default
        c_p); miss_distance_m: Delta_m for this target, its recovery and return (0: the config's).
        Returns the control points (4, 3).
        """
        cfg = self.config
        self._miss_m = _miss(miss_distance_m, cfg)
        c = _vector("c_p", c_p)
        touched = c if touched_m is None else _vector("touched_m", touched_m)
        v = _unit("v_n", v_n, allow_zero=True)
        R = _rotation("R0", R0)
        t_p = _vector("target_p", target_p)
        t_n = _unit("target_n", target_n)
        self._last_contact = touched
        self._target_p, self._target_n = t_p, t_n
        self._exploring = True
        if not v.any() and float(np.linalg.norm(t_p - c)) < cfg.min_chord_m:
            v = -t_n  # no direction and nowhere to go: the loop leaves along the normal (a stalled curve otherwise)
        # Eq. 15: T_p = bezier(c_p, c_p - beta v_n, t_p + beta t_n, t_p), beta = |c_p - t_p| / 3
        self._set_curve(approach_curve(c, v, t_p, t_n, min_chord_m=cfg.min_chord_m), R, t_n)
        self._direction = v
        self._state = ControllerState.APPROACH
        assert self._curve is not None
        return self._curve.P.copy()

    def on_contact(self, r: ArrayLike | None = None, R: ArrayLike | None = None) -> None:
        """Contact detected (Alg. 1 line 40): stop; the next ``command`` returns zero velocities.

        Pass the pose at contact (r, R) so that the last step counts into the motion that made it
        (the initial approach or an exploratory action).
        """
        if r is not None and R is not None:
            self.observe(r, R)
        self._exploring = True
        self._state = ControllerState.IDLE

    def stop(self) -> None:
        """Abandon the current motion without a contact (state IDLE)."""
        self._state = ControllerState.IDLE

    def go_straight(self, start_r: ArrayLike, target_p: ArrayLike, miss_distance_m: float = 0.0) -> None:
        """Move straight from start_r towards target_p (3,) m as an exploratory action, failing once
        the fingertip is Delta_m (miss_distance_m; 0: the config's) beyond target_p without a contact
        (a slide that lost the surface goes back to the last point it touched)."""
        start = _vector("start_r", start_r)
        target = _vector("target_p", target_p)
        self._miss_m = _miss(miss_distance_m, self.config)
        self._go_straight(start, target, _unit("target_p - start_r", target - start))

    def steer(self, direction: FloatArray) -> None:
        """Record the unit direction of a velocity commanded outside the curves (a slide), as v_n."""
        self._direction = np.array(direction, dtype=np.float64)

    def command(self, r: ArrayLike, R: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """One control step (Alg. 1 lines 23-39) from the measured pose.

        r: fingertip position (3,) m; R: fingertip orientation (3, 3). Returns (linear velocity (3,) m/s,
        angular velocity (3,) rad/s), world frame. Zero velocities in IDLE and FAILED.
        """
        self.observe(r, R)
        r_ = np.asarray(r, dtype=np.float64)
        R_ = np.asarray(R, dtype=np.float64)
        xyz = r_.tolist()  # the 3-vector arithmetic below runs on floats: numpy's bits, no call overhead
        cfg = self.config
        if self._state in (ControllerState.IDLE, ControllerState.FAILED):
            return np.zeros(3), np.zeros(3)
        if self._state is ControllerState.DIRECT:
            if dot3(_minus(xyz, self._direct_start.tolist()), self._direction.tolist()) > self._direct_budget_m:
                self._state = ControllerState.FAILED
                return np.zeros(3), np.zeros(3)
            return cfg.v0_m_s * self._direction, np.zeros(3)  # Alg. 1 line 4: setVelocity(v_n v0)

        assert self._curve is not None
        # Alg. 1 line 25: tau <- argmin_{tau* in [tau, 1]} |r - T(tau*)| (searched past 1 to detect misses)
        self._tau = self._curve.closest_tau(r_, self._tau, self._tau_max, samples=cfg.closest_samples)
        if self._tau >= 1.0:
            off = _minus(xyz, self._curve.end.tolist())
            if math.sqrt(dot3(off, off)) > self._miss_m:  # line 26
                if self._state is ControllerState.RECOVERY:
                    if not cfg.return_after_recovery or not self._start_return(r_):
                        self._state = ControllerState.FAILED
                        return np.zeros(3), np.zeros(3)
                    return cfg.v0_m_s * self._direction, np.zeros(3)
                self._start_recovery(r_, R_)

        curve = self._curve
        # Alg. 1 lines 35-37: v* = T_p(tau + dtau) - r, v = v0 v*/|v*|
        d_tau = cfg.d_tau
        if cfg.lookahead_one_step:  # at least the last step's length along the curve, to first order
            velocity = curve.derivative_xyz(self._tau)
            speed = math.sqrt(dot3(velocity, velocity))  # |T'(tau)|, metres per unit of tau
            if speed > 0.0:
                d_tau = max(d_tau, min(MAX_LOOKAHEAD_TAU, self._last_step_m / speed))
        v_star = _minus(curve.point_xyz(self._tau + d_tau), xyz)
        # Not in the paper: where the curve bends sharply (|T'| small at the retract-then-approach turn)
        # T(tau + dtau) can lie closer than one control step; the fingertip then overshoots it, v*
        # points backwards along the curve, and tau stops advancing (a measured limit cycle at 10 ms
        # ticks). Look further ahead (dtau doubled, at most 10 times) until v* points forwards,
        # v* . T'(tau + dtau) > 0. Never triggers while the fingertip stays behind the look-ahead point.
        for _ in range(10):
            if dot3(v_star, curve.derivative_xyz(self._tau + d_tau)) > 0.0:
                break
            d_tau *= 2.0
            v_star = _minus(curve.point_xyz(self._tau + d_tau), xyz)
        tangent = curve.derivative_xyz(min(self._tau, 1.0))
        norm = math.sqrt(dot3(v_star, v_star))
        if norm < 1e-12:
            v_star, norm = tangent, math.sqrt(dot3(tangent, tangent))
        self._direction = np.array([v / norm for v in v_star])
        linear = cfg.v0_m_s * self._direction

        # Alg. 1 lines 38-39: omega from the orientation error R^-1 T_R(tau) (as a rotation vector)
        tau_r = min(self._tau, 1.0)
        R_target = self._R0 @ rotations.exp_so3(tau_r * self._w01)
        angular = cfg.angular_gain_1_s * (R_ @ rotations.log_so3(R_.T @ R_target))
        if cfg.orientation_feedforward and self._tau < 1.0:
            speed = math.sqrt(dot3(tangent, tangent))
            if speed > 1e-12:
                angular = angular + self._R0_w01 * (cfg.v0_m_s / speed)  # d/dt T_R
        return linear, angular

    # --- internals -------------------------------------------------------------------------------
    def _set_curve(self, P: FloatArray, R0: FloatArray, face_n: FloatArray) -> None:
        """Install curve P and the orientation slerp from R0 to getRotation(R0, face_n)."""
        cfg = self.config
        self._curve = Cubic(P)
        self._tau = 0.0
        end_speed = float(np.linalg.norm(self._curve.end_tangent))  # |T'(1)|
        # Search far enough past T(1) that passing it by Delta_m is seen (tau > 1 branch of line 26).
        self._tau_max = 1.0 + cfg.d_tau + 2.0 * self._miss_m / max(end_speed, 1e-12)
        R1 = rotations.get_rotation(R0, face_n)  # Alg. 1 line 20: R1 <- getRotation(R0, t_n)
        self._R0 = R0
        self._w01 = rotations.log_so3(R0.T @ R1)  # T_R(tau) = R0 exp(tau w01)
        self._R0_w01 = R0 @ self._w01

    def _start_recovery(self, r: FloatArray, R: FloatArray) -> None:
        """Alg. 1 lines 27-34 with the text's target: the last contact (always on the surface)."""
        v_n = self._direction  # line 27: current normalised velocity
        t_p, t_n = self._last_contact, self._target_n
        self._target_p = t_p
        # Eq. 17: T_p = bezier(r, r + beta v_n, t_p - beta t_n, t_p)
        P = recovery_curve(r, v_n, t_p, t_n, min_chord_m=self.config.min_chord_m)
        self._set_curve(P, R, -t_n)  # line 32: R1 <- getRotation(R0, -t_n), inverted approach
        self._recoveries += 1
        self._state = ControllerState.RECOVERY

    def _start_return(self, r: FloatArray) -> bool:
        """After a missed recovery: straight from r to the last contact, at most Delta_m beyond it (the
        direct approach of Alg. 1 lines 1-4, counted as exploratory travel). False if r is there (not
        reached in practice: a missed recovery leaves the fingertip Delta_m past the last contact)."""
        to_contact = self._last_contact - r
        distance = float(np.linalg.norm(to_contact))
        if distance < self.config.min_chord_m:
            return False
        self._go_straight(r.copy(), self._last_contact.copy(), to_contact / distance)
        self._straight_returns += 1
        return True

    def _go_straight(self, start: FloatArray, target: FloatArray, direction: FloatArray) -> None:
        """State DIRECT: along the unit ``direction`` from start to target (3,), failing once the
        fingertip is more than Delta_m beyond target without a contact."""
        self._direction = direction
        self._direct_start = start
        self._direct_budget_m = float(np.linalg.norm(target - start)) + self._miss_m
        self._target_p, self._target_n = target, -direction
        self._curve = None
        self._state = ControllerState.DIRECT


def _distance(a: FloatArray, b: FloatArray) -> float:
    d = a - b
    return math.sqrt(float(d @ d))


#: A fingertip in contact that stays within this distance of a point for rearm_push_s is held in place,
#: metres: a fifth of the way it moves at v0 = 5 cm/s in 0.1 s. Wedged in a gap it jumps between the
#: two surfaces that hold it, by 0.13-0.26 mm a tick (measured on the YCB large clamp).
HELD_M = 1e-3


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
        self, config: TouchConfig, controller: ControllerConfig, initial_target_m: ArrayLike | None = None
    ) -> None:
        self.config = config
        self.controller = TrajectoryController(controller)
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
        return ControlStep(linear, angular, touch, failed=self.controller.state is ControllerState.FAILED)

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
