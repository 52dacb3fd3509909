"""The planner's checks of the arrays it is given: PlanningError names the argument and the fault."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.errors import PlanningError

FloatArray = NDArray[np.float64]


def points(name: str, value: ArrayLike) -> FloatArray:
    """``value`` as finite points (m, 3)."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise PlanningError(f"{name} must have shape (m, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise PlanningError(f"{name} holds NaN or infinity in {int((~np.isfinite(a)).any(1).sum())} rows")
    return a


def vector(name: str, value: ArrayLike) -> FloatArray:
    """``value`` as a finite 3-vector (3,)."""
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise PlanningError(f"{name} must be a finite 3-vector, got {value!r}")
    return a


def unit_rows(name: str, value: ArrayLike) -> FloatArray:
    """``value`` (m, 3) with every row normalised; a zero row is an error."""
    a = points(name, value)
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    bad = norm[:, 0] < 1e-12
    if np.any(bad):
        raise PlanningError(
            f"{name}: {int(bad.sum())} normals have zero length (first at row {int(np.argmax(bad))}); "
            "the surface estimate must give a unit normal for every candidate"
        )
    return a / norm
