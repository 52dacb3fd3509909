"""What this machine's numpy does with the short sums that the scalar and compiled paths copy.

palpate's scalar (controller, noise) and compiled (numba) paths add a 3-vector's products left to
right, which is what numpy's ``a @ b`` on float64 (3,) arrays gives where BLAS ddot does (OpenBLAS's
AVX2 kernels). OpenBLAS's AVX-512 kernels fuse the multiply-adds, and the two then differ in the
last bits. Tests that compare the paths bit for bit do so where numpy sums left to right, and to
rounding elsewhere.
"""

from __future__ import annotations

import functools

import numpy as np


@functools.cache
def numpy_dot3_is_left_to_right(samples: int = 2000) -> bool:
    """Whether numpy's ``a @ b`` of float64 3-vectors here equals (a0 b0 + a1 b1) + a2 b2, bit for bit."""
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((2, samples, 3))
    return all(float(x @ y) == (x[0] * y[0] + x[1] * y[1]) + x[2] * y[2] for x, y in zip(a, b, strict=True))


def assert_same_to_rounding(got: np.ndarray, expected: np.ndarray, atol: float = 1e-12) -> None:
    """``got`` and ``expected`` bit for bit where numpy sums left to right, else within ``atol``."""
    if numpy_dot3_is_left_to_right():
        np.testing.assert_array_equal(got, expected)
    else:
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=atol)
