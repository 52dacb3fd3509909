"""Simulation node: the clock source. Steps MuJoCo, applies commands, publishes sensors and truth.

Ports follow the scene (only what the scene needs): a probe takes Cartesian velocity commands and
publishes its pose and contacts; a hand or finger publishes joint states, fingertip pose and contacts,
and either follows the scripted exploration motion or takes joint commands. Ground truth (true
joint angles, the object and its mesh) goes on `truth/` topics, which only evaluators may read.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from palpate.config import KeyPath, PositiveFloat, Validated
from palpate.errors import ConfigError, MeshError, MeshWarning
from palpate.inputs import MAX_COORDINATE_M, MAX_RATE, bounded
from palpate.messages import codec, topics
from palpate.messages.schemas import (
    CartesianVelocityCommand,
    ContactSet,
    JointCommand,
    JointState,
    ObjectTruth,
    Pose,
)
from palpate.nodes.sim.objects import ObjectSpec, load_object, resolve_mesh_path
from palpate.nodes.sim.scene import SceneConfig, effector_mount
from palpate.nodes.sim.session import SimSession, SimTick
from palpate.runtime.spec import Context, NodeSpec, Port


def _default_scene() -> SceneConfig:
    return SceneConfig(effector="probe", object=ObjectSpec(kind="torus"))


@dataclass(frozen=True, kw_only=True)
class SimNodeConfig(Validated):
    """The scene (see SceneConfig: effector, object, physics) and the graph timing."""

    scene: SceneConfig = field(default_factory=_default_scene)
    #: Simulated time between two graph ticks (messages are published once per tick).
    tick_period_s: PositiveFloat = 0.01
    #: The run ends after this much simulated time (or earlier, when a node asks to stop).
    duration_s: PositiveFloat = 60.0
    #: Hand and finger: follow the built-in scripted exploration (true) or take joint commands (false).
    scripted_motion: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        steps = self.tick_period_s / self.scene.timestep_s
        if not math.isfinite(steps) or abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ConfigError(
                f"tick_period_s = {self.tick_period_s!r} must be a positive multiple of the scene's time step "
                f"{self.scene.timestep_s!r}",
                ("tick_period_s",),
            )


class SimNode:
    """Thin wrapper around SimSession (a Simulation, and the scripted motion for hand and finger scenes)."""

    def __init__(self, config: SimNodeConfig, ctx: Context):
        from palpate.nodes.sim.core import Simulation  # MuJoCo and open3d load only in the process that simulates

        self.config, self.ctx = config, ctx
        scene = config.scene
        self.sim = Simulation(scene)
        self.probe = scene.effector == "probe"
        motion = None
        if not self.probe and config.scripted_motion:
            from palpate.nodes.sim.motion import ExplorationMotion

            motion = ExplorationMotion(scene, ctx.rng, obj=self.sim.object)
        self.session = SimSession(
            self.sim,
            tick_period_s=config.tick_period_s,
            duration_s=config.duration_s,
            timestep_s=scene.timestep_s,
            motion=motion,
        )
        self.period_ns = self.session.period_ns  # the runtime puts it in every Clock
        #: The joint velocities published (zero: the joint states carry angles only), frozen once.
        self._joint_velocities = codec.frozen(np.zeros(len(self.sim.joint_names)))

    def on_velocity(self, message: CartesianVelocityCommand) -> None:
        linear = bounded(message.linear_m_s, "linear_m_s", MAX_RATE, "m/s")
        angular = bounded(message.angular_rad_s, "angular_rad_s", MAX_RATE, "rad/s")
        self.sim.set_velocity(linear, angular)

    def on_joint_commands(self, message: JointCommand) -> None:
        self.session.joint_command(message.names, message.positions_rad)

    def step(self) -> int | None:
        tick = self.session.step()
        if tick is None:
            return None
        if tick.first:
            self._publish_object()
        self._publish_state(tick)
        x, y, z = tick.position_m.tolist()
        if not max(abs(x), abs(y), abs(z)) <= MAX_COORDINATE_M:  # its poses are useless to every other node
            self.ctx.request_stop(
                f"the effector left the world: it is at ({x:.6g}, {y:.6g}, {z:.6g}) m, beyond {MAX_COORDINATE_M:g} m "
                "of the origin; check the velocity commands",
                failed=True,
            )
        return tick.stamp_ns

    def on_tick(self, stamp_ns: int) -> None:
        """The clock source does its work in step()."""

    def _publish_state(self, tick: SimTick) -> None:
        stamp = tick.stamp_ns
        self.ctx.publish(
            "pose",
            Pose(
                stamp_ns=stamp,
                frame="fingertip",
                position_m=tick.position_m,
                quaternion_wxyz=tick.quaternion_wxyz,
                linear_velocity_m_s=tick.linear_velocity_m_s,
                angular_velocity_rad_s=tick.angular_velocity_rad_s,
            ),
        )
        c = self.sim.contacts()
        self.ctx.publish(
            "contacts",
            ContactSet(
                stamp_ns=stamp,
                positions_m=c.positions_m,
                local_positions_m=c.local_positions_m,
                normals=c.normals,
                forces_n=c.forces_n,
                links=list(c.links),
            ),
        )
        self.ctx.metrics["sim_time_s"] = self.sim.time_s
        if not self.probe:
            q = self.sim.joint_positions()
            state = JointState(
                stamp_ns=stamp,
                names=list(self.sim.joint_names),
                positions_rad=q,
                velocities_rad_s=self._joint_velocities,
            )
            self.ctx.publish("joint_states", state)
            self.ctx.publish("truth_joint_states", state)

    def _publish_object(self) -> None:
        obj = self.sim.object
        spec = obj.spec
        self.ctx.publish(
            "truth_object",
            ObjectTruth(
                stamp_ns=0,
                name=obj.name,
                source=str(obj.source_path) if obj.source_path else "primitive",
                position_m=np.array(spec.position_m, dtype=np.float64),
                quaternion_wxyz=np.array(spec.quaternion_wxyz, dtype=np.float64),
                vertices_m=np.asarray(obj.mesh.vertices, dtype=np.float64),
                faces=np.asarray(obj.mesh.faces, dtype=np.int32),
            ),
        )


def _ports(config: SimNodeConfig) -> tuple[dict[str, Port], dict[str, Port]]:
    """Ports for the configured scene: only what the effector needs."""
    effector = config.scene.effector
    outputs = {
        "pose": Port(Pose),
        "contacts": Port(ContactSet),
        "truth_object": Port(ObjectTruth),
    }
    if effector == "probe":
        return {"velocity": Port(CartesianVelocityCommand)}, outputs
    outputs["joint_states"] = Port(JointState)
    outputs["truth_joint_states"] = Port(JointState, topic=topics.TRUTH_JOINT_STATES)
    inputs = {} if config.scripted_motion else {"joint_commands": Port(JointCommand)}
    return inputs, outputs


def _files(config: SimNodeConfig) -> dict[KeyPath, str]:
    """The object's mesh file, where the scene names one (``ycb:<id>`` resolved)."""
    spec = config.scene.object
    if spec.kind != "mesh" or not spec.path:
        return {}
    return {("scene", "object", "path"): str(resolve_mesh_path(spec.path))}


#: Draws of touch candidates the launch-time reach check tries before it calls an object unreachable.
REACH_CHECK_DRAWS = 3


def _checks(config: SimNodeConfig) -> dict[KeyPath, str]:
    """What is wrong with the object's mesh file (absurd scale, degenerate, unreadable), read as the node will,
    and, for a finger or hand that taps by script, whether its fingertip reaches the object at all (the
    node found out only when it started). The object is read once for both."""
    spec = config.scene.object
    scripted = config.scene.effector != "probe" and config.scripted_motion
    if not scripted and not (spec.kind == "mesh" and spec.path):
        return {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)  # the node says them when it starts
        try:
            obj = load_object(spec)
        except MeshError as exc:
            return {("scene", "object", "path") if spec.kind == "mesh" else ("scene", "object"): str(exc)}
        if not scripted:
            return {}
        from palpate.nodes.sim.motion import ExplorationMotion

        problem = ""
        for seed in range(REACH_CHECK_DRAWS):  # one draw may miss what the run's own seed finds (at the edge)
            try:
                ExplorationMotion(config.scene, np.random.default_rng(seed), obj=obj)
                return {}
            except ConfigError as exc:
                problem = str(exc)
    return {("scene",): problem}


def _facts(config: SimNodeConfig) -> dict[str, tuple[Any, tuple[str, ...]]]:
    """Where the scene fixes its hand or finger: a mapper of the same graph must be mounted there."""
    scene = config.scene
    # the mount's keys (base_position_m, finger, ...) live in the effector's own section: scene.finger, scene.hand
    path = ("scene",) if scene.effector == "probe" else ("scene", scene.effector)
    return {"hand_mount": (effector_mount(scene), path)}


SPEC = NodeSpec(
    name="sim",
    config=SimNodeConfig,
    factory=SimNode,
    clock_source=True,
    ports_from_config=_ports,
    facts=_facts,
    files=_files,
    checks=_checks,
    doc="MuJoCo simulation (hand, finger or probe on a primitive or mesh): the graph's clock source.",
)
