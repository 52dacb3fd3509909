"""Free space swept by the fingertip, as an inequality on the implicit surface (not in paper 002).

Wherever the centre of a fingertip of radius r passed without a contact, the object's signed
distance is at least r: f >= r. A GP takes equalities only, so the inequality is kept by an active
set: the swept centres where the posterior mean breaks it (f < r) get the value-only observation
f = r, the least that satisfies it there (``GPIS.add_free_space``), thinned to one per ``spacing_m``
voxel, for up to ``rounds`` rounds (each observation moves the mean elsewhere too). An observation
where the mean already satisfies it would say more than the evidence (the true distance may be far
larger) and pull the surface out; this form never adds one there.

The active set belongs to the contacts it was found for: kept across touches, an observation made
when the estimate was coarse stays at f = r where the true distance is larger, and pulls the surface
out (measured: it made every strategy's whole estimate worse). So the GPIS node applies it to the
whole-object estimate it is asked for, from all the contacts so far, and drops it again.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.errors import EstimationError
from palpate.nodes.gpis.core import SurfaceEstimator

FloatArray = NDArray[np.float64]


class SweptSpace:
    """Fingertip centres swept without a contact, one per voxel of edge voxel_m (the first kept)."""

    def __init__(self, voxel_m: float) -> None:
        if not voxel_m > 0.0:
            raise ValueError(f"voxel_m must be > 0, got {voxel_m!r}")
        self.voxel_m = float(voxel_m)
        self._keys: set[tuple[int, int, int]] = set()
        self._points: list[tuple[float, float, float]] = []

    def __len__(self) -> int:
        return len(self._points)

    def add(self, centre_m: ArrayLike) -> None:
        """A fingertip centre (3,) m with no contact."""
        x, y, z = (float(v) for v in np.asarray(centre_m, dtype=np.float64).reshape(3))
        s = self.voxel_m
        key = (int(np.floor(x / s)), int(np.floor(y / s)), int(np.floor(z / s)))
        if key not in self._keys:
            self._keys.add(key)
            self._points.append((x, y, z))

    def points_m(self) -> FloatArray:
        """The kept centres (k, 3)."""
        return np.array(self._points, dtype=np.float64).reshape(-1, 3)


def within_box(points_m: FloatArray, lower_m: FloatArray, upper_m: FloatArray) -> NDArray[np.bool_]:
    """Which points (k, 3) lie inside the box [lower_m, upper_m] (3,): a mask (k,)."""
    return np.asarray(np.all((points_m >= lower_m) & (points_m <= upper_m), axis=1))


def most_broken_per_voxel(points_m: FloatArray, slack: FloatArray, spacing_m: float) -> NDArray[np.int64]:
    """Indices of one point per voxel of edge spacing_m: the one with the smallest slack (k,) in it."""
    order = np.argsort(slack, kind="stable")
    keys = np.floor(points_m[order] / spacing_m).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.asarray(order[np.sort(first)], dtype=np.int64)


def enforce(
    gp: SurfaceEstimator, swept_m: FloatArray, radius_m: float, spacing_m: float, rounds: int, tolerance_m: float
) -> tuple[NDArray[np.int64], bool]:
    """Add f = radius_m at the swept centres (k, 3) where the mean of ``gp`` is below radius_m -
    tolerance_m, one per spacing_m voxel, for up to ``rounds`` rounds, each centre at most once.
    Returns the indices (into swept_m) of the centres added (none when the estimator takes no free
    space: ``supports_free_space`` False) and whether a round was refused (its covariance would not
    factor: the rounds stop there, the earlier ones stay)."""
    added = np.zeros(0, dtype=np.int64)
    if not gp.supports_free_space or len(swept_m) == 0:
        return added, False
    left = np.arange(len(swept_m))
    for _ in range(rounds):
        slack = gp.mean(swept_m[left]) - radius_m
        broken = np.flatnonzero(slack < -tolerance_m)
        if not len(broken):
            break
        picked = broken[most_broken_per_voxel(swept_m[left[broken]], slack[broken], spacing_m)]
        try:
            gp.add_free_space(swept_m[left[picked]], radius_m)
        except EstimationError:
            return added, True
        added = np.concatenate([added, left[picked]])
        left = np.delete(left, picked)
        if not len(left):
            break
    return added, False
