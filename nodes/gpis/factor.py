"""A lower Cholesky factor that grows by block rows in place, with spare capacity (issue 11, item 1).

The GP's factor K~ = L L^T gains four rows per contact. Reallocating L (4n x 4n) and copying it on
every contact costs O(n^2) memory traffic and a fresh allocation per touch; here L lives in the
top-left corner of a larger buffer (C order, row stride = capacity), which grows geometrically
(x GROWTH) only when full, so the amortised copy cost per contact is O(n^2 / n) = O(n).

The triangular solves run on that corner in place. scipy's ``solve_triangular`` would copy a strided
view into a contiguous array first (O(n^2) again), so the solves call BLAS directly through the
function pointers that scipy exports for Cython (``scipy.linalg.cython_blas``), passing the buffer's
row stride as the leading dimension. These are the same BLAS routines that LAPACK's dtrtrs (behind
``solve_triangular``) calls on the same numbers, so the results are bit for bit those of
``solve_triangular`` on a contiguous copy (tests/unit/gpis/test_factor.py checks it): dtrsm for
several right-hand sides, dtrsv for one. The C-ordered buffer seen by Fortran BLAS is U = L^T with
leading dimension = capacity:

    L X = B    <=>  U^T X = B   (dtrsm side L, uplo U, transa T)
    L^T X = B  <=>  U X = B     (dtrsm side L, uplo U, transa N)
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cython_blas

FloatArray = NDArray[np.float64]

#: Capacity growth factor when the buffer is full (1.5: at most 2.25 x the factor's memory, and the
#: amortised copy per row stays O(rows)).
GROWTH = 1.5
#: Smallest capacity (rows) allocated.
MIN_CAPACITY = 16


def _blas_function(name: str, *argtypes: Any) -> Any:
    """A BLAS routine from scipy's Cython BLAS table as a ctypes function (Fortran: arguments by pointer)."""
    capsule = cython_blas.__pyx_capi__[name]
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype = ctypes.c_char_p
    get_name.argtypes = [ctypes.py_object]
    get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
    get_pointer.restype = ctypes.c_void_p
    get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    return ctypes.CFUNCTYPE(None, *argtypes)(get_pointer(capsule, get_name(capsule)))


_INT = ctypes.POINTER(ctypes.c_int)
_CHAR = ctypes.c_char_p
_PTR = ctypes.c_void_p
# dtrsm(side, uplo, transa, diag, m, n, alpha, a, lda, b, ldb); dtrsv(uplo, trans, diag, n, a, lda, x, incx)
_DOUBLE = ctypes.POINTER(ctypes.c_double)
_dtrsm = _blas_function("dtrsm", _CHAR, _CHAR, _CHAR, _CHAR, _INT, _INT, _DOUBLE, _PTR, _INT, _PTR, _INT)
_dtrsv = _blas_function("dtrsv", _CHAR, _CHAR, _CHAR, _INT, _PTR, _INT, _PTR, _INT)


def _int(v: int) -> Any:
    return ctypes.byref(ctypes.c_int(v))


class GrowingCholesky:
    """Lower triangular L (m, m) stored in the corner of a (capacity, capacity) buffer."""

    def __init__(self) -> None:
        self._buf = np.zeros((0, 0))
        self._m = 0

    @property
    def size(self) -> int:
        """Rows m of L."""
        return self._m

    @property
    def capacity(self) -> int:
        """Rows the buffer holds before it must grow."""
        return self._buf.shape[0]

    @property
    def nbytes(self) -> int:
        """Memory of the buffer in bytes."""
        return self._buf.nbytes

    def view(self) -> FloatArray:
        """L (m, m), a read-only view of the buffer (not contiguous when capacity > m)."""
        v = self._buf[: self._m, : self._m]
        v.flags.writeable = False
        return v

    def append(self, X_T: NDArray[np.floating[Any]], L22: NDArray[np.floating[Any]]) -> None:
        """Grow L by block rows: [L 0; X^T L22]. X_T (k, m) and L22 (k, k) lower triangular."""
        m, k = self._m, L22.shape[0]
        if X_T.shape != (k, m):
            raise ValueError(f"new block rows must have shape ({k}, {m}), got {X_T.shape}")
        self.reserve(m + k)
        buf = self._buf
        buf[m : m + k, :m] = X_T
        buf[m : m + k, m : m + k] = L22
        buf[:m, m : m + k] = 0.0  # the buffer is zero beyond m, but keep the upper block exact anyway
        self._m = m + k

    def truncate(self, rows: int) -> None:
        """Keep the leading (rows, rows) block (the factor of the leading block of K~)."""
        if not 0 <= rows <= self._m:
            raise ValueError(f"cannot keep {rows} of {self._m} rows")
        self._buf[rows : self._m, : self._m] = 0.0
        self._m = rows

    def reserve(self, rows: int) -> None:
        """Make room for at least `rows` rows (geometric growth; copies L once when it grows)."""
        if rows <= self.capacity:
            return
        cap = max(rows, int(GROWTH * self.capacity), MIN_CAPACITY)
        buf = np.zeros((cap, cap))
        buf[: self._m, : self._m] = self._buf[: self._m, : self._m]
        self._buf = buf

    def solve_in_place(self, B: FloatArray) -> None:
        """Overwrite B (m, k), Fortran-ordered (column-major), with X: L X = B. No copy."""
        m = self._m
        if B.ndim != 2 or B.shape[0] != m or not B.flags.f_contiguous:
            raise ValueError(f"in-place solve needs a column-major ({m}, k) array, got {B.shape}")
        if m and B.shape[1]:
            one = ctypes.c_double(1.0)
            _dtrsm(
                b"L", b"U", b"T", b"N", _int(m), _int(B.shape[1]), ctypes.byref(one),
                self._buf.ctypes.data, _int(self.capacity), B.ctypes.data, _int(m),
            )  # fmt: skip

    def solve(self, B: FloatArray, *, trans: bool = False) -> FloatArray:
        """X with L X = B (trans=False) or L^T X = B (trans=True); B (m,) or (m, k). A new array.

        Bit for bit ``scipy.linalg.solve_triangular(L, B, lower=True, trans=...)`` on a contiguous L.
        """
        m = self._m
        if B.shape[0] != m:
            raise ValueError(f"right-hand side has {B.shape[0]} rows, the factor {m}")
        # U = L^T in Fortran's eyes: L X = B is U^T X = B ("T"), L^T X = B is U X = B ("N")
        op = b"N" if trans else b"T"
        if B.ndim == 1 or B.shape[1] == 1:
            x = np.array(B, dtype=np.float64, order="F", copy=True)
            if m:
                _dtrsv(b"U", op, b"N", _int(m), self._buf.ctypes.data, _int(self.capacity), x.ctypes.data, _int(1))
            return x
        X = np.array(B, dtype=np.float64, order="F", copy=True)
        if m and X.shape[1]:
            one = ctypes.c_double(1.0)
            _dtrsm(
                b"L", b"U", op, b"N", _int(m), _int(X.shape[1]), ctypes.byref(one),
                self._buf.ctypes.data, _int(self.capacity), X.ctypes.data, _int(m),
            )  # fmt: skip
        return X
