"""The mapper node's decisions, between its messages and the Mapper (pure, no transport).

- A joint reading is put in the chain's joint order when it arrives; a reading that lacks one of the
  chain's joints is refused (InputError) and the previous one is kept. Joints the chain does not
  have (the other fingers of a hand) are ignored.
- Contacts keep only those on the chain's links, as link indices and positions in the link's frame.
- Each tick with a new reading runs one update, with the contacts of the same stamp (the simulator
  publishes both in one tick); a tick without a new reading does nothing.
- The maps go out at the first update and then once every ``publish_period_s`` of simulated time.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.description.names import match_names
from palpate.errors import InputError
from palpate.inputs import coordinates, select_named
from palpate.nodes.mapper.core import Mapper

FloatArray = NDArray[np.float64]

#: A joint reading beyond a full turn is no hinge angle (most likely degrees sent as radians): refused.
MAX_JOINT_RAD = 2.0 * math.pi


@dataclass(frozen=True)
class JointReading:
    """Joint angles q_rad (J,) in the chain's joint order, measured at stamp_ns."""

    stamp_ns: int
    q_rad: FloatArray


@dataclass(frozen=True)
class ChainContacts:
    """The contacts on the chain's links at stamp_ns: link indices (n,), positions (n, 3) in those
    links' frames (metres)."""

    stamp_ns: int
    links: NDArray[np.int64]
    local_m: FloatArray

    @classmethod
    def none(cls, stamp_ns: int) -> ChainContacts:
        return cls(stamp_ns=stamp_ns, links=np.zeros(0, dtype=np.int64), local_m=np.zeros((0, 3)))


@dataclass(frozen=True)
class MapperTick:
    """What one tick's update asks the node to publish."""

    #: The particle filter resampled in this update (reported in the particle summary).
    resampled: bool
    #: The maps are due (first update, then every publish period).
    publish_maps: bool


#: Contact sets kept for a reading of their stamp that has not come yet (a tick's worth or two in real time).
MAX_PENDING_CONTACTS = 64


class MapperSession:
    """Feeds the Mapper from decoded messages and decides when the maps go out."""

    def __init__(
        self, mapper: Mapper, publish_period_s: float, label: str = "", stamp_tolerance_s: float = 0.0
    ) -> None:
        """`stamp_tolerance_s`: contacts stamped at most this far from the joint reading's stamp join its
        update (0: the same stamp, as a lockstep graph stamps a tick's messages)."""
        self.mapper = mapper
        self.stamp_tolerance_ns = round(stamp_tolerance_s * 1e9)
        self.chain = mapper.chain
        self.publish_period_ns = round(publish_period_s * 1e9)
        #: Map kind of the published best map: the configured label, or 'known' / 'best' by mode.
        self.label = label or ("known" if mapper.config.mode == "known" else "best")
        self.next_publish_ns = 0
        self._reading: JointReading | None = None
        #: Contact sets not yet paired with a reading, oldest first: in real time a noisy reading comes a
        #: hop (a tick) after the contacts of its stamp.
        self._pending: list[ChainContacts] = []
        #: Contact points received, and those on links the chain does not have (another finger's).
        self.contacts_received = 0
        self.contacts_off_chain = 0
        #: The first link name a contact gave that the chain does not have ("" before one came).
        self.first_off_link = ""
        #: Joint readings refused (an angle beyond a full turn, a joint of the chain missing), and the stamps
        #: of the latest ones.
        self.readings_refused = 0
        self._refused_stamps: deque[int] = deque(maxlen=MAX_PENDING_CONTACTS)
        #: Whether the contacts that last found no reading had theirs refused.
        self.unmatched_after_refusal = False
        self._last_tick_ns: int | None = None
        #: Contact points on the chain left out because no joint reading had their stamp, and the last
        #: such pair of stamps (contacts', reading's).
        self.contacts_unmatched = 0
        self.last_unmatched: tuple[int, int] | None = None

    def joint_reading(self, names: Sequence[str], positions_rad: ArrayLike, stamp_ns: int) -> JointReading:
        """Keep a reading (joint names and angles in the message's order) for the next tick; returns
        it in the chain's joint order. Raises InputError, keeping the previous reading, when a
        joint of the chain is missing."""
        try:
            q_rad = select_named(names, positions_rad, self.chain.joint_names, "names")
        except InputError:
            self._refuse(stamp_ns)
            raise
        beyond = np.flatnonzero(np.abs(q_rad) > MAX_JOINT_RAD)
        if len(beyond):
            i = int(beyond[0])
            self._refuse(stamp_ns)
            raise InputError(
                "positions_rad",
                f"joint {self.chain.joint_names[i]!r} reads {q_rad[i]:.6g} rad, more than a full turn: degrees "
                "sent as radians? (or joint noise of tens of degrees, as a noise node with a large sigma_deg adds)",
            )
        reading = JointReading(stamp_ns=stamp_ns, q_rad=q_rad)
        self._reading = reading
        return reading

    def _refuse(self, stamp_ns: int) -> None:
        self.readings_refused += 1
        self._refused_stamps.append(stamp_ns)

    def contacts(self, links: Sequence[str], local_positions_m: ArrayLike, stamp_ns: int) -> ChainContacts:
        """Keep the contacts (the link of each and its position in that link's frame) that lie on the
        chain's links, as link indices; returns them. Counts those on other links."""
        index = match_names(links, self.chain.link_names).index
        on_chain = index >= 0
        self.contacts_received += len(index)
        self.contacts_off_chain += int(np.count_nonzero(~on_chain))
        if not self.first_off_link and not on_chain.all():
            self.first_off_link = str(links[int(np.argmin(on_chain))])
        contacts = ChainContacts(
            stamp_ns=stamp_ns,
            links=index[on_chain].astype(np.int64),
            local_m=coordinates(local_positions_m, "local_positions_m").reshape(-1, 3)[on_chain],
        )
        self._pending.append(contacts)
        if len(self._pending) > MAX_PENDING_CONTACTS:  # no reading of their stamp came (none came at all)
            self._unmatched(self._pending.pop(0), -1)
        return contacts

    def tick(self, stamp_ns: int) -> MapperTick | None:
        """One update with the reading received since the last tick (None: there was none) and the
        contacts of the reading's stamp."""
        reading = self._reading
        self._reading = None
        if reading is None:
            return None
        went_back = self._last_tick_ns is not None and stamp_ns < self._last_tick_ns
        self._last_tick_ns = stamp_ns
        if went_back:  # a real-time driver restarted from 0: contacts of its former run pair with no reading now
            for stale in [c for c in self._pending if c.stamp_ns > reading.stamp_ns]:
                self._pending.remove(stale)
                self._unmatched(stale, reading.stamp_ns)
        contacts = self._paired(reading.stamp_ns)
        resamples_before = self.mapper.counters.resamples
        self.mapper.update(reading.q_rad, contacts.links, contacts.local_m)
        publish_maps = stamp_ns >= self.next_publish_ns or went_back  # the publication period starts again
        if publish_maps:
            self.next_publish_ns = stamp_ns + self.publish_period_ns
        return MapperTick(resampled=self.mapper.counters.resamples > resamples_before, publish_maps=publish_maps)

    def _paired(self, reading_ns: int) -> ChainContacts:
        """The pending contact set stamped nearest `reading_ns` within the tolerance (none: no contacts);
        sets stamped earlier, which no later reading can take, are dropped as unmatched."""
        tolerance = self.stamp_tolerance_ns
        near = [c for c in self._pending if abs(c.stamp_ns - reading_ns) <= tolerance]
        chosen = min(near, key=lambda c: abs(c.stamp_ns - reading_ns)) if near else None
        kept = []
        for c in self._pending:
            if c is chosen:
                continue
            if c.stamp_ns <= reading_ns:
                self._unmatched(c, reading_ns)
            else:
                kept.append(c)  # a later reading's
        self._pending = kept
        return chosen if chosen is not None else ChainContacts.none(reading_ns)

    def _unmatched(self, contacts: ChainContacts, reading_ns: int) -> None:
        if len(contacts.links):
            self.contacts_unmatched += len(contacts.links)
            self.last_unmatched = (contacts.stamp_ns, reading_ns)
            tolerance = self.stamp_tolerance_ns
            self.unmatched_after_refusal = any(abs(contacts.stamp_ns - t) <= tolerance for t in self._refused_stamps)
