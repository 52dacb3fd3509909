"""Pure parts of the minimal demo graph: contacts sampled on a cube, and running contact statistics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from palpate.inputs import coordinates


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
        """Fold one contact set, positions (n, 3), into the statistics (InputError for a position
        beyond the bounds of palpate.inputs; the statistics are then unchanged)."""
        positions_m = coordinates(positions_m, "positions_m")
        self.messages += 1
        self.contacts += len(positions_m)
        if len(positions_m):
            self.lower_m = np.minimum(self.lower_m, positions_m.min(axis=0))
            self.upper_m = np.maximum(self.upper_m, positions_m.max(axis=0))

    def extent_m(self) -> np.ndarray:
        """Edge lengths of the bounding box of every contact so far, (3,); zeros before any contact."""
        return np.where(np.isfinite(self.upper_m), self.upper_m - self.lower_m, 0.0)

    def box_variance_m2(self) -> float:
        """The toy estimator's variance, m^2: that of a uniform distribution over the longest edge of the
        bounding box (edge^2 / 12), divided by the number of contacts. Needs at least one contact."""
        return float(self.extent_m().max()) ** 2 / 12.0 / self.contacts


def _box_faces() -> np.ndarray:
    """The 12 triangles of a box whose corner i has bit 0, 1, 2 of i set for the upper x, y, z.

    Each face's two triangles are wound counter-clockwise seen from outside (normal = outward).
    """
    faces = []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3  # (u, v, axis) is a right-handed cycle
        for upper in (0, 1):
            quad = [
                (upper << axis) | (a << u) | (b << v) for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))
            ]  # counter-clockwise around +axis
            if not upper:
                quad = quad[::-1]
            faces += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    return np.array(faces, dtype=np.int32)


BOX_FACES = _box_faces()
_CORNER_SIGNS = np.array([[1.0 if i >> k & 1 else -1.0 for k in range(3)] for i in range(8)])


def box_mesh(lower_m: np.ndarray, upper_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle mesh of the axis-aligned box [lower_m, upper_m] (both (3,), metres).

    Returns vertices (8, 3) in metres, faces (12, 3) int32 wound counter-clockwise from outside, and
    unit corner normals (8, 3) pointing away from the centre along the corner's diagonal.
    """
    vertices = np.where(_CORNER_SIGNS > 0, upper_m, lower_m)
    return vertices, BOX_FACES.copy(), _CORNER_SIGNS / np.sqrt(3.0)
