"""GrowingCholesky: in-place growth with spare capacity, solves bit for bit those of solve_triangular."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from palpate.nodes.gpis.core import GPIS
from palpate.nodes.gpis.factor import GROWTH, MIN_CAPACITY, GrowingCholesky


def _factor_of(rng: np.random.Generator, m: int) -> np.ndarray:
    A = rng.standard_normal((m, m))
    return np.linalg.cholesky(A @ A.T + m * np.eye(m))


@pytest.mark.parametrize("columns", [None, 1, 4, 37])
@pytest.mark.parametrize("trans", [False, True])
def test_solves_are_bit_identical_to_solve_triangular(columns: int | None, trans: bool) -> None:
    rng = np.random.default_rng(0)
    L = _factor_of(rng, 300)
    f = GrowingCholesky()
    for s in range(0, 300, 60):  # five appends: the buffer grows (and is copied) on the way
        f.append(L[s : s + 60, :s], L[s : s + 60, s : s + 60])
    assert f.capacity > f.size == 300
    np.testing.assert_array_equal(f.view(), L)
    B = rng.standard_normal(300 if columns is None else (300, columns))
    ref = scipy.linalg.solve_triangular(L, B, lower=True, trans="T" if trans else "N", check_finite=False)
    got = f.solve(B, trans=trans)
    assert got.shape == ref.shape
    np.testing.assert_array_equal(got, ref)


def test_growth_is_geometric_and_truncate_keeps_the_leading_block() -> None:
    rng = np.random.default_rng(1)
    L = _factor_of(rng, 400)
    f = GrowingCholesky()
    capacities = set()
    for s in range(0, 400, 4):
        f.append(L[s : s + 4, :s], L[s : s + 4, s : s + 4])
        capacities.add(f.capacity)
    geometric = 1 + math.ceil(math.log(400 / MIN_CAPACITY, GROWTH))  # MIN_CAPACITY x GROWTH^k up to 400 rows
    assert len(capacities) <= geometric, f"the buffer was reallocated {len(capacities)} times for 100 appends"
    f.truncate(120)
    np.testing.assert_array_equal(f.view(), L[:120, :120])
    f.append(L[120:124, :120], L[120:124, 120:124])
    np.testing.assert_array_equal(f.view(), L[:124, :124])
    with pytest.raises(ValueError, match="cannot keep"):
        f.truncate(125)


def test_gpis_truncate_equals_a_gp_of_the_first_contacts() -> None:
    rng = np.random.default_rng(2)
    u = rng.standard_normal((30, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    P, N = 0.05 * u, u
    full, part = GPIS(), GPIS()
    full.add_contacts(P, N)
    part.add_contacts(P[:20], N[:20])
    full.truncate(20)
    x = rng.uniform(-0.06, 0.06, (40, 3))
    # one Cholesky of 30 contacts vs one of 20: the same factor up to LAPACK's blocking round-off
    L = part.cholesky_factor()
    np.testing.assert_allclose(full.cholesky_factor(), L, rtol=0, atol=1e-9 * np.abs(L).max())
    np.testing.assert_allclose(full.mean(x), part.mean(x), rtol=0, atol=1e-9)
    np.testing.assert_allclose(full.variance(x), part.variance(x), rtol=0, atol=1e-12)


def test_a_full_buffer_is_used_before_it_grows() -> None:
    L = _factor_of(np.random.default_rng(2), 100)
    f = GrowingCholesky()
    full = MIN_CAPACITY  # 16 rows: 4 contacts of 4 rows
    for s in range(0, full, 4):
        f.append(L[s : s + 4, :s], L[s : s + 4, s : s + 4])
    assert f.size == f.capacity == full
    f.append(L[full : full + 4, :full], L[full : full + 4, full : full + 4])  # one more: grows by GROWTH = 1.5
    assert f.capacity == int(GROWTH * full) == 24
    assert f.nbytes == 24 * 24 * 8
    np.testing.assert_array_equal(f.view(), L[: full + 4, : full + 4])
