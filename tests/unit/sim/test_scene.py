"""Scene config from YAML mappings, model assembly and effector placement."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from palpate.config import load
from palpate.description import load_hand, mount_fact
from palpate.errors import ConfigError
from palpate.nodes.sim.effectors import FingerConfig, HandConfig, ProbeConfig
from palpate.nodes.sim.objects import KINDS, ObjectSpec, load_object
from palpate.nodes.sim.scene import (
    SceneConfig,
    build_model,
    descent_xy,
    effector_base_position,
    effector_mount,
    target_mcp_position,
)

NOT_LOADED = ObjectSpec(kind="mesh", path="/nonexistent.stl")  # never loaded: the base is given
PRIMITIVES = {
    "cube": {"kind": "cube", "size_m": [0.05]},
    "rubiks_cube": {"kind": "rubiks_cube"},
    "box": {"kind": "box", "size_m": [0.04, 0.06, 0.03]},
    "sphere": {"kind": "sphere", "size_m": [0.03]},
    "cylinder": {"kind": "cylinder", "size_m": [0.025, 0.06]},
    "torus": {"kind": "torus", "size_m": [0.03, 0.01]},
}


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))


def test_every_primitive_kind_is_covered() -> None:
    assert set(PRIMITIVES) == set(KINDS) - {"mesh"}


def test_load_reads_every_section() -> None:
    scene = load(
        SceneConfig,
        {
            "effector": "finger",
            "object": {"kind": "sphere", "size_m": [0.03], "position_m": [0.1, 0, 0]},
            "finger": {"finger": "ring", "kp_nm_per_rad": 0.7, "mcp_flex_range_deg": [0, 80]},
            "timestep_s": 0.001,
            "gravity_m_s2": [0, 0, -9.81],
        },
        "scene.yaml: scene",
    )
    assert scene.finger == FingerConfig(finger="ring", kp_nm_per_rad=0.7, mcp_flex_range_deg=(0.0, 80.0))
    assert scene.object.size_m == (0.03,)
    model = build_model(scene)
    assert model.opt.timestep == 0.001
    np.testing.assert_allclose(model.opt.gravity, (0, 0, -9.81))
    assert model.joint(0).name == "ring_mcp_abd"


def test_defaults_have_no_gravity_and_a_2_ms_step() -> None:
    model = build_model(SceneConfig())
    assert model.opt.timestep == 0.002
    np.testing.assert_array_equal(model.opt.gravity, (0, 0, 0))


@pytest.mark.parametrize(
    ("d", "fragment"),
    [
        ({"effector": "probe", "radius_m": 0.01}, "scene.radius_m: unknown key 'radius_m'; known keys: contact_tol"),
        ({"effector": "probe", "probe": {"radius": 0.01}}, "scene.probe.radius: unknown key 'radius'"),
        ({"effector": "gripper"}, "scene.effector: expected one of ['hand', 'finger', 'probe'], got 'gripper'"),
        ({"effector": "probe", "hand": {"scale": 2}}, "scene: section 'hand' is not used by effector 'probe'"),
        ({"effector": "probe", "finger": {}}, "scene: section 'finger' is not used by effector 'probe'; remove it"),
        ({"hand": {}}, "scene: section 'hand' is not used by effector 'finger'; remove it or set effector: hand"),
        ({"effector": "finger", "finger": {"pip_range_deg": [90, 0]}}, "finger: pip_range_deg = [90.0, 0.0]: empty"),
        ({"effector": "hand", "hand": {"thumb_ip_range_deg": [5, 5]}}, "hand: thumb_ip_range_deg = [5.0, 5.0]: empty"),
        ({"timestep_s": "fast"}, "scene.timestep_s: expected a finite number > 0, got 'fast'"),
        ({"timestep_s": -0.001}, "scene.timestep_s: expected a finite number > 0, got -0.001"),
        ({"effector": "finger", "finger": {"finger": "thumb"}}, "scene.finger.finger: expected one of ['index', "),
        ({"effector": "finger", "finger": {"pip_range_deg": [0, 100, 5]}}, "finger.pip_range_deg: expected 2 items"),
        ({"effector": "finger", "finger": {"pip_range_deg": [0, "a"]}}, "pip_range_deg[1]: expected"),
        ({"probe": {"radius_m": 0.0}}, "scene.probe.radius_m: expected a finite number > 0, got 0.0"),
        ({"object": {"kind": "cube", "colour": "red"}}, "scene.object.colour: unknown key 'colour'"),
    ],
)
def test_load_rejects_bad_keys_and_values_naming_them(d: dict[str, object], fragment: str) -> None:
    with pytest.raises(ConfigError) as info:
        load(SceneConfig, d, "launch/x.yaml: scene")
    assert fragment in str(info.value)
    assert "launch/x.yaml" in str(info.value)


def test_an_empty_joint_range_is_refused_at_the_key_that_holds_it() -> None:
    with pytest.raises(ConfigError) as info:
        load(SceneConfig, {"effector": "finger", "finger": {"dip_range_deg": [10, -10]}}, "scene")
    assert info.value.path == ("finger", "dip_range_deg")
    with pytest.raises(ConfigError, match="mcp_abd_range_deg = \\[20, -20\\]: empty joint range"):
        FingerConfig(mcp_abd_range_deg=(20, -20))


def test_only_the_section_of_the_effector_in_use_is_set() -> None:
    scene = load(SceneConfig, {"effector": "probe", "probe": None, "finger": None}, "scene")
    assert scene.probe_config() == ProbeConfig() and (scene.hand, scene.finger) == (None, None)
    assert SceneConfig(effector="finger") == SceneConfig(effector="finger", finger=FingerConfig())
    with pytest.raises(ConfigError, match="the scene's effector is 'probe', not 'finger'"):
        scene.finger_config()


@pytest.mark.parametrize("effector", ["hand", "finger", "probe"])
@pytest.mark.parametrize("kind", sorted(PRIMITIVES))
def test_builds_every_effector_with_every_primitive(effector: str, kind: str) -> None:
    scene = load(SceneConfig, {"effector": effector, "object": PRIMITIVES[kind]})
    model = build_model(scene)
    joints = {"hand": 21, "finger": 4, "probe": 1}[effector]
    assert model.njnt == joints
    names = {model.body(i).name for i in range(model.nbody)}
    assert ("palm" in names) == (effector == "hand")
    assert ("probe" in names) == (effector == "probe")
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=5)
    assert np.all(np.isfinite(data.qpos))


def test_finger_mcp_is_placed_at_the_offset_from_the_object() -> None:
    scene = SceneConfig(effector="finger", object=ObjectSpec(kind="cube", size_m=(0.05,), position_m=(0.2, 0, 0)))
    model = build_model(scene)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    expected = np.array([0.2 - 0.025, 0.0, 0.025]) + np.array(scene.finger_mcp_offset_m)
    np.testing.assert_allclose(data.body("index_proximal").xpos, expected, atol=1e-12)
    np.testing.assert_allclose(target_mcp_position(scene, load_object(scene.object)), expected, atol=1e-12)


def test_the_descriptions_finger_mount_is_where_the_default_scene_puts_the_finger() -> None:
    """hand.yaml's finger_mount (the mappers' default mount) is the finger's placement on the default
    object, exactly: the launch files give neither the simulator nor the mappers a base."""
    mount = load_hand().finger_mount
    scene = SceneConfig(effector="finger")
    base = effector_base_position(scene, load_object(scene.object))
    assert (scene.finger_config().finger, tuple(base.tolist())) == (mount.finger, mount.base_position_m)
    assert effector_mount(scene) == mount_fact("finger", mount.finger, 1.0, mount.base_position_m, (1, 0, 0, 0))
    given = SceneConfig(effector="finger", finger=FingerConfig(base_position_m=(0.1, 0.2, 0.3)), object=NOT_LOADED)
    assert effector_mount(given)["base_position_m"] == [0.1, 0.2, 0.3]
    assert effector_mount(SceneConfig(effector="probe")) == {"effector": "probe"}
    # the hand taps with its pose finger (the index for the thumb): a mapper of another finger sees no tap
    hand = SceneConfig(effector="hand", object=NOT_LOADED, hand=HandConfig(base_position_m=(0.1, 0.2, 0.3)))
    assert effector_mount(hand)["finger"] == "index"
    ring = SceneConfig(
        effector="hand", object=NOT_LOADED, hand=HandConfig(base_position_m=(0.1, 0.2, 0.3), pose_finger="ring")
    )
    assert effector_mount(ring)["finger"] == "ring"


def test_hand_places_its_index_mcp_like_the_finger() -> None:
    finger, hand = SceneConfig(effector="finger"), SceneConfig(effector="hand")
    positions = []
    for scene in (finger, hand):
        model = build_model(scene)
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        positions.append(data.body("index_proximal").xpos.copy())
    np.testing.assert_allclose(positions[0], positions[1], atol=1e-12)


def test_probe_starts_above_the_object_facing_down() -> None:
    scene = SceneConfig(effector="probe", probe=ProbeConfig(start_clearance_m=0.02))
    model = build_model(scene)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.body("probe").xpos, (0, 0, 0.0285 + 0.008 + 0.02), atol=1e-12)
    np.testing.assert_allclose(data.body("probe").xmat.reshape(3, 3)[:, 2], (0, 0, -1), atol=1e-12)


def test_a_probe_start_inside_the_object_is_refused_by_name(tmp_path: Path) -> None:
    sphere = ObjectSpec(**PRIMITIVES["sphere"])
    obj = load_object(sphere)

    def scene(start: tuple[float, float, float]) -> SceneConfig:
        return SceneConfig(effector="probe", object=sphere, probe=ProbeConfig(start_position_m=start))

    with pytest.raises(ConfigError, match=r"start_position_m = \[0.0, 0.0, 0.01\] lies inside the object") as info:
        effector_base_position(scene((0.0, 0.0, 0.01)), obj)
    assert info.value.path == ("start_position_m",)
    np.testing.assert_allclose(effector_base_position(scene((0.0, 0.0, 0.05)), obj), (0.0, 0.0, 0.05))
    np.testing.assert_allclose(effector_base_position(scene((0.029, 0.029, 0.0)), obj), (0.029, 0.029, 0.0))  # corner
    # an open mesh has no inside: its start is not judged
    import trimesh

    box = trimesh.creation.box((0.04, 0.04, 0.04))
    box.update_faces(np.arange(len(box.faces)) > 1)  # one face of the box removed
    box.export(tmp_path / "open.stl")
    open_box = ObjectSpec(kind="mesh", path=str(tmp_path / "open.stl"))
    config = SceneConfig(effector="probe", object=open_box, probe=ProbeConfig(start_position_m=(0.0, 0.0, 0.0)))
    with pytest.warns(UserWarning):
        np.testing.assert_allclose(effector_base_position(config, load_object(open_box)), 0.0)


def test_probe_starts_over_the_object_where_its_centre_is_a_hole() -> None:
    torus = load_object(ObjectSpec(kind="torus"))  # the default ring: major radius 40 mm, tube 15 mm
    x, y = descent_xy(torus, radius_m=0.008)
    off_axis = float(np.hypot(x, y))
    assert 0.025 + 0.005 <= off_axis <= 0.04, (x, y)  # over the tube (inner edge at 25 mm), not the hole
    base = effector_base_position(SceneConfig(effector="probe", object=ObjectSpec(kind="torus")), torus)
    np.testing.assert_allclose(base[:2], [x, y])
    box = load_object(ObjectSpec(**PRIMITIVES["box"]))
    assert descent_xy(box, radius_m=0.008) == (0.0, 0.0)  # the centre when the object lies under it
