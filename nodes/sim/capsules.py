"""The spheres that cover a hand's or finger's capsules: the exact-mesh penalty contacts
(``penalty_contact.PenaltyContacts``) and the scripted motion's clearance checks place them."""

from __future__ import annotations

import mujoco
import numpy as np


def capsule_spheres(
    model: mujoco.MjModel, body_mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Spheres covering every capsule geom of the bodies in ``body_mask`` (nbody,) bool.

    Centres lie on the capsule axis at spacing radius / 2 (the union deviates from the capsule by at
    most 1 - sqrt(15/16) = 3 % of the radius). Returns geom ids (K,), offsets in the geom frame
    (K, 3), radii (K,) and per capsule the (start, stop) index range of its spheres.
    """
    gids: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    radii: list[float] = []
    runs: list[tuple[int, int]] = []
    for g in range(model.ngeom):
        if not body_mask[model.geom_bodyid[g]] or model.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE:
            continue
        r, half = float(model.geom_size[g, 0]), float(model.geom_size[g, 1])
        count = int(np.ceil(2 * half / (0.5 * r))) + 1
        start = len(gids)
        for s in np.linspace(-half, half, count):  # a capsule's axis is its geom frame's z
            gids.append(g)
            offsets.append((0.0, 0.0, float(s)))
            radii.append(r)
        runs.append((start, len(gids)))
    return np.array(gids, dtype=np.int64), np.array(offsets).reshape(-1, 3), np.array(radii), runs


def sphere_centres(data: mujoco.MjData, geoms: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """World centres (K, 3) of spheres given by geom ids (K,) and geom-frame offsets (K, 3)."""
    xmat = data.geom_xmat[geoms].reshape(-1, 3, 3)
    return data.geom_xpos[geoms] + np.einsum("kij,kj->ki", xmat, offsets)
