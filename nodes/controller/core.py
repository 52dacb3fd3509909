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
missed prediction, Alg. 1 lines 26-34) -> IDLE on contact, or FAILED (zero command) when even the
recovery curve or the direct approach runs out without a contact.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.errors import ConfigError, PlanningError
from palpate.geometry import rotations
from palpate.geometry.bezier import Cubic, approach_curve, recovery_curve

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
class ControllerConfig:
    """Parameters of the trajectory controller. The paper gives no values for v0 or Delta_m."""

    #: v0, desired fingertip speed (Table 1). Paper silent; 5 cm/s is a gentle tactile approach speed.
    v0_m_s: float = 0.05
    #: Delta_m, how far past the end of the curve (from T(1)) the fingertip may get without a contact
    #: before the prediction counts as missed (Alg. 1 line 26). Paper silent; 1 cm is about twice the
    #: IGEF prediction miss the paper reports (5 mm), so ordinary prediction errors still end in a
    #: contact and only real misses (an edge) start the recovery curve.
    miss_distance_m: float = 0.01
    #: Proportional gain on the orientation error R^-1 T_R(tau) (Alg. 1 line 38), 1/s.
    angular_gain_1_s: float = 5.0
    #: Add the slerp's own rate (axis * angle * dtau/dt) to the angular velocity, so the fingertip
    #: faces the target normal at tau = 1 instead of lagging behind by rate / gain. Not in the paper.
    orientation_feedforward: bool = True
    #: Delta tau, the look-ahead on the curve parameter for the velocity direction (Alg. 1 line 35).
    d_tau: float = 0.02
    #: Floor on |c_p - t_p| for the control-point scaling beta, metres (a target at the start point).
    min_chord_m: float = 1e-4
    #: Samples of the closest-point search on [tau, tau_max] before Newton refinement.
    closest_samples: int = 33

    def __post_init__(self) -> None:
        positive = {
            "v0_m_s": self.v0_m_s,
            "miss_distance_m": self.miss_distance_m,
            "d_tau": self.d_tau,
            "min_chord_m": self.min_chord_m,
        }
        for name, value in positive.items():
            if not (np.isfinite(value) and value > 0.0):
                raise ConfigError(f"ControllerConfig.{name} must be finite and > 0, got {value!r}")
        if not (np.isfinite(self.angular_gain_1_s) and self.angular_gain_1_s >= 0.0):
            raise ConfigError(f"ControllerConfig.angular_gain_1_s must be >= 0, got {self.angular_gain_1_s!r}")
        if self.closest_samples < 3:
            raise ConfigError(f"ControllerConfig.closest_samples must be >= 3, got {self.closest_samples!r}")


class ControllerState(enum.Enum):
    """What the controller is doing."""

    IDLE = "idle"
    DIRECT = "direct"
    APPROACH = "approach"
    RECOVERY = "recovery"
    FAILED = "failed"


def _vector(name: str, value: ArrayLike) -> FloatArray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise PlanningError(f"{name} must be a finite 3-vector, got {value!r}")
    return v


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
    cols = ((a, d, g), (b, e, h), (c, f, i))
    gram_err = max(
        abs(sum(x * y for x, y in zip(cols[j], cols[k], strict=True)) - (1.0 if j == k else 0.0))
        for j in range(3)
        for k in range(j, 3)
    )
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if not (gram_err <= 1e-6 and det > 0.0):  # also false for NaN
        raise PlanningError(f"{name} is not a finite rotation matrix (|R^T R - I| = {gram_err:.3g}, det = {det:.3g})")
    return R


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
        self._recoveries = 0
        # Odometry: the initial approach is kept apart from the exploratory actions.
        self._prev_r: FloatArray | None = None
        self._prev_R: FloatArray | None = None
        self._exploring = False
        self._travelled = {False: 0.0, True: 0.0}
        self._rotated_rad = {False: 0.0, True: 0.0}

    # --- state -----------------------------------------------------------------------------------
    @property
    def state(self) -> ControllerState:
        return self._state

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

    # --- odometry --------------------------------------------------------------------------------
    @property
    def travelled_m(self) -> float:
        """Path length of the fingertip during exploratory actions (after the first contact), metres."""
        return self._travelled[True]

    @property
    def rotation_deg(self) -> float:
        """Accumulated rotation angle of the fingertip during exploratory actions, degrees."""
        return float(np.degrees(self._rotated_rad[True]))

    @property
    def initial_travelled_m(self) -> float:
        """Path length of the initial direct approach (before the first contact), metres."""
        return self._travelled[False]

    @property
    def initial_rotation_deg(self) -> float:
        """Rotation during the initial direct approach, degrees."""
        return float(np.degrees(self._rotated_rad[False]))

    def observe(self, r: ArrayLike, R: ArrayLike) -> None:
        """Accumulate travelled distance |r_k - r_{k-1}| and rotation angle(R_{k-1}^T R_k).

        ``command`` calls this; call it directly for poses seen while no command is needed.
        """
        r_ = _vector("r", r)
        R_ = _rotation("R", R)
        if self._prev_r is not None and self._prev_R is not None:
            step = r_ - self._prev_r
            self._travelled[self._exploring] += math.sqrt(float(step @ step))
            self._rotated_rad[self._exploring] += rotations.rotation_angle_3x3(self._prev_R.T @ R_)
        self._prev_r, self._prev_R = r_, R_

    # --- commands --------------------------------------------------------------------------------
    def initial_approach(self, start_r: ArrayLike, target_p: ArrayLike) -> None:
        """Alg. 1 lines 1-4: move straight from start_r towards target_p (a point inside the object).

        Fails (state FAILED) if the fingertip gets more than Delta_m beyond target_p without contact.
        """
        start = _vector("start_r", start_r)
        target = _vector("target_p", target_p)
        self._direction = _unit("target_p - start_r", target - start)  # v_n = (t_p - r)/|t_p - r|
        self._direct_start = start
        self._direct_budget_m = float(np.linalg.norm(target - start)) + self.config.miss_distance_m
        self._target_p, self._target_n = target, -self._direction
        self._curve = None
        self._exploring = False
        self._state = ControllerState.DIRECT

    def start(
        self, c_p: ArrayLike, v_n: ArrayLike, R0: ArrayLike, target_p: ArrayLike, target_n: ArrayLike
    ) -> FloatArray:
        """Alg. 1 lines 19-24: the Eq. 15 curve from the last contact c_p to the target.

        c_p: last contact (3,) m, also the curve start; v_n: velocity direction just before that contact
        (normalised here; zero means no retraction); R0: current orientation (3, 3); target_p, target_n:
        target position (m) and outward unit normal. Returns the control points (4, 3).
        """
        cfg = self.config
        c = _vector("c_p", c_p)
        v = _unit("v_n", v_n, allow_zero=True)
        R = _rotation("R0", R0)
        t_p = _vector("target_p", target_p)
        t_n = _unit("target_n", target_n)
        self._last_contact = c
        self._target_p, self._target_n = t_p, t_n
        self._exploring = True
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

    def command(self, r: ArrayLike, R: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """One control step (Alg. 1 lines 23-39) from the measured pose.

        r: fingertip position (3,) m; R: fingertip orientation (3, 3). Returns (linear velocity (3,) m/s,
        angular velocity (3,) rad/s), world frame. Zero velocities in IDLE and FAILED.
        """
        self.observe(r, R)
        zero = (np.zeros(3), np.zeros(3))
        r_ = np.asarray(r, dtype=np.float64)
        R_ = np.asarray(R, dtype=np.float64)
        cfg = self.config
        if self._state in (ControllerState.IDLE, ControllerState.FAILED):
            return zero
        if self._state is ControllerState.DIRECT:
            if float((r_ - self._direct_start) @ self._direction) > self._direct_budget_m:
                self._state = ControllerState.FAILED
                return zero
            return cfg.v0_m_s * self._direction, np.zeros(3)  # Alg. 1 line 4: setVelocity(v_n v0)

        assert self._curve is not None
        # Alg. 1 line 25: tau <- argmin_{tau* in [tau, 1]} |r - T(tau*)| (searched past 1 to detect misses)
        self._tau = self._curve.closest_tau(r_, self._tau, self._tau_max, samples=cfg.closest_samples)
        if self._tau >= 1.0 and float(np.linalg.norm(r_ - self._curve.end)) > cfg.miss_distance_m:  # line 26
            if self._state is ControllerState.RECOVERY:
                self._state = ControllerState.FAILED
                return zero
            self._start_recovery(r_, R_)

        curve = self._curve
        # Alg. 1 lines 35-37: v* = T_p(tau + dtau) - r, v = v0 v*/|v*|
        d_tau = cfg.d_tau
        v_star = curve.point(self._tau + d_tau) - r_
        # Not in the paper: where the curve bends sharply (|T'| small at the retract-then-approach turn)
        # T(tau + dtau) can lie closer than one control step; the fingertip then overshoots it, v*
        # points backwards along the curve, and tau stops advancing (a measured limit cycle at 10 ms
        # ticks). Look further ahead (dtau doubled, at most 10 times) until v* points forwards,
        # v* . T'(tau + dtau) > 0. Never triggers while the fingertip stays behind the look-ahead point.
        for _ in range(10):
            if float(v_star @ curve.derivative(self._tau + d_tau)) > 0.0:
                break
            d_tau *= 2.0
            v_star = curve.point(self._tau + d_tau) - r_
        tangent = curve.derivative(min(self._tau, 1.0))
        norm = math.sqrt(float(v_star @ v_star))
        if norm < 1e-12:
            v_star, norm = tangent, math.sqrt(float(tangent @ tangent))
        self._direction = v_star / norm
        linear = cfg.v0_m_s * self._direction

        # Alg. 1 lines 38-39: omega from the orientation error R^-1 T_R(tau) (as a rotation vector)
        tau_r = min(self._tau, 1.0)
        R_target = self._R0 @ rotations.exp_so3(tau_r * self._w01)
        angular = cfg.angular_gain_1_s * (R_ @ rotations.log_so3(R_.T @ R_target))
        if cfg.orientation_feedforward and self._tau < 1.0:
            speed = math.sqrt(float(tangent @ tangent))
            if speed > 1e-12:
                angular = angular + (self._R0 @ self._w01) * (cfg.v0_m_s / speed)  # d/dt T_R
        return linear, angular

    # --- internals -------------------------------------------------------------------------------
    def _set_curve(self, P: FloatArray, R0: FloatArray, face_n: FloatArray) -> None:
        """Install curve P and the orientation slerp from R0 to getRotation(R0, face_n)."""
        cfg = self.config
        self._curve = Cubic(P)
        self._tau = 0.0
        end_speed = float(np.linalg.norm(self._curve.end_tangent))  # |T'(1)|
        # Search far enough past T(1) that passing it by Delta_m is seen (tau > 1 branch of line 26).
        self._tau_max = 1.0 + cfg.d_tau + 2.0 * cfg.miss_distance_m / max(end_speed, 1e-12)
        R1 = rotations.get_rotation(R0, face_n)  # Alg. 1 line 20: R1 <- getRotation(R0, t_n)
        self._R0 = R0
        self._w01 = rotations.log_so3(R0.T @ R1)  # T_R(tau) = R0 exp(tau w01)

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
