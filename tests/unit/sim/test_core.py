"""Simulation core: commands, exact contacts on true surfaces, divergence, accessor contracts."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from palpate.config import load
from palpate.errors import ConfigError, SimulationDivergedError
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.nodes.sim.contacts import Contacts
from palpate.nodes.sim.core import Simulation
from palpate.nodes.sim.effectors import FingerConfig, ProbeConfig
from palpate.nodes.sim.model_stats import bare_step_rate
from palpate.nodes.sim.objects import ObjectSpec
from palpate.nodes.sim.scene import SceneConfig

TORUS = ObjectSpec(kind="torus", size_m=(0.03, 0.01))
CUBE = ObjectSpec(kind="cube", size_m=(0.05,))


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)  # MuJoCo writes MUJOCO_LOG.TXT into the working directory on divergence


def _probe(obj: ObjectSpec, start: tuple[float, float, float], **kwargs: float) -> Simulation:
    return Simulation(SceneConfig(effector="probe", object=obj, probe=ProbeConfig(start_position_m=start, **kwargs)))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cosine = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))


def _check_contract(c: Contacts) -> None:
    n = len(c.links)
    assert c.positions_m.shape == (n, 3) and c.positions_m.dtype == np.float64
    assert c.local_positions_m.shape == (n, 3) and c.local_positions_m.dtype == np.float64
    assert c.normals.shape == (n, 3) and c.normals.dtype == np.float64
    assert c.forces_n.shape == (n,) and c.forces_n.dtype == np.float64
    assert np.all(c.forces_n >= 0)
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-9)
    for array in (c.positions_m, c.local_positions_m, c.normals, c.forces_n):
        assert np.all(np.isfinite(array))


def test_probe_follows_the_commanded_twist() -> None:
    sim = _probe(CUBE, (0.0, 0.0, 0.2))
    position0, _ = sim.effector_pose()
    sim.set_velocity(np.array([0.02, -0.01, 0.005]), np.array([0.0, 0.0, 1.0]))
    sim.step(100)  # 0.2 s
    position, quat = sim.effector_pose()
    np.testing.assert_allclose(sim.time_s, 0.2, rtol=1e-12)
    np.testing.assert_allclose(position - position0, np.array([0.02, -0.01, 0.005]) * 0.2, atol=1e-9)
    # start faces -z (180 deg about x), then 0.2 rad about world z
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, quat)
    R = R.reshape(3, 3)
    expected_x = np.array([math.cos(0.2), math.sin(0.2), 0.0])
    np.testing.assert_allclose(R[:, 0], expected_x, atol=1e-6)
    np.testing.assert_allclose(R[:, 2], (0, 0, -1), atol=1e-9)
    assert len(sim.contacts()) == 0


def test_probe_batched_free_flight_equals_single_steps_even_with_gravity() -> None:
    scene = SceneConfig(
        effector="probe",
        object=CUBE,
        gravity_m_s2=(0.0, 0.0, -9.81),
        probe=ProbeConfig(start_position_m=(0.0, 0.0, 0.1)),
    )
    batched, single = Simulation(scene), Simulation(scene)
    for sim in (batched, single):
        sim.set_velocity(np.array([0.01, 0.0, -0.05]), np.array([0.3, -0.2, 0.5]))
    batched.step(500)  # 1 s: ends 1.5 cm above the top face, far stretches are batched
    for _ in range(500):
        single.step(1)
    for a, b in zip(batched.effector_pose(), single.effector_pose(), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_allclose(batched.effector_pose()[0], (0.01, 0.0, 0.05), atol=1e-9)


def test_probe_in_the_hole_of_a_torus_touches_nothing() -> None:
    sim = _probe(TORUS, (0.0, 0.0, 0.03))
    sim.set_velocity(np.array([0.0, 0.0, -0.1]), np.zeros(3))
    for _ in range(60):  # down through the hole to z = -0.03
        sim.step(5)
        _check_contract(sim.contacts())
        assert len(sim.contacts()) == 0, sim.effector_pose()[0]
    assert sim.effector_pose()[0][2] == pytest.approx(-0.03, abs=1e-9)


@pytest.mark.ycb
def test_probe_inside_an_open_cup_touches_nothing(ycb: Path) -> None:
    cup = ObjectSpec(kind="mesh", path=str(ycb / "065-j_cups.stl"))
    inside = (0.0, 0.0, 0.047)
    sim = _probe(cup, inside)
    # MuJoCo's convex hull of the cup would contain the probe: the exact sensor must not report it.
    hull = sim.object.mesh.convex_hull
    offsets = hull.face_normals @ np.array(inside) - np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
    assert np.all(offsets < 0)
    sim.set_velocity(np.array([0.0, 0.0, -0.02]), np.zeros(3))
    for _ in range(10):
        sim.step(10)
        assert len(sim.contacts()) == 0


def test_probe_goes_into_an_open_tray_and_touches_its_floor(tmp_path: Path) -> None:
    """An outside walkthrough: on a box without its top the probe's first touch was the rim, 5 cm to the
    side, with a horizontal normal (the opening read as solid). An open surface is a two-sided sheet."""
    from palpate.errors import MeshWarning

    box = trimesh.creation.box(extents=[0.1, 0.1, 0.04])
    box.update_faces(box.face_normals[:, 2] < 0.9)  # no top
    box.remove_unreferenced_vertices()
    path = tmp_path / "tray.stl"
    box.export(path)
    with pytest.warns(MeshWarning, match="two-sided sheet"):
        sim = _probe(ObjectSpec(kind="mesh", path=str(path)), (0.01, 0.0, 0.05))
    sim.set_velocity(np.array([0.0, 0.0, -0.05]), np.zeros(3))
    for _ in range(100):  # 0.4 cm a tick: down through the opening, then onto the floor
        sim.step(40)
        if len(sim.contacts()):
            break
    c = sim.contacts()
    _check_contract(c)
    assert len(c) == 1 and _angle_deg(c.normals[0], np.array([0.0, 0.0, 1.0])) < 1.0  # the floor, seen from above
    np.testing.assert_allclose(c.positions_m[0], (0.01, 0.0, -0.02), atol=1e-6)
    np.testing.assert_allclose(sim.effector_pose()[0], (0.01, 0.0, -0.012), atol=1e-5)
    with pytest.warns(MeshWarning):
        sim = _probe(ObjectSpec(kind="mesh", path=str(path)), (0.0, 0.01, 0.0))  # inside, at mid-height
    sim.set_velocity(np.array([0.05, 0.0, 0.0]), np.zeros(3))  # to a wall, from inside
    sim.step(1000)
    c = sim.contacts()
    assert len(c) == 1 and _angle_deg(c.normals[0], np.array([-1.0, 0.0, 0.0])) < 1.0  # the wall's inner side
    np.testing.assert_allclose(sim.effector_pose()[0], (0.05 - 0.008, 0.01, 0.0), atol=1e-5)


def test_probe_pressed_onto_a_cube_face_reports_one_contact_with_its_normal() -> None:
    sim = _probe(CUBE, (0.01, -0.005, 0.045), force_gain_n_s_per_m=40.0)
    sim.set_velocity(np.array([0.0, 0.0, -0.05]), np.zeros(3))
    sim.step(200)  # would travel 2 cm: stops on the face after 1.2 cm
    c = sim.contacts()
    _check_contract(c)
    assert len(c) == 1 and c.links == ["probe"]
    assert _angle_deg(c.normals[0], np.array([0.0, 0.0, 1.0])) < 5.0
    np.testing.assert_allclose(c.positions_m[0], (0.01, -0.005, 0.025), atol=1e-6)
    np.testing.assert_allclose(sim.effector_pose()[0], (0.01, -0.005, 0.033), atol=1e-6)
    np.testing.assert_allclose(c.forces_n, [40.0 * 0.05], rtol=1e-9)
    # the probe faces world -z, which is its local +z: the contact is on its front
    np.testing.assert_allclose(c.local_positions_m[0], (0, 0, 0.008), atol=1e-6)


def test_probe_slides_along_a_face_without_sinking() -> None:
    sim = _probe(CUBE, (-0.01, 0.0, 0.0331))
    sim.set_velocity(np.array([0.05, 0.0, -0.02]), np.zeros(3))
    sim.step(100)
    position, _ = sim.effector_pose()
    assert position[2] == pytest.approx(0.033, abs=1e-6)
    assert position[0] == pytest.approx(-0.01 + 0.05 * 0.2, abs=1e-6)
    assert len(sim.contacts()) == 1


def test_probe_pressed_onto_a_sphere_reports_the_radial_normal() -> None:
    u = np.array([1.0, -2.0, 2.0]) / 3.0
    sphere = ObjectSpec(kind="sphere", size_m=(0.03,))
    sim = _probe(sphere, tuple(u * 0.05))
    sim.set_velocity(-0.05 * u, np.zeros(3))
    sim.step(300)
    c = sim.contacts()
    assert len(c) == 1
    assert _angle_deg(c.normals[0], u) < 5.0
    assert np.linalg.norm(c.positions_m[0]) == pytest.approx(0.03, rel=2e-3)
    assert np.linalg.norm(sim.effector_pose()[0]) == pytest.approx(0.038, rel=2e-3)


def test_probe_stays_outside_the_torus_tube_when_pushed_into_it() -> None:
    sim = _probe(TORUS, (0.03, 0.0, 0.03))
    sim.set_velocity(np.array([0.0, 0.0, -0.1]), np.zeros(3))
    sim.step(300)
    position, _ = sim.effector_pose()
    distance = ExactContactSensor(sim.object.mesh).closest(position[None, :]).distance_m[0]
    assert distance == pytest.approx(0.008, abs=1e-6)
    c = sim.contacts()
    assert len(c) == 1 and _angle_deg(c.normals[0], np.array([0.0, 0.0, 1.0])) < 5.0


def test_finger_pressing_a_cube_gets_native_contacts_on_the_surface() -> None:
    # MCP 75 mm behind the centre of the 50 mm cube and 15 mm above its top: the tip lands on the top
    finger = FingerConfig(base_position_m=(-0.075 - 0.06812, 0.0, 0.04))
    sim = Simulation(SceneConfig(effector="finger", object=CUBE, finger=finger))
    sim.set_joint_targets(np.array([0.0, 0.6, 0.9, 0.5]))
    sim.step(300)
    c = sim.contacts()
    _check_contract(c)
    assert c.links == ["index_distal"] and c.forces_n[0] > 0
    assert _angle_deg(c.normals[0], np.array([0.0, 0.0, 1.0])) < 5.0
    assert c.positions_m[0, 2] == pytest.approx(0.025, abs=1e-6)
    distance = ExactContactSensor(sim.object.mesh).closest(c.positions_m).distance_m
    np.testing.assert_allclose(distance, 0.0, atol=1e-6)  # on the cube's surface, not mid-penetration
    # normals outward: the surface point plus a little of the normal is outside the cube
    outside = ExactContactSensor(sim.object.mesh).closest(c.positions_m + 1e-3 * c.normals).distance_m
    assert np.all(outside > 0.9e-3)
    # local positions map back to the world positions through the link poses
    for p, local, link in zip(c.positions_m, c.local_positions_m, c.links, strict=True):
        body = sim.data.body(link)
        np.testing.assert_allclose(body.xpos + body.xmat.reshape(3, 3) @ local, p, atol=1e-12)


def test_finger_on_a_torus_gets_exact_mesh_contacts() -> None:
    obj = ObjectSpec(kind="torus", size_m=(0.03, 0.012))
    sim = Simulation(SceneConfig(effector="finger", object=obj))
    sim.set_joint_targets(np.array([0.0, 1.0, 0.6, 0.3]))
    sim.step(300)
    c = sim.contacts()
    _check_contract(c)
    assert len(c) >= 1 and np.all(c.forces_n > 0)
    closest = ExactContactSensor(sim.object.mesh).closest(c.positions_m)
    np.testing.assert_allclose(closest.distance_m, 0.0, atol=1e-9)
    # MuJoCo does not collide the finger with the torus's hull on this path
    assert sim.data.ncon == 0


def test_joint_targets_are_clipped_to_the_limits() -> None:
    sim = Simulation(SceneConfig(effector="finger", finger=FingerConfig(base_position_m=(0.0, 0.0, 0.5))))
    sim.set_joint_targets(np.array([1.0, -1.0, 3.0, 0.5]))
    np.testing.assert_allclose(
        sim.data.ctrl, np.radians([20.0, 0.0, 100.0, 0.0]) + np.array([0, 0, 0, 0.5]), atol=1e-12
    )
    sim.step(500)
    np.testing.assert_allclose(sim.joint_positions(), sim.data.ctrl, atol=0.02)
    assert len(sim.contacts()) == 0


def test_commands_for_the_wrong_effector_or_shape_are_refused() -> None:
    finger = Simulation(SceneConfig(effector="finger"))
    with pytest.raises(ConfigError, match="set_joint_targets"):
        finger.set_velocity(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"\(4,\)"):
        finger.set_joint_targets(np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        finger.set_joint_targets(np.array([0.0, np.nan, 0.0, 0.0]))
    probe = _probe(CUBE, (0.0, 0.0, 0.1))
    with pytest.raises(ConfigError, match="set_velocity"):
        probe.set_joint_targets(np.zeros(0))
    assert probe.joint_positions().shape == (0,)


@pytest.mark.parametrize("effector", ["finger", "hand"])
def test_huge_time_step_raises_naming_it_and_suggesting_a_smaller_one(effector: str) -> None:
    scene = load(
        SceneConfig,
        {"effector": effector, "timestep_s": 0.5, effector: {"kp_nm_per_rad": 1000.0}, "object": {"kind": "cube"}},
    )
    sim = Simulation(scene)
    q = np.zeros(len(sim.joint_names))
    q[1] = 1.2
    sim.set_joint_targets(q)
    with pytest.raises(SimulationDivergedError) as info:
        sim.step(20)
    message = str(info.value)
    assert "time step 0.5 s" in message and "timestep_s: 0.25" in message


def test_huge_time_step_on_the_exact_mesh_path_raises_too() -> None:
    scene = SceneConfig(effector="finger", object=TORUS, timestep_s=0.05)
    sim = Simulation(scene)
    sim.set_joint_targets(np.array([0.0, 1.4, 0.6, 0.0]))
    with pytest.raises(SimulationDivergedError, match=r"time step 0.05 s.*timestep_s: 0.025"):
        sim.step(100)


def test_hand_steps_and_reports_its_fingertip_pose() -> None:
    sim = Simulation(SceneConfig(effector="hand"))
    assert len(sim.joint_names) == 21
    sim.step(10)
    position, quat = sim.effector_pose()
    np.testing.assert_allclose(position, sim.data.site("index_tip").xpos, atol=1e-12)
    assert np.linalg.norm(quat) == pytest.approx(1.0)
    _check_contract(sim.contacts())


def test_same_commands_give_the_same_trajectory() -> None:
    runs = []
    for _ in range(2):
        sim = Simulation(SceneConfig(effector="finger"))
        for k in range(20):
            sim.set_joint_targets(np.array([0.1 * math.sin(k), 0.05 * k, 0.04 * k, 0.02 * k]))
            sim.step(10)
        runs.append(sim.joint_positions())
    np.testing.assert_array_equal(runs[0], runs[1])


def test_bare_step_rate_counts_steps() -> None:
    sim = Simulation(SceneConfig(effector="finger"))
    rate = bare_step_rate(sim.model, seconds=0.05)
    assert 1e3 < rate < 1e8


def test_a_new_instability_warning_raises_once_per_new_count() -> None:
    sim = _probe(CUBE, (0.0, 0.0, 0.1))
    sim.step(1)
    index = int(mujoco.mjtWarning.mjWARN_BADQACC)
    sim.data.warning[index].number = 1  # what MuJoCo does when it resets a blown-up state
    with pytest.raises(SimulationDivergedError, match="bad acceleration"):
        sim.step(1)
    sim.step(1)  # the same count again: nothing new
    sim.data.warning[index].number = 2
    with pytest.raises(SimulationDivergedError, match="bad acceleration"):
        sim.step(1)


def test_a_non_finite_state_raises() -> None:
    sim = _probe(CUBE, (0.0, 0.0, 0.1))
    sim.data.qvel[4] = np.nan
    with pytest.raises(SimulationDivergedError, match="non-finite state"):
        sim._check_diverged(0.0)


def test_a_few_contacts_frames_in_scalars_give_numpys_bits() -> None:
    """Unit normals and body-frame points of up to four contacts in Python scalars, as numpy's path."""
    from palpate.nodes.sim.contacts import frames_match_numpy, unit_and_local, unit_and_local_numpy

    assert frames_match_numpy(samples=2000)
    normals = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    points, xmat, xpos = np.zeros((2, 3)), np.eye(3).reshape(1, 9), np.zeros((1, 3))
    assert unit_and_local(normals, points, [0, 0], xmat, xpos) is None  # numpy's path makes the NaN
    with np.errstate(invalid="ignore"):
        assert np.isnan(unit_and_local_numpy(normals, points, np.array([0, 0]), xmat, xpos)[0][0]).all()


def test_a_finger_pose_that_is_not_finite_is_named() -> None:
    sim = Simulation(SceneConfig(effector="finger", object=ObjectSpec(kind="torus")))
    position, quaternion = sim.effector_pose()
    assert np.isfinite(position).all() and np.isfinite(quaternion).all()
    sim.data.qpos[0] = np.nan
    sim._fresh = False  # as after a step
    with pytest.raises(SimulationDivergedError, match="effector position are not finite"):
        sim.effector_pose()


@pytest.mark.parametrize("compiled", [False, True])
def test_a_probe_centre_inside_the_object_is_pushed_out_along_the_face_normal(compiled: bool) -> None:
    """Centre 5 mm under the cube's top face (z = 0.025), nearest that face: one step puts it one
    probe radius above the face, over the same point, whatever the steps run in."""
    sim = Simulation(SceneConfig(effector="probe", object=CUBE))
    probe = sim.probe_contact
    assert probe is not None
    if compiled and not probe.compiled_steps:
        pytest.skip("MuJoCo's library not found: no compiled steps")
    probe.compiled_steps = compiled
    sim.data.qpos[0:3] = (0.01, 0.005, 0.02)
    sim.set_velocity(np.zeros(3), np.zeros(3))
    sim.step(1)
    np.testing.assert_allclose(sim.effector_pose()[0], (0.01, 0.005, 0.025 + probe.radius_m), atol=1e-9)
    c = sim.contacts()
    assert len(c) == 1
    np.testing.assert_allclose(c.normals[0], (0.0, 0.0, 1.0), atol=1e-9)
    np.testing.assert_allclose(c.positions_m[0], (0.01, 0.005, 0.025), atol=1e-9)
