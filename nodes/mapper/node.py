"""Mapper node: occupancy-grid mapping at a known pose, dead reckoning, or FastSLAM (paper 000).

Each tick with a joint reading it runs one update with that reading and the contacts of the same
tick (contact points in the touching link's frame: where on the finger the touch is felt). The
finger's kinematics come from the hand description the simulator builds its model from
(palpate/description/hand.yaml), placed where the launch file's ``mount`` says: the mapper reads link
lengths and joint axes, never the simulator's state.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from palpate.config import PositiveFloat, Validated
from palpate.description import load_hand
from palpate.inputs import coordinates, select_named
from palpate.messages.schemas import ContactSet, JointState, OccupancyGrid, ParticleSetSummary
from palpate.nodes.mapper.core import Mapper, MapperConfig
from palpate.nodes.mapper.grid import SparseMap
from palpate.nodes.mapper.kinematics import FingerMount, KinematicChain
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class MapperNodeConfig(Validated):
    """The mapper's parameters, where its finger is mounted, and how often maps go out."""

    mapper: MapperConfig
    #: The simulated finger's base in the world (the same pose as the simulator's scene).
    mount: FingerMount
    #: Publish the maps every this much simulated time (the particle summary goes out every update).
    publish_period_s: PositiveFloat = 1.0
    #: Map kind label of the published best map ('known' or 'dead_reckoning' when mode is known).
    label: str = ""


class MapperNode:
    """Thin wrapper around Mapper."""

    def __init__(self, config: MapperNodeConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.chain = KinematicChain.from_description(load_hand(), config.mount)
        self.core = Mapper(config.mapper, self.chain, ctx.rng)
        self.link_index = {name: i for i, name in enumerate(self.chain.link_names)}
        self.reading: tuple[int, np.ndarray] | None = None  # stamp, the chain's joint angles (J,) rad
        self.contacts: tuple[int, np.ndarray, np.ndarray] | None = None  # stamp, link indices, local points
        self.next_publish_ns = 0
        self.resampled = False
        self.label = config.label or ("known" if config.mapper.mode == "known" else "best")

    def on_joint_states(self, message: JointState) -> None:
        q = select_named(message.names, message.positions_rad, self.chain.joint_names, "names")
        self.reading = (message.stamp_ns, q)

    def on_contacts(self, message: ContactSet) -> None:
        local = coordinates(message.local_positions_m, "local_positions_m")
        keep = [i for i, link in enumerate(message.links) if link in self.link_index]
        links = np.array([self.link_index[message.links[i]] for i in keep], dtype=np.int64)
        self.contacts = (message.stamp_ns, links, local[keep])

    def on_tick(self, stamp_ns: int) -> None:
        reading, contacts = self.reading, self.contacts
        self.reading = None
        if reading is None:
            return
        stamp, q = reading
        links, local = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        if contacts is not None and contacts[0] == stamp:
            _, links, local = contacts
        resamples_before = self.core.counters.resamples
        self.core.update(q, links, local)
        c = self.core.counters
        self.resampled = c.resamples > resamples_before
        self.ctx.metrics.update(updates=c.updates, ms_per_update=c.mean_update_ms, n_eff=self.core.n_eff)
        if self.core.filter is not None:
            self._publish_particles(stamp_ns)
        if stamp_ns >= self.next_publish_ns:
            self.next_publish_ns = stamp_ns + round(self.config.publish_period_s * 1e9)
            self.publish_maps(stamp_ns)

    def publish_maps(self, stamp_ns: int) -> None:
        self._publish_map("map", self.core.best_map(), self.label, stamp_ns)
        if self.core.filter is not None:
            self._publish_map("weighted_map", self.core.weighted_map(), "weighted", stamp_ns)

    def _publish_map(self, port: str, sparse: SparseMap, kind: str, stamp_ns: int) -> None:
        spec = sparse.spec
        self.ctx.publish(
            port,
            OccupancyGrid(
                stamp_ns=stamp_ns,
                map_kind=kind,
                origin_m=np.array(spec.origin_m, dtype=np.float64),
                resolution_m=spec.resolution_m,
                shape=np.array(spec.shape, dtype=np.int64),
                cell_indices=sparse.flat,
                log_odds=sparse.log_odds,
            ),
        )

    def _publish_particles(self, stamp_ns: int) -> None:
        fs = self.core.filter
        assert fs is not None
        pose = self.core.pose_estimate()
        weights = fs.weights
        self.ctx.publish(
            "particles",
            ParticleSetSummary(
                stamp_ns=stamp_ns,
                num_particles=len(weights),
                effective_sample_size=self.core.n_eff,
                best_index=int(np.argmax(weights)),
                resampled=self.resampled,
                joint_names=list(self.chain.joint_names),
                pose_mean_rad=pose.mean_q_rad,
                pose_best_rad=pose.best_q_rad,
                weights=weights,
            ),
        )


def _ports(params: Mapping[str, Any]) -> tuple[dict[str, Port], dict[str, Port]]:
    outputs = {"map": Port(OccupancyGrid)}
    mode = (params.get("mapper") or {}).get("mode", "fastslam")
    if mode == "fastslam":
        outputs["weighted_map"] = Port(OccupancyGrid, topic="map/occupancy_weighted")
        outputs["particles"] = Port(ParticleSetSummary)
    return {"joint_states": Port(JointState), "contacts": Port(ContactSet)}, outputs


SPEC = NodeSpec(
    name="mapper",
    config=MapperNodeConfig,
    factory=MapperNode,
    ports_from_params=_ports,
    doc="Haptic SLAM mapper of paper 000: occupancy grid at a known pose, or FastSLAM with K particles.",
)
