"""Effector models: joint counts, names, limits and segment lengths against docs/hand_model.md."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from palpate.config import load
from palpate.errors import ConfigError
from palpate.nodes.sim.effectors import (
    FingerConfig,
    HandConfig,
    ProbeConfig,
    build_finger_mjcf,
    build_hand_mjcf,
    build_probe_mjcf,
    hand_joint_names,
    segment_lengths,
)

# The documented numbers (docs/hand_model.md): Buryanov and Kotiuk 2010, Table I, mm.
BONES_MM = {
    "index": (68.12, 39.78, 22.38, 15.82),
    "middle": (64.60, 44.63, 26.33, 17.40),
    "ring": (58.00, 41.37, 25.65, 17.30),
    "little": (53.69, 32.74, 18.11, 15.96),
    "thumb": (46.22, 31.57, 21.67),
}
RANGES_DEG = {
    "mcp_abd": (-20, 20),
    "mcp_flex": (0, 90),
    "pip": (0, 100),
    "dip": (0, 80),
    "thumb_cmc_flex": (-20, 15),
    "thumb_cmc_abd": (0, 70),
    "thumb_cmc_rot": (-10, 30),
    "thumb_mcp": (0, 50),
    "thumb_ip": (0, 80),
}


def _compile(worldbody: str, actuators: str = "") -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(
        f'<mujoco><compiler angle="radian"/><worldbody>{worldbody}</worldbody><actuator>{actuators}</actuator></mujoco>'
    )


def _distance(data: mujoco.MjData, a: str, b: str) -> float:
    return float(np.linalg.norm(data.body(a).xpos - data.body(b).xpos))


def test_hand_has_21_hinges_4_per_finger_5_thumb() -> None:
    mjcf = build_hand_mjcf(HandConfig())
    model = _compile(mjcf.worldbody, mjcf.actuators)
    names = [model.joint(i).name for i in range(model.njnt)]
    assert model.njnt == 21 and model.nu == 21
    assert np.all(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert names == hand_joint_names()
    for finger in ("index", "middle", "ring", "little"):
        assert [n for n in names if n.startswith(finger)] == [
            f"{finger}_mcp_abd",
            f"{finger}_mcp_flex",
            f"{finger}_pip",
            f"{finger}_dip",
        ]
    assert [n for n in names if n.startswith("thumb")] == [
        "thumb_cmc_flex",
        "thumb_cmc_abd",
        "thumb_cmc_rot",
        "thumb_mcp",
        "thumb_ip",
    ]


def test_hand_joint_limits_are_the_documented_ranges() -> None:
    model = _compile(build_hand_mjcf(HandConfig()).worldbody)
    for i in range(model.njnt):
        name = model.joint(i).name
        key = name if name.startswith("thumb") else name.split("_", 1)[1]
        np.testing.assert_allclose(np.degrees(model.jnt_range[i]), RANGES_DEG[key], atol=1e-6, err_msg=name)
        assert model.jnt_limited[i]


@pytest.mark.parametrize("scale", [1.0, 1.3])
def test_hand_segment_lengths_are_the_documented_bone_lengths(scale: float) -> None:
    cfg = HandConfig(scale=scale)
    model = _compile(build_hand_mjcf(cfg).worldbody)
    data = mujoco.MjData(model)
    data.qpos[:] = np.random.default_rng(0).uniform(model.jnt_range[:, 0], model.jnt_range[:, 1])
    mujoco.mj_kinematics(model, data)  # lengths must not depend on the pose
    lengths = segment_lengths(cfg)
    for finger in ("index", "middle", "ring", "little"):
        expected = scale * np.array(BONES_MM[finger]) / 1000
        np.testing.assert_allclose(lengths[finger], expected, rtol=1e-12)
        measured = [
            float(model.geom(f"{finger}_metacarpal").size[1] * 2),
            _distance(data, f"{finger}_proximal", f"{finger}_middle"),
            _distance(data, f"{finger}_middle", f"{finger}_distal"),
            float(np.linalg.norm(data.site(f"{finger}_tip").xpos - data.body(f"{finger}_distal").xpos)),
        ]
        np.testing.assert_allclose(measured, expected, rtol=1e-7, err_msg=finger)
    thumb = [
        _distance(data, "thumb_metacarpal", "thumb_proximal"),
        _distance(data, "thumb_proximal", "thumb_distal"),
        float(np.linalg.norm(data.site("thumb_tip").xpos - data.body("thumb_distal").xpos)),
    ]
    np.testing.assert_allclose(thumb, scale * np.array(BONES_MM["thumb"]) / 1000, rtol=1e-7)
    np.testing.assert_allclose(model.geom("index_distal").size[0], scale * 0.008, rtol=1e-12)


def test_flexion_curls_towards_the_palm_and_thumb_flexion_crosses_it() -> None:
    model = _compile(build_hand_mjcf(HandConfig()).worldbody)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    index0, thumb0 = data.site("index_tip").xpos.copy(), data.site("thumb_tip").xpos.copy()
    data.qpos[model.joint("index_mcp_flex").qposadr[0]] = 0.5
    data.qpos[model.joint("thumb_cmc_flex").qposadr[0]] = 0.2
    mujoco.mj_kinematics(model, data)
    assert data.site("index_tip").xpos[2] < index0[2] - 0.02  # palm faces -z
    assert data.site("thumb_tip").xpos[1] < thumb0[1] - 0.005  # across the palm, towards -y


def test_finger_has_4_hinges_on_a_fixed_metacarpal() -> None:
    cfg = FingerConfig(finger="middle")
    mjcf = build_finger_mjcf(cfg, base_position_m=(0.1, 0.2, 0.3))
    model = _compile(mjcf.worldbody, mjcf.actuators)
    assert model.njnt == 4 and model.nu == 4
    assert [model.joint(i).name for i in range(4)] == ["middle_mcp_abd", "middle_mcp_flex", "middle_pip", "middle_dip"]
    assert model.body("middle_metacarpal").jntnum == 0
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.body("middle_metacarpal").xpos, (0.1, 0.2, 0.3), atol=1e-12)
    np.testing.assert_allclose(
        _distance(data, "middle_metacarpal", "middle_proximal"), BONES_MM["middle"][0] / 1000, rtol=1e-7
    )
    np.testing.assert_allclose(np.degrees(model.jnt_range[2]), (0, 100), atol=1e-6)


def test_probe_is_a_free_sphere_that_mujoco_never_collides() -> None:
    model = _compile(build_probe_mjcf(ProbeConfig(radius_m=0.01), (0, 0, 0.1)).worldbody)
    assert model.njnt == 1 and model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    sphere = model.geom("probe")
    assert sphere.size[0] == pytest.approx(0.01)
    assert np.all(model.geom_contype == 0) and np.all(model.geom_conaffinity == 0)


def test_fingertip_site_z_points_out_of_the_tip() -> None:
    model = _compile(build_finger_mjcf(FingerConfig()).worldbody)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    z = data.site("index_tip").xmat.reshape(3, 3)[:, 2]
    axis = data.site("index_tip").xpos - data.body("index_distal").xpos
    cosine = float(z @ axis / np.linalg.norm(axis))
    assert math.degrees(math.acos(min(1.0, cosine))) < 1e-4


@pytest.mark.parametrize(
    ("probe", "message"),
    [
        ({"start_position_m": [1e4, 0.0, 0.0]}, r"start_position_m = \[10000.0, 0.0, 0.0\] lies beyond 1000 m"),
        ({"start_quaternion_wxyz": [0.0, 0.0, 0.0, 0.0]}, r"start_quaternion_wxyz = .* has no direction"),
    ],
)
def test_a_probe_start_no_run_could_use_is_a_config_error(probe: dict[str, object], message: str) -> None:
    """An outside audit: a start 10 km out passed the launch and was blamed on the velocity commands at
    t = 0; a zero quaternion failed inside MuJoCo's XML parser without naming the key."""
    with pytest.raises(ConfigError, match=message):
        load(ProbeConfig, probe)
    assert load(ProbeConfig, {"start_quaternion_wxyz": [0.0, 2.0, 0.0, 0.0]})  # MuJoCo normalises the others
