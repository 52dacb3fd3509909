"""Whether the contacts a driver sends agree with the fingertip they are said to touch.

Each contact of a ContactSet can pass every check of its own message (finite, unit normal, within reach of
the fingertip) and still be wrong as a whole: normals that point into the object instead of out of it, or
points in the fingertip's frame instead of the world's. A contact on the fingertip sphere of radius r lies
about r from its centre c, and the object's outward normal n there points towards it, (c - p) . n ~ r
(an inward normal makes it ~ -r; a point probe, r = 0, tells neither apart and is not judged by its normals).
``ContactAgreement`` reads the first contact sets and names, once, what most of them get wrong; contact
noise moves single contacts, not the median of a set, nor most sets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Contact sets (with at least one contact) read before the verdict.
JUDGED_SETS = 10
#: A contact set lies off the fingertip when its median contact is farther than this many radii, plus
#: OFF_SLACK_M, from the fingertip's centre: contact noise of a few millimetres stays within it.
OFF_RADII = 2.0
OFF_SLACK_M = 0.01
#: A contact set's normals point into the fingertip when its median (c - p) . n is below minus this many
#: radii (about -1 for inward normals, +1 for outward ones; 60 degrees of normal noise gives +0.5).
INWARD_RADII = 0.5


@dataclass
class ContactAgreement:
    """Counts, over the first JUDGED_SETS contact sets, those whose median normal points into the fingertip
    (away from where the object's outside is) and those whose median contact lies off the fingertip."""

    tip_radius_m: float
    judged: int = 0
    inward: int = 0
    off: int = 0

    def read(self, centre_m: FloatArray, positions_m: FloatArray, normals: FloatArray) -> str:
        """One contact set (n, 3) against the fingertip's centre (3,), world frame; the note, once, when most
        of the first JUDGED_SETS sets disagree with the fingertip, else ""."""
        if self.judged >= JUDGED_SETS or len(positions_m) == 0:
            return ""
        towards_centre = centre_m - positions_m
        self.judged += 1
        gap = float(np.median(np.einsum("ij,ij->i", towards_centre, normals)))
        self.inward += int(self.tip_radius_m > 0.0 and gap < -INWARD_RADII * self.tip_radius_m)
        distance = float(np.median(np.linalg.norm(towards_centre, axis=1)))
        self.off += int(distance > OFF_RADII * self.tip_radius_m + OFF_SLACK_M)
        if self.judged < JUDGED_SETS:
            return ""
        notes = []
        if 2 * self.inward > self.judged:
            notes.append(
                f"in {self.inward} of the first {self.judged} contact sets the normals point into the fingertip: "
                "ContactSet.normals must point out of the object (docs/messages.md), or the estimate turns inside out"
            )
        if 2 * self.off > self.judged:
            notes.append(
                f"in {self.off} of the first {self.judged} contact sets the contacts lie more than "
                f"{OFF_RADII * self.tip_radius_m + OFF_SLACK_M:g} m from the fingertip's centre, whose radius is "
                f"{self.tip_radius_m:g} m (tip_radius_m): ContactSet.positions_m must be in the world frame, on the "
                "fingertip's surface (docs/messages.md)"
            )
        return "; ".join(notes)
