"""Pure parts of the minimal demo graph: contacts sampled on a cube, and running contact statistics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def sample_cube_contacts(edge_m: float, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points uniformly distributed on the surface of an axis-aligned cube centred at the origin.

    Returns positions (count, 3) in metres and outward unit normals (count, 3).
    """
    face = rng.integers(0, 6, size=count)
    axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
    positions = rng.uniform(-edge_m / 2, edge_m / 2, size=(count, 3))
    positions[np.arange(count), axis] = sign * edge_m / 2
    normals = np.zeros((count, 3))
    normals[np.arange(count), axis] = sign
    return positions, normals


@dataclass
class ContactStatistics:
    """Running statistics of a contact stream: counts and the bounding box of all contacts."""

    messages: int = 0
    contacts: int = 0
    lower_m: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    upper_m: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))

    def add(self, positions_m: np.ndarray) -> None:
        """Fold one contact set, positions (n, 3), into the statistics."""
        self.messages += 1
        self.contacts += len(positions_m)
        if len(positions_m):
            self.lower_m = np.minimum(self.lower_m, positions_m.min(axis=0))
            self.upper_m = np.maximum(self.upper_m, positions_m.max(axis=0))

    def extent_m(self) -> np.ndarray:
        """Edge lengths of the bounding box of every contact so far, (3,); zeros before any contact."""
        return np.where(np.isfinite(self.upper_m), self.upper_m - self.lower_m, 0.0)
