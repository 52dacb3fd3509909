"""Node wrappers of the minimal demo graph (`launch/demo_minimal.yaml`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from palpate.config import NonNegativeFloat, PositiveFloat, Range, Validated
from palpate.messages.schemas import ContactSet, SurfaceMesh
from palpate.nodes.demo.core import ContactStatistics, box_mesh, sample_cube_contacts
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class CubeContactsConfig(Validated):
    #: Edge of the cube, centred at the origin and axis-aligned, metres.
    edge_m: PositiveFloat = 0.05
    #: Contacts drawn uniformly on the cube's faces each tick (0: empty contact sets).
    contacts_per_tick: Annotated[int, Range(ge=0)] = 4
    #: Simulated time between two ticks, seconds.
    period_s: PositiveFloat = 0.01
    #: The run ends after this much simulated time (duration_s / period_s ticks, rounded).
    duration_s: NonNegativeFloat = 1.0


class CubeContacts:
    """Clock source: each tick publishes contacts sampled on a cube."""

    def __init__(self, config: CubeContactsConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.period_ns = round(config.period_s * 1e9)
        self.ticks = round(config.duration_s / config.period_s)
        self.tick = 0

    def step(self) -> int | None:
        if self.tick >= self.ticks:
            return None
        stamp = self.tick * self.period_ns
        positions, normals = sample_cube_contacts(self.config.edge_m, self.config.contacts_per_tick, self.ctx.rng)
        n = len(positions)
        self.ctx.publish(
            "contacts",
            ContactSet(
                stamp_ns=stamp,
                positions_m=positions,
                local_positions_m=np.zeros((n, 3)),
                normals=normals,
                forces_n=np.ones(n),
                links=["probe"] * n,
            ),
        )
        self.tick += 1
        return stamp

    def on_tick(self, stamp_ns: int) -> None:
        """A clock source has nothing to do after its own tick."""


@dataclass(frozen=True, kw_only=True)
class ContactStatsConfig(Validated):
    #: Print a summary line (contact sets, contacts, their bounding box, decode errors) when the run ends.
    report: bool = True


class ContactStats:
    """Consumes contact sets and prints a summary when the run ends."""

    def __init__(self, config: ContactStatsConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.stats = ContactStatistics()

    def on_contacts(self, message: ContactSet) -> None:
        self.stats.add(message.positions_m)
        self.ctx.metrics["contacts"] = float(self.stats.contacts)

    def on_tick(self, stamp_ns: int) -> None:
        """Statistics are updated per message; nothing to do per tick."""

    def close(self) -> None:
        if self.config.report:
            extent = ", ".join(f"{1000 * e:.1f}" for e in self.stats.extent_m())
            print(
                f"summary: {self.stats.messages} contact sets, {self.stats.contacts} contacts, "
                f"bounding box {extent} mm, decode errors {self.ctx.counters['decode_errors']}",
                flush=True,
            )


@dataclass(frozen=True, kw_only=True)
class BboxEstimatorConfig(Validated):
    #: The ``region`` the published SurfaceMesh states.
    region: str = "global"


class BboxEstimator:
    """A toy estimator: after each tick with contacts, publishes the bounding box of all contacts so far.

    Deterministic given its inputs, so re-running it on a recorded log (`palpate launch --replay`)
    must reproduce its recorded meshes byte for byte. Vertex variance: ContactStatistics.box_variance_m2.
    """

    def __init__(self, config: BboxEstimatorConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.stats = ContactStatistics()
        self.updated = False

    def on_contacts(self, message: ContactSet) -> None:
        self.stats.add(message.positions_m)
        self.updated = self.updated or len(message.positions_m) > 0

    def on_tick(self, stamp_ns: int) -> None:
        if not self.updated:
            return
        self.updated = False
        vertices, faces, normals = box_mesh(self.stats.lower_m, self.stats.upper_m)
        variance_m2 = self.stats.box_variance_m2()
        self.ctx.publish(
            "mesh",
            SurfaceMesh(
                stamp_ns=stamp_ns,
                region=self.config.region,
                num_contacts=self.stats.contacts,
                vertices_m=vertices,
                faces=faces,
                vertex_normals=normals,
                variance_vertices=np.arange(len(vertices), dtype=np.int32),
                vertex_variance=np.full(len(vertices), variance_m2),
            ),
        )


CUBE_CONTACTS = NodeSpec(
    name="cube_contacts",
    config=CubeContactsConfig,
    factory=CubeContacts,
    outputs={"contacts": Port(ContactSet)},
    clock_source=True,
    doc="Clock source publishing contacts sampled on a generated cube.",
)
CONTACT_STATS = NodeSpec(
    name="contact_stats",
    config=ContactStatsConfig,
    factory=ContactStats,
    inputs={"contacts": Port(ContactSet)},
    doc="Counts contacts and prints a summary at the end of the run.",
)
BBOX_ESTIMATOR = NodeSpec(
    name="bbox_estimator",
    config=BboxEstimatorConfig,
    factory=BboxEstimator,
    inputs={"contacts": Port(ContactSet)},
    outputs={"mesh": Port(SurfaceMesh)},
    doc="Toy estimator: the bounding box of every contact so far, as a SurfaceMesh, each tick with contacts.",
)
