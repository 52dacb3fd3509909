"""Scripted exploration motion: determinism, limits, smoothness, and that it touches the cube."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from palpate.errors import ConfigError
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.nodes.sim.motion import ExplorationMotion, MotionConfig, explore
from palpate.nodes.sim.objects import ObjectSpec
from palpate.nodes.sim.scene import SceneConfig

FAST = MotionConfig(candidate_samples=400)


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))


def _targets(seed: int, times: np.ndarray, effector: str = "finger") -> np.ndarray:
    motion = ExplorationMotion(SceneConfig(effector=effector), np.random.default_rng(seed), FAST)
    return np.array([motion.targets(float(t)) for t in times])


def test_same_seed_gives_the_same_motion_whatever_the_query_times() -> None:
    times = np.arange(0.0, 4.0, 0.01)
    a = _targets(7, times)
    b = _targets(7, times[::-1])[::-1]  # queried backwards after generating ahead
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - _targets(8, times)).max() > 0.1


def test_targets_stay_within_the_limits_and_move_smoothly() -> None:
    motion = ExplorationMotion(SceneConfig(effector="finger"), np.random.default_rng(1), FAST)
    times = np.arange(0.0, 5.0, 0.001)
    q = np.array([motion.targets(float(t)) for t in times])
    limits = motion.kin.limits
    assert np.all(q >= limits[:, 0] - 1e-12) and np.all(q <= limits[:, 1] + 1e-12)
    speed = np.abs(np.diff(q, axis=0)).max() / 0.001
    assert speed < 30.0  # rad/s: no jumps between waypoints
    assert np.ptp(q[:, 1]) > 0.3  # it does move


def test_hand_motion_moves_only_the_exploring_finger() -> None:
    times = np.arange(0.0, 3.0, 0.05)
    q = _targets(0, times, effector="hand")
    assert q.shape == (len(times), 21)
    np.testing.assert_array_equal(q[:, 4:], 0.0)
    assert np.ptp(q[:, :4]) > 0.3


def test_exploration_taps_the_cube_with_the_fingertip_on_two_faces() -> None:
    scene = SceneConfig(effector="finger")
    positions, times, onsets = explore(scene, seed=3, seconds=4.0)
    assert sum(onsets) >= 4 and len(positions) > 50
    assert np.all(np.diff(times) >= 0) and times[-1] <= 4.0 + 1e-9
    sensor = ExactContactSensor(ExplorationMotion(scene, np.random.default_rng(0), FAST).object.mesh)
    closest = sensor.closest(positions)
    np.testing.assert_allclose(closest.distance_m, 0.0, atol=1e-6)
    faces = {tuple(np.round(n).astype(int)) for n in closest.normals}
    assert len(faces) >= 2, faces


@pytest.mark.parametrize("count", [3, 12, 200])
def test_clearance_distances_skip_only_points_surely_clear(count: int) -> None:
    """Exact distances (the sensor's bits) wherever they may be below the need; elsewhere a bound above it."""
    motion = ExplorationMotion(SceneConfig(effector="hand"), np.random.default_rng(2), FAST)
    rng = np.random.default_rng(count)
    lo, hi = motion._box
    points = lo + (hi - lo) * rng.uniform(-1.0, 2.0, (count, 3))
    need = rng.uniform(0.0, 0.02, count)
    got = motion._distances_below(points, need)
    exact = np.asarray(motion.sensor.closest(points).distance_m)
    may_be_below = exact < need + 1e-3
    np.testing.assert_array_equal(got[may_be_below], exact[may_be_below])
    assert np.all(got[~may_be_below] >= need[~may_be_below])
    np.testing.assert_array_equal(got >= need, exact >= need)


def test_an_object_out_of_the_fingertips_reach_is_a_config_error_naming_it() -> None:
    far = SceneConfig(effector="finger", object=ObjectSpec(kind="sphere", size_m=(0.01,), position_m=(0.4, 0.4, 0.4)))
    with pytest.raises(ConfigError, match=r"finger's fingertip cannot reach the object 'sphere'.*scripted_motion off"):
        ExplorationMotion(far, np.random.default_rng(0), MotionConfig(candidate_samples=50))


def test_a_long_run_keeps_a_bounded_history_with_the_same_targets(monkeypatch: pytest.MonkeyPatch) -> None:
    """Waypoints older than HISTORY_S behind the latest time are dropped (memory flat over hours)."""
    times = np.arange(0.0, 40.0, 0.02)
    whole = ExplorationMotion(SceneConfig(effector="finger"), np.random.default_rng(4), FAST)
    expected = np.array([whole.targets(float(t)) for t in times])
    monkeypatch.setattr(ExplorationMotion, "HISTORY_S", 5.0)
    monkeypatch.setattr(ExplorationMotion, "_TRIM_AT", 16)
    motion = ExplorationMotion(SceneConfig(effector="finger"), np.random.default_rng(4), FAST)
    got, kept = [], []
    for t in times:
        got.append(motion.targets(float(t)))
        kept.append(len(motion._times))
    np.testing.assert_array_equal(np.array(got), expected)
    assert max(kept) < len(whole._times) / 4  # 40 s asked, at most about 5 s kept
    assert 30.0 < motion._times[0] <= times[-1] - 5.0
    np.testing.assert_array_equal(motion.targets(35.5), whole.targets(35.5))
    with pytest.raises(ValueError, match="more than 5 s before the latest time asked"):
        motion.targets(20.0)
