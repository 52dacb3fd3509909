"""Forward kinematics of the finger chain against mujoco.mj_kinematics, and the chain built from the hand
description against the one read from the simulator's model."""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np
import pytest

from palpate.config import load
from palpate.description import load_hand
from palpate.errors import ConfigError
from palpate.nodes.mapper.kinematics import FingerMount, KinematicChain
from palpate.nodes.mapper.observation import capsule_lattice

# A 4-hinge finger with the awkward cases: a tilted, offset base; two hinges in one body (MCP
# abduction then flexion); an off-centre joint anchor; a joint with a reference angle (qpos0 != 0);
# a non-axis-aligned joint axis; a tilted body frame; a joint-less fingertip body with a sphere;
# and a second, unrelated body with a joint that the chain must ignore.
FINGER_XML = """
<mujoco>
  <compiler angle="degree"/>
  <worldbody>
    <body name="other" pos="0.3 0 0"><joint name="other" axis="1 0 0"/><geom size="0.01"/></body>
    <body name="base" pos="0.01 -0.02 0.05" euler="10 -20 30">
      <geom name="palm" type="box" size="0.01 0.01 0.01"/>
      <body name="proximal" pos="0.02 0 0">
        <joint name="mcp_abd" axis="0 0 1"/>
        <joint name="mcp_flex" axis="0 1 0" pos="0.001 0 0" ref="15"/>
        <geom name="proximal" type="capsule" fromto="0 0 0 0.0398 0 0" size="0.009"/>
        <body name="middle" pos="0.0398 0 0" euler="0 5 0">
          <joint name="pip" axis="0 1 0.2"/>
          <geom name="middle" type="capsule" fromto="0 0 0 0.0224 0 0" size="0.008"/>
          <body name="distal" pos="0.0224 0 0">
            <joint name="dip" axis="0 1 0" pos="0 0 0.002"/>
            <geom name="distal" type="capsule" fromto="0 0 0 0.0158 0.001 0" size="0.0075"/>
            <body name="tip" pos="0.0158 0 0" quat="0.9 0.1 0.3 0.1">
              <geom name="tip" type="sphere" size="0.006"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
JOINTS = ["mcp_abd", "mcp_flex", "pip", "dip"]


def _model(xml: str = FINGER_XML) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(xml)


def _mujoco_poses(model: mujoco.MjModel, names: list[str], q: np.ndarray) -> mujoco.MjData:
    data = mujoco.MjData(model)
    for name, value in zip(names, q, strict=True):
        data.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)]] = value
    mujoco.mj_kinematics(model, data)
    return data


def _check_against_mujoco(model: mujoco.MjModel, names: list[str], n: int = 40, seed: int = 0) -> None:
    chain = KinematicChain.from_model(model, names)
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.5, 1.5, size=(n, len(names)))
    rots, pos = chain.forward(q)
    ends, radii = chain.capsules(q)
    for k in range(n):
        data = _mujoco_poses(model, names, q[k])
        for link, body in enumerate(chain.link_body_ids):
            np.testing.assert_allclose(pos[k, link], data.xpos[body], atol=1e-9, rtol=0)
            np.testing.assert_allclose(rots[k, link], data.xmat[body].reshape(3, 3), atol=1e-9, rtol=0)
        for c, cap in enumerate(chain.capsule_list):
            g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, cap.name)
            axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
            half = model.geom_size[g][1] if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            np.testing.assert_allclose(ends[k, c, 0], data.geom_xpos[g] - half * axis, atol=1e-9, rtol=0)
            np.testing.assert_allclose(ends[k, c, 1], data.geom_xpos[g] + half * axis, atol=1e-9, rtol=0)
            assert radii[c] == pytest.approx(model.geom_size[g][0])


def test_forward_matches_mj_kinematics_on_random_angles() -> None:
    _check_against_mujoco(_model(), JOINTS)


def test_chain_reads_links_capsules_and_ignores_other_bodies() -> None:
    chain = KinematicChain.from_model(_model(), JOINTS)
    assert chain.link_names == ["proximal", "middle", "distal", "tip"]
    assert [c.name for c in chain.capsule_list] == ["proximal", "middle", "distal", "tip"]
    assert chain.n_joints == 4


def test_joint_order_in_q_follows_joint_names() -> None:
    model = _model()
    names = ["dip", "mcp_flex", "pip", "mcp_abd"]  # any column order
    _check_against_mujoco(model, names, n=10, seed=1)


def test_slide_joint_chain_matches_mujoco() -> None:
    xml = """
    <mujoco><worldbody><body name="a" pos="0 0 0.1" euler="0.3 0.2 0.1">
      <joint name="s" type="slide" axis="1 1 0"/>
      <joint name="h" axis="0 0 1" pos="0.01 0 0"/>
      <geom name="a" type="capsule" fromto="0 0 0 0.05 0 0" size="0.01"/>
      <body name="b" pos="0.05 0 0"><joint name="s2" type="slide" axis="0 0 1" ref="0.02"/>
        <geom name="b" type="capsule" fromto="0 0 0 0 0.03 0" size="0.005"/></body>
    </body></worldbody></mujoco>"""
    _check_against_mujoco(mujoco.MjModel.from_xml_string(xml), ["s", "h", "s2"], n=10)


def test_to_world_places_link_points() -> None:
    model = _model()
    chain = KinematicChain.from_model(model, JOINTS)
    q = np.random.default_rng(2).uniform(-1, 1, size=(3, 4))
    local = np.array([[0.01, 0.002, -0.003], [0.0, 0.0, 0.0]])
    links = np.array([2, 3])
    world = chain.to_world(q, links, local)
    for k in range(3):
        data = _mujoco_poses(model, JOINTS, q[k])
        for i, link in enumerate(links):
            body = chain.link_body_ids[link]
            expect = data.xpos[body] + data.xmat[body].reshape(3, 3) @ local[i]
            np.testing.assert_allclose(world[k, i], expect, atol=1e-12)


def test_forward_of_identical_rows_is_identical_bitwise() -> None:
    chain = KinematicChain.from_model(_model(), JOINTS)
    q = np.random.default_rng(3).uniform(-1, 1, size=(1, 4))
    r1, p1 = chain.forward(q)
    r7, p7 = chain.forward(np.repeat(q, 7, axis=0))
    assert np.array_equal(r7, np.repeat(r1, 7, axis=0)) and np.array_equal(p7, np.repeat(p1, 7, axis=0))


@pytest.mark.parametrize(
    ("names", "message"),
    [
        (["nope"], "not in the model"),
        (["mcp_abd", "other"], "serial chain"),
        (["mcp_abd", "pip", "dip"], "not listed"),
        ([], "empty"),
    ],
)
def test_bad_joint_lists_are_refused(names: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        KinematicChain.from_model(_model(), names)


def test_moving_base_is_refused() -> None:
    with pytest.raises(ConfigError, match="above the chain has joints"):
        KinematicChain.from_model(_model(), ["pip", "dip"])


def test_wrong_q_shape_is_refused() -> None:
    chain = KinematicChain.from_model(_model(), JOINTS)
    with pytest.raises(ConfigError, match="shape"):
        chain.forward(np.zeros((2, 3)))


def test_real_finger_and_hand_models_match_mujoco() -> None:
    """The simulator's finger (and the index finger of its hand) once palpate.nodes.sim exists."""
    effectors = pytest.importorskip("palpate.nodes.sim.effectors")
    for build, cfg_cls in (
        (effectors.build_finger_mjcf, effectors.FingerConfig),
        (effectors.build_hand_mjcf, effectors.HandConfig),
    ):
        frag = build(cfg_cls(), (0.01, 0.02, 0.1))
        xml = (
            '<mujoco><compiler angle="radian"/><worldbody>'
            + frag.worldbody
            + "</worldbody><actuator>"
            + frag.actuators
            + "</actuator></mujoco>"
        )
        model = mujoco.MjModel.from_xml_string(xml)
        names = effectors.finger_joint_names("index")
        _check_against_mujoco(model, names, n=10)
        chain = KinematicChain.from_model(model, names)
        assert chain.link_names == ["index_proximal", "index_middle", "index_distal"]


# --- the chain from the hand description ---------------------------------------------------------------
LAUNCH_BASE = FingerMount().base_position_m  # the description's finger mount, where the launch files' mappers are
TILTED = (0.9, 0.1, -0.2, 0.3)


def _simulator_chain(mount: FingerMount) -> KinematicChain:
    """The chain read from the simulator's model of the mounted effector (its MJCF, compiled)."""
    effectors = pytest.importorskip("palpate.nodes.sim.effectors")
    if mount.effector == "finger":
        cfg = effectors.FingerConfig(
            finger=mount.finger, scale=mount.scale, base_quaternion_wxyz=mount.base_quaternion_wxyz
        )
        frag = effectors.build_finger_mjcf(cfg, mount.base_position_m)
    else:
        cfg = effectors.HandConfig(scale=mount.scale, base_quaternion_wxyz=mount.base_quaternion_wxyz)
        frag = effectors.build_hand_mjcf(cfg, mount.base_position_m)
    model = _model(f'<mujoco><compiler angle="radian"/><worldbody>{frag.worldbody}</worldbody></mujoco>')
    return KinematicChain.from_model(model, load_hand().digit(mount.finger).joint_names())


@pytest.mark.parametrize("finger", ["index", "middle", "ring", "little"])
@pytest.mark.parametrize(
    ("scale", "base", "quaternion"), [(1.0, LAUNCH_BASE, (1.0, 0.0, 0.0, 0.0)), (1.3, (0.01, -0.2, 0.3), TILTED)]
)
def test_finger_chain_from_the_description_is_the_simulators(
    finger: str, scale: float, base: tuple[float, float, float], quaternion: tuple[float, float, float, float]
) -> None:
    mount = FingerMount(finger=finger, scale=scale, base_position_m=base, base_quaternion_wxyz=quaternion)
    chain = KinematicChain.from_description(load_hand(), mount)
    truth = _simulator_chain(mount)
    assert (chain.link_names, chain.joint_names) == (truth.link_names, truth.joint_names)
    assert [c.name for c in chain.capsule_list] == [c.name for c in truth.capsule_list]
    q = np.random.default_rng(5).uniform(-1.5, 1.5, size=(50, 4))
    # The launch files' untilted mount is the simulator's finger bit for bit; a tilted base's rotation
    # (palpate.geometry.rotations.quat_to_matrix) rounds differently from MuJoCo's compiler by an ulp.
    atol = 0.0 if quaternion == (1.0, 0.0, 0.0, 0.0) else 1e-15
    for got, expected in zip(
        (*chain.forward(q), *chain.capsules(q)), (*truth.forward(q), *truth.capsules(q)), strict=True
    ):
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=atol)
    # so the mapper's free-volume samples, in float32, are the ones it had with the model
    for got_h, expected_h in zip(
        capsule_lattice(chain, 0.002, 0.0005).homogeneous(),
        capsule_lattice(truth, 0.002, 0.0005).homogeneous(),
        strict=True,
    ):
        np.testing.assert_array_equal(got_h, expected_h)


@pytest.mark.parametrize("digit", ["index", "middle", "ring", "little", "thumb"])
def test_hand_chain_from_the_description_is_the_simulators(digit: str) -> None:
    """MuJoCo composes the palm's frames itself: equal to rounding (1e-12)."""
    mount = FingerMount(
        effector="hand", finger=digit, scale=1.1, base_position_m=(0.01, 0.02, 0.1), base_quaternion_wxyz=TILTED
    )
    chain = KinematicChain.from_description(load_hand(), mount)
    truth = _simulator_chain(mount)
    assert chain.link_names == truth.link_names
    q = np.random.default_rng(6).uniform(-1.5, 1.5, size=(50, chain.n_joints))
    for got, expected in zip(
        (*chain.forward(q), *chain.capsules(q)), (*truth.forward(q), *truth.capsules(q)), strict=True
    ):
        np.testing.assert_allclose(got, expected, atol=1e-12, rtol=0)


@pytest.mark.parametrize(
    ("changes", "message", "key"),
    [
        ({"finger": "thumb"}, "finger = 'thumb': the single-finger effector is a long finger", "finger"),
        ({"finger": "pinky"}, "mount.finger: expected one of ['index', 'middle', 'ring', 'little', 'thumb']", "finger"),
        ({"effector": "arm"}, "mount.effector: expected one of ['finger', 'hand']", "effector"),
        ({"scale": 0.0}, "mount.scale: expected a finite number > 0", "scale"),
        (
            {"base_position_m": [0.0, math.nan, 0.0]},
            "mount.base_position_m[1]: expected a finite number",
            "base_position_m",
        ),
        ({"base_quaternion_wxyz": [0.0, 0.0, 0.0, 0.0]}, "zero quaternion", "base_quaternion_wxyz"),
    ],
)
def test_bad_mounts_are_refused_naming_the_key(changes: dict[str, Any], message: str, key: str) -> None:
    with pytest.raises(ConfigError) as info:
        load(FingerMount, changes, "mount")
    assert message in str(info.value)
    assert info.value.path[:1] == (key,)


def test_the_default_mount_is_the_descriptions_and_the_thumb_needs_the_hand() -> None:
    hand = load_hand()
    assert (FingerMount().finger, FingerMount().base_position_m) == (
        hand.finger_mount.finger,
        hand.finger_mount.base_position_m,
    )
    assert FingerMount(effector="hand", finger="thumb").finger == "thumb"
    with pytest.raises(ConfigError, match="set effector: hand to model the thumb"):
        FingerMount(finger="thumb")
