"""A self-contained finger-taps-a-box scene for checking the mapper core without the simulator node.

An index finger of four hinges (MCP abduction and flexion, PIP, DIP; segment lengths
39.8, 22.4, 15.8 mm after Buryanov and Kotiuk 2010) on a fixed base taps the top of a 57 mm cube
(a Rubik's cube, as in the paper) while its abduction sweeps side to side. MuJoCo simulates it;
contacts are read from MuJoCo and expressed in the frame of the link that felt them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from palpate.nodes.mapper.kinematics import KinematicChain

FINGER_JOINTS = ["mcp_abd", "mcp_flex", "pip", "dip"]
CUBE_HALF_M = 0.0285
CUBE_CENTER_M = (0.062, 0.0, -CUBE_HALF_M)


def finger_box_mjcf(
    *,
    cube_center_m: tuple[float, float, float] = CUBE_CENTER_M,
    cube_half_m: float = CUBE_HALF_M,
    base_height_m: float = 0.03,
    timestep_s: float = 0.001,
) -> str:
    """MJCF of the finger (base at (0, 0, base_height_m), pointing along +x) above a cube."""
    cx, cy, cz = cube_center_m
    h = cube_half_m
    return f"""
<mujoco model="synthetic_finger_box">
  <option timestep="{timestep_s}" gravity="0 0 0"/>
  <default>
    <joint damping="0.02" armature="0.0001"/>
    <geom contype="1" conaffinity="2" friction="0.3"/>
    <position kp="0.6"/>
  </default>
  <worldbody>
    <geom name="cube" type="box" size="{h} {h} {h}" pos="{cx} {cy} {cz}" contype="2" conaffinity="1"/>
    <body name="base" pos="0 0 {base_height_m}">
      <body name="proximal">
        <joint name="mcp_abd" axis="0 0 1" range="-25 25"/>
        <joint name="mcp_flex" axis="0 1 0" range="-10 90"/>
        <geom name="proximal" type="capsule" fromto="0 0 0 0.0398 0 0" size="0.009"/>
        <body name="middle" pos="0.0398 0 0">
          <joint name="pip" axis="0 1 0" range="0 100"/>
          <geom name="middle" type="capsule" fromto="0 0 0 0.0224 0 0" size="0.008"/>
          <body name="distal" pos="0.0224 0 0">
            <joint name="dip" axis="0 1 0" range="0 80"/>
            <geom name="distal" type="capsule" fromto="0 0 0 0.0158 0 0" size="0.0075"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="mcp_abd" joint="mcp_abd" ctrlrange="-0.45 0.45"/>
    <position name="mcp_flex" joint="mcp_flex" ctrlrange="-0.2 1.6"/>
    <position name="pip" joint="pip" ctrlrange="0 1.75"/>
    <position name="dip" joint="dip" ctrlrange="0 1.4"/>
  </actuator>
</mujoco>
"""


@dataclass(frozen=True)
class TappingRecord:
    """Samples at the update rate: true joint angles (T, J) rad and per sample the contacts as
    link indices (n_t,) and positions in the link frames (n_t, 3) m."""

    q_true: NDArray[np.float64]
    contact_links: list[NDArray[np.intp]]
    contact_local_m: list[NDArray[np.float64]]
    contact_world_m: list[NDArray[np.float64]]


def finger_command(t: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """Joint commands (..., 4) rad at times t (s): taps at 2 Hz, abduction and curl sweep slowly."""
    t = np.asarray(t, dtype=np.float64)
    abd = np.radians(20.0) * np.sin(2 * np.pi * t / 7.3)
    curl = 0.5 - 0.5 * np.cos(2 * np.pi * t / 4.1)  # 0 .. 1
    tap = 0.5 - 0.5 * np.cos(2 * np.pi * t * 2.0)  # 0 .. 1
    flex = np.radians(-5.0) + np.radians(40.0) * tap - np.radians(15.0) * curl
    pip = np.radians(10.0) + np.radians(55.0) * curl
    dip = np.radians(5.0) + np.radians(40.0) * curl
    return np.stack([abd, flex, pip, dip], axis=-1)


def simulate_tapping(duration_s: float, update_hz: float = 100.0) -> tuple[KinematicChain, TappingRecord]:
    """Run the scene for duration_s and sample joint angles and contacts at update_hz."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(finger_box_mjcf())
    data = mujoco.MjData(model)
    chain = KinematicChain.from_model(model, FINGER_JOINTS)
    qadr = [int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in FINGER_JOINTS]
    cube = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "cube")
    steps_per_update = max(1, round(1.0 / (update_hz * model.opt.timestep)))
    n_updates = round(duration_s * update_hz)
    qs, links, locals_, worlds = [], [], [], []
    for _ in range(n_updates):
        for _ in range(steps_per_update):
            data.ctrl[:] = finger_command(data.time)
            mujoco.mj_step(model, data)
        qs.append(data.qpos[qadr].copy())
        lk, lp, wp = [], [], []
        for i in range(data.ncon):
            con = data.contact[i]
            g = con.geom2 if con.geom1 == cube else con.geom1
            if cube not in (con.geom1, con.geom2):
                continue
            body = int(model.geom_bodyid[g])
            link = chain.link_of_body(body)
            pos = np.array(con.pos)
            lk.append(link)
            lp.append(data.xmat[body].reshape(3, 3).T @ (pos - data.xpos[body]))
            wp.append(pos)
        links.append(np.array(lk, dtype=np.intp))
        locals_.append(np.array(lp, dtype=np.float64).reshape(-1, 3))
        worlds.append(np.array(wp, dtype=np.float64).reshape(-1, 3))
    return chain, TappingRecord(
        q_true=np.array(qs), contact_links=links, contact_local_m=locals_, contact_world_m=worlds
    )
