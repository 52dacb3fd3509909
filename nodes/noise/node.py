"""Noise node: what a real proprioceptive (and tactile) sensor would report, on the same message types.

Joint angles get Gaussian noise (sigma 1.5 deg by default, per-joint override, optional constant
bias); for the probe, contact positions and normals may get noise too. Seeded from the launch file;
sigma 0 passes values through bit for bit. One message out per message in, with the same stamp; joint
velocities, contact forces, links and local positions pass unchanged. A hardware driver that publishes
these topics replaces sim + noise.
"""

from __future__ import annotations

from dataclasses import dataclass

from palpate.messages import topics
from palpate.messages.schemas import ContactSet, JointState
from palpate.nodes.noise.core import ContactNoise, ContactNoiseConfig, JointNoiseConfig, JointStreamNoise
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class NoiseNodeConfig(JointNoiseConfig, ContactNoiseConfig):
    """Which streams to corrupt and how (the joint and contact noise parameters, flat in YAML)."""

    #: Add noise to joint states (hand and finger scenes).
    joints: bool = True
    #: Add noise to contact sets (probe scene).
    contacts: bool = False


class NoiseNode:
    """Thin wrapper around JointStreamNoise and ContactNoise."""

    def __init__(self, config: NoiseNodeConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.joint_noise = JointStreamNoise(config, ctx.rng)
        self.contact_noise = ContactNoise(config, ctx.rng)

    def on_joint_states(self, message: JointState) -> None:
        self.ctx.publish(
            "noisy_joint_states",
            JointState(
                stamp_ns=message.stamp_ns,
                names=message.names,
                positions_rad=self.joint_noise.apply(message.names, message.positions_rad),
                velocities_rad_s=message.velocities_rad_s,
            ),
        )

    def on_contacts(self, message: ContactSet) -> None:
        positions, normals = self.contact_noise.apply(message.positions_m, message.normals)
        self.ctx.publish(
            "noisy_contacts",
            ContactSet(
                stamp_ns=message.stamp_ns,
                positions_m=positions,
                local_positions_m=message.local_positions_m,
                normals=normals,
                forces_n=message.forces_n,
                links=message.links,
            ),
        )

    def on_tick(self, stamp_ns: int) -> None:
        """Noise is applied per message."""


def _ports(config: NoiseNodeConfig) -> tuple[dict[str, Port], dict[str, Port]]:
    inputs: dict[str, Port] = {}
    outputs: dict[str, Port] = {}
    if config.joints:
        inputs["joint_states"] = Port(JointState)
        outputs["noisy_joint_states"] = Port(JointState, topic=topics.NOISY_JOINT_STATES)
    if config.contacts:
        inputs["contacts"] = Port(ContactSet)
        outputs["noisy_contacts"] = Port(ContactSet, topic=topics.NOISY_CONTACTS)
    return inputs, outputs


SPEC = NodeSpec(
    name="noise",
    config=NoiseNodeConfig,
    factory=NoiseNode,
    ports_from_config=_ports,
    doc="Proprioceptive noise on joint angles (and optionally contacts), seeded from the launch file.",
    may_trail=True,  # never stops a run: the clock need not wait for it when nothing in the loop reads it
)
