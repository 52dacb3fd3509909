"""Rotations against scipy, MuJoCo, slow references and known rotations (quaternions are w, x, y, z)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from palpate.geometry import rotations
from tests.unit.numerics import numpy_dot3_is_left_to_right


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, 2.0, np.pi - 1e-4, np.pi])
def test_exp_log_round_trip(angle: float) -> None:
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    w = angle * axis
    R = rotations.exp_so3(w)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    back = rotations.log_so3(R)
    if angle < np.pi:
        np.testing.assert_allclose(back, w, atol=1e-9)
    else:  # at pi the axis sign is arbitrary
        np.testing.assert_allclose(np.abs(back), np.abs(w), atol=1e-7)
    assert rotations.rotation_angle_3x3(R) == pytest.approx(angle, abs=1e-9)


def test_rotation_angle_batched_matches_scipy() -> None:
    rots = Rotation.random(50, random_state=4)
    np.testing.assert_allclose(rotations.rotation_angle(rots.as_matrix()), rots.magnitude(), atol=1e-10)


def test_get_rotation_faces_the_surface_with_the_smallest_turn() -> None:
    R0 = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    n = np.array([0.2, -0.4, 0.9]) / np.linalg.norm([0.2, -0.4, 0.9])
    R1 = rotations.get_rotation(R0, n)
    np.testing.assert_allclose(R1[:, 2], -n, atol=1e-12)  # z pokes into the surface
    needed = np.arccos(np.clip(R0[:, 2] @ -n, -1, 1))
    assert rotations.rotation_angle_3x3(R0.T @ R1) == pytest.approx(needed, abs=1e-10)


def test_get_rotation_half_turn_uses_the_fingertip_x_axis() -> None:
    R0 = np.eye(3)
    R1 = rotations.get_rotation(R0, np.array([0.0, 0.0, 1.0]))  # z = +e_z must become -e_z
    np.testing.assert_allclose(R1[:, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(R1[:, 0], [1, 0, 0], atol=1e-12)  # turned about x: x is unchanged


def test_slerp_ends_and_middle() -> None:
    R0 = Rotation.from_euler("z", 0.2).as_matrix()
    R1 = Rotation.from_euler("z", 1.4).as_matrix()
    np.testing.assert_allclose(rotations.slerp(R0, R1, 0.0), R0, atol=1e-12)
    np.testing.assert_allclose(rotations.slerp(R0, R1, 1.0), R1, atol=1e-12)
    np.testing.assert_allclose(rotations.slerp(R0, R1, 0.5), Rotation.from_euler("z", 0.8).as_matrix(), atol=1e-12)


def test_align_axis_is_the_smallest_rotation_and_handles_antiparallel() -> None:
    rng = np.random.default_rng(5)
    for a, b in rng.normal(size=(20, 2, 3)):
        R = rotations.align_axis(a, b)
        np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        angle = np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))
        assert rotations.rotation_angle_3x3(R) == pytest.approx(angle, abs=1e-9)
    np.testing.assert_array_equal(rotations.align_axis([0, 0, 2.0], [0, 0, 1.0]), np.eye(3))
    R = rotations.align_axis([0, 0, 1.0], [0, 0, -1.0], hint=[0, 1.0, 0])  # half turn about the hint
    np.testing.assert_allclose(R, np.diag([-1.0, 1.0, -1.0]), atol=1e-15)


def test_antiparallel_half_turn_uses_the_part_of_the_hint_perpendicular_to_a() -> None:
    # hint (1, 0, 1) against a = e_z: its perpendicular part is e_x, so the half turn is about x,
    # diag(1, -1, -1); about the raw hint it would take e_z to e_x instead of -e_z
    R = rotations.align_axis([0, 0, 1.0], [0, 0, -1.0], hint=[1.0, 0, 1.0])
    np.testing.assert_allclose(R, np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    R0 = Rotation.from_euler("y", 0.4).as_matrix()  # get_rotation: the hint is the tilted x axis R0[:, 0]
    R1 = rotations.get_rotation(R0, R0[:, 2])
    np.testing.assert_allclose(R1[:, 2], -R0[:, 2], atol=1e-12)
    np.testing.assert_allclose(R1[:, 0], R0[:, 0], atol=1e-12)


def test_exp_so3_keeps_the_second_order_term_below_the_small_angle_threshold() -> None:
    # Rodrigues: R = I + K + (1 - cos t) / t^2 K^2 and (1 - cos t) / t^2 -> 1/2. With w = (1, 2, 0) 1e-9,
    # K has no (0, 1) entry (w_z = 0), so R[0, 1] = R[1, 0] = w_x w_y / 2 = 1e-18 comes from K^2 alone
    w = np.array([1e-9, 2e-9, 0.0])
    R = rotations.exp_so3(w)
    assert R[0, 1] == pytest.approx(1e-18, rel=1e-12, abs=0) and R[1, 0] == pytest.approx(1e-18, rel=1e-12, abs=0)
    assert R[2, 1] == pytest.approx(1e-9, rel=1e-12, abs=0) and R[0, 2] == pytest.approx(2e-9, rel=1e-12, abs=0)


def test_quat_to_matrix_matches_scipy_and_mujoco_wxyz() -> None:
    mujoco = pytest.importorskip("mujoco")
    for q in np.random.default_rng(7).normal(size=(200, 4)):  # not unit: normalised inside
        unit = q / np.linalg.norm(q)
        R = rotations.quat_to_matrix(q)
        np.testing.assert_allclose(R, Rotation.from_quat(q, scalar_first=True).as_matrix(), rtol=0, atol=1e-15)
        expected = np.zeros(9)
        mujoco.mju_quat2Mat(expected, unit)  # MuJoCo's order: scalar first
        np.testing.assert_allclose(R, expected.reshape(3, 3), rtol=0, atol=1e-15)
        np.testing.assert_allclose(R.T @ R, np.eye(3), rtol=0, atol=4e-15)  # a few ulps


def test_quat_to_matrix_conventions() -> None:
    np.testing.assert_array_equal(rotations.quat_to_matrix([1.0, 0.0, 0.0, 0.0]), np.eye(3))  # identity, exact
    np.testing.assert_array_equal(rotations.quat_to_matrix([-3.0, 0.0, 0.0, 0.0]), np.eye(3))  # any scale or sign
    half = np.sqrt(0.5)
    # (w, x, y, z) = (cos 45, 0, 0, sin 45): a quarter turn about +z takes x to y
    np.testing.assert_allclose(rotations.quat_to_matrix([half, 0, 0, half]) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rotations.quat_to_matrix([0.0, 1.0, 0.0, 0.0]), np.diag([1.0, -1.0, -1.0]), atol=0)


def test_matrix_to_quat_round_trip_up_to_sign() -> None:
    for q in Rotation.random(100, random_state=8).as_quat(scalar_first=True):
        back = rotations.matrix_to_quat(rotations.quat_to_matrix(q))
        assert back.shape == (4,) and back.dtype == np.float64
        np.testing.assert_allclose(back * np.sign(back @ q), q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(rotations.matrix_to_quat(np.eye(3)), [1.0, 0.0, 0.0, 0.0], atol=0)


def test_axis_angle_to_matrices_matches_scipy_and_exp() -> None:
    axis = np.array([0.3, -0.5, 0.8])  # not unit: normalised inside
    angles = np.array([0.0, 1e-9, 0.7, -2.0, np.pi])
    u = axis / np.linalg.norm(axis)
    R = rotations.axis_angle_to_matrices(axis, angles)
    assert R.shape == (5, 3, 3)
    np.testing.assert_allclose(R, Rotation.from_rotvec(angles[:, None] * u).as_matrix(), rtol=0, atol=1e-15)
    for a, Ra in zip(angles, R, strict=True):
        np.testing.assert_allclose(Ra, rotations.exp_so3(a * u), rtol=0, atol=1e-15)


def _slow_ypr_quat(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Reference: Hamilton product of the three axis quaternions (w, x, y, z), z then y then x."""

    def axis_quat(axis: int, deg: float) -> np.ndarray:
        q = np.zeros(4)
        q[0], q[1 + axis] = np.cos(np.radians(deg) / 2), np.sin(np.radians(deg) / 2)
        return q

    def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
        return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])

    return mul(mul(axis_quat(2, yaw), axis_quat(1, pitch)), axis_quat(0, roll))


@pytest.mark.parametrize("ypr", [(0.0, 0.0, 0.0), (40.0, 20.0, -90.0), (-170.0, 80.0, 33.0)])
def test_ypr_deg_to_quat_is_intrinsic_z_y_x(ypr: tuple[float, float, float]) -> None:
    q = rotations.ypr_deg_to_quat(*ypr)
    np.testing.assert_allclose(q, _slow_ypr_quat(*ypr), rtol=0, atol=1e-15)
    yaw, pitch, roll = np.radians(ypr)
    Rz = rotations.exp_so3([0, 0, yaw])
    Ry = rotations.exp_so3([0, pitch, 0])
    Rx = rotations.exp_so3([roll, 0, 0])
    np.testing.assert_allclose(rotations.quat_to_matrix(q), Rz @ Ry @ Rx, rtol=0, atol=1e-15)


def test_dot3_gives_numpys_bits() -> None:
    """The controller's scalar dot products must not move a run: the same bits as numpy's a @ b where
    numpy sums left to right (tests/unit/numerics.py), within an ulp of each product elsewhere."""
    rng = np.random.default_rng(5)
    for _ in range(20_000):
        a = rng.normal(size=3) * 10.0 ** rng.integers(-4, 4)
        b = rng.normal(size=3)
        got = rotations.dot3(a.tolist(), b.tolist())
        assert got == (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
        if numpy_dot3_is_left_to_right():
            assert got == float(a @ b)
        else:
            assert abs(got - float(a @ b)) <= 4e-16 * float(np.abs(a * b).sum())


def test_a_tiny_quaternion_is_normalised_without_underflow() -> None:
    np.testing.assert_array_equal(rotations.quat_to_matrix([1e-200, 0.0, 0.0, 0.0]), np.eye(3))
    q = np.array([0.3, -0.5, 0.1, 0.8])
    np.testing.assert_allclose(rotations.quat_to_matrix(q * 1e-160), rotations.quat_to_matrix(q), atol=1e-15)
    np.testing.assert_allclose(rotations.quat_to_matrix(q * 1e160), rotations.quat_to_matrix(q), atol=1e-15)


@pytest.mark.parametrize(
    "q", [[0.0, 0.0, 0.0, 0.0], [np.nan, 0.0, 0.0, 0.0], [1.0, np.nan, 0.0, 0.0], [np.inf, 0, 0, 0]]
)
def test_a_quaternion_that_names_no_rotation_is_refused(q: list[float]) -> None:
    with pytest.raises(ValueError, match="must be finite and nonzero to name a rotation"):
        rotations.quat_to_matrix(q)


def test_a_vector_without_direction_is_refused() -> None:
    with pytest.raises(ValueError, match="two finite nonzero vectors"):
        rotations.align_axis([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="two finite nonzero vectors"):
        rotations.align_axis([0.0, 0.0, 1.0], [np.nan, 0.0, 1.0])
    with pytest.raises(ValueError, match="nonzero surface normal n"):
        rotations.get_rotation(np.eye(3), [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="rotation axis must be finite and nonzero"):
        rotations.axis_angle_to_matrices([0.0, 0.0, 0.0], np.array([0.1]))
