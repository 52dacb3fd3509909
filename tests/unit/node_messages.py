"""Messages that node tests feed by hand: a pose, a contact set without contacts, a touch."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from palpate.messages.schemas import ContactSet, Pose, TouchEvent


def pose(
    position_m: ArrayLike, quaternion_wxyz: Sequence[float] = (1.0, 0.0, 0.0, 0.0), frame: str = "fingertip"
) -> Pose:
    """A pose at rest at position_m (3,)."""
    return Pose(
        stamp_ns=0,
        frame=frame,
        position_m=np.asarray(position_m, dtype=np.float64),
        quaternion_wxyz=np.array(quaternion_wxyz, dtype=np.float64),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )


def no_contacts() -> ContactSet:
    """A contact set with no contact."""
    empty = np.zeros((0, 3))
    return ContactSet(
        stamp_ns=0, positions_m=empty, local_positions_m=empty, normals=empty, forces_n=np.zeros(0), links=[]
    )


def touch(position_m: ArrayLike, normal: ArrayLike) -> TouchEvent:
    """The first touch, at position_m (3,) with the outward normal (3,), made moving down (-z)."""
    return TouchEvent(
        stamp_ns=0,
        index=0,
        position_m=np.asarray(position_m, dtype=np.float64),
        normal=np.asarray(normal, dtype=np.float64),
        approach_direction=np.array([0.0, 0.0, -1.0]),
        predicted_contact_m=np.full(3, np.nan),
        missed=False,
        travelled_m=0.0,
        rotation_deg=0.0,
    )
