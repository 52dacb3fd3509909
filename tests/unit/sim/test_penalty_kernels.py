"""A hand's or finger's compiled steps on a mesh (nodes/sim/penalty_kernels.py) give the Python loop's bits."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from palpate.errors import SimulationDivergedError
from palpate.geometry.mesh_query import WarmClosest
from palpate.nodes.sim import penalty_kernels
from palpate.nodes.sim.core import Simulation
from palpate.nodes.sim.motion import ExplorationMotion, MotionConfig
from palpate.nodes.sim.objects import ObjectSpec
from palpate.nodes.sim.penalty_contact import PenaltyContacts
from palpate.nodes.sim.scene import SceneConfig

TORUS = ObjectSpec(kind="torus")


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))


def _penalty(sim: Simulation) -> PenaltyContacts:
    assert sim.penalty_contacts is not None
    return sim.penalty_contacts


def _compiled_or_skip(sim: Simulation) -> None:
    if not _penalty(sim).compiled_steps:
        pytest.skip("MuJoCo's library not found, or numpy sums in another order here: the Python loop runs")


def test_penalty_wrench_gives_numpys_bits() -> None:
    if penalty_kernels.mujoco_functions() is None:
        pytest.skip("MuJoCo's library not found")
    assert penalty_kernels.matches_numpy(samples=2000)


def _explore(effector: str, compiled: bool, ticks: int = 250, arena_faces: int = 0) -> tuple[str, int, dict[str, int]]:
    """The scripted exploration of a torus: hash of qpos, qvel, the applied wrench and the contacts per
    tick, the contacts, and the spheres' query counts (``arena_faces``: the compiled patches' arena
    at first)."""
    scene = SceneConfig(effector=effector, object=TORUS)
    sim = Simulation(scene)
    if compiled:
        _compiled_or_skip(sim)
    penalty = _penalty(sim)
    penalty.compiled_steps = compiled
    if arena_faces:
        penalty.patches = penalty_kernels.WarmPatches(
            len(penalty.sphere_geoms), WarmClosest(penalty.sensor).max_patch_faces, capacity=arena_faces
        )
    motion = ExplorationMotion(scene, np.random.default_rng(0), MotionConfig(candidate_samples=400), obj=sim.object)
    digest, contacts = hashlib.sha256(), 0
    for _ in range(ticks):
        sim.set_joint_targets(motion.targets(sim.time_s))
        sim.step(5)
        arrays = (sim.data.qpos, sim.data.qvel, sim.data.xfrc_applied)
        c = sim.contacts()
        for array in (*arrays, c.positions_m, c.local_positions_m, c.normals, c.forces_n):
            digest.update(np.ascontiguousarray(array).tobytes())
        digest.update(" ".join(c.links).encode())
        contacts += len(c)
    counts = {"builds": 0, "patch": 0}
    for warm in penalty.warm_queries.values():
        for key in counts:
            counts[key] += warm.counts[key]
    counts["arena"] = len(penalty.patches.faces)
    return digest.hexdigest(), contacts, counts


@pytest.mark.parametrize("effector", ["finger", "hand"])
def test_compiled_steps_give_the_python_loops_trajectory(effector: str) -> None:
    python = _explore(effector, compiled=False)
    compiled = _explore(effector, compiled=True)
    assert python[1] > 10  # the motion touched the torus
    assert compiled[:2] == python[:2]
    # the compiled path builds patches itself
    assert python[2]["builds"] > compiled[2]["builds"]


@pytest.mark.parametrize("few_points", [4, 0])
def test_reading_the_contacts_between_steps_leaves_the_trajectory_as_it_is(
    few_points: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """contacts() fills the query buffers that the next step then takes (HITS_CURRENT): the same
    trajectory to the bit as stepping without reading them (FEW_POINTS 0: every query a batch, which
    the step asks again)."""
    monkeypatch.setattr("palpate.nodes.sim.penalty_contact.FEW_POINTS", few_points)
    trajectories, touching = [], 0
    for read in (True, False):
        scene = SceneConfig(effector="finger", object=TORUS)
        sim = Simulation(scene)
        _compiled_or_skip(sim)
        motion = ExplorationMotion(scene, np.random.default_rng(0), MotionConfig(candidate_samples=400), obj=sim.object)
        digest = hashlib.sha256()
        for tick in range(200):
            sim.set_joint_targets(motion.targets(sim.time_s))
            sim.step(5)
            digest.update(sim.data.qpos.tobytes() + sim.data.qvel.tobytes())
            if read and tick % 3:  # and a tick now and then without: the next step asks again
                touching += len(sim.contacts())
        trajectories.append(digest.hexdigest())
    assert touching > 10  # the reused answers held touching spheres
    assert trajectories[0] == trajectories[1]


def test_a_full_arena_hands_the_build_to_python_and_grows() -> None:
    python = _explore("finger", compiled=False, ticks=150)
    compiled = _explore("finger", compiled=True, ticks=150, arena_faces=64)
    assert compiled[:2] == python[:2] and compiled[2]["arena"] > 64


def test_more_near_spheres_than_the_few_point_path_go_to_the_sensors_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    """With FEW_POINTS at 0 every step with a near sphere takes the sensor's vectorised query."""
    monkeypatch.setattr("palpate.nodes.sim.penalty_contact.FEW_POINTS", 0)
    python = _explore("finger", compiled=False, ticks=120)
    compiled = _explore("finger", compiled=True, ticks=120)
    assert python[1] > 0
    assert compiled[:2] == python[:2]


def test_warm_patches_pack_each_spheres_patch_and_grow_the_arena() -> None:
    sensor = _penalty(Simulation(SceneConfig(effector="finger", object=TORUS))).sensor
    patches = penalty_kernels.WarmPatches(3, max_patch_faces=8)  # an arena of 64 faces: it must grow
    warms = [WarmClosest(sensor) for _ in range(2)]
    for k, (warm, point) in enumerate(zip(warms, ([0.04, 0.0, 0.0], [0.0, 0.035, 0.005]), strict=True)):
        warm.query(np.array(point))
        patches.store(2 * k, warm)
    assert patches.size[1] == 0 and patches.size.sum() > 64 and patches.used[0] == patches.size.sum()
    for k, warm in zip((0, 2), warms, strict=True):
        fresh = WarmClosest(sensor)
        patches.searches[k] = 5
        patches.load(k, fresh)
        assert patches.searches[k] == 0 and fresh.counts["patch"] == 5
        for got, expected in zip(fresh.patch(), warm.patch(), strict=True):
            np.testing.assert_array_equal(got, expected)


def test_the_face_grid_finds_the_k_d_trees_faces() -> None:
    sensor = _penalty(Simulation(SceneConfig(effector="finger", object=TORUS))).sensor
    grid, cell_m, _ = penalty_kernels.face_grid(sensor)
    tree, _, _ = sensor.face_index()
    out = np.zeros(len(sensor.face_normals), dtype=np.int64)
    rng = np.random.default_rng(5)
    for _ in range(200):
        p = 0.05 * rng.standard_normal(3)
        reach = float(rng.uniform(0.001, 0.03))
        count = penalty_kernels.grid_faces(grid, cell_m, *p, reach, out, len(out))
        expected = tree.query_ball_point(p, reach)
        np.testing.assert_array_equal(np.sort(out[:count]), np.sort(expected))
        if len(expected) > 3:  # a smaller limit stops the scan at limit + 1 of the same faces
            stopped = penalty_kernels.grid_faces(grid, cell_m, *p, reach, out, 2)
            assert stopped == 3 and set(out[:3].tolist()) <= set(expected)


def test_without_mujocos_library_the_python_loop_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(penalty_kernels, "mujoco_functions", lambda: None)
    sim = Simulation(SceneConfig(effector="finger", object=TORUS))
    assert not _penalty(sim).compiled_steps
    sim.set_joint_targets(np.array([0.0, 1.0, 0.6, 0.3]))
    sim.step(300)
    assert len(sim.contacts()) >= 1


def test_a_segment_overrun_by_a_huge_time_step_raises_on_the_compiled_path() -> None:
    sim = Simulation(SceneConfig(effector="finger", object=TORUS, timestep_s=0.05))
    _compiled_or_skip(sim)
    sim.set_joint_targets(np.array([0.0, 1.4, 0.6, 0.0]))
    with pytest.raises(SimulationDivergedError, match=r"time step 0.05 s.*timestep_s: 0.025"):
        sim.step(100)


def test_a_query_from_a_stale_face_gives_the_sensors_answer_and_keeps_a_patch_only_within_reach() -> None:
    """query_near from a face the sphere found far away (its last query was elsewhere): the sensor's
    own answer; a sphere farther out than its reach plus the patch reach keeps no patch (it is asked
    again only after leaving that patch), a nearer one keeps one."""
    sim = Simulation(SceneConfig(effector="finger", object=TORUS))
    _compiled_or_skip(sim)
    penalty = _penalty(sim)
    sensor = penalty.sensor
    k = penalty_kernels
    reach_m = float(penalty.kernel_params[k.P_REACH])
    sphere_reach = np.array([0.008])
    rng = np.random.default_rng(11)
    kept, dropped, python = 0, 0, 0
    for _ in range(150):
        surface = sensor.closest(0.06 * rng.standard_normal((1, 3)))
        depth = float(rng.uniform(0.0, 0.025))
        centre = surface.points_m + depth * surface.normals  # outside, depth from the surface
        patches = k.WarmPatches(1, WarmClosest(sensor).max_patch_faces)
        elsewhere = surface.points_m + rng.uniform(-0.01, 0.01, 3)
        patches.face[0] = int(sensor.closest(elsewhere).face_ids[0])  # a stale face, up to 1.7 cm away
        points, dist, hit = np.zeros((1, 3)), np.zeros(1), np.zeros(1, dtype=np.int64)
        scratch, search = np.zeros(len(sensor.face_normals), dtype=np.int64), np.zeros(k.SEARCH_SIZE)
        done = k.query_near(
            0, centre, np.zeros(1, dtype=np.int64), 1, sphere_reach, penalty.kernel_mesh, penalty.kernel_grid,
            patches.arrays(), penalty.kernel_params, points, dist, hit, scratch, search,
        )  # fmt: skip
        if done == 0:  # Python's turn (too far from the face to build a patch, a weak sign)
            python += 1
            continue
        expected = sensor.closest(centre)
        np.testing.assert_array_equal(points, expected.points_m)
        np.testing.assert_array_equal(dist, expected.distance_m)
        np.testing.assert_array_equal(hit, expected.face_ids)
        far = dist[0] - sphere_reach[0] > reach_m * 1.001
        near = dist[0] - sphere_reach[0] < reach_m * 0.999
        assert (patches.size[0] == 0) == far or not (far or near)
        kept += int(near)
        dropped += int(far)
    assert kept > 20 and dropped > 20 and python < 30, (kept, dropped, python)


def test_the_steps_leave_their_final_states_queries_to_the_contacts(monkeypatch: pytest.MonkeyPatch) -> None:
    """A compiled step call ends with the queries of the state it reaches (END_QUERIED): contacts()
    reads them without asking again, and asking again gives the same contacts."""
    scene = SceneConfig(effector="finger", object=TORUS)
    sim = Simulation(scene)
    _compiled_or_skip(sim)
    motion = ExplorationMotion(scene, np.random.default_rng(0), MotionConfig(candidate_samples=400), obj=sim.object)
    asked = []
    sphere_hits = penalty_kernels.sphere_hits

    def counted(*args: object) -> tuple[int, int]:
        asked.append(1)
        return sphere_hits(*args)

    monkeypatch.setattr(penalty_kernels, "sphere_hits", counted)
    reused, touching = 0, 0
    for _ in range(200):
        sim.set_joint_targets(motion.targets(sim.time_s))
        sim.step(5)
        held = _penalty(sim).hits_current
        asked.clear()
        read = sim.contacts()
        if held:
            reused += 1
            assert not asked  # read from the buffers
            _penalty(sim).hits_current = False  # ask again at the same state
            again = sim.contacts()
            assert asked
            for name in ("positions_m", "normals", "forces_n"):
                np.testing.assert_array_equal(getattr(read, name), getattr(again, name))
        touching += len(read)
    assert reused > 150 and touching > 10
