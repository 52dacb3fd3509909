"""Controller node: Algorithm 1's loop around the pure TrajectoryController.

Reads the fingertip pose and the (noisy) contacts, follows the curve to each planned target, stops
on contact and announces it as a TouchEvent (the contact joins the set C), then waits for the next
target. Publishes velocity commands every tick and the curve it follows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from palpate.geometry.bezier import bezier_length
from palpate.geometry.rotations import matrix_to_quat, quat_to_matrix
from palpate.messages.schemas import CartesianVelocityCommand, ContactSet, Pose, TouchEvent, TouchTarget, Trajectory
from palpate.nodes.controller.core import ControllerConfig, ControllerState, TrajectoryController, retract_direction
from palpate.runtime.spec import NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class ControllerNodeConfig:
    """The controller's parameters plus the initial touch target (Alg. 1 line 2)."""

    #: A point inside the object the first approach aims at (the object's position is enough).
    initial_target_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Radius of the fingertip sphere: the curve guides its centre, which touches a surface point
    #: t_p when it reaches t_p + radius t_n.
    tip_radius_m: float = 0.008
    #: A contact counts as a new touch once the fingertip has left the last one, or (not in the paper)
    #: once the contact point has slid this far from the last touch while the fingertip stayed in
    #: contact, metres. Without it a curve that grazes the surface (retracting along a tangential v_n,
    #: or bending around an edge) slides along the object for ever without a touch event: measured on
    #: the YCB wood block. 3 mm is half the coverage radius, so such a touch still explores new surface.
    #: 0 disables it.
    rearm_distance_m: float = 0.003
    #: ... or once the fingertip has pushed against the surface (normal force > 0) without interruption
    #: for this long, seconds (not in the paper): a curve blocked by the object (under the lip of a cup)
    #: otherwise pushes in place for ever. 0 disables it.
    rearm_push_s: float = 0.1
    #: Not in the paper: the next curve retracts along -v_n (Eq. 15) only when v_n points into the
    #: surface, v_n . (-n) >= this cosine (n the measured contact normal); otherwise it retracts along
    #: n. A touch made while sliding (v_n tangential) would otherwise start the next curve along the
    #: surface, and the fingertip touches again a few millimetres on (measured: 600 contacts on 2 % of
    #: the YCB sponge with GP-V). 0.5 = 60 degrees; -1 keeps Eq. 15 as written.
    retract_min_cos: float = 0.5
    controller: ControllerConfig = field(default_factory=ControllerConfig)


class ControllerNode:
    """Thin wrapper: messages in, TrajectoryController calls, messages out."""

    def __init__(self, config: ControllerNodeConfig, ctx: Any):
        self.config, self.ctx = config, ctx
        self.core = TrajectoryController(config.controller)
        self.pose: Pose | None = None
        self.contacts: ContactSet | None = None
        self.started = False
        self.armed = True  # contacts count only once the fingertip has left the last one
        self.push_since_ns: int | None = None  # stamp since which the fingertip pushes without a touch
        self.touches = 0
        self.missed_before = 0
        self.last_contact = np.zeros(3)
        self.retract_from = np.zeros(3)  # v_n of the next curve (Eq. 15), set at each touch
        self.predicted = np.full(3, np.nan)

    def on_pose(self, message: Pose) -> None:
        self.pose = message

    def on_contacts(self, message: ContactSet) -> None:
        self.contacts = message

    def on_target(self, message: TouchTarget) -> None:
        if self.pose is None:
            return
        R = quat_to_matrix(self.pose.quaternion_wxyz)
        centre_at_target = message.position_m + self.config.tip_radius_m * message.normal
        P = self.core.start(self.pose.position_m, self.retract_from, R, centre_at_target, message.normal)
        self.predicted = np.array(message.predicted_contact_m)
        self.armed = False
        R1 = matrix_to_quat(R)
        self.ctx.publish(
            "trajectory",
            Trajectory(
                stamp_ns=self.ctx.stamp_ns,
                kind="approach",
                control_points_m=P,
                start_quaternion_wxyz=R1,
                end_quaternion_wxyz=R1,
                length_m=float(bezier_length(P)),
            ),
        )

    def on_tick(self, stamp_ns: int) -> None:
        if self.pose is None:
            return
        r, R = np.array(self.pose.position_m), quat_to_matrix(self.pose.quaternion_wxyz)
        if not self.started:
            self.core.initial_approach(r, np.array(self.config.initial_target_m))
            self.started = True
        touching = self.contacts is not None and len(self.contacts.forces_n) > 0
        if not touching:
            self.armed = True
        elif not self.armed and self.touches > 0:
            assert self.contacts is not None
            cfg = self.config
            strongest = int(np.argmax(self.contacts.forces_n))
            slid = self.contacts.positions_m[strongest] - self.last_contact
            if cfg.rearm_distance_m > 0.0 and float(slid @ slid) > cfg.rearm_distance_m**2:
                self.armed = True
            if self.contacts.forces_n[strongest] > 0.0:
                self.push_since_ns = stamp_ns if self.push_since_ns is None else self.push_since_ns
                if cfg.rearm_push_s > 0.0 and stamp_ns - self.push_since_ns >= cfg.rearm_push_s * 1e9:
                    self.armed = True
            else:
                self.push_since_ns = None
        if self.armed:
            self.push_since_ns = None
        moving = self.core.state in (ControllerState.DIRECT, ControllerState.APPROACH, ControllerState.RECOVERY)
        if moving and touching and self.armed:
            self._touch(r, R)  # Alg. 1 lines 6-10: contact, stop until the next trajectory
            linear, angular = np.zeros(3), np.zeros(3)
        else:
            linear, angular = self.core.command(r, R)
        if self.core.state is ControllerState.FAILED:
            self.ctx.request_stop(
                "controller: the fingertip found no surface (approach and recovery missed)"
                if self.touches
                else "controller: the initial approach from the start position towards the initial target "
                f"{list(self.config.initial_target_m)} found no surface; the target must lie inside the object "
                "(launch arguments start:= and target:= of launch/explore.yaml)"
            )
        self.ctx.publish(
            "velocity", CartesianVelocityCommand(stamp_ns=stamp_ns, linear_m_s=linear, angular_rad_s=angular)
        )
        self.ctx.metrics["travelled_m"] = self.core.travelled_m
        self.ctx.metrics["rotation_deg"] = self.core.rotation_deg

    def _touch(self, r: np.ndarray, R: np.ndarray) -> None:
        assert self.contacts is not None
        strongest = int(np.argmax(self.contacts.forces_n))
        normal = np.array(self.contacts.normals[strongest])
        direction = retract_direction(self.core.direction, normal, self.config.retract_min_cos)
        self.retract_from = direction
        self.core.on_contact(r, R)
        self.last_contact = np.array(self.contacts.positions_m[strongest])
        missed = self.core.recoveries > self.missed_before
        self.missed_before = self.core.recoveries
        self.ctx.publish(
            "touches",
            TouchEvent(
                stamp_ns=self.ctx.stamp_ns,
                index=self.touches,
                position_m=self.last_contact,
                normal=normal,
                approach_direction=direction,
                predicted_contact_m=self.predicted,
                missed=missed,
                travelled_m=self.core.travelled_m,
                rotation_deg=self.core.rotation_deg,
            ),
        )
        self.touches += 1


SPEC = NodeSpec(
    name="controller",
    config=ControllerNodeConfig,
    factory=ControllerNode,
    inputs={"pose": Port(Pose), "contacts": Port(ContactSet), "target": Port(TouchTarget)},
    outputs={"velocity": Port(CartesianVelocityCommand), "touches": Port(TouchEvent), "trajectory": Port(Trajectory)},
    doc="Bezier trajectory controller of paper 002 (Algorithm 1): velocity commands and touch events.",
)
