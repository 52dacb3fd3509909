"""Whole-shape scores of a surface estimate: bidirectional Chamfer distance and F-score at thresholds.

The two scores the shape-reconstruction literature reports beside coverage (F-score as Tatarchenko et
al., CVPR 2019 define it; the tactile-exploration papers that follow use the same pair):

- accuracy (estimate -> truth) and completeness (truth -> estimate): mean distance of points drawn
  uniformly by area on one surface to the other surface;
- Chamfer distance = (accuracy + completeness) / 2, metres (the mean of the two one-sided means,
  unsquared, so it reads in millimetres like the RMSE);
- precision(tau) = fraction of estimate points within tau of the truth, recall(tau) = fraction of
  true points within tau of the estimate, F(tau) = 2 P R / (P + R) (0 when both are 0).

Distances are point-to-surface (exact, ``DistanceField``), not point-to-point, so the score does not
depend on how densely the other surface is sampled. ``ShapeScorer`` keeps the true surface's samples
and distance field, so scoring an estimate after every contact costs the estimate's part only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from palpate.metrics.exploration import DistanceField, Mesh, mesh_arrays, sample_surface, triangle_areas

#: The thresholds the tables report, metres.
FSCORE_THRESHOLDS_M: tuple[float, ...] = (0.001, 0.002, 0.005, 0.010)


@dataclass(frozen=True)
class ShapeScores:
    """Chamfer distance and F-scores of one estimate against the true surface (lengths in metres)."""

    accuracy_m: float
    completeness_m: float
    chamfer_m: float
    thresholds_m: tuple[float, ...]
    precision: tuple[float, ...]
    recall: tuple[float, ...]
    fscore: tuple[float, ...]

    def fscore_at(self, threshold_m: float) -> float:
        """F-score at one of ``thresholds_m``."""
        for tau, f in zip(self.thresholds_m, self.fscore, strict=True):
            if abs(tau - threshold_m) <= 1e-12:
                return f
        raise KeyError(f"no F-score at {threshold_m!r} m; scored at {self.thresholds_m}")

    def as_dict(self) -> dict[str, float]:
        """Flat figures for a results row: chamfer_mm, accuracy_mm, completeness_mm, fscore_<t>mm."""
        row = {
            "chamfer_mm": 1e3 * self.chamfer_m,
            "accuracy_mm": 1e3 * self.accuracy_m,
            "completeness_mm": 1e3 * self.completeness_m,
        }
        for tau, f in zip(self.thresholds_m, self.fscore, strict=True):
            row[f"fscore_{1e3 * tau:g}mm"] = f
        return row


def fscore_from_distances(
    d_estimate_to_truth: np.ndarray, d_truth_to_estimate: np.ndarray, thresholds_m: Sequence[float]
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """(precision, recall, F) per threshold from the two one-sided distance samples (metres)."""
    taus = np.asarray(thresholds_m, dtype=np.float64)[:, None]
    P = np.mean(np.asarray(d_estimate_to_truth)[None, :] <= taus, axis=1)
    R = np.mean(np.asarray(d_truth_to_estimate)[None, :] <= taus, axis=1)
    denominator = P + R
    F = np.divide(2.0 * P * R, denominator, out=np.zeros_like(denominator), where=denominator > 0.0)
    return tuple(P.tolist()), tuple(R.tolist()), tuple(F.tolist())


class ShapeScorer:
    """Scores estimates of one true surface; the truth's samples and distance field are built once.

    samples: points drawn by area on each surface (the standard error of a fraction is about
    sqrt(p (1 - p) / samples)); rng draws the truth's samples now and each estimate's when scored.
    """

    def __init__(
        self,
        true_mesh: Mesh,
        samples: int = 20000,
        thresholds_m: Sequence[float] = FSCORE_THRESHOLDS_M,
        rng: np.random.Generator | None = None,
    ) -> None:
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples!r}")
        taus = tuple(float(t) for t in np.atleast_1d(np.asarray(thresholds_m, dtype=np.float64)))  # one, or many
        if not taus or not all(np.isfinite(t) and t > 0.0 for t in taus):
            raise ValueError(f"thresholds_m must be finite and > 0, got {thresholds_m!r}")
        self.samples = int(samples)
        self.thresholds_m = taus
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self._truth_field = DistanceField(true_mesh)
        self.truth_points_m = sample_surface(true_mesh, self.samples, self._rng)

    def score(self, estimate: Mesh) -> ShapeScores:
        """Scores of an estimated mesh; an estimate without area scores as nothing found (F = 0)."""
        V, F = _mesh_or_empty(estimate)
        if F.shape[0] == 0 or not triangle_areas(V, F).sum() > 0.0:
            inf = float("inf")
            zeros = tuple(0.0 for _ in self.thresholds_m)
            return ShapeScores(inf, inf, inf, self.thresholds_m, zeros, zeros, zeros)
        estimate_points = sample_surface((V, F), self.samples, self._rng)
        d_e2t = self._truth_field.distance(estimate_points)  # accuracy samples
        d_t2e = DistanceField((V, F)).distance(self.truth_points_m)  # completeness samples
        accuracy, completeness = float(d_e2t.mean()), float(d_t2e.mean())
        P, R, Fs = fscore_from_distances(d_e2t, d_t2e, self.thresholds_m)
        return ShapeScores(accuracy, completeness, 0.5 * (accuracy + completeness), self.thresholds_m, P, R, Fs)


def shape_scores(
    estimate: Mesh,
    true_mesh: Mesh,
    samples: int = 20000,
    thresholds_m: Sequence[float] = FSCORE_THRESHOLDS_M,
    rng: np.random.Generator | None = None,
) -> ShapeScores:
    """Chamfer distance and F-scores of one estimate (see the module docstring)."""
    return ShapeScorer(true_mesh, samples, thresholds_m, rng).score(estimate)


def _mesh_or_empty(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V, F) of a mesh; an estimate with no faces yet is (0, 3) arrays rather than an error."""
    faces = mesh[1] if isinstance(mesh, tuple) else mesh.faces
    if np.asarray(faces).size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return mesh_arrays(mesh)
