"""The hand's and finger's compiled broad phase (nodes/sim/capsule_kernels.py) gives numpy's bits."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from palpate.nodes.sim import capsule_kernels
from palpate.nodes.sim.capsules import sphere_centres
from palpate.nodes.sim.core import Simulation
from palpate.nodes.sim.motion import ExplorationMotion, MotionConfig
from palpate.nodes.sim.objects import ObjectSpec
from palpate.nodes.sim.scene import SceneConfig


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))


def test_sphere_bounds_give_numpys_centres_and_spheres() -> None:
    """Random frames, offsets (general, and along the axis as capsules have them) and caches, including
    spheres exactly at the reach and caches that never skip (-inf)."""
    if not capsule_kernels.matches_numpy():
        pytest.skip("numpy sums in another order on this machine: the simulation keeps the numpy path")
    rng = np.random.default_rng(3)
    for trial in range(500):
        count = int(rng.integers(1, 200))
        xpos, xmat = rng.standard_normal((12, 3)), rng.standard_normal((12, 9))
        geoms = rng.integers(0, 12, count)
        offsets = rng.standard_normal((count, 3))
        if trial % 2:
            offsets[:, :2] = 0.0
        cache_p = xpos[geoms] + 0.01 * rng.standard_normal((count, 3))
        cache_d = 0.02 * rng.standard_normal(count)
        cache_d[rng.random(count) < 0.1] = -np.inf
        reach = np.full(count, 0.0081)
        centres, near = capsule_kernels.numpy_bounds(xpos, xmat, geoms, offsets, cache_p, cache_d, reach)
        reach[near[:1]] = (cache_d - np.linalg.norm(centres - cache_p, axis=1))[near[:1]]  # on the edge
        centres, near = capsule_kernels.numpy_bounds(xpos, xmat, geoms, offsets, cache_p, cache_d, reach)
        got, found = np.empty((count, 3)), np.empty(count, dtype=np.int64)
        n = capsule_kernels.sphere_bounds(xpos, xmat, geoms, offsets, cache_p, cache_d, reach, got, found)
        assert got.tobytes() == centres.tobytes()
        np.testing.assert_array_equal(found[:n], near)


def _explore(effector: str, compiled: bool, ticks: int = 250) -> tuple[str, int]:
    """The scripted exploration of a torus (exact-mesh penalty contacts): hash of joint angles, velocities
    and contacts per tick, and the contacts."""
    scene = SceneConfig(effector=effector, object=ObjectSpec(kind="torus"))
    sim = Simulation(scene)
    assert sim.penalty_contacts is not None
    sim.penalty_contacts.compiled_bounds = compiled
    sim.penalty_contacts.compiled_steps = False  # the Python step loop, which places the spheres with either path
    motion = ExplorationMotion(scene, np.random.default_rng(0), MotionConfig(candidate_samples=400), obj=sim.object)
    digest, contacts = hashlib.sha256(), 0
    for _ in range(ticks):
        sim.set_joint_targets(motion.targets(sim.time_s))
        sim.step(5)
        c = sim.contacts()
        for array in (sim.data.qpos, sim.data.qvel, c.positions_m, c.normals, c.forces_n):
            digest.update(np.ascontiguousarray(array).tobytes())
        contacts += len(c)
    return digest.hexdigest(), contacts


@pytest.mark.parametrize("effector", ["finger", "hand"])
def test_compiled_bounds_give_the_numpy_paths_trajectory(effector: str) -> None:
    if not capsule_kernels.matches_numpy():
        pytest.skip("numpy sums in another order on this machine: the simulation keeps the numpy path")
    numpy_run = _explore(effector, compiled=False)
    assert numpy_run[1] > 10  # the motion touched the torus
    assert _explore(effector, compiled=True) == numpy_run


def test_the_simulation_keeps_the_numpy_path_where_the_bits_differ(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(capsule_kernels, "matches_numpy", lambda: False)
    penalty = Simulation(SceneConfig(effector="finger", object=ObjectSpec(kind="torus"))).penalty_contacts
    assert penalty is not None and not penalty.compiled_bounds


@pytest.mark.parametrize("effector", ["finger", "hand"])
def test_the_motions_spheres_are_the_simulations_centres(effector: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The scripted motion places its clearance spheres in compiled code: sphere_centres' bits."""
    if not capsule_kernels.matches_numpy():
        pytest.skip("numpy sums in another order on this machine: the motion keeps the numpy path")
    scene = SceneConfig(effector=effector, object=ObjectSpec(kind="torus"))
    kin = ExplorationMotion(scene, np.random.default_rng(0), MotionConfig(candidate_samples=400)).kin
    lo, hi = kin.limits[:, 0], kin.limits[:, 1]
    rng = np.random.default_rng(7)
    for q in lo + (hi - lo) * rng.random((50, len(lo))):
        compiled = kin.spheres(q)
        with monkeypatch.context() as patch:
            patch.setattr(capsule_kernels, "matches_numpy", lambda: False)
            reference = kin.spheres(q)
        assert compiled.tobytes() == reference.tobytes()
        kin.forward(q)
        assert compiled.tobytes() == sphere_centres(kin.data, kin.sph_geoms, kin.sph_offsets).tobytes()
