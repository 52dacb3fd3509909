"""Rotation helpers against scipy and known rotations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from palpate.nodes.controller import so3


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, 2.0, np.pi - 1e-4, np.pi])
def test_exp_log_round_trip(angle: float) -> None:
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    w = angle * axis
    R = so3.exp_so3(w)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    back = so3.log_so3(R)
    if angle < np.pi:
        np.testing.assert_allclose(back, w, atol=1e-9)
    else:  # at pi the axis sign is arbitrary
        np.testing.assert_allclose(np.abs(back), np.abs(w), atol=1e-7)
    assert so3.rotation_angle_3x3(R) == pytest.approx(angle, abs=1e-9)


def test_rotation_angle_batched_matches_scipy() -> None:
    rots = Rotation.random(50, random_state=4)
    np.testing.assert_allclose(so3.rotation_angle(rots.as_matrix()), rots.magnitude(), atol=1e-10)


def test_get_rotation_faces_the_surface_with_the_smallest_turn() -> None:
    R0 = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    n = np.array([0.2, -0.4, 0.9]) / np.linalg.norm([0.2, -0.4, 0.9])
    R1 = so3.get_rotation(R0, n)
    np.testing.assert_allclose(R1[:, 2], -n, atol=1e-12)  # z pokes into the surface
    needed = np.arccos(np.clip(R0[:, 2] @ -n, -1, 1))
    assert so3.rotation_angle_3x3(R0.T @ R1) == pytest.approx(needed, abs=1e-10)


def test_get_rotation_half_turn_uses_the_fingertip_x_axis() -> None:
    R0 = np.eye(3)
    R1 = so3.get_rotation(R0, np.array([0.0, 0.0, 1.0]))  # z = +e_z must become -e_z
    np.testing.assert_allclose(R1[:, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(R1[:, 0], [1, 0, 0], atol=1e-12)  # turned about x: x is unchanged


def test_slerp_ends_and_middle() -> None:
    R0 = Rotation.from_euler("z", 0.2).as_matrix()
    R1 = Rotation.from_euler("z", 1.4).as_matrix()
    np.testing.assert_allclose(so3.slerp(R0, R1, 0.0), R0, atol=1e-12)
    np.testing.assert_allclose(so3.slerp(R0, R1, 1.0), R1, atol=1e-12)
    np.testing.assert_allclose(so3.slerp(R0, R1, 0.5), Rotation.from_euler("z", 0.8).as_matrix(), atol=1e-12)
