"""Rotations: SO(3) as 3x3 matrices, quaternions as (w, x, y, z) (MuJoCo's and the messages' order).

Code that runs every control tick gets single-rotation fast paths (``exp_so3``, ``log_so3``,
``rotation_angle_3x3``, ``dot3``; ``quat_to_matrix`` on Python floats takes 3 us against scipy's 18 us), the
mapper's particle loop a batched Rodrigues (``axis_angle_to_matrices``); the rest builds on
``scipy.spatial.transform.Rotation`` (imported where used: loading scipy.spatial takes 0.2 s, and the
mapper and the viewer need only the fast paths).

Convention used throughout the exploration code: the fingertip's local z axis, ``R[:, 2]`` in world
coordinates, is the direction the fingertip pokes. Facing a surface with outward normal n means
``R[:, 2] = -n``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
_I3 = np.eye(3)
_I3.setflags(write=False)


def _hat(w: FloatArray) -> FloatArray:
    """Skew-symmetric matrix [w]x (3, 3) of w (3,): [w]x v = w x v."""
    x, y, z = w.tolist()
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def dot3(a: list[float], b: list[float]) -> float:
    """a . b of two 3-vectors given as floats, summed left to right: the bits of numpy's ``a @ b`` on
    float64 (3,) arrays (BLAS ddot) where BLAS sums left to right (OpenBLAS's AVX2 kernels; its AVX-512
    ones fuse multiply-adds, an ulp or so apart), without its call overhead (the controller's per-tick path)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def exp_so3(w: ArrayLike) -> FloatArray:
    """Rotation matrix of the rotation vector w (axis * angle, radians), Rodrigues. (3,) -> (3, 3)."""
    w_ = np.asarray(w, dtype=np.float64)
    xyz = w_.tolist()
    theta = math.sqrt(dot3(xyz, xyz))
    K = _hat(w_)
    if theta < 1e-8:
        return _I3 + K + 0.5 * (K @ K)
    # R = I + sin(theta)/theta K + (1 - cos(theta))/theta^2 K^2
    return _I3 + (math.sin(theta) / theta) * K + ((1.0 - math.cos(theta)) / theta**2) * (K @ K)


def log_so3(R: ArrayLike) -> FloatArray:
    """Rotation vector (axis * angle, angle in [0, pi]) of the rotation matrix R. (3, 3) -> (3,)."""
    R_ = np.asarray(R, dtype=np.float64)
    theta = rotation_angle_3x3(R_)
    (_, b, c), (d, _, f), (g, h, _) = R_.tolist()
    vee = 0.5 * np.array([h - f, c - g, d - b])  # sin(theta) axis
    if theta < 1e-6:
        return vee
    if theta > np.pi - 1e-3:  # sin(theta) ~ 0: the axis comes from the symmetric part instead
        from scipy.spatial.transform import Rotation

        return np.asarray(Rotation.from_matrix(R_).as_rotvec(), dtype=np.float64)
    return (theta / math.sin(theta)) * vee


def rotation_angle_3x3(R: FloatArray) -> float:
    """Angle in [0, pi] of one rotation matrix (3, 3), radians (scalar fast path of rotation_angle)."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    cos = 0.5 * (a + e + i - 1.0)
    sin = 0.5 * math.sqrt((h - f) ** 2 + (c - g) ** 2 + (d - b) ** 2)
    return math.atan2(sin, cos)


def rotation_angle(R: ArrayLike) -> FloatArray:
    """Angle in [0, pi] of rotation matrices, robust near 0 and pi. (..., 3, 3) -> (...) radians."""
    R = np.asarray(R, dtype=np.float64)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    sin = 0.5 * np.linalg.norm(skew, axis=-1)
    return np.asarray(np.arctan2(sin, cos), dtype=np.float64)


def align_axis(a: ArrayLike, b: ArrayLike, hint: ArrayLike | None = None) -> FloatArray:
    """The smallest rotation taking vector a onto vector b (world frame). -> (3, 3).

    For antiparallel vectors (no unique smallest rotation) it turns by pi about the part of ``hint``
    perpendicular to a (default: the coordinate axis least aligned with a).
    """
    a_ = np.asarray(a, dtype=np.float64)
    b_ = np.asarray(b, dtype=np.float64)
    norm_a, norm_b = float(np.linalg.norm(a_)), float(np.linalg.norm(b_))
    if not (0.0 < norm_a < math.inf and 0.0 < norm_b < math.inf):
        raise ValueError(f"align_axis needs two finite nonzero vectors (a direction each), got {a_} and {b_}")
    a_ = a_ / norm_a
    b_ = b_ / norm_b
    axis = np.cross(a_, b_)
    s = float(np.linalg.norm(axis))
    c = float(np.clip(a_ @ b_, -1.0, 1.0))
    if s < 1e-12:
        if c > 0.0:
            return np.eye(3)
        perp = np.zeros(3)
        if hint is not None:
            h = np.asarray(hint, dtype=np.float64)
            perp = h - (h @ a_) * a_
        if float(np.linalg.norm(perp)) < 1e-9:
            perp = np.cross(a_, np.eye(3)[int(np.argmin(np.abs(a_)))])
        return exp_so3(np.pi * perp / np.linalg.norm(perp))
    return exp_so3(axis / s * np.arctan2(s, c))


def get_rotation(R0: ArrayLike, n: ArrayLike) -> FloatArray:
    """getRotation(R0, n) of Algorithm 1: R0 turned minimally so that its z axis pokes along -n.

    n: outward surface normal (3,). The result faces the surface: ``R1[:, 2] = -n``. A half turn
    (z already along +n) is made about the fingertip's own x axis, so it does not depend on rounding.
    """
    R0_ = np.asarray(R0, dtype=np.float64)
    n_ = np.asarray(n, dtype=np.float64)
    if not 0.0 < float(np.linalg.norm(n_)) < math.inf:
        raise ValueError(f"get_rotation needs a finite nonzero surface normal n, got {n_}")
    return align_axis(R0_[:, 2], -n_, hint=R0_[:, 0]) @ R0_


def slerp(R0: ArrayLike, R1: ArrayLike, tau: float) -> FloatArray:
    """T_R(tau): geodesic interpolation R0 exp(tau log(R0^T R1)), tau in [0, 1] ("lerp" of Alg. 1)."""
    R0_ = np.asarray(R0, dtype=np.float64)
    w = log_so3(R0_.T @ np.asarray(R1, dtype=np.float64))
    return R0_ @ exp_so3(float(np.clip(tau, 0.0, 1.0)) * w)


def quat_to_matrix(q_wxyz: ArrayLike) -> FloatArray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z); normalised here. Scalar fast path.

    ValueError for a zero or non-finite quaternion (it names no rotation)."""
    w, x, y, z = np.asarray(q_wxyz, dtype=np.float64).reshape(4).tolist()
    norm2 = w * w + x * x + y * y + z * z
    if not 1e-100 < norm2 < 1e100:  # also NaN: scale first, so that 1e-200 does not underflow to zero
        largest = max(abs(w), abs(x), abs(y), abs(z))
        if not (all(map(math.isfinite, (w, x, y, z))) and largest > 0.0):
            raise ValueError(f"a quaternion must be finite and nonzero to name a rotation, got {[w, x, y, z]}")
        w, x, y, z = w / largest, x / largest, y / largest, z / largest
        norm2 = w * w + x * x + y * y + z * z
    s = 2.0 / norm2
    return np.array(
        [
            [1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
            [s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)],
            [s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R: ArrayLike) -> FloatArray:
    """Unit quaternion (w, x, y, z) (4,) of a rotation matrix (3, 3) (scipy; sign as scipy returns it)."""
    from scipy.spatial.transform import Rotation

    return np.asarray(
        Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat(scalar_first=True), dtype=np.float64
    )


def axis_angle_to_matrices(axis: ArrayLike, angle: ArrayLike) -> FloatArray:
    """Rotations (K, 3, 3) about one axis (3,) (normalised here) by angles (K,) radians (Rodrigues).

    The batched twin of ``exp_so3`` for a fixed axis (a hinge joint over many particles).
    """
    u = np.asarray(axis, dtype=np.float64)
    norm = float(np.linalg.norm(u))
    if not 0.0 < norm < math.inf:
        raise ValueError(f"a rotation axis must be finite and nonzero, got {u}")
    u = u / norm
    c = np.cos(angle)[:, None, None]
    s = np.sin(angle)[:, None, None]
    # R = cos a I + sin a [u]x + (1 - cos a) u u^T
    return np.asarray(c * np.eye(3) + s * _hat(u) + (1.0 - c) * np.outer(u, u), dtype=np.float64)


def ypr_deg_to_quat(yaw_deg: float, pitch_deg: float, roll_deg: float) -> FloatArray:
    """Quaternion (w, x, y, z) (4,) of Rz(yaw) @ Ry(pitch) @ Rx(roll), angles in degrees (intrinsic z-y'-x'')."""
    from scipy.spatial.transform import Rotation

    rotation = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True)
    return np.asarray(rotation.as_quat(scalar_first=True), dtype=np.float64)
