"""LocalGPIS (local exact GPs blended by a partition of unity) against the exact GPIS, its oracle."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from palpate.errors import ConfigError, EstimationError
from palpate.nodes.gpis.core import GPIS, GPISConfig
from palpate.nodes.gpis.expert_pack import FAR_SLOT
from palpate.nodes.gpis.local import AutoGPIS, LocalGPIS, _pack, make_estimator

AXES = np.array([0.06, 0.04, 0.03])
CENTRE = np.array([0.013, -0.007, 0.1])  # off the voxel grid's origin on purpose
#: Cells twice the default with 400 contacts: about the default's density at 1600 contacts.
CONFIG = GPISConfig(local_cell_m=0.02, local_blend_m=0.004, local_margin_m=0.006)


def ellipsoid(n: int, rng: np.random.Generator, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = u * AXES * scale
    normal = p / (AXES * scale) ** 2
    return CENTRE * scale + p, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def near_surface(rng: np.random.Generator, n: int, band_m: float, scale: float = 1.0) -> np.ndarray:
    """Points within band_m of the ellipsoid (both sides): where the surface estimate matters."""
    P, N = ellipsoid(n, rng, scale)
    return P + rng.uniform(-band_m, band_m, (n, 1)) * N


@pytest.fixture(scope="module")
def pair() -> tuple[GPIS, LocalGPIS, np.ndarray]:
    rng = np.random.default_rng(0)
    P, N = ellipsoid(400, rng)
    exact, local = GPIS(CONFIG), LocalGPIS(CONFIG)
    exact.add_contacts(P, N)
    local.add_contacts(P[:300], N[:300])
    for p, n in zip(P[300:], N[300:], strict=True):  # the incremental path, one contact at a time
        local.add_contact(p, n)
    return exact, local, near_surface(np.random.default_rng(1), 2000, 0.003)


def test_mean_matches_the_exact_gp_near_the_surface(pair: tuple[GPIS, LocalGPIS, np.ndarray]) -> None:
    exact, local, x = pair
    assert local.n_contacts == exact.n_contacts == 400 and local.n_experts > 20
    # displacement of the level sets: |f_local - f_exact| / |grad f_exact|
    shift_m = np.abs(local.mean(x) - exact.mean(x)) / np.linalg.norm(exact.gradient(x), axis=1)
    assert np.percentile(shift_m, 95) < 6e-5, np.percentile(shift_m, 95)
    assert shift_m.max() < 5e-4, shift_m.max()


def test_gradient_matches_the_exact_gp_and_its_own_mean(pair: tuple[GPIS, LocalGPIS, np.ndarray]) -> None:
    exact, local, x = pair
    g_local, g_exact = local.gradient(x), exact.gradient(x)
    cos = np.einsum("ij,ij->i", g_local, g_exact) / np.linalg.norm(g_local, axis=1) / np.linalg.norm(g_exact, axis=1)
    angle_deg = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    assert np.percentile(angle_deg, 95) < 0.5 and angle_deg.max() < 5.0, (np.percentile(angle_deg, 95), angle_deg.max())
    # the blended gradient is the derivative of the blended mean (weights' gradients included)
    h = 1e-6
    xs = x[:200]
    fd = np.column_stack(
        [(local.mean(xs + h * e) - local.mean(xs - h * e)) / (2 * h) for e in np.eye(3)]
    )  # fmt: skip
    np.testing.assert_allclose(local.gradient(xs), fd, rtol=0, atol=1e-6)


def test_variance_is_close_to_the_exact_gp_and_never_below_it(pair: tuple[GPIS, LocalGPIS, np.ndarray]) -> None:
    exact, local, x = pair
    v_local, v_exact = local.variance(x), exact.variance(x)
    assert np.all(v_local >= 0)
    ratio = v_local / v_exact
    assert np.median(ratio) < 1.05 and np.percentile(ratio, 95) < 1.6, (np.median(ratio), np.percentile(ratio, 95))
    # each expert conditions on a subset of the contacts: its variance is never below the exact GP's
    assert np.all(v_local >= v_exact * (1 - 1e-6) - 1e-18)


def test_weights_form_a_partition_of_unity_with_zero_gradient_sum() -> None:
    rng = np.random.default_rng(3)
    P, N = ellipsoid(200, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    x = CENTRE + rng.uniform(-0.08, 0.08, (3000, 3))
    pairs = local._pairs(x, gradient=True)
    point = np.concatenate([pairs.point, pairs.far_point])
    weight = np.concatenate([pairs.weight, pairs.far_weight])
    weight_grad = np.concatenate([pairs.weight_grad, pairs.far_weight_grad])
    assert len(pairs.far_point) and len(pairs.point)  # both kinds of weight are in play
    total = np.bincount(point, weights=weight, minlength=len(x))
    np.testing.assert_allclose(total, 1.0, rtol=0, atol=1e-12)
    for k in range(3):
        grad_sum = np.bincount(point, weights=weight_grad[:, k], minlength=len(x))
        np.testing.assert_allclose(grad_sum, 0.0, rtol=0, atol=1e-9)


def test_far_from_the_contacts_the_sign_holds() -> None:
    """Deep inside (no expert) the far-field GP keeps f < 0; far outside f > 0."""
    rng = np.random.default_rng(4)
    P, N = ellipsoid(400, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    inside = CENTRE + 0.3 * (rng.uniform(-1, 1, (200, 3)) * AXES)
    outside = CENTRE + (1.0 + rng.uniform(0.3, 0.6, (200, 1))) * (P[:200] - CENTRE)
    assert np.all(local.mean(inside) < 0) and np.all(local.mean(outside) > 0)


def test_duplicates_near_duplicates_and_contradictory_normals_stay_finite() -> None:
    rng = np.random.default_rng(5)
    P, N = ellipsoid(150, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    for _ in range(3):
        local.add_contact(P[0], N[0])  # exact duplicates
    local.add_contact(P[1] + 1e-6 * np.array([0.6, 0.0, 0.8]), N[1])  # 1 um away
    local.add_contact(P[2] + 1e-6, -N[2])  # the opposite normal 1 um away: contradictory
    x = near_surface(rng, 300, 0.003)
    for values in (local.mean(x), local.gradient(x), local.variance(x)):
        assert np.all(np.isfinite(values))
    assert abs(local.mean(P[3:4])[0]) < 1e-4


@pytest.mark.parametrize("size_m", [0.005, 1.0])
def test_tiny_and_huge_objects_scale_with_for_object_size(size_m: float) -> None:
    """for_object_size scales the cells too, so the local fit of a scaled object is the scaled fit."""
    rng = np.random.default_rng(6)
    scale = size_m / 0.2
    P, N = ellipsoid(300, rng)
    ref = LocalGPIS(GPISConfig.for_object_size(0.2, estimator="local"))
    scaled = LocalGPIS(GPISConfig.for_object_size(size_m, estimator="local"))
    ref.add_contacts(P, N)
    scaled.add_contacts(P * scale, N)
    x = near_surface(rng, 300, 0.003)
    np.testing.assert_allclose(scaled.mean(x * scale), scale * ref.mean(x), rtol=1e-6, atol=1e-9 * scale)
    np.testing.assert_allclose(scaled.variance(x * scale), scale**2 * ref.variance(x), rtol=1e-5, atol=1e-15)


def test_nan_inputs_are_rejected_by_name_and_leave_the_state_unchanged() -> None:
    rng = np.random.default_rng(7)
    P, N = ellipsoid(50, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    x = near_surface(rng, 20, 0.002)
    before = local.mean(x)
    with pytest.raises(EstimationError, match="contact positions row 0 is not finite"):
        local.add_contact([np.nan, 0.0, 0.0], [0.0, 0.0, 1.0])
    with pytest.raises(EstimationError, match="contact normal 0 is not finite"):
        local.add_contact(P[0], [0.0, np.nan, 1.0])
    with pytest.raises(EstimationError, match="query points row 1 is not finite"):
        local.mean(np.array([P[0], [0.0, np.inf, 0.0]]))
    assert local.n_contacts == 50
    np.testing.assert_array_equal(local.mean(x), before)


def test_a_failed_update_rolls_every_expert_back() -> None:
    """A contact beyond the thin-plate range fails in the far-field GP after the experts took it."""
    rng = np.random.default_rng(8)
    P, N = ellipsoid(60, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    sizes = local.expert_sizes()
    x = near_surface(rng, 30, 0.002)
    before = local.mean(x)
    with pytest.raises(EstimationError, match="R_m"):
        local.add_contact(CENTRE + np.array([0.6, 0.0, 0.0]), [1.0, 0.0, 0.0])
    assert local.n_contacts == 60 and local.expert_sizes() == sizes
    np.testing.assert_array_equal(local.mean(x), before)


def test_auto_is_exact_up_to_the_threshold_then_local() -> None:
    rng = np.random.default_rng(9)
    P, N = ellipsoid(260, rng)
    config = GPISConfig(
        local_cell_m=0.02, local_blend_m=0.004, local_margin_m=0.006, auto_local_above_contacts=250
    )  # fmt: skip
    auto, exact = make_estimator(config), GPIS(config)
    assert isinstance(auto, AutoGPIS)
    auto.add_contacts(P[:250], N[:250])
    exact.add_contacts(P[:250], N[:250])
    x = near_surface(rng, 200, 0.003)
    assert not auto.is_local
    np.testing.assert_array_equal(auto.mean(x), exact.mean(x))  # the same GP, bit for bit
    np.testing.assert_array_equal(auto.variance(x), exact.variance(x))
    auto.add_contact(P[250], N[250])
    assert auto.is_local and auto.n_contacts == 251
    for p, n in zip(P[251:], N[251:], strict=True):
        auto.add_contact(p, n)
    exact.add_contacts(P[250:], N[250:])
    shift_m = np.abs(auto.mean(x) - exact.mean(x)) / np.linalg.norm(exact.gradient(x), axis=1)
    assert np.percentile(shift_m, 95) < 5e-5


def test_estimator_choice_is_validated() -> None:
    assert isinstance(make_estimator(GPISConfig(estimator="exact")), GPIS)
    assert isinstance(make_estimator(GPISConfig(estimator="local")), LocalGPIS)
    with pytest.raises(ConfigError, match="estimator"):
        GPISConfig(estimator="sparse")
    with pytest.raises(ConfigError, match="local_blend_m"):
        GPISConfig(local_cell_m=0.01, local_blend_m=0.006)


def test_full_experts_shrink_their_margin_and_stay_accurate() -> None:
    """local_max_contacts caps an expert (down to margin 0); the surface stays close to the exact GP's."""
    rng = np.random.default_rng(10)
    P, N = ellipsoid(400, rng)
    config = GPISConfig(local_cell_m=0.02, local_blend_m=0.004, local_margin_m=0.006, local_max_contacts=30)
    local, exact = LocalGPIS(config), GPIS(config)
    local.add_contacts(P[:300], N[:300])  # two chunks of at most BATCH contacts
    for p, n in zip(P[300:], N[300:], strict=True):
        local.add_contact(p, n)
    exact.add_contacts(P, N)
    margins = local._margins
    assert margins and all(m < 0.006 for m in margins.values())  # some experts shrank
    for key, expert in local._experts.items():
        assert expert.n_contacts <= 30 or margins.get(key) == 0.0
    x = near_surface(np.random.default_rng(11), 1000, 0.003)
    shift_m = np.abs(local.mean(x) - exact.mean(x)) / np.linalg.norm(exact.gradient(x), axis=1)
    assert np.percentile(shift_m, 95) < 1e-4, np.percentile(shift_m, 95)


def test_the_cap_holds_where_the_same_spot_or_a_small_object_is_touched_again_and_again() -> None:
    """An outside audit: at margin 0 an expert held every contact of its voxel, so 1000 touches at one
    spot gave 8 experts of 1001 contacts (93 ms a touch, 1.4 GB) and 10,000 on a 3 cm sphere 552. Thinned
    to one contact per cube, every expert stays within the cap, and the surface where they were thinned
    stays that of the exact GP."""
    rng = np.random.default_rng(13)
    config = GPISConfig(estimator="local")
    spot = LocalGPIS(config)
    corner = np.array([0.016, 0.016, 0.016])  # a voxel corner: 8 experts hold it
    for _ in range(200):
        spot.add_contact(corner + rng.normal(scale=1e-5, size=3), [0.0, 0.0, 1.0])
    assert spot.n_contacts == 200 and max(spot.expert_sizes()) <= config.local_max_contacts
    d = rng.normal(size=(3000, 3))
    N = d / np.linalg.norm(d, axis=1, keepdims=True)
    P = 0.015 * N  # a 3 cm sphere, 3000 contacts: about 4 per square millimetre
    dense, exact = LocalGPIS(config), GPIS(config)
    dense.add_contacts(P, N)
    exact.add_contacts(P[:600], N[:600])
    assert max(dense.expert_sizes()) <= config.local_max_contacts and dense._thinned
    x = 0.015 * N[:500] * (1.0 + rng.uniform(-0.1, 0.1, size=(500, 1)))
    shift_m = np.abs(dense.mean(x) - exact.mean(x)) / np.linalg.norm(exact.gradient(x), axis=1)
    assert np.percentile(shift_m, 95) < 5e-5, np.percentile(shift_m, 95)


def test_a_contact_beyond_the_voxel_keys_reach_is_refused_not_misfiled() -> None:
    """Voxel keys hold 21 bits per axis: with 0.4 mm cells (a 1 cm object's scaled config) a contact
    600 m out overflowed them silently and experts merged (an outside audit)."""
    config = GPISConfig.for_object_size(0.01, estimator="local")
    local = LocalGPIS(config)
    with pytest.raises(EstimationError, match="beyond the local estimator's reach"):
        local.add_contact([0.0, -600.0, 600.0], [0.0, 0.0, 1.0])
    assert local.n_contacts == 0
    local.add_contact([0.0, -300.0, 300.0], [0.0, 0.0, 1.0])  # within 2^20 cells
    assert local.n_contacts == 1


def test_the_pack_holds_every_experts_current_rows_after_many_updates_and_compactions() -> None:
    """ExpertPack: after one-by-one updates (appends, garbage, compactions) each slot's rows are its
    expert's current contacts and weights, and the far field sits in slot 0."""
    rng = np.random.default_rng(12)
    P, N = ellipsoid(300, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P[:100], N[:100])
    written = 0
    for i in range(100, 300):
        local.add_contact(P[i], N[i])
        used = local._pack._used
        local.mean(P[:5])  # the pack refreshes when a query needs it
        written += max(0, local._pack._used - used)
    assert written > 2 * local._pack._live  # garbage was written, so the arrays were compacted on the way
    assert local._pack._used <= 2 * local._pack._live + 256
    packed_P, packed_A, starts, ends = local._pack.arrays()
    assert local._pack.experts[FAR_SLOT] is local._far
    assert len(local._pack.experts) == local.n_experts + 1
    for s, expert in enumerate(local._pack.experts):
        assert expert is not None
        positions, alpha = expert.residual_weights()
        np.testing.assert_array_equal(packed_P[starts[s] : ends[s]], positions)
        np.testing.assert_array_equal(packed_A[starts[s] : ends[s]], alpha)
    keys, slots = local._pack.table()
    assert np.all(np.diff(keys) > 0) and sorted(slots.tolist()) == list(range(1, local.n_experts + 1))


#: Voxels of 4 cm: a point with every coordinate in (0.01, 0.03) m is in voxel (0, 0, 0)'s data box only.
WIDE = GPISConfig(local_cell_m=0.04, local_blend_m=0.004, local_margin_m=0.006)


def _expert_000(local: LocalGPIS) -> int:
    key = int(_pack(np.zeros(3, dtype=np.int64)))
    assert key in local._experts
    return key


def test_an_expert_that_shrinks_to_no_contact_hands_its_weight_to_the_far_field() -> None:
    """An outside audit: one contact touched 65 times (one over the cap) left four of the eight experts
    around it with no contact once their margins shrank; they stayed in the table and gave the points
    they weigh the prior variance (0.03 m^2 against the exact GP's 2e-5, 14 mm from the contact)."""
    p = np.array([[0.00944086, -0.00991952, 0.04808818]])
    n = p / np.linalg.norm(p)
    q = np.array([[0.0, 0.0, 0.05]])
    for k in (64, 65):
        exact, local = GPIS(GPISConfig()), LocalGPIS(GPISConfig())
        exact.add_contacts(np.repeat(p, k, axis=0), np.repeat(n, k, axis=0))
        local.add_contacts(np.repeat(p, k, axis=0), np.repeat(n, k, axis=0))
        assert min(local.expert_sizes()) >= 1, local.expert_sizes()
        assert local.variance(q)[0] == pytest.approx(exact.variance(q)[0], rel=0.2)
        assert local.mean(q)[0] == pytest.approx(exact.mean(q)[0], rel=0.01)
    assert local.n_experts < 8  # the shrunk ones are gone


def test_an_expert_over_the_cap_halves_its_margin_once_when_that_is_enough() -> None:
    """Voxel 0's box is [-0.01, 0.05] per axis with margin 6 mm, [-0.007, 0.047] with 3 mm: a fourth
    contact at x = -0.009 lies only in the first, so one halving brings the expert back to the cap."""
    local = LocalGPIS(dataclasses.replace(WIDE, local_max_contacts=3))
    P = np.array([[0.02, 0.02, 0.02], [0.022, 0.02, 0.02], [0.02, 0.022, 0.02], [-0.009, 0.02, 0.02]])
    local.add_contacts(P, np.tile([0.0, 0.0, 1.0], (4, 1)))
    key = _expert_000(local)
    assert local._margins == {key: 0.003}  # 0.006 / 2 (not 0, not a quarter)
    np.testing.assert_array_equal(local._experts[key].positions_m, P[:3])
    assert key not in local._thinned
    local.add_contact([-0.0085, 0.02, 0.02], [0.0, 0.0, 1.0])  # in the 6 mm box only: not the expert's now
    assert local._margins == {key: 0.003}
    np.testing.assert_array_equal(local._experts[key].positions_m, P[:3])


def test_a_thinned_expert_keeps_the_first_contact_per_cube_of_an_eighth_cell_and_remembers_them() -> None:
    """Cap 4, five contacts on x in voxel 0's interior: margin 0 keeps all five, so the expert is thinned
    to one per cube of edge h / 8 = 5 mm; x / 5 mm = 2.1, 2.3, 3.1, 4.1, 4.2 gives cubes 2, 3, 4 (three
    contacts, at most the cap: no coarser cube). A later contact in a new cube (5) joins; one more
    in that cube does not."""
    local = LocalGPIS(dataclasses.replace(WIDE, local_max_contacts=4))
    x = np.array([0.0105, 0.0115, 0.0155, 0.0205, 0.021])
    P = np.column_stack([x, np.full(5, 0.02), np.full(5, 0.02)])
    up = np.tile([0.0, 0.0, 1.0], (5, 1))
    local.add_contacts(P, up)
    key = _expert_000(local)
    assert local._margins[key] == 0.0 and local._thinned[key][0] == 0.005
    np.testing.assert_array_equal(local._experts[key].positions_m, P[[0, 2, 3]])
    local.add_contact([0.0255, 0.02, 0.02], [0.0, 0.0, 1.0])  # cube 5: new
    assert local._experts[key].n_contacts == 4
    local.add_contact([0.026, 0.02, 0.02], [0.0, 0.0, 1.0])  # cube 5 again: left out
    assert local._experts[key].n_contacts == 4 and local._thinned[key][0] == 0.005
    assert local.n_contacts == 7


def test_the_far_field_keeps_the_first_contact_of_each_of_its_voxels_across_batches() -> None:
    """local_far_cell_m = 2 cm: x = 1, 2 mm share cell 0, 30 mm is cell 1, 50 mm cell 2."""
    local = LocalGPIS(CONFIG)
    up = np.tile([0.0, 0.0, 1.0], (3, 1))
    first = np.array([[0.001, 0.001, 0.001], [0.002, 0.001, 0.001], [0.03, 0.001, 0.001]])
    local.add_contacts(first, up)
    local.add_contacts(np.array([[0.003, 0.002, 0.001], [0.05, 0.001, 0.001]]), up[:2])
    assert local._far is not None
    np.testing.assert_array_equal(local._far.positions_m, [first[0], first[2], [0.05, 0.001, 0.001]])


def test_a_far_field_over_its_cap_doubles_its_voxels_and_keeps_the_first_contact_of_each() -> None:
    """Along x at 1 cm steps, 2 cm voxels: every other contact is a voxel's first. With a cap of 8, the
    ninth such contact (x = 16 cm) makes the voxels 4 cm (x = 0, 4, 8, 12, 16 cm kept), in one batch or
    one by one."""
    config = dataclasses.replace(CONFIG, local_far_max_contacts=8)
    P = np.column_stack([np.arange(20) * 0.01 + 0.001, np.full(20, 0.001), np.full(20, 0.001)])
    up = np.tile([0.0, 0.0, 1.0], (20, 1))
    for batched in (True, False):
        local = LocalGPIS(config)
        if batched:
            local.add_contacts(P, up)
        else:
            for p, n in zip(P, up, strict=True):
                local.add_contact(p, n)
        assert local._far is not None and local._far_cell_m == 0.04
        np.testing.assert_array_equal(local._far.positions_m, P[[0, 4, 8, 12, 16]])  # 17-19: voxel 4 is held
        assert local._pack.experts[FAR_SLOT] is local._far
        local.add_contact([0.201, 0.001, 0.001], [0.0, 0.0, 1.0])  # 20.1 cm: voxel 5 of 4 cm, new
        np.testing.assert_array_equal(local._far.positions_m[-1], [0.201, 0.001, 0.001])
        assert np.isfinite(local.mean(P)).all()
    with pytest.raises(ConfigError, match="local_far_max_contacts"):  # 8 octants about the origin: 7 never fit
        dataclasses.replace(CONFIG, local_far_max_contacts=7)


def test_a_far_field_that_fails_to_coarsen_leaves_the_estimator_as_it_was(monkeypatch: pytest.MonkeyPatch) -> None:
    config = dataclasses.replace(CONFIG, local_far_max_contacts=8)
    P = np.column_stack([np.arange(9) * 0.02 + 0.001, np.full(9, 0.001), np.full(9, 0.001)])
    up = np.tile([0.0, 0.0, 1.0], (9, 1))
    local = LocalGPIS(config)
    local.add_contacts(P[:8], up[:8])
    before = (local.n_contacts, sorted(local.expert_sizes()), local._far_cell_m, set(local._far_cells))
    far = local._far
    assert far is not None and far.n_contacts == 8

    def fails(self: LocalGPIS, far: GPIS) -> None:
        raise EstimationError("the rebuilt far field does not factor")

    monkeypatch.setattr(LocalGPIS, "_coarsened_far", fails)
    with pytest.raises(EstimationError, match="does not factor"):
        local.add_contact(P[8], up[8])
    assert (local.n_contacts, sorted(local.expert_sizes()), local._far_cell_m, set(local._far_cells)) == before
    assert local._far is far and far.n_contacts == 8 and local._pack.experts[FAR_SLOT] is far


def test_where_no_expert_weighs_the_estimate_is_the_far_fields_and_the_handover_is_smooth() -> None:
    """w_far = 1 away from every expert: f = m + (f_far - m) = f_far exactly, with its gradient. In the
    band where experts hand over to the far field, the gradient (w_far's gradient term included) is
    still the derivative of the mean."""
    rng = np.random.default_rng(14)
    P, N = ellipsoid(60, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    assert local._far is not None
    x = CENTRE + rng.uniform(-0.07, 0.07, (3000, 3))
    pairs = local._pairs(x, gradient=True)
    alone = np.setdiff1d(pairs.far_point[pairs.far_weight == 1.0], pairs.point)  # no expert weighs these
    assert len(alone) > 20
    np.testing.assert_allclose(local.mean(x[alone]), local._far.mean(x[alone]), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(local.gradient(x[alone]), local._far.gradient(x[alone]), rtol=1e-10, atol=1e-12)
    band = pairs.far_point[(pairs.far_weight > 0.05) & (pairs.far_weight < 0.95)]
    assert len(band) > 20
    xs, h = x[band], 1e-6
    fd = np.column_stack([(local.mean(xs + h * e) - local.mean(xs - h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(local.gradient(xs), fd, rtol=0, atol=1e-6)


def test_the_mixture_variance_is_never_negative(monkeypatch: pytest.MonkeyPatch) -> None:
    """With a prior variance of 0, Eq. 6 (prior minus a positive term) is negative for every expert:
    the mixture clamps each at +0.0."""
    rng = np.random.default_rng(15)
    P, N = ellipsoid(60, rng)
    local = LocalGPIS(CONFIG)
    local.add_contacts(P, N)
    monkeypatch.setattr(type(local.kernel), "value_variance", property(lambda self: 0.0))
    x = near_surface(rng, 50, 0.003)
    assert local.variance(x).tobytes() == np.zeros(len(x)).tobytes()


def test_a_failed_update_cuts_an_existing_expert_back() -> None:
    """The contact at x = 21 mm joins the existing expert of voxel 0 (box [-0.01, 0.03]) and opens a
    new far-field cell, where it fails: 0.511 m from the contact at x = -0.49 (R_m = 0.5 m)."""
    local = LocalGPIS(CONFIG)
    local.add_contacts(np.array([[0.0, 0.01, 0.01], [-0.49, 0.01, 0.01]]), np.tile([1.0, 0.0, 0.0], (2, 1)))
    sizes = dict(zip(local._experts, local.expert_sizes(), strict=True))
    x = np.array([[0.0, 0.01, 0.01], [0.004, 0.012, 0.008]])
    before = local.mean(x)
    with pytest.raises(EstimationError, match="R_m"):
        local.add_contact([0.021, 0.01, 0.01], [1.0, 0.0, 0.0])
    assert dict(zip(local._experts, local.expert_sizes(), strict=True)) == sizes
    np.testing.assert_array_equal(local.mean(x), before)
