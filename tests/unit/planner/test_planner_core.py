"""Planner: IGEF terms against a slow per-candidate reference, strategies, edge cases."""

from __future__ import annotations

import time

import numpy as np
import pytest

from palpate.errors import ConfigError, PlanningError
from palpate.geometry.bezier import approach_curve, bezier_length, bezier_point
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.core import Planner, sample_candidates
from palpate.nodes.planner.scores import igef_terms

RNG_SEED = 5


def plane_patch(step: float = 0.005, radius: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Grid points on the plane z = 0 within ``radius`` of the origin, normals +z."""
    g = np.arange(-radius, radius + 1e-12, step)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    pts = pts[np.linalg.norm(pts, axis=1) <= radius + 1e-12]
    return pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1))


def slow_igef(
    S: np.ndarray, N: np.ndarray, C: np.ndarray, r: np.ndarray, v_n: np.ndarray, R_z: np.ndarray, cfg: PlannerConfig
) -> np.ndarray:
    """Algorithm 2 written out per candidate and per contact, Psi2 by a fine polyline."""
    out = np.zeros((len(S), 4))
    taus = np.linspace(0.0, 1.0, 40_001)
    for i, (s, s_n) in enumerate(zip(S, N, strict=True)):
        psi1 = min(1 - np.exp(-np.sum((s - c) ** 2) / cfg.sigma1_m**2) for c in C)  # Eq. 7
        d = np.linalg.norm(r - s)
        beta = d * cfg.psi2_control_scale
        P = np.array([r, r - v_n * beta, s + s_n * beta, s])
        length = np.sum(np.linalg.norm(np.diff(bezier_point(P, taus), axis=0), axis=1))
        psi2 = 1 / max(length, cfg.min_path_m)  # Eqs. 8-9
        psi3 = sum(np.exp(-((np.linalg.norm(s - c) - cfg.mu3_m) ** 2) / cfg.sigma3_m**2) for c in C)  # Eq. 10
        alpha = np.arccos(np.clip(R_z @ -s_n, -1, 1))  # rotation needed to poke along -s_n
        psi4 = np.exp(-2 * np.sin(alpha / 2) ** 2 / cfg.sigma_alpha**2)  # Eq. 11
        out[i] = psi1, psi2, psi3, psi4
    return out


def test_defaults_are_the_papers() -> None:
    cfg = PlannerConfig()
    assert (cfg.sigma1_m, cfg.mu3_m, cfg.sigma3_m, cfg.sigma_alpha) == (0.02, 0.02, 0.02, 1.0)
    assert (cfg.candidate_step_m, cfg.candidate_radius_m, cfg.gpv_radius_m) == (0.005, 0.05, 0.06)
    assert cfg.radius_m == 0.05 and PlannerConfig(strategy="gpv").radius_m == 0.06
    with pytest.raises(ConfigError, match="strategy"):
        PlannerConfig(strategy="greedy")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="sigma1_m"):
        PlannerConfig(sigma1_m=-1.0)


@pytest.mark.parametrize("scale", [1.0 / 3.0, 1.0])
def test_igef_terms_match_the_slow_reference(scale: float) -> None:
    rng = np.random.default_rng(RNG_SEED)
    S = rng.normal(scale=0.02, size=(12, 3))
    N = rng.normal(size=(12, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    C = rng.normal(scale=0.02, size=(5, 3))
    r = C[-1] + np.array([0.0, 0.0, 0.004])
    v_n = np.array([0.0, 0.6, -0.8])
    R_z = np.array([0.0, 0.0, -1.0])
    cfg = PlannerConfig(psi2_control_scale=scale)
    fast = igef_terms(S, N, C, r, v_n, R_z, cfg)
    slow = slow_igef(S, N, C, r, v_n, R_z, cfg)
    np.testing.assert_allclose(fast[:, [0, 2, 3]], slow[:, [0, 2, 3]], rtol=1e-10)
    # Psi2: quadrature against a 40k-segment polyline; random normals make loops and near-cusps.
    np.testing.assert_allclose(fast[:, 1], slow[:, 1], rtol=1e-4)


def test_igef_contact_terms_read_only_the_contacts_in_reach_above_the_threshold(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An outside audit: Psi3's dense distances made each plan cost O(contacts) (45-205 ms at 10,000). Above
    NEAR_CONTACTS_ABOVE only contacts within reach count: the same Psi1 and Psi3 to 1e-12, whether the far
    contacts are many, or every contact is far (a candidate's Psi1 from all of them)."""
    from palpate.nodes.planner import scores

    rng = np.random.default_rng(RNG_SEED)
    S = rng.normal(scale=0.02, size=(40, 3))
    near = rng.normal(scale=0.03, size=(30, 3))
    far = rng.uniform(-1.0, 1.0, size=(500, 3)) + np.array([3.0, 0.0, 0.0])  # 2-4 m off: beyond all reach
    cfgs = [PlannerConfig(), PlannerConfig(sigma1_m=5.0)]  # Psi1 from far contacts matters with a wide sigma1
    read: list[int] = []  # contacts in each distance matrix
    real_cdist = scores.cdist

    def counting_cdist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        read.append(len(b))
        return real_cdist(a, b)

    monkeypatch.setattr(scores, "cdist", counting_cdist)
    for C in (np.vstack([near, far]), far):
        dense = [scores.contact_terms(S, C, cfg) for cfg in cfgs]
        assert read == [len(C), len(C)]
        read.clear()
        monkeypatch.setattr(scores, "NEAR_CONTACTS_ABOVE", 10)
        for cfg, (psi1, psi3) in zip(cfgs, dense, strict=True):
            fast1, fast3 = scores.contact_terms(S, C, cfg)
            np.testing.assert_allclose(fast1, psi1, rtol=1e-12)
            np.testing.assert_allclose(fast3, psi3, rtol=1e-12, atol=1e-300)
        # only the contacts in reach: the 30 near ones; with none in reach, one, then all for Psi1 alone
        assert read == ([len(near)] * 2 if len(C) > len(far) else [1, len(far)] * 2), read
        read.clear()
        monkeypatch.setattr(scores, "NEAR_CONTACTS_ABOVE", 2000)


def test_psi2_uses_the_executed_eq15_curve_by_default() -> None:
    s = np.array([[0.02, 0.01, 0.0]])
    n = np.array([[0.0, 0.0, 1.0]])
    r, v_n = np.zeros(3), np.array([0.0, 0.0, -1.0])
    psi = igef_terms(s, n, np.zeros((1, 3)), r, v_n, np.array([0.0, 0.0, -1.0]), PlannerConfig())
    assert psi[0, 1] == pytest.approx(1 / float(bezier_length(approach_curve(r, v_n, s[0], n[0]))), rel=1e-12)


def test_psi4_prefers_no_rotation() -> None:
    cfg = PlannerConfig()
    s = np.zeros((3, 3))
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    psi4 = igef_terms(s, normals, np.ones((1, 3)), np.ones(3), np.zeros(3), np.array([0, 0, -1.0]), cfg)[:, 3]
    np.testing.assert_allclose(psi4, [1.0, np.exp(-1.0), np.exp(-2.0)], rtol=1e-12)


def test_psi4_divides_by_sigma_alpha_squared() -> None:
    # Eq. 11 with sigma_alpha = 0.5: exp(-2 sin^2(alpha / 2) / 0.25) = exp(-4 (1 - cos alpha)):
    # 1 facing the target, exp(-4) a quarter turn away, exp(-8) a half turn away
    cfg = PlannerConfig(sigma_alpha=0.5)
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    psi4 = igef_terms(np.zeros((3, 3)), normals, np.ones((1, 3)), np.ones(3), np.zeros(3), np.array([0, 0, -1.0]), cfg)
    np.testing.assert_allclose(psi4[:, 3], [1.0, np.exp(-4.0), np.exp(-8.0)], rtol=1e-12)


def test_igef_picks_a_local_target_and_gpv_the_far_edge() -> None:
    """Fig. 4: after two contacts on a plane, IGEF stays near, GP-V goes to the 6 cm border."""
    S, N = plane_patch(radius=0.07)
    C = np.array([[-0.01, 0.0, 0.0], [0.0, 0.0, 0.0]])
    variance = 1 - np.exp(-(np.min(np.linalg.norm(S[:, None] - C[None], axis=2), axis=1) ** 2) / 0.03**2)
    args = (S, N, variance, C, C[-1], np.array([0, 0, -1.0]), np.array([0, 0, -1.0]))
    rng = np.random.default_rng(RNG_SEED)
    igef = Planner(PlannerConfig(strategy="igef")).select(*args, rng)
    gpv = Planner(PlannerConfig(strategy="gpv")).select(*args, rng)
    d_igef = np.linalg.norm(igef.target_m - C[-1])
    d_gpv = np.linalg.norm(gpv.target_m - C[-1])
    assert 0.005 <= d_igef <= 0.03
    assert 0.055 <= d_gpv <= 0.06 + 1e-12  # the border of GP-V's 6 cm: the 7 cm points are ignored
    assert igef.score == pytest.approx(igef.scores.max()) and igef.psi is not None
    assert igef.score == pytest.approx(np.prod(igef.psi[igef.index]))
    np.testing.assert_array_equal(igef.predicted_contact_m, igef.target_m)
    np.testing.assert_array_equal(igef.normal, [0.0, 0.0, 1.0])
    far = np.sum((S - C[-1]) ** 2, axis=1) > 0.05**2
    assert not igef.scores[far].any()  # outside IGEF's 5 cm: score 0
    assert gpv.score == pytest.approx(variance[np.linalg.norm(S - C[-1], axis=1) <= 0.06].max())


def test_random_is_uniform_over_candidates_in_range_and_seeded() -> None:
    S, N = plane_patch(step=0.02, radius=0.07)
    valid = np.flatnonzero(np.linalg.norm(S, axis=1) <= 0.05)
    planner = Planner(PlannerConfig(strategy="random"))
    args = (S, N, np.zeros(len(S)), np.zeros((1, 3)), np.zeros(3), np.zeros(3), np.array([0, 0, -1.0]))
    picks = [planner.select(*args, np.random.default_rng(i)).index for i in range(400)]
    assert set(picks) <= set(valid.tolist())
    counts = np.bincount(picks, minlength=len(S))[valid]
    expected = 400 / len(valid)
    assert counts.min() > 0 and np.abs(counts - expected).max() < 5 * np.sqrt(expected)
    first = planner.select(*args, np.random.default_rng(7)).index
    assert planner.select(*args, np.random.default_rng(7)).index == first


def test_no_candidate_is_a_clear_error() -> None:
    planner = Planner()
    C = np.zeros((1, 3))
    with pytest.raises(PlanningError, match="no candidate"):
        planner.select(
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            np.zeros(0),
            C,
            C[0],
            C[0],
            np.array([0, 0, -1.0]),
            np.random.default_rng(0),
        )
    far = np.array([[0.2, 0.0, 0.0]])
    with pytest.raises(PlanningError, match=r"candidate target within 0\.05 m"):
        planner.select(
            far, np.array([[0, 0, 1.0]]), np.ones(1), C, C[0], C[0], np.array([0, 0, -1.0]), np.random.default_rng(0)
        )
    with pytest.raises(PlanningError, match="at least one contact"):
        planner.select(
            far, np.array([[0, 0, 1.0]]), np.ones(1), np.zeros((0, 3)), C[0], C[0], C[0], np.random.default_rng(0)
        )
    with pytest.raises(PlanningError, match="zero length"):
        planner.select(
            far, np.zeros((1, 3)), np.ones(1), C, C[0], C[0], np.array([0, 0, -1.0]), np.random.default_rng(0)
        )


def test_arrays_of_the_wrong_shape_or_not_finite_are_refused_by_name() -> None:
    planner, rng = Planner(), np.random.default_rng(0)
    C, down = np.zeros((1, 3)), np.array([0, 0, -1.0])
    S, N = np.array([[0.01, 0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0, 0.0]])  # 4 columns
    with pytest.raises(PlanningError, match=r"candidates_m must have shape \(m, 3\)"):
        planner.select(S, N, np.ones(1), C, C[0], down, down, rng)
    S, N = np.array([[0.01, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(PlanningError, match="r must be a finite 3-vector"):
        planner.select(S, N, np.ones(1), C, np.array([np.nan, 0.0, 0.0]), down, down, rng)


def test_v_n_is_normalised_before_it_shapes_the_curve() -> None:
    S, N = plane_patch()
    C, down = np.zeros((1, 3)), np.array([0.0, 0.0, -1.0])
    planner = Planner(PlannerConfig(strategy="igef"))
    unit = planner.select(S, N, np.ones(len(S)), C, C[0], down, down, np.random.default_rng(0))
    longer = planner.select(S, N, np.ones(len(S)), C, C[0], 3.0 * down, down, np.random.default_rng(0))
    assert longer.index == unit.index
    np.testing.assert_array_equal(longer.scores, unit.scores)  # (0, 0, -3) / 3 is (0, 0, -1) exactly


def test_target_closer_than_the_fingertip_radius_is_finite() -> None:
    cfg = PlannerConfig()
    r = np.array([0.0, 0.0, 0.004])  # fingertip centre 4 mm above the last contact
    S = np.array([[0.0, 0.0, 0.004], [0.0, 0.0, 0.0039], [0.001, 0.0, 0.0], [0.01, 0.0, 0.0]])
    N = np.tile([0.0, 0.0, 1.0], (4, 1))
    psi = igef_terms(S, N, np.zeros((1, 3)), r, np.array([0, 0, -1.0]), np.array([0, 0, -1.0]), cfg)
    assert np.all(np.isfinite(psi))
    assert psi[0, 1] == pytest.approx(1 / cfg.min_path_m)  # zero-length path: Psi2 at its cap
    assert psi[:, 1].max() <= 1 / cfg.min_path_m
    sel = Planner(cfg).select(
        S, N, np.ones(4), np.zeros((1, 3)), r, np.array([0, 0, -1.0]), np.array([0, 0, -1.0]), np.random.default_rng(0)
    )
    assert np.all(np.isfinite(sel.scores))


def test_two_contacts_a_micrometre_apart() -> None:
    S, N = plane_patch()
    C = np.array([[0.0, 0.0, 0.0], [1e-6, 0.0, 0.0]])
    sel = Planner().select(
        S, N, np.ones(len(S)), C, C[-1], np.array([0, 0, -1.0]), np.array([0, 0, -1.0]), np.random.default_rng(0)
    )
    assert np.all(np.isfinite(sel.scores)) and sel.score > 0


def test_thousand_contacts_are_fast() -> None:
    rng = np.random.default_rng(RNG_SEED)
    S, N = plane_patch(step=0.0035)  # ~640 candidates
    C = np.column_stack([rng.uniform(-0.1, 0.1, size=(1000, 2)), np.zeros(1000)])
    C[-1] = 0.0
    planner = Planner()
    args = (S, N, np.ones(len(S)), C, C[-1], np.array([0, 0, -1.0]), np.array([0, 0, -1.0]), rng)
    elapsed = []
    for _ in range(3):  # best of 3: the machine is shared; vectorised this is ~30 ms, loops take seconds
        t0 = time.perf_counter()
        sel = planner.select(*args)
        elapsed.append(time.perf_counter() - t0)
    assert np.all(np.isfinite(sel.scores))
    assert min(elapsed) < 0.5, f"select with 1000 contacts took {min(elapsed):.3f} s"


@pytest.mark.parametrize("radius_m", [0.0025, 0.5])
def test_tiny_and_huge_objects(radius_m: float) -> None:
    """A 5 mm and a 1 m sphere: candidates sampled around the last contact give a finite choice."""
    rng = np.random.default_rng(RNG_SEED)
    x = rng.normal(size=(20_000, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    V = radius_m * x
    contacts = V[:3]
    cand = sample_candidates(V, x, rng.random(len(V)), contacts[-1])
    assert len(cand.indices) > 0
    R_z = -x[2]
    for strategy in ("igef", "gpv", "random"):
        sel = Planner(PlannerConfig(strategy=strategy)).select(
            cand.points_m, cand.normals, cand.variance, contacts, contacts[-1], R_z, R_z, rng
        )
        assert np.all(np.isfinite(sel.scores)) and np.isfinite(sel.score)
        assert np.linalg.norm(sel.target_m - contacts[-1]) <= 0.05 + 1e-12


def test_admissible_mask_excludes_candidates() -> None:
    S, N = plane_patch()
    args = (S, N, np.ones(len(S)), np.zeros((1, 3)), np.zeros(3), np.array([0, 0, -1.0]), np.array([0, 0, -1.0]))
    planner = Planner()
    best = planner.select(*args, np.random.default_rng(0)).index
    mask = np.ones(len(S), dtype=bool)
    mask[best] = False
    second = planner.select(*args, np.random.default_rng(0), admissible=mask)
    assert second.index != best and second.scores[best] == 0.0
    within = int((np.linalg.norm(S, axis=1) <= planner.config.radius_m).sum())
    with pytest.raises(PlanningError, match=f"{within} within it\\): the curve to every one of these runs through"):
        planner.select(*args, np.random.default_rng(0), admissible=np.zeros(len(S), dtype=bool))
    # candidates only beyond the radius (a few not admissible): no vertex near the contact is the reason
    far = (S + np.array([1.0, 0.0, 0.0]), N, *args[2:])
    some_out = np.arange(len(S)) < 3
    with pytest.raises(PlanningError, match="0 within it\\): the estimated surface's mesh has no vertex there"):
        planner.select(*far, np.random.default_rng(0), admissible=~some_out)
    with pytest.raises(PlanningError, match=f"boolean mask of shape \\({len(S)},\\), got \\(3,\\)"):
        planner.select(*args, np.random.default_rng(0), admissible=np.ones(3, dtype=bool))
    with pytest.raises(PlanningError, match="boolean mask, got dtype int64"):
        planner.select(*args, np.random.default_rng(0), admissible=np.ones(len(S), dtype=np.int64))


def test_away_from_drops_points_within_the_radius_of_any_avoided_point() -> None:
    from palpate.nodes.planner.curves import away_from

    points = np.array([[0.0, 0.0, 0.0], [0.005, 0.0, 0.0], [0.0, 0.007, 0.0], [0.02, 0.0, 0.0]])
    avoid = np.array([[0.0, 0.0, 0.001], [0.02, 0.0, 0.0]])
    np.testing.assert_array_equal(away_from(points, avoid, 0.006), [False, False, True, False])
    np.testing.assert_array_equal(away_from(points, np.zeros((0, 3)), 0.006), [True] * 4)
    np.testing.assert_array_equal(away_from(points, avoid, 0.0), [True] * 4)


@pytest.mark.parametrize(
    ("config", "refused"),
    [
        (PlannerConfig(strategy="gpv"), True),
        (PlannerConfig(strategy="tour", tour_variance_weight=1.0), True),
        (PlannerConfig(strategy="area", area_variance_weight=1.0), True),
        (PlannerConfig(strategy="tour", tour_variance_weight=0.0), False),
        (PlannerConfig(strategy="igef"), False),
    ],
)
def test_a_nan_variance_is_refused_by_every_strategy_that_rates_it(config: PlannerConfig, refused: bool) -> None:
    S, N = plane_patch()
    C = np.array([[0.0, 0.0, 0.0]])
    variance = np.ones(len(S))
    variance[3] = np.nan
    args = (S, N, variance, C, C[-1], np.array([0, 0, -1.0]), np.array([0, 0, -1.0]), np.random.default_rng(0))
    if refused:
        with pytest.raises(PlanningError, match="NaN or infinity"):
            Planner(config).select(*args)
    else:
        assert np.isfinite(Planner(config).select(*args).score)


def test_a_strategy_without_a_rating_is_an_error_not_a_uniform_choice() -> None:
    """A name added to Strategy but not to Planner._rate fell through to the random strategy's uniform
    scores, whose argmax is always the first candidate: a silent wrong planner."""
    S, N = plane_patch(radius=0.03)
    C = np.array([[0.0, 0.0, 0.0]])
    args = (S, N, np.zeros(len(S)), C, C[-1], np.array([0, 0, -1.0]), np.array([0, 0, -1.0]))
    config = PlannerConfig()
    object.__setattr__(config, "strategy", "nearest")  # as if added to Strategy only (the config refuses it)
    with pytest.raises(PlanningError, match=r"strategy 'nearest' has no rating in Planner\._rate"):
        Planner(config).select(*args, np.random.default_rng(RNG_SEED))
