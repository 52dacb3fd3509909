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
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.config import NonNegativeFloat, PositiveFloat, Range, Validated
from palpate.errors import PlanningError
from palpate.geometry import rotations
from palpate.geometry.bezier import Cubic, approach_curve, recovery_curve
from palpate.geometry.rotations import dot3

FloatArray = NDArray[np.float64]


#: Fastest turn a command asks for, rad/s. The feedforward rate grows as one over the curve's length:
#: a curve of a few micrometres (a target at the last contact) asked for 3,500 rad/s, which the
#: simulator refuses (1000), and the fingertip stood still. Normal runs turn at most about 11 rad/s,
#: a slide at most pi / MIN_SLIDE_TURN_S = 157 rad/s.
MAX_ANGULAR_RAD_S = 200.0


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
    #: recovery curve; False ends the motion there (state FAILED).
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
        rate = math.sqrt(float(angular @ angular))  # per tick: numpy's norm costs four times as much
        if rate > MAX_ANGULAR_RAD_S:  # a curve of a few micrometres turning the fingertip round
            angular = angular * (MAX_ANGULAR_RAD_S / rate)
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
