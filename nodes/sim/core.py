"""The simulation core: steps MuJoCo, takes joint or velocity commands, reports pose and contacts.

Pure: no sockets, no messages. The sim node wraps a :class:`Simulation` and publishes what its
accessors return; every accessor returns finite float64 arrays or raises.

Contacts follow the TRUE surface, not MuJoCo's convex hull of a mesh:
- **probe** (every object): MuJoCo never collides the probe; after each step it is checked against
  the object mesh with :class:`ExactContactSensor`, pushed out of the surface and reports the closest
  surface point (``probe_contact.ProbeContact``).
- **hand / finger on convex primitives** (box, cube, sphere, cylinder): MuJoCo's native contacts,
  which are exact for these geoms. The reported point is moved from MuJoCo's mid-penetration point
  onto the object's surface; the force is the constraint solver's normal force.
- **hand / finger on meshes and the torus**: MuJoCo collision between effector and object is off;
  spheres covering the capsules get spring-damper penalty forces along the exact-mesh normal
  (``penalty_contact.PenaltyContacts``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from palpate.errors import ConfigError, SimulationDivergedError
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.inputs import all_finite
from palpate.nodes.sim.contacts import FEW_CONTACTS, Contacts, frames_match_numpy, make_contacts
from palpate.nodes.sim.effectors import FingerConfig, HandConfig
from palpate.nodes.sim.objects import ObjectModel, load_object
from palpate.nodes.sim.penalty_contact import PenaltyContacts
from palpate.nodes.sim.physics import Physics
from palpate.nodes.sim.probe_contact import ProbeContact
from palpate.nodes.sim.scene import OBJECT_BODY, SceneConfig, build_model, uses_exact_contacts

#: MuJoCo warnings that mean the integration blew up (MuJoCo then resets the state silently).
_INSTABILITY_WARNINGS = (
    (mujoco.mjtWarning.mjWARN_BADQACC, "bad acceleration"),
    (mujoco.mjtWarning.mjWARN_BADQVEL, "bad velocity"),
    (mujoco.mjtWarning.mjWARN_BADQPOS, "bad position"),
)
#: Their indices in MjData.warning, which the divergence check compares with the counts it has seen.
_INSTABILITY_INDEX = [int(warning) for warning, _ in _INSTABILITY_WARNINGS]


def _mat_to_quat(R: np.ndarray) -> np.ndarray:
    """MuJoCo's own conversion (3, 3) -> (w, x, y, z) of a site frame (0.4 us; scipy's takes 60 us and
    picks the other sign for some rotations)."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(R, dtype=np.float64).reshape(9))
    return q


class Simulation:
    """One scene in MuJoCo: commands in, joint state, effector pose and contacts out."""

    def __init__(self, scene: SceneConfig, obj: ObjectModel | None = None) -> None:
        self.scene = scene
        self.object = load_object(scene.object) if obj is None else obj
        self.model = build_model(scene, self.object)
        self.data = mujoco.MjData(self.model)
        self._physics = Physics(self.model, self.data)
        self._dt = self._physics.dt
        self._setup_divergence_check()
        self._setup_bodies()
        #: The probe's contacts (probe scenes), the capsule spheres' penalty contacts (hand or finger on
        #: a non-convex object); neither: MuJoCo's own contacts.
        self.probe_contact: ProbeContact | None = None
        self.penalty_contacts: PenaltyContacts | None = None
        sensor = ExactContactSensor(self.object.mesh) if uses_exact_contacts(scene, self.object) else None
        if scene.effector == "probe":
            assert sensor is not None
            self.joint_names: list[str] = []
            self.probe_contact = ProbeContact(self._physics, scene, sensor)
        else:
            self._setup_joints()
            frames_match_numpy()  # checked now (a few ms), not at the first contact
            if sensor is not None:
                self.penalty_contacts = PenaltyContacts(self._physics, scene, sensor, self._is_effector_body)
        mujoco.mj_forward(self.model, self.data)
        #: The accessors' frames (and MuJoCo's contacts) are those of the current state (see _refresh).
        self._fresh = True

    def _setup_divergence_check(self) -> None:
        self._warnings_seen = [0] * len(_INSTABILITY_WARNINGS)  # counts of _INSTABILITY_WARNINGS
        self._warning_counts = self.data.warning.number  # a view of MjData's counters, read every step

    def _setup_bodies(self) -> None:
        """Which geoms belong to the object and which bodies to the effector, and the bodies' names."""
        m = self.model
        object_body = m.body(OBJECT_BODY).id
        self._is_object_geom = m.geom_bodyid == object_body
        self._is_effector_body = np.ones(m.nbody, dtype=bool)
        self._is_effector_body[[0, object_body]] = False
        self._body_names = [m.body(i).name for i in range(m.nbody)]

    def _setup_joints(self) -> None:
        """A hand's or finger's joints, their actuators and the fingertip site; the targets at zero."""
        m = self.model
        cfg = self.scene.effector_config()
        assert isinstance(cfg, HandConfig | FingerConfig)
        self.joint_names = [m.joint(i).name for i in range(m.njnt)]
        self._ranges = np.array(m.jnt_range, dtype=np.float64)
        # actuator k drives joint k (built in the same order); keep the map explicit anyway
        self._actuator_of_joint = np.argsort(m.actuator_trnid[:, 0])
        tip = cfg.pose_finger if isinstance(cfg, HandConfig) else cfg.finger
        self._tip_site = m.site(f"{tip}_tip").id
        self.set_joint_targets(np.zeros(len(self.joint_names)))

    @property
    def exact_contact_spheres(self) -> int:
        """Spheres whose contacts the exact mesh query senses (the probe; the capsule spheres of a hand
        or finger on a non-convex object); 0 when MuJoCo's own contacts serve."""
        if self.probe_contact is not None:
            return 1
        return 0 if self.penalty_contacts is None else len(self.penalty_contacts.sphere_geoms)

    @property
    def time_s(self) -> float:
        """Simulated time since the start, seconds."""
        return self._physics.steps * self._dt

    @property
    def timestep_s(self) -> float:
        """The physics time step, seconds."""
        return self._dt

    # --- commands ----------------------------------------------------------------------------------
    def set_joint_targets(self, q_rad: np.ndarray) -> None:
        """Position-actuator targets (J,) in radians, clipped to the joint limits (hand, finger)."""
        if self.scene.effector == "probe":
            raise ConfigError(
                "set_joint_targets needs a hand or finger scene; this scene's effector is 'probe': "
                "command it with set_velocity"
            )
        q = np.asarray(q_rad, dtype=np.float64)
        if q.shape != (len(self.joint_names),):
            raise ValueError(f"joint targets have shape {q.shape}; expected ({len(self.joint_names)},)")
        if not all_finite(q):
            raise ValueError(f"joint targets must be finite, got {q!r}")
        clipped = q.clip(self._ranges[:, 0], self._ranges[:, 1])  # np.clip without its wrappers
        self.data.ctrl[self._actuator_of_joint] = clipped

    def set_velocity(self, linear_m_s: np.ndarray, angular_rad_s: np.ndarray) -> None:
        """Probe twist in the world frame: linear (3,) m/s of its centre, angular (3,) rad/s."""
        if self.probe_contact is None:
            raise ConfigError(
                f"set_velocity needs a probe scene; this scene's effector is {self.scene.effector!r}: "
                "command it with set_joint_targets"
            )
        v = np.asarray(linear_m_s, dtype=np.float64)
        w = np.asarray(angular_rad_s, dtype=np.float64)
        if v.shape != (3,) or w.shape != (3,):
            raise ValueError(f"velocities have shapes {v.shape} and {w.shape}; expected (3,) and (3,)")
        if not math.isfinite(sum(v.tolist()) + sum(w.tolist())) and not (all_finite(v) and all_finite(w)):
            raise ValueError(f"velocities must be finite, got linear {v!r}, angular {w!r}")
        self.probe_contact.set_command(v, w)

    # --- stepping ----------------------------------------------------------------------------------
    def step(self, n: int = 1) -> None:
        """Advance ``n`` time steps; SimulationDivergedError if the state blows up."""
        if n < 0:
            raise ValueError(f"step count must be >= 0, got {n}")
        if n == 0:
            return
        t0 = self.time_s
        queried = False
        if self.probe_contact is not None:
            self.probe_contact.advance(n)
        elif self.penalty_contacts is not None:
            finite, queried = self.penalty_contacts.advance(n)
            if not finite:
                self._check_diverged(t0, state_not_finite=True)
        else:
            mujoco.mj_step(self.model, self.data, nstep=n)
            self._physics.steps += n
        # the compiled penalty steps end with the frames, velocities and sphere queries of the state they reach
        self._fresh = queried
        self._check_diverged(t0)

    def _check_diverged(self, t0: float, state_not_finite: bool = False) -> None:
        """SimulationDivergedError when MuJoCo warned of an instability since the last check, or the
        state is not finite (``state_not_finite``: the caller saw so already)."""
        d = self.data
        counts = self._warning_counts.tolist()
        # a finite state: one sum of Python floats (NaN and infinity propagate), else the exact test
        finite = math.isfinite(sum(d.qpos.tolist()) + sum(d.qvel.tolist()))
        if (
            not state_not_finite
            and [counts[i] for i in _INSTABILITY_INDEX] == self._warnings_seen
            and (finite or (all_finite(d.qpos) and all_finite(d.qvel)))
        ):
            return
        problems = []
        for i, (warning, what) in enumerate(_INSTABILITY_WARNINGS):
            count = counts[int(warning)]
            if count > self._warnings_seen[i]:
                problems.append(what)
                self._warnings_seen[i] = count
        if state_not_finite or not (all_finite(d.qpos) and all_finite(d.qvel)):
            problems.append("non-finite state")
        if problems:
            dt = self._dt
            raise SimulationDivergedError(
                f"MuJoCo diverged between t = {t0:.6g} s and t = {self.time_s:.6g} s "
                f"({', '.join(problems)}) with time step {dt:g} s; the time step is too large for the "
                f"scene's stiffness: use a smaller one, e.g. timestep_s: {dt / 2:g}"
            )

    def _refresh(self) -> None:
        """Recompute what the accessors read for the current state (once per step batch): MuJoCo's
        contacts too (mj_forward) where they are the sensor; with the exact-mesh sensor, the frames
        and the bodies' velocities alone (what the penalty contacts and the effector pose read; the
        same functions mj_forward calls first, so the same values)."""
        if not self._fresh:
            m, d = self.model, self.data
            if self.penalty_contacts is not None:
                mujoco.mj_kinematics(m, d)
                mujoco.mj_comPos(m, d)
                mujoco.mj_comVel(m, d)
            else:
                mujoco.mj_forward(m, d)
            self._fresh = True

    # --- hand / finger on convex primitives: MuJoCo's native contacts -------------------------------
    def _native_contacts(self) -> Contacts:
        m, d = self.model, self.data
        n = int(d.ncon)
        if n == 0:
            return Contacts.empty()
        con = d.contact
        g1 = np.asarray(con.geom1[:n])
        g2 = np.asarray(con.geom2[:n])
        obj1, obj2 = self._is_object_geom[g1], self._is_object_geom[g2]
        keep = np.flatnonzero(obj1 ^ obj2)
        if len(keep) == 0:
            return Contacts.empty()
        frame_normal = np.asarray(con.frame[:n, :3])[keep]  # from geom1 towards geom2
        sign = np.where(obj1[keep], 1.0, -1.0)  # outward from the object
        normals = frame_normal * sign[:, None]
        # MuJoCo's point is mid-penetration; the object's surface is half the (signed) depth back.
        points = np.asarray(con.pos[:n])[keep] - normals * (0.5 * np.asarray(con.dist[:n])[keep])[:, None]
        forces = np.zeros(len(keep))
        wrench = np.zeros(6)
        for j, i in enumerate(keep):
            mujoco.mj_contactForce(m, d, int(i), wrench)
            forces[j] = max(0.0, wrench[0])
        effector_geom = np.where(obj1[keep], g2[keep], g1[keep])
        return make_contacts(points, normals, forces, m.geom_bodyid[effector_geom], d, self._body_names)

    # --- accessors ---------------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        """Joint angles (J,) in radians, ``joint_names`` order (empty for the probe)."""
        if self.probe_contact is not None:
            return np.zeros(0)
        q = np.array(self.data.qpos[: len(self.joint_names)], dtype=np.float64)
        return self._finite(q, "joint positions")

    def effector_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Fingertip site (hand, finger) or probe centre: position (3,) m and quaternion (w, x, y, z)."""
        d = self.data
        if self.probe_contact is not None:
            pos = d.qpos[0:3].copy()
            quat = d.qpos[3:7].copy()
            quat /= math.sqrt(quat.dot(quat))  # np.linalg.norm's own expression
            if math.isfinite(sum(pos.tolist()) + sum(quat.tolist())):  # as below, in one sum
                return pos, quat
        else:
            self._refresh()
            pos = np.array(d.site_xpos[self._tip_site], dtype=np.float64)
            quat = _mat_to_quat(d.site_xmat[self._tip_site])
            if math.isfinite(sum(pos.tolist()) + sum(quat.tolist())):  # as the probe's, in one sum
                return pos, quat
        return self._finite(pos, "effector position"), self._finite(quat, "effector orientation")

    def contacts(self) -> Contacts:
        """Contacts with the object's true surface (see the module docstring for each path)."""
        if self.probe_contact is not None:
            out = self.probe_contact.contacts()
        else:
            self._refresh()
            out = self._native_contacts() if self.penalty_contacts is None else self.penalty_contacts.contacts()
        if len(out) <= FEW_CONTACTS and math.isfinite(
            sum(out.positions_m.ravel().tolist())
            + sum(out.local_positions_m.ravel().tolist())
            + sum(out.normals.ravel().tolist())
            + sum(out.forces_n.tolist())
        ):  # a NaN or infinity makes the sum so (as in all_finite); an overflowing sum takes the loop
            return out
        for name, array in (
            ("contact positions", out.positions_m),
            ("contact local positions", out.local_positions_m),
            ("contact normals", out.normals),
            ("contact forces", out.forces_n),
        ):
            self._finite(array, name)
        return out

    def _finite(self, array: np.ndarray, what: str) -> np.ndarray:
        if not all_finite(array):
            dt = self._dt
            raise SimulationDivergedError(
                f"{what} are not finite at t = {self.time_s:.6g} s with time step {dt:g} s; the simulation "
                f"diverged: use a smaller time step, e.g. timestep_s: {dt / 2:g}"
            )
        return array
