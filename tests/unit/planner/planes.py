"""A flat test surface for the planner's strategies: candidates on a square grid in the plane z = 0."""

from __future__ import annotations

import numpy as np

UP = np.array([0.0, 0.0, 1.0])
DOWN = -UP


def plane_grid(step: float = 0.005, half: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Points (m, 3) of the grid of pitch ``step`` over [-half, half]^2 and their normals (m, 3), +z."""
    x = np.arange(-half, half + 1e-9, step)
    X, Y = np.meshgrid(x, x, indexing="ij")
    S = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    return S, np.tile(UP, (len(S), 1))
