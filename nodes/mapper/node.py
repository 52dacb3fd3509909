"""Mapper node: occupancy-grid mapping at a known pose, dead reckoning, or FastSLAM (paper 000).

Each tick with a joint reading it runs one update with that reading and the contacts of the same
tick (contact points in the touching link's frame: where on the finger the touch is felt). The
finger's kinematics come from the hand description the simulator builds its model from
(palpate/description/hand.yaml), placed where the launch file's ``mount`` says: the mapper reads link
lengths and joint axes, never the simulator's state.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from palpate.config import NonNegativeFloat, PositiveFloat, Validated
from palpate.description import load_hand
from palpate.errors import ConfigError, PalpateError
from palpate.messages import topics
from palpate.messages.schemas import ContactSet, JointState, OccupancyGrid, ParticleSetSummary
from palpate.nodes.mapper.core import Mapper, MapperConfig, check_fits
from palpate.nodes.mapper.grid import SparseMap
from palpate.nodes.mapper.kinematics import FingerMount, KinematicChain
from palpate.nodes.mapper.session import MapperSession
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class MapperNodeConfig(Validated):
    """The mapper's parameters, where its finger is mounted, and how often maps go out."""

    mapper: MapperConfig
    #: Which finger the mapper models and where the hand is fixed: the simulator's finger in a simulated
    #: graph (``palpate launch`` checks it); default: the hand description's finger mount.
    mount: FingerMount = field(default_factory=FingerMount)
    #: Publish the maps every this much simulated time (the particle summary goes out every update).
    publish_period_s: PositiveFloat = 1.0
    #: Map kind label of the published best map ('known' or 'dead_reckoning' when mode is known).
    label: str = ""
    #: Contacts join the update of the joint reading stamped within this of theirs (0: the same stamp, as
    #: a lockstep graph stamps a tick's messages; a driver whose joint and tactile streams are stamped
    #: apart sets, for example, half its joint reading period).
    stamp_tolerance_s: NonNegativeFloat = 0.0


#: Contacts that all lie outside the mapped region before the mapper says so (a region that misses the object).
WARN_OUTSIDE_AFTER = 10


#: Free-volume point updates per reading (points a pose x maps) beyond which the mapper warns that its updates
#: are slow: the paper's K = 100 at 2 mm makes about 2.4e5 (7.8 ms a reading, NS_PER_POINT_UPDATE each);
#: 2e6 is about 66 ms, over six times the 10 ms between the simulator's readings. K = 100,000 at 2 mm (2.4e8)
#: advanced a lockstep graph 0.27 s of simulated time in 5 minutes, unnamed; K = 3000 at 2 mm (7e6, 0.3-0.9 s
#: a reading measured) ran at a hundredth of real time below the former line of 1e7.
COSTLY_POINT_UPDATES = 2_000_000
#: The simulator's joint readings come every this many seconds of simulated time (its 10 ms tick).
READING_PERIOD_S = 0.01
#: Nanoseconds per free-volume point and map of a FastSLAM update at 2 mm (7.8 ms / 2.4e5; docs/slam.md).
NS_PER_POINT_UPDATE = 33.0


class MapperNode:
    """Thin wrapper around MapperSession (and its Mapper)."""

    def __init__(self, config: MapperNodeConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.chain = KinematicChain.from_description(load_hand(), config.mount)
        self.core = Mapper(config.mapper, self.chain, ctx.rng)
        self.session = MapperSession(self.core, config.publish_period_s, config.label, config.stamp_tolerance_s)
        self._warned: set[str] = set()  # the one-time warnings given
        self._last_tick_ns: int | None = None  # the last update's stamp, and the last maps'
        self._last_maps_ns: int | None = None
        mapper_config = config.mapper
        n_maps = mapper_config.n_maps
        if (point_updates := self.core.free_volume.n_points * n_maps) > COSTLY_POINT_UPDATES:
            self._warn_once(
                "costly updates",
                "mapper: each reading updates %d free-volume points in each of %d maps (%.3g in all; resolution_m "
                "%g m): about %.2g s a reading at the %g ns each that K = 100 at 2 mm takes (more with finer cells "
                "or many particles), %.0f times the %g s between the simulator's readings, and a lockstep graph "
                "waits for each; fewer particles, a coarser resolution_m or a larger free_spacing_m make it cheaper",
                self.core.free_volume.n_points,
                n_maps,
                point_updates,
                mapper_config.resolution_m,
                point_updates * NS_PER_POINT_UPDATE * 1e-9,
                NS_PER_POINT_UPDATE,
                point_updates * NS_PER_POINT_UPDATE * 1e-9 / READING_PERIOD_S,
                READING_PERIOD_S,
            )
        if self.core.free_volume.n_points == 0:
            spacing, margin = config.mapper.free_lattice()
            self._warn_once(
                "no free volume",
                "mapper: the finger's free volume holds no lattice point (spacing %g m, margin %g m, cells of %g m): "
                "the maps learn from contacts only, nothing is cleared; set the mapper's free_spacing_m finer",
                spacing,
                margin,
                config.mapper.resolution_m,
            )

    def on_joint_states(self, message: JointState) -> None:
        self.session.joint_reading(message.names, message.positions_rad, message.stamp_ns)

    def on_contacts(self, message: ContactSet) -> None:
        self.session.contacts(message.links, message.local_positions_m, message.stamp_ns)
        received, off = self.session.contacts_received, self.session.contacts_off_chain
        if off:  # another finger's, or the palm's: this mapper models one finger
            self.ctx.counters["contacts_off_finger"] = off
        if received >= WARN_OUTSIDE_AFTER and off == received:
            self._warn_once(
                "finger",
                "mapper: the first %d contacts all lie on links its %s finger does not have (%r, where its links are "
                "%s): another finger's (the scene's tapping finger is another one; set the mapper's mount.finger to "
                "it), or names that are no link of the hand description (docs/hand_model.md); the maps stay empty",
                received,
                self.config.mount.finger,
                self.session.first_off_link,
                ", ".join(self.core.chain.link_names),
            )

    def on_tick(self, stamp_ns: int) -> None:
        step = self.session.tick(stamp_ns)
        if step is None:
            return
        self._last_tick_ns = stamp_ns
        if self.session.contacts_unmatched:
            self.ctx.counters["contacts_unmatched"] = self.session.contacts_unmatched
            contacts_ns, reading_ns = self.session.last_unmatched or (0, 0)
            refused = self.session.readings_refused
            self._warn_once(
                "stamps",
                "mapper: contacts found no joint reading stamped within stamp_tolerance_s (%g s) of theirs (contacts "
                "at %d ns, the next reading at %s) and are left out of the maps (counter contacts_unmatched): "
                + (
                    f"joint readings were refused (said above; {refused} so far), and their contacts with them"
                    if self.session.unmatched_after_refusal
                    else "in real time a mapper slower than the tick skips readings (see its ms_per_update); a "
                    "driver stamps a tick's joint and contact messages alike, or the mapper's stamp_tolerance_s "
                    "allows the difference"
                ),
                self.config.stamp_tolerance_s,
                contacts_ns,
                f"{reading_ns} ns" if reading_ns >= 0 else "none yet",
            )
        c = self.core.counters
        self.ctx.metrics.update(updates=c.updates, n_eff=self.core.n_eff)
        self.ctx.counters.update(
            contacts_outside=c.contacts_outside,
            contacts_outside_measured=c.contacts_outside_measured,
            free_points_outside=c.free_points_outside,
        )
        region = (self.config.mapper.region_min_m, self.config.mapper.region_max_m)
        # where the readings put the contacts (a particle's placement alone is no sign: under large joint
        # noise particles put contacts well inside the region out of it, and some outside it back in)
        if c.contacts >= WARN_OUTSIDE_AFTER and c.contacts_outside_measured == c.contacts:
            self._warn_once(
                "all outside",
                "mapper: the first %d contacts all lie outside the mapped region (region_min_m %s, region_max_m %s); "
                "the maps stay empty: widen the region to hold the object (or, from a driver, give the contacts' "
                "local_positions_m in metres, in their link's frame)",
                c.contacts,
                *region,
            )
        elif 0 < c.contacts_outside_measured < c.contacts and "all outside" not in self._warned:
            self._warn_once(
                "outside",
                "mapper: a contact lies outside the mapped region (region_min_m %s, region_max_m %s), and the maps "
                "leave it out (counters contacts_outside_measured, and contacts_outside per particle map): widen the "
                "region to hold the object",
                *region,
            )
        self.ctx.timings["ms_per_update"] = c.mean_update_ms
        if self.core.filter is not None:
            self._publish_particles(stamp_ns, step.resampled)
        if step.publish_maps:
            self.publish_maps(stamp_ns)

    def close(self) -> None:
        """At the end of a run, the maps of the last update when the last ones published are older (a run
        whose length is no multiple of ``publish_period_s`` would end without its last maps); not after a
        failure, whose state they would show (and whose error a fault here would hide)."""
        if self.ctx.failure or self._last_tick_ns is None or self._last_tick_ns == self._last_maps_ns:
            return
        try:
            self.publish_maps(self._last_tick_ns)
        except PalpateError as exc:
            self.ctx.log.warning("mapper: the last maps were not published: %s", exc)

    def _warn_once(self, kind: str, text: str, *args: Any) -> None:
        if kind not in self._warned:
            self._warned.add(kind)
            self.ctx.log.warning(text, *args)

    def publish_maps(self, stamp_ns: int) -> None:
        self._last_maps_ns = stamp_ns
        self._publish_map("map", self.core.best_map(), self.session.label, stamp_ns)
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

    def _publish_particles(self, stamp_ns: int, resampled: bool) -> None:
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
                resampled=resampled,
                joint_names=list(self.chain.joint_names),
                pose_mean_rad=pose.mean_q_rad,
                pose_best_rad=pose.best_q_rad,
                weights=weights,
            ),
        )


#: The ports every mapper has, whatever its mode.
INPUTS = {"joint_states": Port(JointState), "contacts": Port(ContactSet)}
OUTPUTS = {
    "map": Port(
        OccupancyGrid,
        doc="the map (FastSLAM: its best particle's); mode fastslam adds weighted_map (map/occupancy_weighted) and "
        "particles (map/particles, ParticleSetSummary)",
    )
}


def _ports(config: MapperNodeConfig) -> tuple[dict[str, Port], dict[str, Port]]:
    outputs = dict(OUTPUTS)
    if config.mapper.mode == "fastslam":
        outputs["weighted_map"] = Port(OccupancyGrid, topic=topics.WEIGHTED_OCCUPANCY_GRID)
        outputs["particles"] = Port(ParticleSetSummary)
    return dict(INPUTS), outputs


def _checks(config: MapperNodeConfig) -> dict[tuple[str | int, ...], str]:
    """What the mapper would refuse at its start, said at launch: per_joint_sigma_deg naming joints its finger
    lacks, a grid and particle count that do not fit in memory."""
    try:
        check_fits(config.mapper, KinematicChain.from_description(load_hand(), config.mount))
    except ConfigError as exc:
        return {("mapper", *exc.path): str(exc)}
    return {}


def _facts(config: MapperNodeConfig) -> dict[str, tuple[Any, tuple[str, ...]]]:
    """Where the mapper's finger is mounted: the simulator of the same graph must put it there."""
    return {"hand_mount": (config.mount.fact(), ("mount",))}


SPEC = NodeSpec(
    name="mapper",
    config=MapperNodeConfig,
    factory=MapperNode,
    inputs=INPUTS,
    outputs=OUTPUTS,
    ports_from_config=_ports,
    facts=_facts,
    checks=_checks,
    doc="Haptic SLAM mapper of paper 000: occupancy grid at a known pose, or FastSLAM with K particles.",
    may_trail=True,  # never stops a run: the clock need not wait for it when nothing in the loop reads it
)
