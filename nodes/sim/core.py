"""The simulation core: steps MuJoCo, takes joint or velocity commands, reports pose and contacts.

Pure: no sockets, no messages. The sim node wraps a :class:`Simulation` and publishes what its
accessors return; every accessor returns finite float64 arrays or raises.

Contacts follow the TRUE surface, not MuJoCo's convex hull of a mesh:
- **probe** (every object): MuJoCo never collides the probe. After each step the probe centre c is
  checked against the object mesh with :class:`ExactContactSensor`; if its signed distance d < r
  the probe is projected back to distance r along the contact normal and its inward velocity is
  zeroed (a rigid, frictionless surface). A contact is reported when d <= r + tolerance, at the
  closest surface point. The normal force is the velocity controller's push against the surface,
  ``force_gain * max(0, -v_cmd . n)``. A probe in the hole of a torus or inside a cup touches
  nothing and reports nothing. Far from the object (by a 1-Lipschitz bound on the signed distance)
  steps are batched into one ``mj_step`` call without queries.
- **hand / finger on convex primitives** (box, cube, sphere, cylinder): MuJoCo's native contacts,
  which are exact for these geoms. The reported point is moved from MuJoCo's mid-penetration point
  onto the object's surface; the force is the constraint solver's normal force.
- **hand / finger on meshes and the torus**: MuJoCo collision between effector and object is off;
  each capsule is covered by spheres along its axis (spacing radius / 2, so the covered surface
  deviates from the capsule by at most 3 % of the radius, 0.25 mm at 8 mm) and each sphere within
  reach of the surface gets a spring-damper penalty force ``k (r - d) - b v_n`` (clipped at 0) along
  the exact-mesh normal, applied at the surface point through ``xfrc_applied``. This reuses the exact
  sensor instead of a CoACD decomposition, so there is no decomposition to compute or cache (CoACD
  takes seconds to a minute per mesh and its parts still bulge by its concavity threshold). Cost:
  one closest-point query per capsule sphere that is near the surface (a 1-Lipschitz bound on the
  signed distance skips the others), about 10 to 30 spheres per finger; reported contacts are
  one per touching run of spheres along a capsule, at the deepest sphere, with the run's summed
  force.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from palpate.errors import ConfigError, SimulationDivergedError
from palpate.geometry.mesh_query import (
    FEW_POINTS,
    ClosestPoints,
    ExactContactSensor,
    WarmClosest,
)
from palpate.inputs import all_finite
from palpate.messages import codec
from palpate.nodes.sim import capsule_kernels, penalty_kernels, probe_kernels
from palpate.nodes.sim.capsules import capsule_spheres
from palpate.nodes.sim.contacts import FEW_CONTACTS, NO_ROWS, NO_VALUES, Contacts, frames_match_numpy, make_contacts
from palpate.nodes.sim.effectors import FingerConfig, HandConfig
from palpate.nodes.sim.objects import ObjectModel, load_object
from palpate.nodes.sim.scene import OBJECT_BODY, SceneConfig, build_model, uses_exact_contacts

#: MuJoCo warnings that mean the integration blew up (MuJoCo then resets the state silently).
_INSTABILITY_WARNINGS = (
    (mujoco.mjtWarning.mjWARN_BADQACC, "bad acceleration"),
    (mujoco.mjtWarning.mjWARN_BADQVEL, "bad velocity"),
    (mujoco.mjtWarning.mjWARN_BADQPOS, "bad position"),
)
#: Their indices in MjData.warning, which the divergence check compares with the counts it has seen.
_INSTABILITY_INDEX = [int(warning) for warning, _ in _INSTABILITY_WARNINGS]
#: No touching capsule sphere: `Simulation._sphere_hits`'s answer (indices, centres, points, distances,
#: normals), read-only.
_NO_HITS = (codec.frozen(np.zeros(0, dtype=np.int64)), NO_ROWS, NO_ROWS, NO_VALUES, NO_ROWS)


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
        m = self.model
        self._dt = float(m.opt.timestep)
        self._steps = 0
        self._warnings_seen = [0] * len(_INSTABILITY_WARNINGS)  # counts of _INSTABILITY_WARNINGS
        self._warning_counts = self.data.warning.number  # a view of MjData's counters, read every step
        self._exact = uses_exact_contacts(scene, self.object)
        self._sensor = ExactContactSensor(self.object.mesh) if self._exact else None
        self._tol = float(scene.contact_tolerance_m)
        object_body = m.body(OBJECT_BODY).id
        self._is_object_geom = m.geom_bodyid == object_body
        self._is_effector_body = np.ones(m.nbody, dtype=bool)
        self._is_effector_body[[0, object_body]] = False
        self._body_names = [m.body(i).name for i in range(m.nbody)]
        self._fresh = False
        #: The compiled steps' query buffers hold the current state's answers (see contacts()).
        self._hits_current = False

        if scene.effector == "probe":
            self._probe_body = m.body("probe").id
            probe = scene.probe_config()
            self._probe_radius = float(probe.radius_m)
            self._probe_force_gain = float(probe.force_gain_n_s_per_m)
            self._cmd_lin = np.zeros(3)
            self._cmd_ang = np.zeros(3)
            self._speed_per_step = 0.0  # |linear| x dt and whether the probe turns: set with the command
            self._turning = False
            self.joint_names: list[str] = []
            self._ranges = np.zeros((0, 2))
            # the last query (centre, signed distance) and its hit (point, distance, normal), in one
            # vector that the compiled steps read and write (probe_kernels.CACHE_P, ...)
            self._probe_cache = np.zeros(probe_kernels.CACHE_SIZE)
            self._probe_cache[probe_kernels.CACHE_D] = -np.inf  # no query yet: the bound never skips
            self._R = np.zeros(9)  # rotation matrix of the probe, row-major (mju_quat2Mat's buffer)
            self._R_contact = np.zeros(9)  # the same, for a contact's local position
            assert self._sensor is not None
            self._warm: WarmClosest | None = WarmClosest(self._sensor)
            #: Run the probe's steps in compiled code (probe_kernels) when MuJoCo's library is found.
            self.compiled_steps = probe_kernels.mujoco_functions() is not None
            self._patch: penalty_kernels.WarmPatches | None = None  # the probe's patch for compiled steps
            if self.compiled_steps:
                self._setup_probe_kernels()
        else:
            cfg = scene.effector_config()
            assert isinstance(cfg, HandConfig | FingerConfig)
            self.joint_names = [m.joint(i).name for i in range(m.njnt)]
            self._ranges = np.array(m.jnt_range, dtype=np.float64)
            # actuator k drives joint k (built in the same order); keep the map explicit anyway
            self._actuator_of_joint = np.argsort(m.actuator_trnid[:, 0])
            tip = cfg.pose_finger if isinstance(cfg, HandConfig) else cfg.finger
            self._tip_site = m.site(f"{tip}_tip").id
            self.set_joint_targets(np.zeros(len(self.joint_names)))
            frames_match_numpy()  # checked now (a few ms), not at the first contact
            if self._exact:
                self._setup_capsule_spheres()
        mujoco.mj_forward(m, self.data)
        self._fresh = True

    # --- commands ----------------------------------------------------------------------------------
    @property
    def exact_contact_spheres(self) -> int:
        """Spheres whose contacts the exact mesh query senses (the probe; the capsule spheres of a hand
        or finger on a non-convex object); 0 when MuJoCo's own contacts serve."""
        if not self._exact:
            return 0
        return 1 if self.scene.effector == "probe" else len(self._sph_geom)

    @property
    def time_s(self) -> float:
        """Simulated time since the start, seconds."""
        return self._steps * self._dt

    @property
    def timestep_s(self) -> float:
        """The physics time step, seconds."""
        return self._dt

    @property
    def joint_limits_rad(self) -> np.ndarray:
        """Joint limits (J, 2), radians, in ``joint_names`` order."""
        return self._ranges.copy()

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
        if self.scene.effector != "probe":
            raise ConfigError(
                f"set_velocity needs a probe scene; this scene's effector is {self.scene.effector!r}: "
                "command it with set_joint_targets"
            )
        v = np.asarray(linear_m_s, dtype=np.float64)
        w = np.asarray(angular_rad_s, dtype=np.float64)
        if v.shape != (3,) or w.shape != (3,):
            raise ValueError(f"velocities have shapes {v.shape} and {w.shape}; expected (3,) and (3,)")
        linear, angular = v.tolist(), w.tolist()
        if not math.isfinite(sum(linear) + sum(angular)) and not (all_finite(v) and all_finite(w)):
            raise ValueError(f"velocities must be finite, got linear {v!r}, angular {w!r}")
        self._cmd_lin = np.array(linear)
        self._cmd_ang = np.array(angular)
        # the probe's steps read these; |v| as np.linalg.norm computes it, sqrt(v . v)
        self._speed_per_step = math.sqrt(v.dot(v)) * self._dt
        self._turning = any(angular)

    # --- stepping ----------------------------------------------------------------------------------
    def step(self, n: int = 1) -> None:
        """Advance ``n`` time steps; SimulationDivergedError if the state blows up."""
        if n < 0:
            raise ValueError(f"step count must be >= 0, got {n}")
        if n == 0:
            return
        t0 = self.time_s
        m, d = self.model, self.data
        queried = False
        if self.scene.effector == "probe":
            self._probe_advance(n)
        elif self._exact and self.compiled_penalty:
            queried = self._penalty_advance(n, t0)
        elif self._exact:
            for _ in range(n):
                mujoco.mj_step1(m, d)  # kinematics and velocities of the current state
                self._apply_penalty_forces()
                mujoco.mj_step2(m, d)  # forces, acceleration, integration
                self._steps += 1
                if not np.isfinite(d.qpos).all():
                    self._check_diverged(t0, force=True)
        else:
            mujoco.mj_step(m, d, nstep=n)
            self._steps += n
        # the compiled steps end with the frames, velocities and sphere queries of the state they reach
        self._fresh = self._hits_current = queried
        self._check_diverged(t0)

    def _check_diverged(self, t0: float, force: bool = False) -> None:
        d = self.data
        counts = self._warning_counts.tolist()
        # a finite state: one sum of Python floats (NaN and infinity propagate), else the exact test
        finite = math.isfinite(sum(d.qpos.tolist()) + sum(d.qvel.tolist()))
        if (
            not force
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
        if force or not (all_finite(d.qpos) and all_finite(d.qvel)):
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
            if self._exact:
                mujoco.mj_kinematics(m, d)
                mujoco.mj_comPos(m, d)
                mujoco.mj_comVel(m, d)
            else:
                mujoco.mj_forward(m, d)
            self._fresh = True

    # --- probe -------------------------------------------------------------------------------------
    def _probe_advance(self, n: int) -> None:
        """``n`` probe steps. Stretches that surely stay clear of the object (by the 1-Lipschitz bound
        on the signed distance) run as one ``mj_step`` call; the others are checked step by step.
        With ``compiled_steps`` the loop runs in ``probe_kernels.probe_steps`` (the same bits), and
        only the steps that need Python (the warm query's first patch or one it cannot build, a weak
        sign) come here."""
        d = self.data
        qvel = d.qvel
        cache = self._probe_cache
        speed_per_step = self._speed_per_step
        turning = self._turning
        remaining = n
        projected = False
        while remaining > 0:
            if self.compiled_steps:
                taken, status, projected = self._probe_compiled(remaining, turning, speed_per_step)
                remaining -= taken
                if status == probe_kernels.DONE:  # it dropped the inward velocity itself
                    break
                # the last step's mj_step ran; its projection needs Python (the compiled query said so)
                projected = math.isfinite(sum(d.qpos.tolist())) and self._probe_project(try_compiled=False)
                continue
            remaining, projected = self._probe_python_step(remaining, turning, speed_per_step)
        if projected and cache[probe_kernels.HAS_HIT] == 1.0:
            # drop the inward velocity of the last projection (every step above sets the command anew)
            normal = cache[probe_kernels.HIT_NORMAL : probe_kernels.HIT_NORMAL + 3]
            inward = float(qvel[0:3] @ normal)
            if inward < 0.0:
                qvel[0:3] -= inward * normal

    def _probe_python_step(self, remaining: int, turning: bool, speed_per_step: float) -> tuple[int, bool]:
        """One pass of the Python loop: a batch of free steps or one checked step; returns the steps
        still to go and whether this pass projected the probe."""
        m, d = self.model, self.data
        qpos, qvel = d.qpos, d.qvel
        cache = self._probe_cache
        qvel[0:3] = self._cmd_lin  # free joint: linear velocity in the world frame
        if turning:
            # angular velocity in the body frame; constant during a batch since the probe's inertia
            # is isotropic (a sphere) and it rotates about a fixed axis
            mujoco.mju_quat2Mat(self._R, qpos[3:7])
            qvel[3:6] = self._R.reshape(3, 3).T @ self._cmd_ang
        else:
            qvel[3:6] = 0.0
        offset = qpos[0:3] - cache[0:3]
        margin = float(cache[probe_kernels.CACHE_D]) - math.sqrt(offset.dot(offset)) - self._probe_radius - self._tol
        free = 0
        if math.isfinite(margin) and margin > 0:
            free = remaining if speed_per_step == 0 else min(remaining, int(margin / speed_per_step))
        if free > 0:
            mujoco.mj_step(m, d, nstep=free)
            self._steps += free
            return remaining - free, False
        mujoco.mj_step(m, d)
        self._steps += 1
        return remaining - 1, math.isfinite(sum(qpos.tolist())) and self._probe_project()

    def _setup_probe_kernels(self) -> None:
        """What the compiled steps read and write (probe_kernels): the mesh, its face grid, the probe's
        patch (a one-sphere ``WarmPatches``, the warm query's state while the compiled steps run) and
        the parameters of its query."""
        warm, sensor = self._warm, self._sensor
        assert warm is not None and sensor is not None
        self._pk_mesh, self._pk_grid, self._pk_params = penalty_kernels.query_setup(sensor, warm)
        self._patch = penalty_kernels.WarmPatches(1, warm.max_patch_faces, capacity=2 * warm.max_patch_faces)
        self._pk_face_normals = sensor.face_normals
        self._pk_candidates = np.zeros(len(sensor.face_normals), dtype=np.int64)

    def _probe_compiled(self, steps: int, turning: bool, speed_per_step: float) -> tuple[int, int, bool]:
        """Up to ``steps`` steps in ``probe_kernels.probe_steps``: (steps taken, status, projected)."""
        functions = probe_kernels.mujoco_functions()
        assert functions is not None
        taken, status, projected = probe_kernels.probe_steps(
            functions[0],
            functions[1],
            self.model._address,
            self.data._address,
            steps,
            self.data.qpos,
            self.data.qvel,
            self._cmd_lin,
            self._cmd_ang,
            turning,
            speed_per_step,
            self._R,
            *self._probe_kernel_arguments(),
        )
        self._steps += taken
        assert self._warm is not None and self._patch is not None
        self._warm.resume(int(self._patch.face[0]), int(self._patch.searches[0]))  # counts and face
        self._patch.searches[0] = 0
        return taken, status, projected

    def _probe_kernel_arguments(self) -> tuple[Any, ...]:
        """The arguments that ``probe_kernels.probe_steps`` and ``probe_closest`` share: the cache, the
        probe, the mesh and the probe's patch."""
        assert self._patch is not None
        return (
            self._probe_cache,
            self._probe_radius,
            self._tol,
            self._pk_mesh,
            self._pk_face_normals,
            self._pk_grid,
            self._patch.arrays(),
            self._pk_params,
            self._pk_candidates,
        )

    def _warm_query(self, p: np.ndarray) -> tuple[tuple[float, float, float], float, int]:
        """The warm query at p (3,) in Python; where the compiled steps keep the probe's patch it takes
        it over and hands it back (``WarmPatches.load`` and ``store``), even after ``compiled_steps``
        was turned off."""
        assert self._warm is not None
        if self._patch is None:
            return self._warm.query(p)
        self._patch.load(0, self._warm)
        answer = self._warm.query(p)
        self._patch.store(0, self._warm)
        return answer

    def _probe_project(self, try_compiled: bool = True) -> bool:
        """Push the probe out of the surface along the contact normal; True when it was pushed (the
        caller then drops its inward velocity). `try_compiled`: as `_probe_closest`.

        One projection per step: in a concave corner a second surface may still be penetrated by at
        most one step of motion, which the next step corrects.
        """
        hit = self._probe_closest(try_compiled)
        r = self._probe_radius
        if hit is None or hit[1] >= r:
            return False
        point, _, normal = hit
        self.data.qpos[0:3] = point + r * normal
        return True

    def _probe_closest(self, try_compiled: bool = True) -> tuple[np.ndarray, float, np.ndarray] | None:
        """Closest surface point, signed centre distance and contact normal; None if surely apart.
        `try_compiled` False: the compiled query just said it needs Python here (skip asking again)."""
        assert self._warm is not None and self._sensor is not None
        k = probe_kernels
        cache = self._probe_cache
        p = self.data.qpos[0:3].copy()
        if cache[k.HAS_HIT] == 1.0 and p.tolist() == cache[0:3].tolist():  # held (the compiled steps ask)
            return self._probe_hit()
        if self.compiled_steps and try_compiled:  # the same answer in compiled code, unless it needs Python
            status = k.probe_closest(self.data.qpos, *self._probe_kernel_arguments())
            if status != k.NEEDS_PYTHON:
                return None if status == k.NO_HIT else self._probe_hit()
        # The signed distance is 1-Lipschitz: skip the query while it cannot be within reach.
        offset = p - cache[0:3]
        bound = float(cache[k.CACHE_D]) - math.sqrt(offset.dot(offset))
        if bound > self._probe_radius + self._tol:
            return None
        found, dist, face = self._warm_query(p)  # the exact query, warm-started from the last answer
        point = np.array(found)
        # Contact normal of a sphere: from the surface point to the centre (equals the surface normal
        # on faces, and is the true contact normal on edges and vertices); inside, the mesh normal.
        normal = self._sensor.face_normals[face]
        offset = p - point
        length = math.sqrt(offset.dot(offset))
        if dist > 0 and length > 1e-9:
            normal = offset / length
        cache[0:3] = p
        cache[k.CACHE_D] = cache[k.HIT_DIST] = dist
        cache[k.HIT_POINT : k.HIT_POINT + 3] = point
        cache[k.HIT_NORMAL : k.HIT_NORMAL + 3] = normal / math.sqrt(normal.dot(normal))
        cache[k.HAS_HIT] = 1.0
        return self._probe_hit()

    def _probe_hit(self) -> tuple[np.ndarray, float, np.ndarray]:
        """The held hit: surface point (3,), signed distance, contact normal (3,) (copies)."""
        k, cache = probe_kernels, self._probe_cache
        point = cache[k.HIT_POINT : k.HIT_POINT + 3].copy()
        return point, float(cache[k.HIT_DIST]), cache[k.HIT_NORMAL : k.HIT_NORMAL + 3].copy()

    def _probe_contacts(self) -> Contacts:
        hit = self._probe_closest()
        if hit is None or hit[1] > self._probe_radius + self._tol:
            return Contacts.empty()
        point, _, normal = hit
        q = self.data.qpos
        mujoco.mju_quat2Mat(self._R_contact, q[3:7])  # MuJoCo's rotation matrix, row-major
        r = self._R_contact.tolist()
        (px, py, pz), (nx, ny, nz), (cx, cy, cz) = point.tolist(), normal.tolist(), q[0:3].tolist()
        vx, vy, vz = self._cmd_lin.tolist()
        ox, oy, oz = px - cx, py - cy, pz - cz
        # R^T (p - c) and the force, summed left to right as numpy's 3-element products are
        local = (
            r[0] * ox + r[3] * oy + r[6] * oz,
            r[1] * ox + r[4] * oy + r[7] * oz,
            r[2] * ox + r[5] * oy + r[8] * oz,
        )
        force = self._probe_force_gain * max(0.0, -(vx * nx + vy * ny + vz * nz))
        return Contacts(point.reshape(1, 3), np.array([local]), normal.reshape(1, 3), np.array([force]), ["probe"])

    # --- hand / finger on non-convex objects: exact-mesh penalty contacts ---------------------------
    def _setup_capsule_spheres(self) -> None:
        m = self.model
        spheres = capsule_spheres(m, self._is_effector_body)
        self._sph_geom, self._sph_offset, self._sph_radius, runs = spheres
        #: Each sphere's capsule (the index of its run).
        self._sph_capsule = [c for c, (start, stop) in enumerate(runs) for _ in range(start, stop)]
        count = len(self._sph_geom)
        self._sph_body = m.geom_bodyid[self._sph_geom]
        self._sph_cache_p = np.zeros((count, 3))
        self._sph_cache_d = np.full(count, -np.inf)  # no query yet: the bound never skips
        self._sph_reach = self._sph_radius + self._tol
        #: Place the spheres and bound their distances in compiled code (capsule_kernels), where it gives
        #: numpy's bits.
        self.compiled_bounds = capsule_kernels.matches_numpy()
        #: Run the physics steps in compiled code (penalty_kernels) where MuJoCo's library is found and
        #: the compiled arithmetic gives numpy's bits.
        self.compiled_penalty = (
            self.compiled_bounds and penalty_kernels.mujoco_functions() is not None and penalty_kernels.matches_numpy()
        )
        self._sph_warm: dict[int, WarmClosest] = {}  # each sphere's warm-started query, made on first use
        self._setup_penalty_kernels(count)

    def _setup_penalty_kernels(self, count: int) -> None:
        """What the compiled steps of ``count`` capsule spheres read and write (penalty_kernels)."""
        m, d, sensor = self.model, self.data, self._sensor
        assert sensor is not None
        template = WarmClosest(sensor)  # the settings of every sphere's query
        self._pk_mesh, self._pk_grid, self._pk_params = penalty_kernels.query_setup(sensor, template)
        self._patches = penalty_kernels.WarmPatches(count, template.max_patch_faces)
        # what the compiled steps read and write: MuJoCo's arrays (views that stay valid), the spheres,
        # the mesh, per-step buffers and parameters (penalty_kernels.sphere_hits documents them)
        self._pk_frames = (d.geom_xpos, d.geom_xmat)
        self._pk_dynamics = (np.asarray(m.body_rootid), (d.cvel, d.subtree_com, d.xipos, d.xfrc_applied))
        self._pk_spheres = (
            self._sph_geom,
            self._sph_offset,
            self._sph_radius,
            self._sph_reach,
            self._sph_body,
            self._sph_cache_p,
            self._sph_cache_d,
        )
        self._pk_face_normals = sensor.face_normals
        self._pk_buffers = (
            np.zeros((count, 3)),
            np.zeros(count, dtype=np.int64),
            np.zeros((count, 3)),
            np.zeros(count),
            np.zeros(count, dtype=np.int64),
            np.zeros(count, dtype=np.int64),
            np.zeros(2, dtype=np.int64),
            np.zeros(len(sensor.face_normals), dtype=np.int64),
            np.zeros(penalty_kernels.SEARCH_SIZE),
        )
        self._pk_params[penalty_kernels.P_STIFFNESS] = self.scene.mesh_contact_stiffness_n_per_m
        self._pk_params[penalty_kernels.P_DAMPING] = self.scene.mesh_contact_damping_n_s_per_m
        if self.compiled_penalty:  # load the forces' kernel for these argument types now, not at the first touch
            self._sphere_forces(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))

    def _penalty_advance(self, n: int, t0: float) -> bool:
        """``n`` steps in ``penalty_kernels.penalty_steps`` (the bits of the Python loop); the queries
        that need Python are answered here, and the step goes on in compiled code. True when the last
        call also refreshed the frames and answered the final state's queries (``END_QUERIED``)."""
        functions = penalty_kernels.mujoco_functions()
        assert functions is not None
        addresses = (*functions, self.model._address, self.data._address)
        k = penalty_kernels
        remaining, resume = n, k.HITS_CURRENT if self._hits_current else -1
        queried = False
        while remaining > 0:
            taken, status, at = k.penalty_steps(
                addresses,
                remaining,
                resume,
                FEW_POINTS,
                self.data.qpos,
                self._pk_frames,
                self._pk_dynamics,
                self._pk_spheres,
                self._pk_mesh,
                self._pk_grid,
                self._pk_face_normals,
                self._patches.arrays(),
                self._pk_buffers,
                self._pk_params,
            )
            self._steps += taken
            remaining -= taken
            resume = -1
            if status == k.DONE:
                queried = at == k.END_QUERIED
            elif status == k.NEEDS_PYTHON:
                resume = self._answer_in_python(at)
            elif status == k.PENETRATED:
                _, near, _, dist, _, touch, state, _, _ = self._pk_buffers
                rows = touch[: state[k.S_TOUCHING]]
                raise self._penetration_error(near[rows], dist[rows])
            elif status == k.NOT_FINITE:
                self._check_diverged(t0, force=True)
        return queried

    def _answer_in_python(self, at: int) -> int:
        """Answer the query at position ``at`` of the compiled near spheres (or all of them: BATCH) into
        the buffers, as ``_sphere_closest`` does; returns where the compiled queries go on."""
        assert self._sensor is not None
        centres, near, points, dist, faces, _, state, _, search = self._pk_buffers
        k = penalty_kernels
        if at == k.BATCH:
            count = int(state[k.S_NEAR])
            hit = self._sensor.closest(centres[near[:count]])
            points[:count], dist[:count], faces[:count] = hit.points_m, hit.distance_m, hit.face_ids
            # each sphere's next query starts from its face here (any start gives the same answer)
            self._patches.face[near[:count]] = hit.face_ids
            return count
        sphere = int(near[at])
        if search[k.SEARCH_PENDING]:  # a weak sign of the compiled search
            search[k.SEARCH_PENDING] = 0.0
            s = search.tolist()
            q = s[k.SEARCH_Q : k.SEARCH_Q + 3]
            found = (int(s[k.SEARCH_FACE]), q[0], q[1], q[2], s[k.SEARCH_DIST])
            signs = (bool(s[k.SEARCH_INSIDE]), bool(s[k.SEARCH_WEAK]))
            warm = self._sphere_warm(sphere)
            answer = warm.settle(s[k.SEARCH_P : k.SEARCH_P + 3], (*found, *signs))
            points[at], dist[at], faces[at] = answer
            self._patches.face[sphere] = faces[at]
            self._patches.searches[sphere] += 1
            return at + 1
        x, y, z = centres[sphere].tolist()
        if self._patches.face[sphere] < 0 and math.isfinite(x + y + z):
            # a sphere's first query: its face starts at Open3D's, as WarmClosest._build seeds it, and
            # the compiled build goes on from there
            cx, cy, cz = self._sensor._centre_list
            seed = self._sensor._scene.closest_face_ids(np.array([[x - cx, y - cy, z - cz]]))[0]
            self._patches.face[sphere] = seed
            return at
        warm = self._sphere_warm(sphere)
        self._patches.load(sphere, warm)
        points[at], dist[at], faces[at] = warm.query(centres[sphere])
        self._patches.store(sphere, warm)
        return at + 1

    def _sphere_warm(self, k: int) -> WarmClosest:
        """Sphere k's warm-started query, made on first use."""
        warm = self._sph_warm.get(k)
        if warm is None:
            assert self._sensor is not None
            warm = self._sph_warm[k] = WarmClosest(self._sensor)
        return warm

    def _sphere_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World centres (K, 3) of the capsule spheres and the indices (t,) of those the 1-Lipschitz bound
        on the signed distance leaves within reach of the surface, in increasing order."""
        d = self.data
        frames = (d.geom_xpos, d.geom_xmat, self._sph_geom, self._sph_offset)
        caches = (self._sph_cache_p, self._sph_cache_d, self._sph_reach)
        if not self.compiled_bounds:
            return capsule_kernels.numpy_bounds(*frames, *caches)
        count = len(self._sph_geom)
        centres, near = np.empty((count, 3)), np.empty(count, dtype=np.int64)
        return centres, near[: capsule_kernels.sphere_bounds(*frames, *caches, centres, near)]

    def _sphere_hits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Touching spheres: indices (t,), centres (t, 3), surface points (t, 3), distances (t,),
        normals (t, 3), using the current kinematics."""
        assert self._sensor is not None
        if self.compiled_penalty:
            return self._compiled_sphere_hits()
        P, near = self._sphere_bounds()
        if len(near) == 0:
            empty = np.zeros((0, 3))
            return np.zeros(0, dtype=np.int64), empty, empty, np.zeros(0), empty
        hit = self._sphere_closest(P, near)
        dist = np.asarray(hit.distance_m, dtype=np.float64)
        self._sph_cache_p[near] = P[near]
        self._sph_cache_d[near] = dist
        touching = dist <= self._sph_radius[near] + self._tol
        idx = near[touching]
        return (
            idx,
            P[idx],
            np.asarray(hit.points_m, dtype=np.float64)[touching],
            dist[touching],
            np.asarray(hit.normals, dtype=np.float64)[touching],
        )

    def _compiled_sphere_hits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``_sphere_hits`` by ``penalty_kernels.sphere_hits``, answering in Python what needs it."""
        k = penalty_kernels
        resume = -1
        while not self._hits_current:  # else the buffers hold this state's queries already
            status, at = k.sphere_hits(
                resume,
                FEW_POINTS,
                self._pk_frames,
                self._pk_spheres,
                self._pk_mesh,
                self._pk_grid,
                self._patches.arrays(),
                self._pk_buffers,
                self._pk_params,
            )
            if status == k.DONE:
                break
            resume = self._answer_in_python(at)
        centres, near, points, dist, faces, touch, state, _, _ = self._pk_buffers
        if state[k.S_TOUCHING] == 0:  # the common case: no sphere touches
            return _NO_HITS
        rows = touch[: state[k.S_TOUCHING]]
        idx = near[rows]
        return idx, centres[idx], points[rows], dist[rows], self._pk_face_normals[faces[rows]]

    def _sphere_closest(self, P: np.ndarray, near: np.ndarray) -> ClosestPoints:
        """The sensor's answer for the spheres ``near`` (indices into centres P (K, 3)). Up to
        FEW_POINTS spheres, where the sensor answers point by point, each sphere's own warm-started
        query gives the same bits (its face too) for less; more go to the sensor in one
        batch, whose vectorised path rounds differently."""
        assert self._sensor is not None
        if len(near) > FEW_POINTS:
            return self._sensor.closest(P[near])
        points, distances, faces = [], [], []
        for k in near.tolist():
            point, distance, face = self._sphere_warm(k).query(P[k])
            points.append(point)
            distances.append(distance)
            faces.append(face)
        face_ids = np.array(faces, dtype=np.int64)
        return ClosestPoints(
            points_m=np.array(points, dtype=np.float64).reshape(-1, 3),
            distance_m=np.array(distances, dtype=np.float64),
            normals=self._sensor.face_normals[face_ids],
            face_ids=face_ids,
        )

    def _sphere_forces(self, idx: np.ndarray, points: np.ndarray, dist: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Penalty normal force (t,) >= 0 of touching spheres: k (r - d) - b v_n."""
        d = self.data
        k = self.scene.mesh_contact_stiffness_n_per_m
        b = self.scene.mesh_contact_damping_n_s_per_m
        # cvel is (angular, linear) at the subtree centre of mass of the body's root, world frame
        if self.compiled_penalty:  # the same bits (penalty_kernels.matches_numpy)
            forces = np.empty(len(idx))
            body, radius, root = self._sph_body, self._sph_radius, self._pk_dynamics[0]
            penalty_kernels.penalty_forces(
                idx, points, dist, normals, body, radius, root, d.cvel, d.subtree_com, k, b, forces
            )
            return forces
        bodies = self._sph_body[idx]
        origin = d.subtree_com[self.model.body_rootid[bodies]]
        return penalty_kernels.numpy_forces(bodies, self._sph_radius[idx], points, dist, normals, d.cvel, origin, k, b)

    def _apply_penalty_forces(self) -> None:
        """Set xfrc_applied from the current kinematics (call between mj_step1 and mj_step2)."""
        d = self.data
        d.xfrc_applied[:] = 0.0
        idx, _, points, dist, normals = self._sphere_hits()
        if len(idx) == 0:
            return
        if np.any(dist < 0.0):
            raise self._penetration_error(idx, dist)
        forces = self._sphere_forces(idx, points, dist, normals)
        # xfrc_applied acts at the body's centre of mass
        d.xfrc_applied[:] = penalty_kernels.numpy_wrench(self._sph_body[idx], points, normals, forces, d.xipos)

    def _penetration_error(self, idx: np.ndarray, dist: np.ndarray) -> SimulationDivergedError:
        """The error for touching spheres idx (t,) at distances (t,) of which one has its centre inside."""
        dt = self._dt
        return SimulationDivergedError(
            f"at t = {self.time_s:.6g} s a finger segment's axis is inside the object (penetration "
            f"{1000 * (self._sph_radius[idx] - dist).max():.3g} mm, more than the segment radius): the "
            f"penalty contact (stiffness {self.scene.mesh_contact_stiffness_n_per_m:g} N/m) was "
            f"overrun with time step {dt:g} s; use a smaller time step, e.g. timestep_s: {dt / 2:g} "
            "(or check that the effector does not start inside the object)"
        )

    def _penalty_contacts(self) -> Contacts:
        idx, _, points, dist, normals = self._sphere_hits()
        if len(idx) == 0:
            return Contacts.empty()
        forces = self._sphere_forces(idx, points, dist, normals)
        # idx is increasing: a run of touching spheres is a stretch of consecutive indices on one capsule
        spheres = idx.tolist()
        depth = (dist - self._sph_radius[idx]).tolist()
        capsule = self._sph_capsule
        rows: list[int] = []
        sums: list[float] = []
        first = 0
        for j in range(1, len(spheres) + 1):
            k = spheres[j - 1]
            if j < len(spheres) and spheres[j] == k + 1 and capsule[k + 1] == capsule[k]:
                continue
            rows.append(min(range(first, j), key=depth.__getitem__))  # the run's deepest sphere
            sums.append(float(forces[first:j].sum()))
            first = j
        sel = np.array(rows, dtype=np.int64)
        bodies = self._sph_body[idx[sel]]
        return make_contacts(points[sel], normals[sel], np.array(sums), bodies, self.data, self._body_names)

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
        if self.scene.effector == "probe":
            return np.zeros(0)
        q = np.array(self.data.qpos[: len(self.joint_names)], dtype=np.float64)
        return self._finite(q, "joint positions")

    def effector_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Fingertip site (hand, finger) or probe centre: position (3,) m and quaternion (w, x, y, z)."""
        d = self.data
        if self.scene.effector == "probe":
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
        if self.scene.effector == "probe":
            out = self._probe_contacts()
        else:
            self._refresh()
            out = self._penalty_contacts() if self._exact else self._native_contacts()
            if self._exact and self.compiled_penalty:
                # the next step's first queries are these, if they were asked one by one (a batch rounds
                # differently, and the next step may ask fewer): buffers as in penalty_kernels.sphere_hits
                state = self._pk_buffers[6]
                self._hits_current = bool(state[penalty_kernels.S_NEAR] <= FEW_POINTS)
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
