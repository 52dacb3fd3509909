"""The contacts that the simulation reports: :class:`Contacts`, and how a set of surface points,
normals and forces on effector bodies becomes one (:func:`make_contacts`: unit normals and
body-frame points, in Python scalars for a few contacts, where they give numpy's bits)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import mujoco
import numpy as np

from palpate.messages import codec

#: Up to this many contacts, ``Simulation.contacts`` checks their values for finiteness in one sum and
#: :func:`make_contacts` computes their frames in Python scalars.
FEW_CONTACTS = 4
#: No contact: read-only arrays over an empty bytes object, shared by every empty Contacts (nothing can
#: change them, so the message codec passes them on without a copy).
NO_ROWS = codec.frozen(np.zeros((0, 3)))
NO_VALUES = codec.frozen(np.zeros(0))


@dataclass(frozen=True)
class Contacts:
    """Contacts between the effector and the object at one instant (n may be 0).

    positions_m (n, 3): points on the object's surface, world frame, metres.
    local_positions_m (n, 3): the same points in the frame of the touching effector body.
    normals (n, 3): unit, outward from the object's surface.
    forces_n (n,): normal force, >= 0, newtons.
    links: names of the touching effector bodies, length n.
    """

    positions_m: np.ndarray
    local_positions_m: np.ndarray
    normals: np.ndarray
    forces_n: np.ndarray
    links: list[str]

    @staticmethod
    def empty() -> Contacts:
        """No contact (read-only arrays)."""
        return Contacts(NO_ROWS, NO_ROWS, NO_ROWS, NO_VALUES, [])

    def __len__(self) -> int:
        return len(self.links)


def unit_and_local_numpy(
    normals: np.ndarray, points: np.ndarray, bodies: np.ndarray, xmat: np.ndarray, xpos: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (n, 3) and contact points (n, 3) in their bodies' frames, R^T (p - x), from MuJoCo's
    body frames xmat (nbody, 9) and xpos (nbody, 3)."""
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    R = xmat[bodies].reshape(-1, 3, 3)
    return unit, np.einsum("kji,kj->ki", R, points - xpos[bodies])


def unit_and_local(
    normals: np.ndarray, points: np.ndarray, bodies: list[int], xmat: np.ndarray, xpos: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`unit_and_local_numpy` of a few contacts in Python scalars (numpy's norm adds its three
    squares left to right, and this einsum its three products: ``frames_match_numpy`` checks both);
    None for a normal of length zero, which numpy's path turns into NaN (and the caller's check names)."""
    unit, local = [], []
    for (n0, n1, n2), (p0, p1, p2), b in zip(normals.tolist(), points.tolist(), bodies, strict=True):
        length = math.sqrt((n0 * n0 + n1 * n1) + n2 * n2)
        if length == 0.0:
            return None
        unit.append((n0 / length, n1 / length, n2 / length))
        R, (x0, x1, x2) = xmat[b].tolist(), xpos[b].tolist()
        v0, v1, v2 = p0 - x0, p1 - x1, p2 - x2
        local.append(tuple((R[i] * v0 + R[3 + i] * v1) + R[6 + i] * v2 for i in range(3)))
    return np.array(unit, dtype=np.float64).reshape(-1, 3), np.array(local, dtype=np.float64).reshape(-1, 3)


@cache
def frames_match_numpy(samples: int = 300) -> bool:
    """Whether :func:`unit_and_local` gives numpy's bits here (random normals, points and frames)."""
    rng = np.random.default_rng(20261127)
    for _ in range(samples):
        n = int(rng.integers(1, FEW_CONTACTS + 1))
        normals, points = rng.standard_normal((n, 3)), 0.1 * rng.standard_normal((n, 3))
        xmat, xpos = rng.standard_normal((5, 9)), 0.1 * rng.standard_normal((5, 3))
        bodies = rng.integers(0, 5, n)
        got = unit_and_local(normals, points, bodies.tolist(), xmat, xpos)
        expected = unit_and_local_numpy(normals, points, bodies, xmat, xpos)
        if got is None or any(a.tobytes() != e.tobytes() for a, e in zip(got, expected, strict=True)):
            return False
    return True


def make_contacts(
    points: np.ndarray,
    normals: np.ndarray,
    forces: np.ndarray,
    bodies: np.ndarray,
    data: mujoco.MjData,
    body_names: list[str],
) -> Contacts:
    """Contacts at surface points (n, 3) with normals (n, 3) (any length but zero) and forces (n,) on
    effector bodies (n,) (ids into ``body_names``), in the body frames of ``data``'s current state."""
    few = None
    if len(bodies) <= FEW_CONTACTS and frames_match_numpy():
        few = unit_and_local(normals, points, bodies.tolist(), data.xmat, data.xpos)
    normals, local = few if few is not None else unit_and_local_numpy(normals, points, bodies, data.xmat, data.xpos)
    return Contacts(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(local, dtype=np.float64),
        np.ascontiguousarray(normals, dtype=np.float64),
        np.ascontiguousarray(forces, dtype=np.float64),
        [body_names[b] for b in bodies],
    )
