"""A hand's or finger's contacts with a mesh or the torus: exact-mesh penalty contacts.

MuJoCo collision between effector and object is off; each capsule is covered by spheres along its
axis (``capsules.capsule_spheres``: spacing radius / 2, so the covered surface deviates from the
capsule by at most 3 % of the radius, 0.25 mm at 8 mm) and each sphere within reach of the surface
gets a spring-damper penalty force ``k (r - d) - b v_n`` (clipped at 0) along the exact-mesh normal,
applied at the surface point through ``xfrc_applied``. This reuses the exact sensor instead of a
CoACD decomposition, so there is no decomposition to compute or cache (CoACD takes seconds to a
minute per mesh and its parts still bulge by its concavity threshold). Cost: one closest-point query
per capsule sphere that is near the surface (a 1-Lipschitz bound on the signed distance skips the
others), about 10 to 30 spheres per finger; reported contacts are one per touching run of spheres
along a capsule, at the deepest sphere, with the run's summed force. With ``compiled_steps`` the
step loop runs in ``penalty_kernels.penalty_steps`` (the same bits).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from palpate.errors import SimulationDivergedError
from palpate.geometry.mesh_query import FEW_POINTS, ClosestPoints, ExactContactSensor, WarmClosest
from palpate.inputs import all_finite
from palpate.messages import codec
from palpate.nodes.sim import capsule_kernels, penalty_kernels
from palpate.nodes.sim.capsules import capsule_spheres
from palpate.nodes.sim.contacts import NO_ROWS, NO_VALUES, Contacts, make_contacts
from palpate.nodes.sim.physics import Physics
from palpate.nodes.sim.scene import SceneConfig

#: No touching capsule sphere: `PenaltyContacts._sphere_hits`'s answer (indices, centres, points,
#: distances, normals), read-only.
_NO_HITS = (codec.frozen(np.zeros(0, dtype=np.int64)), NO_ROWS, NO_ROWS, NO_VALUES, NO_ROWS)


class PenaltyContacts:
    """The capsule spheres of a hand or finger on an exact mesh: their queries, the penalty forces of
    each step (``advance``) and the contacts they report (``contacts``)."""

    def __init__(
        self, physics: Physics, scene: SceneConfig, sensor: ExactContactSensor, effector_bodies: np.ndarray
    ) -> None:
        """``effector_bodies`` (nbody,) bool: the bodies whose capsules touch (their names name the
        contacts' links)."""
        self._physics, self._model, self._data, self.sensor = physics, physics.model, physics.data, sensor
        self._body_names = [self._model.body(i).name for i in range(self._model.nbody)]
        self._tolerance_m = float(scene.contact_tolerance_m)
        self._stiffness = scene.mesh_contact_stiffness_n_per_m
        self._damping = scene.mesh_contact_damping_n_s_per_m
        self._setup_spheres(effector_bodies)
        #: Place the spheres and bound their distances in compiled code (capsule_kernels), where it gives
        #: numpy's bits.
        self.compiled_bounds = capsule_kernels.matches_numpy()
        #: Run the physics steps in compiled code (penalty_kernels) where MuJoCo's library is found and
        #: the compiled arithmetic gives numpy's bits.
        self.compiled_steps = (
            self.compiled_bounds and penalty_kernels.mujoco_functions() is not None and penalty_kernels.matches_numpy()
        )
        #: Each sphere's warm-started query in Python, made on first use.
        self.warm_queries: dict[int, WarmClosest] = {}
        #: The compiled steps' query buffers hold the current state's answers (see contacts()).
        self.hits_current = False
        self._setup_kernels()

    def _setup_spheres(self, effector_bodies: np.ndarray) -> None:
        """The spheres covering the capsules, and each one's last query (none yet)."""
        spheres = capsule_spheres(self._model, effector_bodies)
        self.sphere_geoms, self._sphere_offsets, self._sphere_radii, runs = spheres
        #: Each sphere's capsule (the index of its run).
        self._sphere_capsule = [c for c, (start, stop) in enumerate(runs) for _ in range(start, stop)]
        count = len(self.sphere_geoms)
        self._sphere_bodies = self._model.geom_bodyid[self.sphere_geoms]
        #: Where each sphere's last query was and its signed distance there (the 1-Lipschitz bound's start).
        self._queried_centres = np.zeros((count, 3))
        self._queried_distances = np.full(count, -np.inf)  # no query yet: the bound never skips
        self._sphere_reach = self._sphere_radii + self._tolerance_m

    def _setup_kernels(self) -> None:
        """What the compiled steps of the capsule spheres read and write (penalty_kernels)."""
        m, d, sensor = self._model, self._data, self.sensor
        count = len(self.sphere_geoms)
        template = WarmClosest(sensor)  # the settings of every sphere's query
        self.kernel_mesh, self.kernel_grid, self.kernel_params = penalty_kernels.query_setup(sensor, template)
        #: The spheres' warm-started queries, packed for the compiled steps.
        self.patches = penalty_kernels.WarmPatches(count, template.max_patch_faces)
        # what the compiled steps read and write: MuJoCo's arrays (views that stay valid), the spheres,
        # the mesh, per-step buffers and parameters (penalty_kernels.sphere_hits documents them)
        self._kernel_frames = (d.geom_xpos, d.geom_xmat)
        self._kernel_dynamics = (np.asarray(m.body_rootid), (d.cvel, d.subtree_com, d.xipos, d.xfrc_applied))
        self._kernel_spheres = (
            self.sphere_geoms,
            self._sphere_offsets,
            self._sphere_radii,
            self._sphere_reach,
            self._sphere_bodies,
            self._queried_centres,
            self._queried_distances,
        )
        self._face_normals = sensor.face_normals
        self._buffers = (
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
        self.kernel_params[penalty_kernels.P_STIFFNESS] = self._stiffness
        self.kernel_params[penalty_kernels.P_DAMPING] = self._damping
        if self.compiled_steps:  # load the forces' kernel for these argument types now, not at the first touch
            self._sphere_forces(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))

    # --- stepping ----------------------------------------------------------------------------------
    def advance(self, n: int) -> tuple[bool, bool]:
        """``n`` physics steps with the penalty forces: (whether the state stayed finite, whether the
        last compiled call also refreshed the frames and answered the final state's queries,
        ``END_QUERIED``). A state that is not finite ends the steps at once (the caller raises); a
        sphere whose centre is inside the object raises SimulationDivergedError."""
        if not self.compiled_steps:
            if not self._python_steps(n):
                return False, False
            self.hits_current = False
            return True, False
        functions = penalty_kernels.mujoco_functions()
        assert functions is not None
        addresses = (*functions, self._model._address, self._data._address)
        k = penalty_kernels
        physics = self._physics
        remaining, resume = n, k.HITS_CURRENT if self.hits_current else -1
        queried = False
        while remaining > 0:
            taken, status, at = k.penalty_steps(
                addresses,
                remaining,
                resume,
                FEW_POINTS,
                self._data.qpos,
                self._kernel_frames,
                self._kernel_dynamics,
                self._kernel_spheres,
                self.kernel_mesh,
                self.kernel_grid,
                self._face_normals,
                self.patches.arrays(),
                self._buffers,
                self.kernel_params,
            )
            physics.steps += taken
            remaining -= taken
            resume = -1
            if status == k.DONE:
                queried = at == k.END_QUERIED
            elif status == k.NEEDS_PYTHON:
                resume = self._answer_in_python(at)
            elif status == k.PENETRATED:
                _, near, _, dist, _, touch, state, _, _ = self._buffers
                rows = touch[: state[k.S_TOUCHING]]
                raise self._penetration_error(near[rows], dist[rows])
            elif status == k.NOT_FINITE:
                return False, False
        self.hits_current = queried
        return True, queried

    def _python_steps(self, n: int) -> bool:
        """``n`` steps in Python: mj_step1, the penalty forces, mj_step2; False at the first one that
        leaves a state that is not finite."""
        m, d = self._model, self._data
        physics = self._physics
        for _ in range(n):
            mujoco.mj_step1(m, d)  # kinematics and velocities of the current state
            self._apply_forces()
            mujoco.mj_step2(m, d)  # forces, acceleration, integration
            physics.steps += 1
            if not all_finite(d.qpos):
                return False
        return True

    def _answer_in_python(self, at: int) -> int:
        """Answer the query at position ``at`` of the compiled near spheres (or all of them: BATCH) into
        the buffers, as ``_sphere_closest`` does; returns where the compiled queries go on."""
        centres, near, points, dist, faces, _, state, _, search = self._buffers
        k = penalty_kernels
        if at == k.BATCH:
            count = int(state[k.S_NEAR])
            hit = self.sensor.closest(centres[near[:count]])
            points[:count], dist[:count], faces[:count] = hit.points_m, hit.distance_m, hit.face_ids
            # each sphere's next query starts from its face here (any start gives the same answer)
            self.patches.face[near[:count]] = hit.face_ids
            return count
        sphere = int(near[at])
        if search[k.SEARCH_PENDING]:  # a weak sign of the compiled search
            search[k.SEARCH_PENDING] = 0.0
            s = search.tolist()
            q = s[k.SEARCH_Q : k.SEARCH_Q + 3]
            found = (int(s[k.SEARCH_FACE]), q[0], q[1], q[2], s[k.SEARCH_DIST])
            signs = (bool(s[k.SEARCH_INSIDE]), bool(s[k.SEARCH_WEAK]))
            warm = self._warm_query(sphere)
            answer = warm.settle(s[k.SEARCH_P : k.SEARCH_P + 3], (*found, *signs))
            points[at], dist[at], faces[at] = answer
            self.patches.face[sphere] = faces[at]
            self.patches.searches[sphere] += 1
            return at + 1
        x, y, z = centres[sphere].tolist()
        if self.patches.face[sphere] < 0 and math.isfinite(x + y + z):
            # a sphere's first query: its face starts at Open3D's, as WarmClosest._build seeds it, and
            # the compiled build goes on from there
            self.patches.face[sphere] = self.sensor.seed_face(x, y, z)
            return at
        warm = self._warm_query(sphere)
        self.patches.load(sphere, warm)
        points[at], dist[at], faces[at] = warm.query(centres[sphere])
        self.patches.store(sphere, warm)
        return at + 1

    def _warm_query(self, k: int) -> WarmClosest:
        """Sphere k's warm-started query, made on first use."""
        warm = self.warm_queries.get(k)
        if warm is None:
            warm = self.warm_queries[k] = WarmClosest(self.sensor)
        return warm

    def _sphere_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World centres (K, 3) of the capsule spheres and the indices (t,) of those the 1-Lipschitz bound
        on the signed distance leaves within reach of the surface, in increasing order."""
        d = self._data
        frames = (d.geom_xpos, d.geom_xmat, self.sphere_geoms, self._sphere_offsets)
        caches = (self._queried_centres, self._queried_distances, self._sphere_reach)
        if not self.compiled_bounds:
            return capsule_kernels.numpy_bounds(*frames, *caches)
        count = len(self.sphere_geoms)
        centres, near = np.empty((count, 3)), np.empty(count, dtype=np.int64)
        return centres, near[: capsule_kernels.sphere_bounds(*frames, *caches, centres, near)]

    def _sphere_hits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Touching spheres: indices (t,), centres (t, 3), surface points (t, 3), distances (t,),
        normals (t, 3), using the current kinematics."""
        if self.compiled_steps:
            return self._compiled_sphere_hits()
        P, near = self._sphere_bounds()
        if len(near) == 0:
            empty = np.zeros((0, 3))
            return np.zeros(0, dtype=np.int64), empty, empty, np.zeros(0), empty
        hit = self._sphere_closest(P, near)
        dist = np.asarray(hit.distance_m, dtype=np.float64)
        self._queried_centres[near] = P[near]
        self._queried_distances[near] = dist
        touching = dist <= self._sphere_radii[near] + self._tolerance_m
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
        while not self.hits_current:  # else the buffers hold this state's queries already
            status, at = k.sphere_hits(
                resume,
                FEW_POINTS,
                self._kernel_frames,
                self._kernel_spheres,
                self.kernel_mesh,
                self.kernel_grid,
                self.patches.arrays(),
                self._buffers,
                self.kernel_params,
            )
            if status == k.DONE:
                break
            resume = self._answer_in_python(at)
        centres, near, points, dist, faces, touch, state, _, _ = self._buffers
        if state[k.S_TOUCHING] == 0:  # the common case: no sphere touches
            return _NO_HITS
        rows = touch[: state[k.S_TOUCHING]]
        idx = near[rows]
        return idx, centres[idx], points[rows], dist[rows], self._face_normals[faces[rows]]

    def _sphere_closest(self, P: np.ndarray, near: np.ndarray) -> ClosestPoints:
        """The sensor's answer for the spheres ``near`` (indices into centres P (K, 3)). Up to
        FEW_POINTS spheres, where the sensor answers point by point, each sphere's own warm-started
        query gives the same bits (its face too) for less; more go to the sensor in one
        batch, whose vectorised path rounds differently."""
        if len(near) > FEW_POINTS:
            return self.sensor.closest(P[near])
        points, distances, faces = [], [], []
        for k in near.tolist():
            point, distance, face = self._warm_query(k).query(P[k])
            points.append(point)
            distances.append(distance)
            faces.append(face)
        face_ids = np.array(faces, dtype=np.int64)
        return ClosestPoints(
            points_m=np.array(points, dtype=np.float64).reshape(-1, 3),
            distance_m=np.array(distances, dtype=np.float64),
            normals=self.sensor.face_normals[face_ids],
            face_ids=face_ids,
        )

    def _sphere_forces(self, idx: np.ndarray, points: np.ndarray, dist: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Penalty normal force (t,) >= 0 of touching spheres: k (r - d) - b v_n."""
        d = self._data
        k, b = self._stiffness, self._damping
        # cvel is (angular, linear) at the subtree centre of mass of the body's root, world frame
        if self.compiled_steps:  # the same bits (penalty_kernels.matches_numpy)
            forces = np.empty(len(idx))
            body, radius, root = self._sphere_bodies, self._sphere_radii, self._kernel_dynamics[0]
            penalty_kernels.penalty_forces(
                idx, points, dist, normals, body, radius, root, d.cvel, d.subtree_com, k, b, forces
            )
            return forces
        bodies, radii = self._sphere_bodies[idx], self._sphere_radii[idx]
        origin = d.subtree_com[self._model.body_rootid[bodies]]
        return penalty_kernels.numpy_forces(bodies, radii, points, dist, normals, d.cvel, origin, k, b)

    def _apply_forces(self) -> None:
        """Set xfrc_applied from the current kinematics (call between mj_step1 and mj_step2)."""
        d = self._data
        d.xfrc_applied[:] = 0.0
        idx, _, points, dist, normals = self._sphere_hits()
        if len(idx) == 0:
            return
        if np.any(dist < 0.0):
            raise self._penetration_error(idx, dist)
        forces = self._sphere_forces(idx, points, dist, normals)
        # xfrc_applied acts at the body's centre of mass
        d.xfrc_applied[:] = penalty_kernels.numpy_wrench(self._sphere_bodies[idx], points, normals, forces, d.xipos)

    def _penetration_error(self, idx: np.ndarray, dist: np.ndarray) -> SimulationDivergedError:
        """The error for touching spheres idx (t,) at distances (t,) of which one has its centre inside."""
        dt = self._physics.dt
        return SimulationDivergedError(
            f"at t = {self._physics.time_s:.6g} s a finger segment's axis is inside the object (penetration "
            f"{1000 * (self._sphere_radii[idx] - dist).max():.3g} mm, more than the segment radius): the "
            f"penalty contact (stiffness {self._stiffness:g} N/m) was "
            f"overrun with time step {dt:g} s; use a smaller time step, e.g. timestep_s: {dt / 2:g} "
            "(or check that the effector does not start inside the object)"
        )

    # --- reading -----------------------------------------------------------------------------------
    def contacts(self) -> Contacts:
        """The contacts at the current state (the caller refreshed the frames and velocities): one per
        touching run of spheres along a capsule, at its deepest sphere, with the run's summed force."""
        out = self._touching_runs()
        if self.compiled_steps:
            # the next step's first queries are these, if they were asked one by one (a batch rounds
            # differently, and the next step may ask fewer): buffers as in penalty_kernels.sphere_hits
            state = self._buffers[6]
            self.hits_current = bool(state[penalty_kernels.S_NEAR] <= FEW_POINTS)
        return out

    def _touching_runs(self) -> Contacts:
        idx, _, points, dist, normals = self._sphere_hits()
        if len(idx) == 0:
            return Contacts.empty()
        forces = self._sphere_forces(idx, points, dist, normals)
        # idx is increasing: a run of touching spheres is a stretch of consecutive indices on one capsule
        spheres = idx.tolist()
        depth = (dist - self._sphere_radii[idx]).tolist()
        capsule = self._sphere_capsule
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
        bodies = self._sphere_bodies[idx[sel]]
        return make_contacts(points[sel], normals[sel], np.array(sums), bodies, self._data, self._body_names)
