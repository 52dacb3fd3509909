"""FastSLAM: weights, resampling, likelihood and the numerical extremes of issue 4, item 6."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest

from palpate.nodes.mapper.core import Mapper, MapperConfig
from palpate.nodes.mapper.fastslam import (
    cell_scores,
    normalise_log_weights,
    observation_log_likelihood,
    systematic_resample,
)
from palpate.nodes.mapper.grid import LogOddsGrids
from palpate.nodes.mapper.kinematics import KinematicChain
from palpate.nodes.mapper.observation import observation_keys
from tests.unit.mapper.synthetic import CUBE_CENTER_M, CUBE_HALF_M, TappingRecord, simulate_tapping


@pytest.fixture(scope="module")
def scene() -> tuple[KinematicChain, TappingRecord]:
    return simulate_tapping(0.8)  # 80 updates, finger tapping the cube


def _config(**changes: object) -> MapperConfig:
    c = np.asarray(CUBE_CENTER_M)
    lo = c - CUBE_HALF_M - np.array([0.05, 0.03, 0.03])
    hi = c + CUBE_HALF_M + np.array([0.03, 0.03, 0.06])
    base = MapperConfig(region_min_m=(lo[0], lo[1], lo[2]), region_max_m=(hi[0], hi[1], hi[2]), resolution_m=0.004)
    return replace(base, **changes)  # type: ignore[arg-type]


def _feed(mapper: Mapper, rec: TappingRecord, q: np.ndarray) -> Iterator[None]:
    for t in range(len(q)):
        mapper.update(q[t], rec.contact_links[t], rec.contact_local_m[t])
        yield


def _noisy(rec: TappingRecord, sigma_deg: float, seed: int) -> np.ndarray:
    return rec.q_true + np.radians(sigma_deg) * np.random.default_rng(seed).standard_normal(rec.q_true.shape)


# --- weights ---------------------------------------------------------------------------------------
def test_log_weights_far_below_underflow_normalise_without_nan() -> None:
    lw, n_eff = normalise_log_weights(np.full(5, -1e6))  # exp(-1e6) == 0.0 in float64
    np.testing.assert_allclose(np.exp(lw), 0.2, rtol=1e-12)
    assert n_eff == pytest.approx(5.0)
    lw, n_eff = normalise_log_weights(np.array([-1e6, -1e6 - math.log(3.0), -2e6]))
    # the input -1e6 - log 3 itself is only resolved to 1.2e-10
    np.testing.assert_allclose(np.exp(lw), [0.75, 0.25, 0.0], rtol=1e-9, atol=1e-300)
    assert n_eff == pytest.approx(1.0 / (0.75**2 + 0.25**2))
    lw, n_eff = normalise_log_weights(np.array([-np.inf, -1e300, -np.inf]))
    np.testing.assert_allclose(np.exp(lw), [0.0, 1.0, 0.0])
    assert n_eff == pytest.approx(1.0)
    lw, n_eff = normalise_log_weights(np.array([-np.inf, np.nan]))  # nothing usable: uniform
    np.testing.assert_allclose(np.exp(lw), [0.5, 0.5])
    lw, n_eff = normalise_log_weights(np.full(4, -np.inf))  # every linear weight underflowed to 0
    np.testing.assert_allclose(np.exp(lw), 0.25, rtol=1e-12)
    assert n_eff == pytest.approx(4.0)


def test_systematic_resampling_counts_follow_the_weights() -> None:
    rng = np.random.default_rng(0)
    for K in (1, 7, 100):
        for _ in range(50):
            w = rng.dirichlet(np.full(K, 0.3))
            anc = systematic_resample(w, rng)
            counts = np.bincount(anc, minlength=K)
            assert counts.sum() == K and np.all(np.diff(anc) >= 0)
            # low-variance property: each particle gets floor(K w) or ceil(K w) copies
            assert np.all(counts >= np.floor(K * w) - 1e-9) and np.all(counts <= np.ceil(K * w) + 1e-9)


def test_systematic_resampling_is_unbiased() -> None:
    rng = np.random.default_rng(1)
    w = np.array([0.05, 0.15, 0.3, 0.5])
    counts = sum(np.bincount(systematic_resample(w, rng), minlength=4) for _ in range(4000))
    np.testing.assert_allclose(counts / (4 * 4000), w, atol=0.01)


# --- likelihood ------------------------------------------------------------------------------------
def test_cell_scores_match_the_definition() -> None:
    l = np.linspace(-10, 10, 41).astype(np.float32)
    p = 1.0 - 1.0 / (1.0 + np.exp(l.astype(np.float64)))
    for floor in (0.05, 1e-3):
        occ = np.log(np.maximum(p, floor) / 0.5)
        free = np.log(np.maximum(1 - p, floor) / 0.5)
        np.testing.assert_allclose(cell_scores(l, True, floor), occ, atol=2e-6)
        np.testing.assert_allclose(cell_scores(l, False, floor), free, atol=2e-6)
    assert cell_scores(np.zeros(3, np.float32), True, 0.05).tolist() == [0.0, 0.0, 0.0]


def test_likelihood_prefers_the_pose_that_agrees_with_the_map(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    mapper = Mapper(_config(mode="known"), chain, np.random.default_rng(0))
    for _ in _feed(mapper, rec, rec.q_true):
        pass
    # two maps, both the known-pose map; pose 0 true, pose 1 off by 4 deg in MCP flexion
    g = LogOddsGrids(mapper.spec, 2, chunk_edge=8)
    t = next(i for i in range(len(rec.q_true) - 1, 0, -1) if len(rec.contact_links[i]))
    flat = mapper.best_map()
    g.update_flat(0, free_flat=flat.flat[flat.log_odds < 0], occ_flat=flat.flat[flat.log_odds > 0])
    g.resample(np.array([0, 0]))
    q = np.repeat(rec.q_true[t][None], 2, axis=0)
    q[1, 1] += math.radians(4.0)
    rots, pos = chain.forward(q)
    free_h = mapper.free_volume.homogeneous()
    free, occ = observation_keys(g, rots, pos, free_h, rec.contact_links[t], rec.contact_local_m[t])
    ll = observation_log_likelihood(g.observe(free, occ), floor=0.05)
    assert ll[0] > ll[1] + 1.0


# --- extremes of issue 4, item 6 ---------------------------------------------------------------------
@pytest.mark.parametrize("K", [1, 7])
def test_sigma_zero_gives_the_known_pose_map_bit_for_bit(scene: tuple[KinematicChain, TappingRecord], K: int) -> None:
    chain, rec = scene
    q = _noisy(rec, 1.5, seed=3)  # any angles: both mappers get the same stream
    known = Mapper(_config(mode="known"), chain, np.random.default_rng(0))
    slam = Mapper(_config(mode="fastslam", n_particles=K, sigma_deg=0.0), chain, np.random.default_rng(1))
    for _ in zip(_feed(known, rec, q), _feed(slam, rec, q), strict=True):
        pass
    ref = known.best_map()
    assert len(ref.flat) > 100
    for k in range(K):
        m = slam.grids.to_sparse(k)
        np.testing.assert_array_equal(m.flat, ref.flat)
        np.testing.assert_array_equal(m.log_odds, ref.log_odds)
    np.testing.assert_array_equal(slam.best_map().log_odds, ref.log_odds)
    np.testing.assert_array_equal(slam.pose_estimate().best_q_rad, q[-1])


def test_sigma_ten_degrees_runs_and_keeps_weights_normalised(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    slam = Mapper(_config(n_particles=20, sigma_deg=10.0), chain, np.random.default_rng(2))
    assert slam.filter is not None
    for _ in _feed(slam, rec, _noisy(rec, 10.0, seed=4)):
        w = slam.filter.weights
        assert np.all(np.isfinite(slam.filter.log_weights))
        assert w.sum() == pytest.approx(1.0, abs=1e-12)
        assert 1.0 - 1e-9 <= slam.n_eff <= 20 + 1e-9
    m = slam.weighted_map()
    assert np.all(np.isfinite(m.log_odds)) and np.all(np.abs(m.log_odds) <= 10.0 + 1e-5)
    assert np.all(np.isfinite(slam.pose_estimate().mean_q_rad))


def test_one_particle(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    slam = Mapper(_config(n_particles=1), chain, np.random.default_rng(5))
    for _ in _feed(slam, rec, _noisy(rec, 1.5, seed=6)):
        assert slam.n_eff == 1.0
    assert slam.counters.resamples == 0
    assert slam.filter is not None and slam.filter.log_weights.tolist() == [0.0]
    np.testing.assert_array_equal(slam.weighted_map().flat, slam.best_map().flat)


@pytest.mark.parametrize(
    "start",
    [-1e6 - np.arange(10.0), np.full(10, -np.inf)],  # every exp() underflows to 0; every log is -inf
    ids=["minus_1e6", "minus_inf"],
)
def test_weights_below_underflow_inside_the_filter(
    scene: tuple[KinematicChain, TappingRecord], start: np.ndarray
) -> None:
    chain, rec = scene
    slam = Mapper(_config(n_particles=10, resample_threshold=0.0), chain, np.random.default_rng(7))
    assert slam.filter is not None
    slam.filter.log_weights = start.copy()
    for _ in _feed(slam, rec, _noisy(rec, 1.5, seed=8)):
        assert np.all(np.isfinite(slam.filter.log_weights))
        assert slam.filter.weights.sum() == pytest.approx(1.0, abs=1e-12)
        assert 1.0 - 1e-9 <= slam.n_eff <= 10 + 1e-9
    assert np.all(np.isfinite(slam.pose_estimate().mean_q_rad))
    assert np.all(np.isfinite(slam.weighted_map().log_odds))


def test_resampling_only_below_the_threshold(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    never = Mapper(_config(n_particles=10, resample_threshold=0.0), chain, np.random.default_rng(9))
    always = Mapper(_config(n_particles=10, resample_threshold=1.0), chain, np.random.default_rng(9))
    q = _noisy(rec, 1.5, seed=10)
    for _ in zip(_feed(never, rec, q), _feed(always, rec, q), strict=True):
        pass
    assert never.counters.resamples == 0
    assert always.counters.resamples > len(q) // 2
    assert always.grids.chunk_copies > 0


def test_same_seed_same_result(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    q = _noisy(rec, 1.5, seed=11)
    a = Mapper(_config(n_particles=8), chain, np.random.default_rng(12))
    b = Mapper(_config(n_particles=8), chain, np.random.default_rng(12))
    for _ in zip(_feed(a, rec, q), _feed(b, rec, q), strict=True):
        pass
    assert a.filter is not None and b.filter is not None
    np.testing.assert_array_equal(a.filter.log_weights, b.filter.log_weights)
    np.testing.assert_array_equal(a.weighted_map().log_odds, b.weighted_map().log_odds)


def test_weights_at_their_extremes() -> None:
    lw, n_eff = normalise_log_weights(np.array([np.inf, 0.0, 1.0, np.inf]))  # +inf: the likeliest
    np.testing.assert_array_equal(np.exp(lw), [0.5, 0.0, 0.0, 0.5])
    assert n_eff == 2.0
    with pytest.raises(ValueError, match="at least one particle"):
        normalise_log_weights(np.array([]))
    rng = np.random.default_rng(0)
    for bad in ([np.nan, 1.0, 1.0, 1.0], [-1.0, 1.0, 1.0, 1.0], [0.0, 0.0], []):
        with pytest.raises(ValueError, match="finite, non-negative and not all zero"):
            systematic_resample(np.array(bad), rng)
