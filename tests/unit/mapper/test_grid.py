"""Sparse log-odds grids: updates, clamping, extremes of size, copy-on-write, export."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from palpate.errors import ConfigError
from palpate.nodes.mapper.grid import (
    L_FREE,
    L_OCC,
    GridSpec,
    LogOddsGrids,
    belief,
    log_odds_of,
    update_log_odds,
)

SPEC = GridSpec(origin_m=(-0.1, 0.0, 0.2), resolution_m=0.01, shape=(13, 9, 20))


def test_belief_is_the_paper_formula_and_stable() -> None:
    l = np.linspace(-30, 30, 121)
    np.testing.assert_allclose(belief(l), 1.0 - 1.0 / (1.0 + np.exp(l)), rtol=1e-12, atol=1e-15)
    extreme = belief(np.array([-1e30, -800.0, 0.0, 800.0, 1e30]))
    assert np.all(np.isfinite(extreme))
    np.testing.assert_array_equal(extreme, [0.0, 0.0, 0.5, 1.0, 1.0])
    np.testing.assert_allclose(log_odds_of(belief(np.array([-3.0, 0.5, 7.0]))), [-3.0, 0.5, 7.0], atol=1e-9)


def test_increments_are_the_paper_values() -> None:
    assert math.log(0.9 / 0.1) == pytest.approx(L_OCC) and pytest.approx(-L_OCC) == L_FREE
    g = LogOddsGrids(SPEC, 1)
    g.update_flat(0, free_flat=[5, 6], occ_flat=[7])
    np.testing.assert_allclose(g.read_flat(0, [5, 6, 7, 8]), [L_FREE, L_FREE, L_OCC, 0.0], rtol=1e-6)
    g.update_flat(0, free_flat=[7], occ_flat=[])
    np.testing.assert_allclose(g.read_flat(0, [7]), [0.0], atol=1e-6)
    assert belief(g.read_flat(0, [5]))[0] == pytest.approx(0.1, rel=1e-6)


def test_one_update_per_cell_per_observation_and_contacts_win() -> None:
    g = LogOddsGrids(SPEC, 1)
    obs = g.update_flat(0, free_flat=[3, 3, 3, 4, 9], occ_flat=[4, 4])
    np.testing.assert_allclose(g.read_flat(0, [3, 4, 9]), [L_FREE, L_OCC, L_FREE], rtol=1e-6)
    # counted: one entry per distinct cell; cell 4 counted once, as occupied
    assert obs.counted_free is not None and obs.counted_occ is not None
    assert obs.counted_free.sum() == 2 and obs.counted_occ.sum() == 1


def test_updates_match_a_dense_reference() -> None:
    rng = np.random.default_rng(0)
    g = LogOddsGrids(SPEC, 1, chunk_edge=4, l_min=-3.0, l_max=4.0)
    ref = np.zeros(SPEC.n_cells)
    for _ in range(60):
        free = rng.integers(0, SPEC.n_cells, 50)
        occ = rng.integers(0, SPEC.n_cells, 5)
        g.update_flat(0, free, occ)
        delta = np.zeros(SPEC.n_cells)
        delta[np.unique(free)] = L_FREE
        delta[np.unique(occ)] = L_OCC
        ref = np.clip(ref + delta, -3.0, 4.0)
    np.testing.assert_allclose(g.to_dense(0).ravel(), ref, atol=1e-5)
    sparse = g.to_sparse(0)
    assert np.all(np.diff(sparse.flat) > 0) and sparse.flat.dtype == np.int64
    assert sparse.log_odds.dtype == np.float32
    np.testing.assert_array_equal(sparse.flat, np.flatnonzero(np.abs(ref) > 1e-5))


def test_many_updates_of_one_cell_stay_clamped_through_the_grid() -> None:
    g = LogOddsGrids(GridSpec(origin_m=(0, 0, 0), resolution_m=1.0, shape=(1, 1, 1)), 1)
    for i in range(2_000):
        g.update_flat(0, free_flat=[], occ_flat=[0])
        if i % 100 == 0:
            assert g.read_flat(0, [0])[0] <= 10.0
    assert g.read_flat(0, [0])[0] == np.float32(10.0)
    for _ in range(5):  # the cell can change its mind: 5 x log 9 > 10
        g.update_flat(0, free_flat=[0], occ_flat=[])
    assert belief(g.read_flat(0, [0]))[0] < 0.5


@pytest.mark.slow
def test_a_million_updates_of_one_cell_do_not_overflow() -> None:
    l = np.zeros(1, dtype=np.float32)
    for _ in range(1_000_000):  # the grid's per-update kernel, a million times
        l = update_log_odds(l, L_OCC, -10.0, 10.0)
    assert l[0] == np.float32(10.0)
    b = belief(l)
    assert np.all(np.isfinite(b)) and 0.0 <= b[0] <= 1.0
    for _ in range(5):
        l = update_log_odds(l, L_FREE, -10.0, 10.0)
    assert belief(l)[0] < 0.5


def test_grid_of_one_cell_and_points_outside() -> None:
    spec = GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=0.002, shape=(1, 1, 1))
    g = LogOddsGrids(spec, 2)
    inside, chunk, offset = g.locate(np.array([[0.001, 0.001, 0.001], [0.003, 0.0, 0.0], [-1e-9, 0, 0]]))
    np.testing.assert_array_equal(inside, [True, False, False])
    assert chunk.tolist() == [0] and offset.tolist() == [0]
    f = np.array([[[0.5, 1.5, np.nan], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]]], dtype=np.float32)
    keys = g.cell_keys(np.repeat(f, 2, axis=0))
    assert keys.n_outside == 4 and keys.valid is not None
    none = g.cell_keys(np.zeros((2, 3, 0), dtype=np.float32))
    g.observe(keys, none)
    np.testing.assert_allclose(g.read_flat(0, [0]), [L_FREE], rtol=1e-6)
    np.testing.assert_allclose(g.to_dense(1), np.full((1, 1, 1), L_FREE, dtype=np.float32), rtol=1e-6)
    assert g.to_sparse(0).flat.tolist() == [0]


def test_grid_of_ten_million_cells_is_sparse() -> None:
    tracemalloc.start()
    spec = GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=0.001, shape=(216, 216, 216))
    assert spec.n_cells > 10**7
    g = LogOddsGrids(spec, 1)
    pts = np.random.default_rng(1).uniform(0, 0.216, size=(200, 3))
    _inside, flat = spec.flat_of_points(pts)
    g.update_flat(0, free_flat=flat[:150], occ_flat=flat[150:])
    sparse = g.to_sparse(0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 3 * 2**20, f"peak {peak / 2**20:.1f} MB; a dense float32 grid would take 40 MB"
    assert g.nbytes < 2 * 2**20
    assert len(sparse.flat) == len(np.unique(flat))
    np.testing.assert_allclose(g.read_flat(0, flat[150:]), L_OCC, rtol=1e-6)


def test_cell_keys_agree_with_flat_indices() -> None:
    rng = np.random.default_rng(2)
    g = LogOddsGrids(SPEC, 3, chunk_edge=4)
    pts = rng.uniform(-0.12, 0.35, size=(3, 500, 3))
    f = ((pts - np.asarray(SPEC.origin_m)) / SPEC.resolution_m).astype(np.float32).transpose(0, 2, 1)
    keys = g.cell_keys(np.ascontiguousarray(f))
    for k in range(3):
        inside, flat = SPEC.flat_of_points(pts[k].astype(np.float32).astype(np.float64))
        assert keys.valid is not None
        np.testing.assert_array_equal(keys.valid[k], inside)
        chunk, offset = g.chunk_offset_of_flat(flat)
        np.testing.assert_array_equal(keys.key[k][inside], chunk + k * (g.n_chunks + 1))
        np.testing.assert_array_equal(keys.offset[k][inside], offset)
        np.testing.assert_array_equal(g.flat_of_chunk_offset(chunk, offset), flat)


def test_resampling_shares_chunks_and_copies_none() -> None:
    g = LogOddsGrids(SPEC, 3, chunk_edge=4)
    g.update_flat(0, free_flat=np.arange(0, 400, 7), occ_flat=[1000])
    live_before, pool_before = g.n_live_chunks, g._pool.copy()
    g.resample(np.array([0, 0, 0]))
    assert g.chunk_copies == 0
    assert g.n_live_chunks == live_before
    np.testing.assert_array_equal(g._pool[: len(pool_before)], pool_before)
    assert g.shares_chunk_data(0, 1) == g.shares_chunk_data(0, 2) == live_before
    for k in range(3):
        np.testing.assert_array_equal(g.to_dense(k), g.to_dense(0))


def test_writes_after_resampling_do_not_leak_between_particles() -> None:
    g = LogOddsGrids(SPEC, 3, chunk_edge=4)
    g.update_flat(0, free_flat=[10, 11], occ_flat=[500])
    g.resample(np.array([0, 0, 0]))
    before = g.to_dense(0)
    g.update_flat(1, free_flat=[], occ_flat=[10])  # one chunk of map 1 diverges
    assert g.chunk_copies == 1
    np.testing.assert_array_equal(g.to_dense(0), before)
    np.testing.assert_array_equal(g.to_dense(2), before)
    assert g.read_flat(1, [10])[0] == pytest.approx(L_FREE + L_OCC, abs=1e-6)
    assert g.shares_chunk_data(0, 1) == g.shares_chunk_data(0, 2) - 1
    # the last sharer writes in place, without a copy
    g.update_flat(0, free_flat=[], occ_flat=[11])
    g.update_flat(2, free_flat=[], occ_flat=[12])
    assert g.chunk_copies == 2
    np.testing.assert_allclose(g.read_flat(0, [10, 11, 12]), [L_FREE, L_FREE + L_OCC, 0.0], atol=1e-6)
    np.testing.assert_allclose(g.read_flat(2, [10, 11, 12]), [L_FREE, L_FREE, L_OCC], atol=1e-6)


def test_when_every_sharer_writes_one_keeps_the_original() -> None:
    g = LogOddsGrids(SPEC, 2, chunk_edge=4)
    g.update_flat(0, free_flat=[3], occ_flat=[])
    g.resample(np.array([0, 0]))
    f = np.zeros((2, 3, 1), dtype=np.float32) + 0.5  # cell (0, 0, 0) in both maps
    none = g.cell_keys(np.zeros((2, 3, 0), dtype=np.float32))
    g.observe(g.cell_keys(f), none)
    assert g.chunk_copies == 1
    assert g.n_live_chunks == 2


def test_freed_chunks_are_reused() -> None:
    g = LogOddsGrids(SPEC, 2, chunk_edge=4)
    g.update_flat(0, free_flat=[0], occ_flat=[])
    g.update_flat(1, free_flat=[SPEC.n_cells - 1], occ_flat=[])
    used = g._n_used
    g.resample(np.array([0, 0]))  # map 1's chunk is garbage now
    assert g.n_live_chunks == 1
    g.update_flat(1, free_flat=[0], occ_flat=[])  # copy-on-write takes the freed slot
    assert g._n_used == used


def test_weighted_map_is_the_weighted_belief() -> None:
    g = LogOddsGrids(SPEC, 2)
    g.update_flat(0, free_flat=[1], occ_flat=[2])
    g.update_flat(1, free_flat=[], occ_flat=[2, 3])
    w = np.array([0.25, 0.75])
    m = g.weighted(w)
    assert m.flat.tolist() == [1, 2, 3]
    expect = [0.25 * 0.1 + 0.75 * 0.5, 0.9, 0.25 * 0.5 + 0.75 * 0.9]
    np.testing.assert_allclose(m.belief(), expect, rtol=1e-6)


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ConfigError, match="power of two"):
        LogOddsGrids(SPEC, 1, chunk_edge=6)
    with pytest.raises(ConfigError, match="l_min"):
        LogOddsGrids(SPEC, 1, l_min=1.0)
    with pytest.raises(ConfigError, match="resolution_m"):
        GridSpec(origin_m=(0, 0, 0), resolution_m=0.0, shape=(1, 1, 1))
    with pytest.raises(ConfigError, match="must exceed"):
        GridSpec.from_bounds((0, 0, 0), (1, 0, 1), 0.1)
    assert GridSpec.from_bounds((0, 0, 0), (0.1, 0.2, 0.3), 0.1).shape == (1, 2, 3)


def test_weighted_map_with_shared_chunks_matches_a_per_map_reference() -> None:
    rng = np.random.default_rng(4)
    g = LogOddsGrids(SPEC, 6, chunk_edge=4)
    for step in range(12):
        for k in range(6):
            g.update_flat(k, rng.integers(0, SPEC.n_cells, 30), rng.integers(0, SPEC.n_cells, 3))
        if step % 4 == 3:
            g.resample(np.sort(rng.integers(0, 6, 6)))
    w = rng.dirichlet(np.ones(6))
    dense = np.stack([g.to_dense(k).ravel() for k in range(6)]).astype(np.float64)
    ref = np.sum(w[:, None] * belief(dense), axis=0)
    touched = np.flatnonzero(np.any(dense != 0, axis=0))
    m = g.weighted(w)
    np.testing.assert_array_equal(m.flat, touched)
    np.testing.assert_allclose(m.belief(), ref[touched], rtol=1e-5)


def test_the_per_cell_interface_names_indices_outside_the_grid() -> None:
    """Out-of-range cells and maps were bare numpy errors, and a negative map index wrote into the last map."""
    g = LogOddsGrids(GridSpec.from_bounds((0.0, 0.0, 0.0), (0.01, 0.01, 0.01), 0.001), 3)
    for call, message in (
        (lambda: g.update_flat(0, [1000], []), r"flat cell indices must be 0\.\.999, got 1000\.\.1000"),
        (lambda: g.read_flat(0, [-1]), r"flat cell indices must be 0\.\.999"),
        (lambda: g.read_flat(0, [0.5]), "must be integers"),
        (lambda: g.update_flat(7, [0], []), r"map_index must be 0\.\.2, got 7"),
        (lambda: g.update_flat(-1, [], [7]), r"map_index must be 0\.\.2, got -1"),
        (lambda: g.resample([0, -1, 0]), r"ancestors must be map indices 0\.\.2"),
        (lambda: g.resample([0, 1, 5]), r"ancestors must be map indices 0\.\.2"),
        (lambda: g.to_sparse(9), r"map_index must be 0\.\.2, got 9"),
        (lambda: g.weighted(np.array([1.0])), "weights must be 3 finite non-negative numbers"),
        (lambda: g.weighted(np.array([np.nan, 0.5, 0.5])), "finite non-negative"),
        (lambda: g.weighted(np.array([1.0, 1.0, 0.0])), "must sum to 1, got 2.0"),
    ):
        with pytest.raises(ValueError, match=message):
            call()
    assert g.to_sparse(2).flat.size == 0  # nothing was written into any map
    g.update_flat(2, [], [7])
    np.testing.assert_array_equal(g.read_flat(2, [7, 8]), np.float32([L_OCC, 0.0]))
    assert g.weighted(np.array([0.0, 0.0, 1.0])).flat.tolist() == [7]


def test_a_long_vector_in_a_message_is_shown_in_part() -> None:
    from palpate.nodes.mapper.grid import shown

    assert shown(np.array([0.5, 0.5])) == "[0.5, 0.5]"
    assert shown(np.full(300, 0.01)) == "[0.01, 0.01, 0.01, 0.01, 0.01, ...] (300 values, sum 3)"


@pytest.mark.parametrize("resolution_m", [5e-324, 1e-21])
def test_a_resolution_too_fine_for_int64_cell_indices_is_refused_by_name(resolution_m: float) -> None:
    """5e-324 m overflowed the cell counts to negative numbers ("shape must be 3 positive cell counts");
    1e-21 m over 9 cm gives 9e19 cells per axis."""
    with pytest.raises(ConfigError, match=r"resolution_m .* is too fine for the region .* more than 4.61e\+18"):
        GridSpec.from_bounds((-0.045,) * 3, (0.045,) * 3, resolution_m)
    assert GridSpec.from_bounds((-0.045,) * 3, (0.045,) * 3, 1e-6).shape == (90_000,) * 3  # 7.3e14 cells: sparse


def test_a_shape_of_non_integers_or_beyond_32_bit_coordinates_is_refused() -> None:
    """An outside audit: shape (2.7, 3, 3) was taken (18 cells), and an axis of 3e9 cells wrote to the wrong
    cell (its coordinates are int32)."""
    with pytest.raises(ConfigError, match=r"shape must be 3 positive integer cell counts, got \(2.7, 3, 3\)"):
        GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=1.0, shape=(2.7, 3, 3))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"more than 2,147,483,647 cells along an axis"):
        GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=1.0, shape=(3_000_000_000, 1, 1))
    with pytest.raises(ConfigError, match=r"3e\+09 x 1 x 1 cells, .* or more than 2.15e\+09 along an axis"):
        GridSpec.from_bounds((0.0, 0.0, 0.0), (3e9, 1.0, 1.0), 1.0)
    assert GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=1.0, shape=(np.int64(2), 3, 3)).shape[0] == 2
