"""Map RMSE and surface distances against a known box."""

from __future__ import annotations

import math

import numpy as np
import pytest

from palpate.nodes.mapper.grid import GridSpec, SparseMap
from palpate.nodes.mapper.metrics import (
    box_sdf,
    box_surface_points,
    map_rmse,
    surface_band,
    surface_distances_mm,
)

CENTER = np.array([0.0, 0.0, 0.0])
HALF = np.array([0.02, 0.02, 0.02])
# faces fall a quarter cell into cells, not on cell boundaries
SPEC = GridSpec.from_bounds((-0.0305, -0.0305, -0.0305), (0.0305, 0.0305, 0.0305), 0.002)


def sdf(p: np.ndarray) -> np.ndarray:
    return box_sdf(p, CENTER, HALF)


def test_box_sdf_against_hand_values() -> None:
    pts = np.array([[0, 0, 0], [0.03, 0, 0], [0.03, 0.03, 0], [0.01, 0.015, -0.005], [0.02, 0.02, 0.02]])
    expect = [-0.02, 0.01, math.hypot(0.01, 0.01), -0.005, 0.0]
    np.testing.assert_allclose(box_sdf(pts, CENTER, HALF), expect, atol=1e-15)


def test_band_holds_a_shell_of_truth_and_free_cells_outside() -> None:
    region, truth = surface_band(SPEC, sdf, band_m=0.004)
    d = sdf(SPEC.centers(region))
    h = SPEC.resolution_m / 2
    assert np.all(d[truth] <= h + 1e-12) and np.all(d[~truth] > h)
    assert np.all(d > -h) and np.all(d <= h + 0.004 + 1e-12)
    # each face column holds one shell cell: 6 faces of 20 x 20 cells plus edges and corners
    assert 6 * 20 * 20 <= truth.sum() <= 6 * 22 * 22


def _map_from_belief(flat: np.ndarray, bel: np.ndarray) -> SparseMap:
    l = np.log(bel / (1 - bel)).astype(np.float32)
    order = np.argsort(flat)
    return SparseMap(spec=SPEC, flat=flat[order].astype(np.int64), log_odds=l[order])


def test_rmse_of_perfect_empty_and_inverted_maps() -> None:
    region, truth = surface_band(SPEC, sdf, band_m=0.004)
    perfect = _map_from_belief(region, np.where(truth, 1 - 1e-6, 1e-6))
    assert map_rmse(perfect, region, truth) == pytest.approx(1e-6, rel=1e-3)
    empty = SparseMap(spec=SPEC, flat=np.zeros(0, np.int64), log_odds=np.zeros(0, np.float32))
    assert map_rmse(empty, region, truth) == pytest.approx(0.5)
    inverted = _map_from_belief(region, np.where(truth, 0.1, 0.9))
    assert map_rmse(inverted, region, truth) == pytest.approx(0.9)
    # half the region unobserved, half perfect: sqrt(0.5 * 0.25)
    half = _map_from_belief(region[::2], np.where(truth[::2], 1 - 1e-9, 1e-9))
    n = len(region)
    assert map_rmse(half, region, truth) == pytest.approx(math.sqrt((n // 2) * 0.25 / n), rel=1e-3)
    # cells outside the region do not count
    extra = _map_from_belief(np.array([0]), np.array([0.99]))
    assert 0 not in region
    assert map_rmse(extra, region, truth) == pytest.approx(0.5)


def test_surface_distances() -> None:
    region, truth = surface_band(SPEC, sdf, band_m=0.004)
    shell = region[truth]
    m = _map_from_belief(shell, np.full(len(shell), 0.9))
    surface = box_surface_points(CENTER, HALF, 0.001)
    np.testing.assert_allclose(np.abs(sdf(surface)), 0.0, atol=1e-15)
    acc, comp = surface_distances_mm(m, sdf, surface)
    assert acc <= 1.0 + 1e-9  # shell centres lie within half a cell (1 mm) of the surface
    assert comp <= math.sqrt(3) + 1e-9  # every surface point within half a cell diagonal of a centre
    shifted = _map_from_belief(shell + 1, np.full(len(shell), 0.9))  # one cell along z
    assert surface_distances_mm(shifted, sdf, surface)[0] > acc
    empty = SparseMap(spec=SPEC, flat=np.zeros(0, np.int64), log_odds=np.zeros(0, np.float32))
    assert surface_distances_mm(empty, sdf, surface) == (math.inf, math.inf)
