"""The probe's compiled steps (nodes/sim/probe_kernels.py) give the Python loop's bits (to rounding where
numpy's 3-element sums fuse multiply-adds: tests/unit/numerics.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from palpate.nodes.sim import probe_kernels
from palpate.nodes.sim.core import Simulation
from palpate.nodes.sim.effectors import ProbeConfig
from palpate.nodes.sim.objects import ObjectSpec
from palpate.nodes.sim.scene import SceneConfig
from tests.unit.numerics import assert_same_to_rounding

pytestmark = pytest.mark.skipif(probe_kernels.mujoco_functions() is None, reason="MuJoCo's library not found")


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))


def _run(
    obj: ObjectSpec, start: tuple[float, float, float], compiled: bool, ticks: int = 400
) -> tuple[np.ndarray, int, int, int]:
    """Press, slide and turn the probe; qpos, qvel and the contacts of every tick in one array, contacts,
    compiled flag, and the patches built in Python."""
    sim = Simulation(SceneConfig(effector="probe", object=obj, probe=ProbeConfig(start_position_m=start)))
    probe = sim.probe_contact
    assert probe is not None
    probe.compiled_steps = compiled
    trace: list[np.ndarray] = []
    normal: np.ndarray | None = None
    touching, contacts = False, 0
    for k in range(ticks):
        angular = np.array([0.3 * math.sin(0.01 * k), 0.2, -0.5]) if (k // 50) % 2 else np.zeros(3)
        if normal is None:
            linear = np.array([0.0, 0.0, -0.05])
        elif not touching:
            linear = -0.05 * normal
        else:
            d = np.array([math.cos(0.02 * k), math.sin(0.02 * k), 0.0])
            t = d - (d @ normal) * normal
            linear = 0.03 * t / max(float(np.linalg.norm(t)), 1e-9) - 0.01 * normal
        sim.set_velocity(linear, angular)
        sim.step(5)
        c = sim.contacts()
        for array in (sim.data.qpos, sim.data.qvel, c.positions_m, c.normals, c.forces_n, c.local_positions_m):
            trace.append(np.ravel(array).copy())
        touching = len(c) > 0
        contacts += len(c)
        if touching:
            normal = c.normals.mean(axis=0) / np.linalg.norm(c.normals.mean(axis=0))
    return np.concatenate(trace), contacts, int(probe.compiled_steps), probe.warm_query.counts["builds"]


@pytest.mark.parametrize(
    ("obj", "start"),
    [
        (ObjectSpec(kind="torus", size_m=(0.03, 0.01)), (0.03, 0.0, 0.03)),
        (ObjectSpec(kind="cube", size_m=(0.05,)), (0.01, 0.005, 0.05)),
    ],
)
def test_compiled_probe_steps_give_the_python_loops_bits(obj: ObjectSpec, start: tuple[float, float, float]) -> None:
    python = _run(obj, start, compiled=False)
    compiled = _run(obj, start, compiled=True)
    assert python[1] > 100  # the probe pressed and slid for most ticks
    assert compiled[1] == python[1] and compiled[0].shape == python[0].shape
    assert_same_to_rounding(compiled[0], python[0])
    # the compiled steps build the patches themselves: Python builds only the first one
    assert python[3] > 20 and compiled[3] == 1


def test_the_steps_end_with_the_contacts_query_and_the_inward_velocity_dropped(monkeypatch: pytest.MonkeyPatch) -> None:
    """A compiled call that ends on a projection holds the hit at the projected centre (contacts() asks
    nothing), the same hit a fresh query gives, with no velocity into the surface left."""
    sim = Simulation(SceneConfig(effector="probe", object=ObjectSpec(kind="cube", size_m=(0.05,))))
    sim.data.qpos[0:3] = (0.01, 0.005, 0.035)  # 1 cm above the top face
    probe = sim.probe_contact
    assert probe is not None
    asked = []
    closest = probe_kernels.probe_closest

    def counted(*args: object) -> int:
        asked.append(1)
        return int(closest(*args))

    monkeypatch.setattr(probe_kernels, "probe_closest", counted)
    held = 0
    for _ in range(60):
        sim.set_velocity(np.array([0.02, 0.0, -0.05]), np.zeros(3))  # into the top face while sliding
        sim.step(5)
        asked.clear()
        read = sim.contacts()
        if len(read) and not asked:
            held += 1
            normal = read.normals[0]
            assert float(sim.data.qvel[0:3] @ normal) > -1e-12  # no velocity into the surface (0.05 m/s before)
            probe.query_cache[probe_kernels.HAS_HIT] = 0.0  # ask again at the same centre
            again = sim.contacts()
            assert asked
            for name in ("positions_m", "normals", "forces_n"):
                np.testing.assert_array_equal(getattr(read, name), getattr(again, name))
    assert held > 30


def test_a_fast_probe_gets_the_same_bits_in_python_and_compiled_steps() -> None:
    """At 0.5 m/s a step moves the probe 1 mm, more than the 0.2 mm contact tolerance: a free stretch
    batched one step too long would end inside the torus and be projected a step late."""

    def run(compiled: bool) -> tuple[np.ndarray, int]:
        sim = Simulation(SceneConfig(effector="probe", object=ObjectSpec(kind="torus", size_m=(0.03, 0.01))))
        probe = sim.probe_contact
        assert probe is not None
        probe.compiled_steps = compiled
        sim.data.qpos[0:3] = (0.045, 0.01, 0.04)
        trace, contacts = [], 0
        for k in range(60):
            sim.set_velocity(np.array([-0.2 * math.cos(0.1 * k), 0.1, -0.5]), np.zeros(3))
            sim.step(5)
            trace += [sim.data.qpos.copy(), sim.data.qvel.copy()]
            contacts += len(sim.contacts())
        return np.concatenate(trace), contacts

    python, compiled = run(False), run(True)
    assert python[1] >= 5  # it pressed on the tube for a while
    assert compiled[1] == python[1]
    assert_same_to_rounding(compiled[0], python[0])
