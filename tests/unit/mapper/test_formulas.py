"""Hand-computed values for the mapper's formulas: cell geometry at the region's edges, the particle
likelihood, the filter's bookkeeping, the free-volume lattice and the map metrics on a grid whose
faces lie on cell boundaries (every distance a dyadic number, so the boundary cases are exact)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from palpate.errors import ConfigError
from palpate.nodes.mapper.fastslam import FastSlam, normalise_log_weights, observation_log_likelihood
from palpate.nodes.mapper.grid import L_OCC, GridSpec, LogOddsGrids, Observed, SparseMap
from palpate.nodes.mapper.kinematics import KinematicChain
from palpate.nodes.mapper.metrics import box_sdf, surface_band, surface_distances_mm
from palpate.nodes.mapper.observation import capsule_lattice, observation_keys
from tests.unit.mapper.synthetic import FINGER_JOINTS, finger_box_mjcf

# dyadic grid: cells of 0.25 m from -2 m, so centres lie at +-0.125, +-0.375, ... exactly
DYADIC = GridSpec(origin_m=(-2.0, -2.0, -2.0), resolution_m=0.25, shape=(16, 16, 16))
ONE_LINK_XML = """<mujoco><worldbody><body name="link"><joint name="j" axis="1 0 0"/>
<geom type="capsule" fromto="0 0 0 0 0 1" size="0.375"/></body></worldbody></mujoco>"""


def _finger() -> KinematicChain:
    return KinematicChain.from_model(mujoco.MjModel.from_xml_string(finger_box_mjcf()), FINGER_JOINTS)


# --- grid geometry ---------------------------------------------------------------------------------
def test_cell_centres_are_half_a_cell_inside_their_cells() -> None:
    spec = GridSpec(origin_m=(-1.0, 0.5, 2.0), resolution_m=0.25, shape=(2, 3, 4))
    # flat = (i * ny + j) * nz + k: 0 = (0, 0, 0), 23 = (1, 2, 3), 7 = (0, 1, 3)
    np.testing.assert_allclose(
        spec.centers(np.array([0, 23, 7])),
        [[-0.875, 0.625, 2.125], [-0.625, 1.125, 2.875], [-0.875, 0.875, 2.875]],
        atol=1e-15,
    )
    inside, flat = spec.flat_of_points(spec.centers(np.arange(24)))
    assert inside.all() and flat.tolist() == list(range(24))


def test_the_upper_faces_of_the_region_are_outside() -> None:
    spec = GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=0.25, shape=(2, 3, 4))
    # cells cover [i, i + 1) * resolution: x = 2 * 0.25 = 0.5 is the first point past the last cell
    pts = np.array([[0.5, 0.1, 0.1], [0.1, 0.75, 0.1], [0.1, 0.1, 1.0], [0.4999, 0.7499, 0.9999]])
    inside, flat = spec.flat_of_points(pts)
    assert inside.tolist() == [False, False, False, True]
    assert flat.tolist() == [23]
    # the same in cell coordinates through cell_keys: f = n on an axis is outside, f = n - 1e-3 inside
    g = LogOddsGrids(spec, 1)
    f = np.array([[[2.0, 0.5, 0.5, 1.999], [0.5, 3.0, 0.5, 2.999], [0.5, 0.5, 4.0, 3.999]]], dtype=np.float32)
    keys = g.cell_keys(f)
    assert keys.valid is not None and keys.valid.tolist() == [[False, False, False, True]]
    assert keys.n_outside == 3
    g.observe(g.cell_keys(np.zeros((1, 3, 0), dtype=np.float32)), keys)
    # only cell (1, 2, 3) = 23 took the contact; the clamped cells (1, 0, 0), (0, 2, 0), (0, 0, 3) did not
    np.testing.assert_allclose(g.to_dense(0).ravel(), np.where(np.arange(24) == 23, L_OCC, 0.0), rtol=1e-6)


# --- likelihood and filter -------------------------------------------------------------------------
def _softplus(x: float) -> float:
    return math.log1p(math.exp(x))


def test_likelihood_weighs_free_cells_and_drops_the_reward_on_request() -> None:
    # one particle; free cells at l = 2 and l = -2, contact cell at l = 1, a second free cell at l = -2
    # not counted (a duplicate): score = log(max(1 - p, floor) / 0.5) = log 2 - softplus(l) for a free cell,
    # log 2 - softplus(-l) for a contact cell (floor 0.01 inactive: all |score| < -log(2 * 0.01))
    obs = Observed(
        prior_free=np.array([[2.0, -2.0, -2.0]], np.float32),
        prior_occ=np.array([[1.0]], np.float32),
        counted_free=np.array([[True, True, False]]),
        counted_occ=np.array([[True]]),
    )
    free_hit = math.log(2) - _softplus(2.0)  # -1.4338: the finger where the map believes occupied
    free_clear = math.log(2) - _softplus(-2.0)  # +0.5662: the finger in known free space
    occ = math.log(2) - _softplus(-1.0)  # +0.3799
    ll = observation_log_likelihood(obs, 0.01, free_weight=0.5, free_reward=True)
    np.testing.assert_allclose(ll, [0.5 * (free_hit + free_clear) + occ], atol=1e-5)
    ll = observation_log_likelihood(obs, 0.01, free_weight=0.5, free_reward=False)  # min(0, score)
    np.testing.assert_allclose(ll, [0.5 * free_hit + occ], atol=1e-5)
    ll = observation_log_likelihood(obs, 0.01, free_weight=2.0, free_reward=False)
    np.testing.assert_allclose(ll, [2.0 * free_hit + occ], atol=1e-5)


def test_normalising_keeps_small_differences_next_to_a_tiny_weight() -> None:
    # a particle 1e12 below the others must not swallow their difference: shifted by the largest
    # log-weight the two leaders keep 0.1234567 apart to 1e-16; the weights are their softmax
    lw, n_eff = normalise_log_weights(np.array([0.0, 0.1234567, -1e12]))
    w1 = 1.0 / (1.0 + math.exp(-0.1234567))
    np.testing.assert_allclose(np.exp(lw), [1.0 - w1, w1, 0.0], rtol=1e-12, atol=0.0)
    assert n_eff == pytest.approx(1.0 / ((1.0 - w1) ** 2 + w1**2), rel=1e-12)


def _silent_filter(K: int, sigma_rad: float | np.ndarray, threshold: float, seed: int) -> FastSlam:
    """A filter whose grid lies far from the finger: no cell observed, every likelihood 0."""
    chain = _finger()
    spec = GridSpec(origin_m=(5.0, 5.0, 5.0), resolution_m=0.01, shape=(4, 4, 4))
    return FastSlam(
        chain=chain,
        grids=LogOddsGrids(spec, K),
        free_volume=capsule_lattice(chain, 0.004, 0.002),
        sigma_rad=sigma_rad,
        rng=np.random.default_rng(seed),
        resample_threshold=threshold,
    )


def test_the_best_particle_survives_resampling_at_its_new_index() -> None:
    K, sigma, seed = 10, 0.05, 3
    fs = _silent_filter(K, sigma, 1.0, seed)
    # particle 1 is the best; particle 0 (w 0.30, floor(K w) = 3 copies) fills ancestors 0..2, so the
    # best's copies start at index 3 or later and index 1 becomes a copy of particle 0
    w = np.array([0.30, 0.31] + [0.39 / 8] * 8)
    fs.log_weights = np.log(w)
    q_noisy = np.radians([5.0, 20.0, 10.0, 5.0])
    q_proposed = q_noisy + sigma * np.random.default_rng(seed).standard_normal((K, 4))  # the filter's draw
    stats = fs.update(q_noisy, np.zeros(0, np.intp), np.zeros((0, 3)))
    assert stats.resampled
    np.testing.assert_allclose(fs.weights, 0.1, rtol=1e-12)
    np.testing.assert_array_equal(fs.best_q(), q_proposed[1])


def test_the_proposal_draws_each_joint_with_its_own_sigma() -> None:
    """A glove's joint sensors differ in noise: per_joint_sigma_deg gives each joint its own proposal."""
    K, seed = 200, 4
    sigma = np.radians([0.0, 1.5, 3.0, 1.5])
    fs = _silent_filter(K, sigma, 0.0, seed)
    q_noisy = np.radians([5.0, 20.0, 10.0, 5.0])
    fs.update(q_noisy, np.zeros(0, np.intp), np.zeros((0, 3)))
    expected = q_noisy + sigma * np.random.default_rng(seed).standard_normal((K, 4))
    np.testing.assert_array_equal(fs.q, expected)
    assert np.all(fs.q[:, 0] == q_noisy[0]) and fs.q[:, 2].std() > 1.5 * fs.q[:, 1].std()
    with pytest.raises(ConfigError, match="sigma must be finite and >= 0"):
        _silent_filter(K, np.radians([0.0, -1.0, 1.0, 1.0]), 0.0, seed)


def test_a_per_joint_sigma_of_a_joint_the_finger_lacks_is_refused() -> None:
    from palpate.nodes.mapper.core import MapperConfig, check_fits

    region = {"region_min_m": (-0.045, -0.045, -0.045), "region_max_m": (0.045, 0.045, 0.045)}
    chain = _finger()
    check_fits(MapperConfig(**region, per_joint_sigma_deg={chain.joint_names[2]: 3.0}), chain)
    with pytest.raises(ConfigError, match=r"names joint\(s\) \['thumb_ip'\] that the mapper's finger lacks") as info:
        check_fits(MapperConfig(**region, per_joint_sigma_deg={"thumb_ip": 3.0}), chain)
    assert info.value.path == ("per_joint_sigma_deg",)


def test_resampling_waits_until_the_effective_size_is_below_the_threshold() -> None:
    fs = _silent_filter(2, 0.0, 0.5, 0)
    fs.log_weights = np.array([0.0, -np.inf])  # one particle holds all weight: N_eff = 1 = 0.5 * K
    stats = fs.update(np.zeros(4), np.zeros(0, np.intp), np.zeros((0, 3)))
    assert stats.n_eff == 1.0 and not stats.resampled and fs.n_resamples == 0
    np.testing.assert_array_equal(fs.weights, [1.0, 0.0])


# --- free volume -----------------------------------------------------------------------------------
def test_capsule_lattice_fills_the_shrunk_capsule_including_its_caps() -> None:
    chain = KinematicChain.from_model(mujoco.MjModel.from_xml_string(ONE_LINK_XML), ["j"])
    # capsule of length 1 and radius 0.375 shrunk by 0.125: r = 0.25 = 2 lattice steps of 0.125.
    # In steps, the cylinder holds 9 planes (z = 0 .. 1) of the 13 nodes with u^2 + v^2 <= 4, and each cap
    # 9 nodes (u^2 + v^2 <= 3) one step out plus its tip (0, 0) two steps out: 9 * 13 + 2 * 10 = 137
    pts = capsule_lattice(chain, 0.125, 0.125).local_m[0]
    assert len(pts) == 137
    np.testing.assert_allclose(pts.min(axis=0), [-0.25, -0.25, -0.25], atol=1e-12)
    np.testing.assert_allclose(pts.max(axis=0), [0.25, 0.25, 1.25], atol=1e-12)


def test_culled_links_are_only_those_wholly_outside_the_region() -> None:
    chain = _finger()
    fv = capsule_lattice(chain, 0.002, 0.002)
    q = np.radians([[20.0, 0.0, 0.0, 0.0], [-20.0, 40.0, 30.0, 20.0]])
    rots, pos = chain.forward(q)
    world = [np.concatenate([p @ rots[k, l].T + pos[k, l] for l, p in enumerate(fv.local_m)]) for k in range(2)]
    total = sum(len(w) for w in world)
    # a slab of the region 12 mm thick slides along the finger: part of a link is often inside
    for x0 in np.arange(-0.03, 0.09, 0.0037):
        spec = GridSpec(origin_m=(float(x0), -0.03, 0.0), resolution_m=0.003, shape=(4, 20, 20))
        free, _ = observation_keys(
            LogOddsGrids(spec, 2), rots, pos, fv.homogeneous(), np.zeros(0, np.intp), np.zeros((0, 3))
        )
        got = free.key.shape[1] * np.ones(2, np.int64) if free.valid is None else free.valid.sum(axis=1)
        expected = [int(spec.flat_of_points(w)[0].sum()) for w in world]  # every point tested, none culled
        assert got.tolist() == expected, f"slab at x = {x0:.4f} m"
        assert free.n_outside == total - sum(expected)


# --- metrics ---------------------------------------------------------------------------------------
def _unit_box(p: np.ndarray) -> np.ndarray:
    return box_sdf(p, np.zeros(3), np.ones(3))  # faces at +-1 m, on cell boundaries of DYADIC


def test_band_and_truth_on_faces_aligned_with_the_grid() -> None:
    # h = 0.125. Cells just outside a face have d = h exactly (truth: they hold the face, cells being
    # [i, i + 1)); cells just inside have d = -h (excluded: -h < d). With band 0.25, d <= 0.375 keeps
    # faces at d = 0.125 and 0.375 (6 faces x 64 cells x 2 layers = 768), edges at 0.125 sqrt 2
    # (12 x 8 = 96) and corners at 0.125 sqrt 3 (8): 872 cells; the truth is the 384 face cells at d = h
    region, truth = surface_band(DYADIC, _unit_box, band_m=0.25)
    d = _unit_box(DYADIC.centers(region))
    assert len(region) == 872 and int(truth.sum()) == 384
    np.testing.assert_allclose(d[truth], 0.125, atol=1e-15)
    assert d.min() == pytest.approx(0.125)


def test_surface_distances_by_hand() -> None:
    spec = DYADIC
    _, flat = spec.flat_of_points(np.array([[0.875, 0.125, 0.125], [1.125, 0.125, 0.125], [-0.125, 0.125, 0.125]]))
    # occupied: a cell 0.125 inside the face x = 1 and one 0.125 outside it; the third (l < 0) is free
    m = SparseMap(spec=spec, flat=np.sort(flat), log_odds=np.array([-2.0, 2.0, 2.0], np.float32))
    assert m.flat.tolist() == sorted(flat.tolist()) and flat[2] < flat[0] < flat[1]
    surface = np.array([[1.0, 0.125, 0.125], [1.0, 0.125, 1.125]])
    acc, comp = surface_distances_mm(m, _unit_box, surface)
    # accuracy: mean |d| = (|-0.125| + 0.125) / 2 = 0.125 m; completeness: distances 0.125 and
    # hypot(0.125, 1) to the nearest occupied centre, mean in mm
    assert acc == pytest.approx(125.0)
    assert comp == pytest.approx((125.0 + 1e3 * math.hypot(0.125, 1.0)) / 2)
