"""Noise core: configured bias and sigma reproduced, sigma 0 exact, seeded streams reproducible."""

from __future__ import annotations

import math

import numpy as np
import pytest

from palpate.config import load
from palpate.errors import ConfigError, InputError
from palpate.nodes.noise.core import (
    ContactNoise,
    ContactNoiseConfig,
    JointNoise,
    JointNoiseConfig,
    JointStreamNoise,
    perturb_directions,
)

JOINTS = ("mcp_flex", "mcp_abd", "pip", "dip")
N = 10_000


def _readings(config: JointNoiseConfig, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    q = np.array([0.1, -0.2, 0.7, 0.3])
    noise = JointNoise(config, JOINTS, np.random.default_rng(seed))
    return q, np.stack([noise.apply(q) for _ in range(N)])


def _assert_mean_std(samples: np.ndarray, mean: np.ndarray, std: np.ndarray) -> None:
    """Sample mean within 3 standard errors (sigma / sqrt N) and sample std within 3 standard errors
    of the standard deviation (sigma / sqrt(2 (N - 1)))."""
    n = len(samples)
    np.testing.assert_array_less(np.abs(samples.mean(axis=0) - mean), 3 * std / math.sqrt(n) + 1e-15)
    np.testing.assert_array_less(np.abs(samples.std(axis=0, ddof=1) - std), 3 * std / math.sqrt(2 * (n - 1)))


def test_default_is_paper_sigma_1_5_deg() -> None:
    assert JointNoiseConfig().sigma_deg == 1.5
    q, samples = _readings(JointNoiseConfig())
    _assert_mean_std(samples, q, np.full(4, math.radians(1.5)))


def test_bias_and_per_joint_sigma() -> None:
    config = JointNoiseConfig(sigma_deg=2.0, per_joint_sigma_deg={"pip": 5.0}, bias_deg={"mcp_abd": -3.0})
    q, samples = _readings(config, seed=1)
    sigma = np.radians([2.0, 2.0, 5.0, 2.0])
    bias = np.radians([0.0, -3.0, 0.0, 0.0])
    _assert_mean_std(samples, q + bias, sigma)


def test_constant_bias_for_every_joint() -> None:
    q, samples = _readings(JointNoiseConfig(sigma_deg=1.0, bias_deg=4.0), seed=2)
    _assert_mean_std(samples, q + math.radians(4.0), np.full(4, math.radians(1.0)))


def test_a_bias_without_sigma_is_still_added() -> None:
    # sigma 0: q_noisy = q + b exactly; a joint with neither keeps its bits
    q = np.radians([10.0, -20.0, 30.0, 5.0])
    every = JointNoise(JointNoiseConfig(sigma_deg=0.0, bias_deg=2.0), JOINTS, np.random.default_rng(0))
    np.testing.assert_allclose(every.apply(q), q + math.radians(2.0), rtol=0, atol=1e-15)
    one = JointNoise(JointNoiseConfig(sigma_deg=0.0, bias_deg={"pip": -1.0}), JOINTS, np.random.default_rng(0))
    out = one.apply(q)
    np.testing.assert_array_equal(out[[0, 1, 3]], q[[0, 1, 3]])
    assert out[2] == pytest.approx(q[2] - math.radians(1.0), rel=0, abs=1e-15)


def test_wrong_bias_or_sigma_is_detected() -> None:
    """The statistical check can fail: a 10 % wrong sigma or a 0.1-sigma bias are outside 3 SE."""
    q, samples = _readings(JointNoiseConfig(sigma_deg=1.5), seed=3)
    with pytest.raises(AssertionError):
        _assert_mean_std(samples, q, np.full(4, math.radians(1.65)))
    with pytest.raises(AssertionError):
        _assert_mean_std(samples, q + math.radians(0.15), np.full(4, math.radians(1.5)))


def test_sigma_zero_is_bit_exact_and_draws_nothing() -> None:
    rng = np.random.default_rng(4)
    state = rng.bit_generator.state
    noise = JointNoise(JointNoiseConfig(sigma_deg=0.0), JOINTS, rng)
    q = np.array([0.1, -0.0, np.nextafter(0.7, 1.0), 1e-300])
    out = noise.apply(q)
    assert out.tobytes() == q.tobytes()
    assert out is not q
    assert rng.bit_generator.state == state


def test_zero_sigma_joint_is_exact_among_noisy_ones() -> None:
    noise = JointNoise(
        JointNoiseConfig(sigma_deg=1.5, per_joint_sigma_deg={"dip": 0.0}), JOINTS, np.random.default_rng(5)
    )
    q = np.array([0.1, 0.2, 0.3, -0.0])
    out = noise.apply(np.tile(q, (100, 1)))
    assert out[:, 3].tobytes() == np.full(100, -0.0).tobytes()
    assert np.all(out[:, :3] != q[:3])


def test_same_seed_same_stream() -> None:
    q = np.array([0.1, 0.2, 0.3, 0.4])
    a = JointNoise(JointNoiseConfig(), JOINTS, np.random.default_rng(42))
    b = JointNoise(JointNoiseConfig(), JOINTS, np.random.default_rng(42))
    c = JointNoise(JointNoiseConfig(), JOINTS, np.random.default_rng(43))
    sa = np.stack([a.apply(q) for _ in range(50)])
    sb = np.stack([b.apply(q) for _ in range(50)])
    np.testing.assert_array_equal(sa, sb)
    assert not np.array_equal(sa, np.stack([c.apply(q) for _ in range(50)]))


def test_config_errors_name_the_key_and_value() -> None:
    with pytest.raises(ConfigError, match=r"JointNoiseConfig.sigma_deg: expected a finite number >= 0 and <= 90"):
        JointNoiseConfig(sigma_deg=-1.0)
    # an outside walkthrough: 1000 deg (and 1 m of contact noise) were taken, and the runs failed elsewhere
    with pytest.raises(ConfigError, match=r"sigma_deg: expected a finite number >= 0 and <= 90, got 1000"):
        JointNoiseConfig(sigma_deg=1000.0)
    with pytest.raises(ConfigError, match=r"position_sigma_m: expected a finite number >= 0 and <= 0.05, got 1.0"):
        ContactNoiseConfig(position_sigma_m=1.0)
    with pytest.raises(ConfigError, match=r"<launch>.sigma: unknown key 'sigma'; known keys: bias_deg, per_joint"):
        load(JointNoiseConfig, {"sigma": 1.0}, "<launch>")
    with pytest.raises(InputError, match=r"names: lacks joint\(s\) \['thumb'\] that the noise node's per_joint_sigma"):
        JointNoise(JointNoiseConfig(per_joint_sigma_deg={"thumb": 1.0}), JOINTS, np.random.default_rng(0))
    with pytest.raises(InputError, match=r"names: repeated name\(s\) 'pip'"):
        JointNoise(JointNoiseConfig(), ("pip", "dip", "pip"), np.random.default_rng(0))
    with pytest.raises(ConfigError, match=r"JointNoiseConfig.bias_deg.pip: expected a finite number, got 'x'"):
        load(JointNoiseConfig, {"bias_deg": {"pip": "x"}})
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 4\)"):
        JointNoise(JointNoiseConfig(), JOINTS, np.random.default_rng(0)).apply(np.zeros(3))
    assert load(JointNoiseConfig, {"sigma_deg": 0.5}).sigma_deg == 0.5


def test_stream_builds_its_model_from_the_first_reading_names() -> None:
    """The first reading's names fix the model (per-joint sigma found by name); later readings use it
    and draw from the one generator, as a JointNoise built up front does."""
    config = JointNoiseConfig(sigma_deg=0.0, per_joint_sigma_deg={"pip": 2.0})
    stream = JointStreamNoise(config, np.random.default_rng(5))
    assert stream.model is None  # nothing is known before a reading
    reference = JointNoise(config, JOINTS, np.random.default_rng(5))
    q = np.array([0.1, -0.2, 0.7, 0.3])
    for _ in range(3):
        assert stream.apply(JOINTS, q).tobytes() == reference.apply(q).tobytes()
    assert stream.model is not None and stream.model.joint_names == JOINTS
    np.testing.assert_array_equal(stream.model.sigma_rad, np.radians([0.0, 0.0, 2.0, 0.0]))
    with pytest.raises(InputError, match=r"lacks joint\(s\) \['pip'\] that the noise node's per_joint_sigma_deg"):
        JointStreamNoise(config, np.random.default_rng(0)).apply(["a", "b"], np.zeros(2))


# --- contacts --------------------------------------------------------------------------------------
def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return np.asarray(v / np.linalg.norm(v, axis=1, keepdims=True))


def test_contact_noise_zero_is_exact() -> None:
    rng = np.random.default_rng(6)
    p, n = rng.normal(size=(20, 3)), _unit(rng, 20)
    state = rng.bit_generator.state
    out_p, out_n = ContactNoise(ContactNoiseConfig(), rng).apply(p, n)
    assert out_p.tobytes() == p.tobytes() and out_n.tobytes() == n.tobytes()
    assert rng.bit_generator.state == state


def test_contact_position_noise_statistics() -> None:
    sigma = 0.002
    noise = ContactNoise(ContactNoiseConfig(position_sigma_m=sigma), np.random.default_rng(7))
    p = np.tile([[0.1, 0.2, 0.3]], (N, 1))
    out_p, out_n = noise.apply(p, np.tile([[0.0, 0.0, 1.0]], (N, 1)))
    _assert_mean_std(out_p, p[0], np.full(3, sigma))
    assert np.all(out_n == [0.0, 0.0, 1.0])


def test_contact_normal_noise_is_rayleigh_and_unit() -> None:
    sigma_deg = 4.0
    rng = np.random.default_rng(8)
    normals = _unit(rng, N)
    _, out = ContactNoise(ContactNoiseConfig(normal_sigma_deg=sigma_deg), rng).apply(np.zeros((N, 3)), normals)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", out, normals), -1, 1))
    s = math.radians(sigma_deg)
    # Rayleigh(s): mean s sqrt(pi/2), std s sqrt((4 - pi)/2)
    mean, std = s * math.sqrt(math.pi / 2), s * math.sqrt((4 - math.pi) / 2)
    assert abs(angle.mean() - mean) < 3 * std / math.sqrt(N)
    # the perturbation has no preferred tangent direction: its mean is along the normal
    np.testing.assert_allclose(np.einsum("ij,ij->i", out - normals, normals).mean(), -(s**2), rtol=0.1)


def test_perturb_directions_exact_angle_for_a_known_draw() -> None:
    """n' = cos|t| n + sin|t| t/|t| with t the tangent part of the drawn z: compare to a direct formula."""
    n = np.array([[0.0, 0.0, 1.0]])
    out = perturb_directions(n, 0.1, np.random.default_rng(9))
    z = 0.1 * np.random.default_rng(9).standard_normal((1, 3))
    t = np.array([z[0, 0], z[0, 1], 0.0])
    a = np.linalg.norm(t)
    np.testing.assert_allclose(out[0], np.cos(a) * n[0] + np.sin(a) * t / a, atol=1e-15)


def test_contact_noise_same_seed_same_stream() -> None:
    config = ContactNoiseConfig(position_sigma_m=1e-3, normal_sigma_deg=2.0)
    p, n = np.zeros((5, 3)), np.tile([[1.0, 0.0, 0.0]], (5, 1))
    a = ContactNoise(config, np.random.default_rng(10)).apply(p, n)
    b = ContactNoise(config, np.random.default_rng(10)).apply(p, n)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(
        ConfigError, match=r"ContactNoiseConfig.normal_sigma_deg: expected a finite number >= 0, got -2"
    ):
        ContactNoiseConfig(normal_sigma_deg=-2)


def test_contact_noise_draws_the_positions_then_the_normals() -> None:
    """One draw per reading gives the values of two: the positions' block first, then the normals'."""
    from palpate.nodes.noise.core import _perturb_many

    config = ContactNoiseConfig(position_sigma_m=1e-3, normal_sigma_deg=2.0)
    for rows in (1, 7):
        p = np.arange(3.0 * rows).reshape(rows, 3) * 0.01
        n = np.tile([[0.0, 0.6, 0.8]], (rows, 1))
        out_p, out_n = ContactNoise(config, np.random.default_rng(3)).apply(p, n)
        rng = np.random.default_rng(3)
        z_p, z_n = rng.standard_normal((rows, 3)), rng.standard_normal((rows, 3))
        assert out_p.tobytes() == (p + 1e-3 * z_p).tobytes()
        assert out_n.tobytes() == _perturb_many(n, math.radians(2.0) * z_n).tobytes()


def test_few_directions_take_the_scalar_path_with_numpys_bits() -> None:
    """perturb_directions computes up to FEW_DIRECTIONS rows in Python: the same bits as the
    vectorised maths for the same draw (normals within the unit tolerance, small and large steps)."""
    from palpate.nodes.noise.core import FEW_DIRECTIONS, _perturb_few, _perturb_many

    rng = np.random.default_rng(5)
    for n in range(1, FEW_DIRECTIONS + 1):
        for _ in range(2000):
            v = rng.standard_normal((n, 3))
            v *= (1.0 + rng.uniform(-0.009, 0.009, (n, 1))) / np.linalg.norm(v, axis=1, keepdims=True)
            z = rng.standard_normal((n, 3)) * rng.choice([1e-3, 0.035, 0.5, 2.0])
            assert _perturb_few(v, z).tobytes() == _perturb_many(v, z).tobytes()
    v = np.array([[0.0, 0.0, 1.0]])
    assert _perturb_few(v, np.array([[0.0, 0.0, 0.3]])).tobytes() == v.tobytes()  # a step along n: no turn


def test_contact_noise_of_no_contact_is_empty_and_draws_nothing() -> None:
    config = ContactNoiseConfig(position_sigma_m=1e-3, normal_sigma_deg=2.0)
    rng = np.random.default_rng(4)
    state = rng.bit_generator.state
    empty = np.zeros((0, 3))
    empty.flags.writeable = False  # as received
    p, n = ContactNoise(config, rng).apply(empty, empty)
    assert p.shape == n.shape == (0, 3) and p.dtype == n.dtype == np.float64
    assert p is empty and n is empty  # read-only: nothing can change them, so no copy
    assert rng.bit_generator.state == state


def test_contact_noise_zero_passes_received_arrays_and_copies_others() -> None:
    p, n = np.array([[0.1, 0.2, 0.3]]), np.array([[0.0, 0.0, 1.0]])
    out_p, out_n = ContactNoise(ContactNoiseConfig(), np.random.default_rng(1)).apply(p, n)
    assert not np.shares_memory(out_p, p) and not np.shares_memory(out_n, n)  # writable: copied
    p.flags.writeable = n.flags.writeable = False  # as received
    out_p, out_n = ContactNoise(ContactNoiseConfig(), np.random.default_rng(1)).apply(p, n)
    assert out_p is p and out_n is n


@pytest.mark.parametrize("rows", [1, 5])
def test_perturb_directions_refuses_rows_without_direction(rows: int) -> None:
    """One zero row among one or five: the same named error (it was a ZeroDivisionError for one row and
    NaN rows for five)."""
    normals = np.tile([0.0, 0.0, 1.0], (rows, 1))
    normals[-1] = 0.0
    with pytest.raises(ValueError, match="finite and nonzero"):
        perturb_directions(normals, 0.1, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"shape \(n, 3\), got \(3,\)"):
        perturb_directions(np.array([0.0, 0.0, 1.0]), 0.1, np.random.default_rng(0))
