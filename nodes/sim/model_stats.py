"""What a scene's MuJoCo model holds and how fast it steps bare (the simulation benchmark's
reference, ``palpate bench sim``)."""

from __future__ import annotations

import time

import mujoco
import numpy as np


def model_sizes(model: mujoco.MjModel) -> dict[str, int]:
    """What a scene's MuJoCo model holds: bodies (the world excluded), geoms, degrees of freedom,
    actuators, and the geom pairs MuJoCo's collision detection considers (``contact_pairs``): pairs of
    geoms on different bodies whose contype and conaffinity match, less parent-child pairs (unless the
    parent is the world) and pairs of two static bodies, plus explicit ``<pair>`` elements."""
    contype = np.asarray(model.geom_contype, dtype=np.int64)
    affinity = np.asarray(model.geom_conaffinity, dtype=np.int64)
    body = np.asarray(model.geom_bodyid)
    weld = np.asarray(model.body_weldid)[body]
    parent = np.asarray(model.body_parentid)
    g1, g2 = np.triu_indices(model.ngeom, k=1)
    b1, b2 = body[g1], body[g2]
    match = ((contype[g1] & affinity[g2]) | (contype[g2] & affinity[g1])) != 0
    family = ((parent[b1] == b2) & (b2 != 0)) | ((parent[b2] == b1) & (b1 != 0))
    static = (weld[g1] == 0) & (weld[g2] == 0)
    pairs = int(np.count_nonzero(match & (b1 != b2) & ~family & ~static)) + int(model.npair)
    return {
        "bodies": int(model.nbody) - 1,
        "geoms": int(model.ngeom),
        "dof": int(model.nv),
        "actuators": int(model.nu),
        "contact_pairs": pairs,
    }


def bare_step_rate(model: mujoco.MjModel, seconds: float = 1.0, batch: int = 100) -> float:
    """Steps per second of a bare ``mj_step`` loop on ``model`` (fresh data, zero controls)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    steps = 0
    start = time.perf_counter()
    elapsed = 0.0
    while elapsed < seconds:
        mujoco.mj_step(model, data, nstep=batch)
        steps += batch
        elapsed = time.perf_counter() - start
    return steps / elapsed
