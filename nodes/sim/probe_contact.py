"""The probe's contacts with the object's true surface (every object): MuJoCo never collides the probe.

After each step the probe centre c is checked against the object mesh with ``ExactContactSensor``;
if its signed distance d < r the probe is projected back to distance r along the contact normal and
its inward velocity is zeroed (a rigid, frictionless surface). A contact is reported when
d <= r + tolerance, at the closest surface point. The normal force is the velocity controller's push
against the surface, ``force_gain * max(0, -v_cmd . n)``. A probe in the hole of a torus or inside a
cup touches nothing and reports nothing. Far from the object (by a 1-Lipschitz bound on the signed
distance) steps are batched into one ``mj_step`` call without queries. With ``compiled_steps`` the
loop runs in ``probe_kernels.probe_steps`` (the same bits).

A mesh that is not closed (an open cup, a scan with holes) has no inside: the sign of a distance
across its openings is a guess (an open cup's opening reads as solid, and the probe was pushed
sideways onto the rim). Its surface is a two-sided sheet: the distance is unsigned, the contact
normal points from the surface to the probe's centre, and the probe passes through the openings and
touches either side (``two_sided``; the steps run in Python).
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from palpate.geometry.mesh_query import ExactContactSensor, WarmClosest
from palpate.nodes.sim import penalty_kernels, probe_kernels
from palpate.nodes.sim.contacts import Contacts
from palpate.nodes.sim.physics import Physics
from palpate.nodes.sim.scene import SceneConfig


class ProbeContact:
    """The probe of one simulation: its velocity command, its last query and hit, and the steps that
    keep it out of the surface (``advance``) and report its contact (``contacts``)."""

    def __init__(self, physics: Physics, scene: SceneConfig, sensor: ExactContactSensor) -> None:
        self._physics, self._model, self._data, self._sensor = physics, physics.model, physics.data, sensor
        probe = scene.probe_config()
        self.radius_m = float(probe.radius_m)
        self._force_gain = float(probe.force_gain_n_s_per_m)
        self._tolerance_m = float(scene.contact_tolerance_m)
        #: The commanded twist in the world frame (set_command): linear m/s of the centre, angular rad/s.
        self._linear_command = np.zeros(3)
        self._angular_command = np.zeros(3)
        self._speed_per_step = 0.0  # |linear| x dt and whether the probe turns: set with the command
        self._turning = False
        #: The last query (centre, signed distance) and its hit (point, distance, normal), in one vector
        #: that the compiled steps read and write (probe_kernels.CACHE_P, ...).
        self.query_cache = np.zeros(probe_kernels.CACHE_SIZE)
        self.query_cache[probe_kernels.CACHE_D] = -np.inf  # no query yet: the bound never skips
        self._step_rotation = np.zeros(9)  # the probe's rotation matrix, row-major (mju_quat2Mat's buffer)
        self._contact_rotation = np.zeros(9)  # the same, for a contact's local position
        #: The exact query, warm-started from the last answer.
        self.warm_query = WarmClosest(sensor)
        #: The mesh is not closed: its surface is a two-sided sheet (the module's docstring).
        self.two_sided = not sensor.mesh.is_watertight
        #: Run the probe's steps in compiled code (probe_kernels) when MuJoCo's library is found (they
        #: take the signed distance of a closed mesh).
        self.compiled_steps = probe_kernels.mujoco_functions() is not None and not self.two_sided
        self._kernel_patch: penalty_kernels.WarmPatches | None = None  # the warm query's state in compiled steps
        if self.compiled_steps:
            self._setup_kernels()

    def _setup_kernels(self) -> None:
        """What the compiled steps read and write (probe_kernels): the mesh, its face grid, the probe's
        patch (a one-sphere ``WarmPatches``, the warm query's state while the compiled steps run) and
        the parameters of its query."""
        warm, sensor = self.warm_query, self._sensor
        self._kernel_mesh, self._kernel_grid, self._kernel_params = penalty_kernels.query_setup(sensor, warm)
        self._kernel_patch = penalty_kernels.WarmPatches(1, warm.max_patch_faces, capacity=2 * warm.max_patch_faces)
        self._face_normals = sensor.face_normals
        self._candidates = np.zeros(len(sensor.face_normals), dtype=np.int64)

    def set_command(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """The commanded twist: linear (3,) m/s of the centre and angular (3,) rad/s, world frame (finite
        float64 arrays, copied)."""
        self._linear_command = linear.copy()
        self._angular_command = angular.copy()
        # the steps read these; |v| as np.linalg.norm computes it, sqrt(v . v)
        self._speed_per_step = math.sqrt(linear.dot(linear)) * self._physics.dt
        self._turning = any(angular.tolist())

    # --- stepping ----------------------------------------------------------------------------------
    def advance(self, n: int) -> None:
        """``n`` probe steps. Stretches that surely stay clear of the object (by the 1-Lipschitz bound
        on the signed distance) run as one ``mj_step`` call; the others are checked step by step.
        With ``compiled_steps`` the loop runs in ``probe_kernels.probe_steps`` (the same bits), and
        only the steps that need Python (the warm query's first patch or one it cannot build, a weak
        sign) come here."""
        d = self._data
        qvel = d.qvel
        cache = self.query_cache
        speed_per_step = self._speed_per_step
        turning = self._turning
        remaining = n
        projected = False
        while remaining > 0:
            if self.compiled_steps:
                taken, status, projected = self._compiled_steps(remaining, turning, speed_per_step)
                remaining -= taken
                if status == probe_kernels.DONE:  # it dropped the inward velocity itself
                    break
                # the last step's mj_step ran; its projection needs Python (the compiled query said so)
                projected = math.isfinite(sum(d.qpos.tolist())) and self._project(try_compiled=False)
                continue
            remaining, projected = self._python_step(remaining, turning, speed_per_step)
        if projected and cache[probe_kernels.HAS_HIT] == 1.0:
            # drop the inward velocity of the last projection (every step above sets the command anew)
            normal = cache[probe_kernels.HIT_NORMAL : probe_kernels.HIT_NORMAL + 3]
            inward = float(qvel[0:3] @ normal)
            if inward < 0.0:
                qvel[0:3] -= inward * normal

    def _python_step(self, remaining: int, turning: bool, speed_per_step: float) -> tuple[int, bool]:
        """One pass of the Python loop: a batch of free steps or one checked step; returns the steps
        still to go and whether this pass projected the probe."""
        m, d = self._model, self._data
        qpos, qvel = d.qpos, d.qvel
        cache = self.query_cache
        qvel[0:3] = self._linear_command  # free joint: linear velocity in the world frame
        if turning:
            # angular velocity in the body frame; constant during a batch since the probe's inertia
            # is isotropic (a sphere) and it rotates about a fixed axis
            mujoco.mju_quat2Mat(self._step_rotation, qpos[3:7])
            qvel[3:6] = self._step_rotation.reshape(3, 3).T @ self._angular_command
        else:
            qvel[3:6] = 0.0
        offset = qpos[0:3] - cache[0:3]
        margin = float(cache[probe_kernels.CACHE_D]) - math.sqrt(offset.dot(offset)) - self.radius_m - self._tolerance_m
        free = 0
        if math.isfinite(margin) and margin > 0:
            free = remaining if speed_per_step == 0 else min(remaining, int(margin / speed_per_step))
        if free > 0:
            mujoco.mj_step(m, d, nstep=free)
            self._physics.steps += free
            return remaining - free, False
        mujoco.mj_step(m, d)
        self._physics.steps += 1
        return remaining - 1, math.isfinite(sum(qpos.tolist())) and self._project()

    def _compiled_steps(self, steps: int, turning: bool, speed_per_step: float) -> tuple[int, int, bool]:
        """Up to ``steps`` steps in ``probe_kernels.probe_steps``: (steps taken, status, projected)."""
        functions = probe_kernels.mujoco_functions()
        assert functions is not None
        taken, status, projected = probe_kernels.probe_steps(
            functions[0],
            functions[1],
            self._model._address,
            self._data._address,
            steps,
            self._data.qpos,
            self._data.qvel,
            self._linear_command,
            self._angular_command,
            turning,
            speed_per_step,
            self._step_rotation,
            *self._kernel_arguments(),
        )
        self._physics.steps += taken
        assert self._kernel_patch is not None
        self.warm_query.resume(int(self._kernel_patch.face[0]), int(self._kernel_patch.searches[0]))  # counts, face
        self._kernel_patch.searches[0] = 0
        return taken, status, projected

    def _kernel_arguments(self) -> tuple[Any, ...]:
        """The arguments that ``probe_kernels.probe_steps`` and ``probe_closest`` share: the cache, the
        probe, the mesh and the probe's patch."""
        assert self._kernel_patch is not None
        return (
            self.query_cache,
            self.radius_m,
            self._tolerance_m,
            self._kernel_mesh,
            self._face_normals,
            self._kernel_grid,
            self._kernel_patch.arrays(),
            self._kernel_params,
            self._candidates,
        )

    # --- the exact query ---------------------------------------------------------------------------
    def _warm_query(self, p: np.ndarray) -> tuple[tuple[float, float, float], float, int]:
        """The warm query at p (3,) in Python; where the compiled steps keep the probe's patch it takes
        it over and hands it back (``WarmPatches.load`` and ``store``), even after ``compiled_steps``
        was turned off."""
        if self._kernel_patch is None:
            return self.warm_query.query(p)
        self._kernel_patch.load(0, self.warm_query)
        answer = self.warm_query.query(p)
        self._kernel_patch.store(0, self.warm_query)
        return answer

    def _project(self, try_compiled: bool = True) -> bool:
        """Push the probe out of the surface along the contact normal; True when it was pushed (the
        caller then drops its inward velocity). `try_compiled`: as `_closest`.

        One projection per step: in a concave corner a second surface may still be penetrated by at
        most one step of motion, which the next step corrects.
        """
        hit = self._closest(try_compiled)
        r = self.radius_m
        if hit is None or hit[1] >= r:
            return False
        point, _, normal = hit
        self._data.qpos[0:3] = point + r * normal
        return True

    def _closest(self, try_compiled: bool = True) -> tuple[np.ndarray, float, np.ndarray] | None:
        """Closest surface point, signed centre distance and contact normal; None if surely apart.
        `try_compiled` False: the compiled query just said it needs Python here (skip asking again)."""
        k = probe_kernels
        cache = self.query_cache
        p = self._data.qpos[0:3].copy()
        if cache[k.HAS_HIT] == 1.0 and p.tolist() == cache[0:3].tolist():  # held (the compiled steps ask)
            return self._held_hit()
        if self.compiled_steps and try_compiled:  # the same answer in compiled code, unless it needs Python
            status = k.probe_closest(self._data.qpos, *self._kernel_arguments())
            if status != k.NEEDS_PYTHON:
                return None if status == k.NO_HIT else self._held_hit()
        # The signed distance is 1-Lipschitz: skip the query while it cannot be within reach.
        offset = p - cache[0:3]
        bound = float(cache[k.CACHE_D]) - math.sqrt(offset.dot(offset))
        if bound > self.radius_m + self._tolerance_m:
            return None
        found, dist, face = self._warm_query(p)  # the exact query, warm-started from the last answer
        if self.two_sided:  # a sheet has no inside: the normal below points to the centre's side
            dist = abs(dist)
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
        return self._held_hit()

    def _held_hit(self) -> tuple[np.ndarray, float, np.ndarray]:
        """The held hit: surface point (3,), signed distance, contact normal (3,) (copies)."""
        k, cache = probe_kernels, self.query_cache
        point = cache[k.HIT_POINT : k.HIT_POINT + 3].copy()
        return point, float(cache[k.HIT_DIST]), cache[k.HIT_NORMAL : k.HIT_NORMAL + 3].copy()

    # --- reading -----------------------------------------------------------------------------------
    def contacts(self) -> Contacts:
        """The probe's contact at the current state (none, or one on the link "probe")."""
        hit = self._closest()
        if hit is None or hit[1] > self.radius_m + self._tolerance_m:
            return Contacts.empty()
        point, _, normal = hit
        q = self._data.qpos
        mujoco.mju_quat2Mat(self._contact_rotation, q[3:7])  # MuJoCo's rotation matrix, row-major
        r = self._contact_rotation.tolist()
        (px, py, pz), (nx, ny, nz), (cx, cy, cz) = point.tolist(), normal.tolist(), q[0:3].tolist()
        vx, vy, vz = self._linear_command.tolist()
        ox, oy, oz = px - cx, py - cy, pz - cz
        # R^T (p - c) and the force, summed left to right as numpy's 3-element products are
        local = (
            r[0] * ox + r[3] * oy + r[6] * oz,
            r[1] * ox + r[4] * oy + r[7] * oz,
            r[2] * ox + r[5] * oy + r[8] * oz,
        )
        force = self._force_gain * max(0.0, -(vx * nx + vy * ny + vz * nz))
        return Contacts(point.reshape(1, 3), np.array([local]), normal.reshape(1, 3), np.array([force]), ["probe"])
