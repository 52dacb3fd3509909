"""Controller node: Algorithm 1's loop around the pure TouchLoop (nodes/controller/core.py).

Reads the fingertip pose and the (noisy) contacts, follows the curve to each planned target, stops
on contact and announces it as a TouchEvent (the contact joins the set C), then waits for the next
target. Publishes velocity commands every tick and the curve it follows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from palpate.geometry.bezier import bezier_length
from palpate.geometry.rotations import matrix_to_quat
from palpate.inputs import contact_arrays, fingertip_pose, within_reach
from palpate.messages.schemas import CartesianVelocityCommand, ContactSet, Pose, TouchEvent, TouchTarget, Trajectory
from palpate.nodes.controller.contact_check import ContactAgreement
from palpate.nodes.controller.core import AXIS_APPROACH_M, Touch, TouchConfig, TouchLoop, tick_step_problem
from palpate.nodes.controller.trajectory import ControllerConfig
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class ControllerNodeConfig(TouchConfig):
    """The touch rules (TouchConfig: tip_radius_m, rearm_distance_m, rearm_push_s, retract_min_cos and the
    slide's slide_press_m_s, slide_arrive_m, slide_slack_m, slide_normal_weight), the controller's
    parameters and the initial touch target (Alg. 1 line 2)."""

    #: A point inside the object the first approach aims at (the object's position is enough); None:
    #: the first approach runs along the fingertip's poking axis from where it starts.
    initial_target_m: tuple[float, float, float] | None = None
    controller: ControllerConfig = field(default_factory=ControllerConfig)


_NO_CONTACT = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
#: How far beyond the fingertip's surface a contact may lie (m): far more than contact noise and a tick's
#: travel; a contact farther off is not the fingertip's (a contact in millimetres lies 1000x too far).
CONTACT_REACH_M = 0.1


class ControllerNode:
    """Thin wrapper: messages in, TouchLoop calls, messages out."""

    def __init__(self, config: ControllerNodeConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.core = TouchLoop(config, config.controller, config.initial_target_m)
        self.pose: tuple[np.ndarray, np.ndarray] | None = None  # fingertip position (3,) m, orientation (3, 3)
        self.contacts = _NO_CONTACT
        self._first_stamp_ns: int | None = None  # until the tick period is known and checked
        self.agreement = ContactAgreement(config.tip_radius_m)

    def on_pose(self, message: Pose) -> None:
        self.pose = fingertip_pose(message.position_m, message.quaternion_wxyz)

    def on_contacts(self, message: ContactSet) -> None:
        positions, normals, forces = contact_arrays(message.positions_m, message.normals, message.forces_n)
        if self.pose is None:  # nothing to check them against, nor to do with them (on_tick waits for a pose)
            return
        reach_m = self.config.tip_radius_m + CONTACT_REACH_M
        within_reach(positions, self.pose[0], reach_m, "positions_m", "fingertip")
        self.contacts = positions, normals, forces
        if note := self.agreement.read(self.pose[0], positions, normals):
            self.ctx.log.warning("controller: %s", note)

    def on_target(self, message: TouchTarget) -> None:
        if self.pose is None:
            return
        r, R = self.pose
        P = self.core.aim(
            r,
            R,
            message.position_m,
            message.normal,
            message.predicted_contact_m,
            message.slide,
            message.miss_distance_m,
        )
        R1 = matrix_to_quat(R)
        self.ctx.publish(
            "trajectory",
            Trajectory(
                stamp_ns=self.ctx.stamp_ns,
                kind="slide" if self.core.slide is not None else "approach",
                control_points_m=P,
                start_quaternion_wxyz=R1,
                end_quaternion_wxyz=R1,
                length_m=float(bezier_length(P)),
            ),
        )

    def _failure(self) -> str:
        returned = self.core.controller.straight_returns > 0
        missed = "approach, recovery and straight return" if returned else "approach and recovery"
        return f"controller: the fingertip found no surface ({missed} missed)"

    def _no_first_touch(self) -> str:
        target = self.config.initial_target_m
        if target is None:
            return (
                f"controller: the initial approach along the fingertip's poking axis found no surface within "
                f"{AXIS_APPROACH_M:g} m of the start; start the fingertip facing the object (launch arguments "
                "start:= and start_quaternion:= of launch/explore.yaml) or give a point inside it (target:=)"
            )
        return (
            f"controller: the initial approach from the start position towards the initial target {list(target)} "
            "found no surface; the target must lie inside the object (launch argument target:= of "
            "launch/explore.yaml, or target:=null to approach along the fingertip's poking axis)"
        )

    def _check_tick(self, stamp_ns: int) -> str:
        """The speed against the tick period (tick_step_problem), once, from the first two stamps."""
        if self._first_stamp_ns is None:
            self._first_stamp_ns = stamp_ns
            return ""
        if self._first_stamp_ns < 0:
            return ""
        tick_s = (stamp_ns - self._first_stamp_ns) * 1e-9
        self._first_stamp_ns = -1
        return tick_step_problem(self.config.controller.v0_m_s, tick_s, self.config.tip_radius_m)

    def on_tick(self, stamp_ns: int) -> None:
        problem = self._check_tick(stamp_ns)
        if problem:
            self.ctx.request_stop(problem, failed=True)
            return
        if self.pose is None:
            return
        step = self.core.step(stamp_ns, *self.pose, *self.contacts)
        if step.touch is not None:
            self._publish_touch(step.touch)
        if step.failed:
            reason = self.core.blocked or (self._failure() if self.core.touches else self._no_first_touch())
            self.ctx.request_stop(reason, failed=True)
        self.ctx.publish(
            "velocity",
            CartesianVelocityCommand(stamp_ns=stamp_ns, linear_m_s=step.linear_m_s, angular_rad_s=step.angular_rad_s),
        )
        self.ctx.metrics["travelled_m"] = self.core.travelled_m
        self.ctx.metrics["rotation_deg"] = self.core.rotation_deg

    def _publish_touch(self, touch: Touch) -> None:
        self.ctx.publish(
            "touches",
            TouchEvent(
                stamp_ns=self.ctx.stamp_ns,
                index=touch.index,
                position_m=touch.position_m,
                normal=touch.normal,
                approach_direction=touch.approach_direction,
                predicted_contact_m=touch.predicted_contact_m,
                missed=touch.missed,
                travelled_m=touch.travelled_m,
                rotation_deg=touch.rotation_deg,
            ),
        )


SPEC = NodeSpec(
    name="controller",
    config=ControllerNodeConfig,
    factory=ControllerNode,
    inputs={"pose": Port(Pose), "contacts": Port(ContactSet), "target": Port(TouchTarget)},
    outputs={"velocity": Port(CartesianVelocityCommand), "touches": Port(TouchEvent), "trajectory": Port(Trajectory)},
    doc="Bezier trajectory controller of paper 002 (Algorithm 1): velocity commands and touch events.",
)
