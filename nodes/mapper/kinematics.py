"""Forward kinematics of a serial finger chain, vectorised over particles.

The mapper builds its chain from the hand description (``KinematicChain.from_description``: the
file the simulator generates its MJCF from), placed where a ``FingerMount`` says; the chain equals
the one read from the simulator's MuJoCo model (``from_model``): bit for bit for an untilted mount
(every launch file), to 1e-15 for a tilted one. ``forward`` reproduces
``mujoco.mj_kinematics`` (engine_core_smooth.c) for hinge and slide joints:

    x_b = x_parent + R_parent @ body_pos_b,          R_b = R_parent @ R(body_quat_b)
    for each joint j of body b, in order:
      hinge: anchor = x_b + R_b @ jnt_pos_j;  R_b = R_b @ Rot(jnt_axis_j, q_j - qpos0_j);
             x_b = anchor - R_b @ jnt_pos_j
      slide: x_b = x_b + (R_b @ jnt_axis_j) * (q_j - qpos0_j)

A "link" is a body of the chain: the bodies from the first joint's body to the last joint's body,
plus the joint-less bodies fixed to them (a fingertip body, a nail). Everything above the first
joint's body must be fixed (no joints): it is the chain's base.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import NDArray

from palpate.config import OneOf, PositiveFloat, Validated
from palpate.description import HandDescription, as_written, load_hand, mount_fact
from palpate.errors import ConfigError
from palpate.geometry.rotations import axis_angle_to_matrices, quat_to_matrix, ypr_deg_to_quat

FloatArray = NDArray[np.float64]

_HINGE = 3  # mujoco.mjtJoint.mjJNT_HINGE
_SLIDE = 2  # mujoco.mjtJoint.mjJNT_SLIDE
_SPHERE = 2  # mujoco.mjtGeom.mjGEOM_SPHERE
_CAPSULE = 3  # mujoco.mjtGeom.mjGEOM_CAPSULE


def _bone_capsule_ends(length_m: float) -> tuple[FloatArray, FloatArray]:
    """Ends (a, b) (3,) of the capsule from a segment's joint to (length_m, 0, 0), as ``from_model``
    reads the simulator's ``fromto`` capsule: MuJoCo turns the geom's z axis onto from - to (-x) by
    the quaternion (cos 45 deg, 0, -sin 45 deg, 0) (mjuu_z2quat), which leaves about 1e-18 m of
    rounding in z and puts the distal end first. Doing the same keeps the mapper's free-volume
    lattice (observation.capsule_lattice) what it was with the model, bit for bit."""
    half = length_m / 2
    z = quat_to_matrix(np.array([math.cos(math.pi / 4), 0.0, -math.sin(math.pi / 4), 0.0]))[:, 2]
    centre = np.array([half, 0.0, 0.0])
    return centre - z * half, centre + z * half


def _matvec(a: FloatArray, v: FloatArray) -> FloatArray:
    """Batched a @ v for a (..., 3, 3), v (..., 3)."""
    return np.asarray((a * v[..., None, :]).sum(axis=-1))


@dataclass(frozen=True)
class Capsule:
    """A capsule (or sphere: half_length 0) fixed to a link, in the link frame (metres)."""

    link: int
    a_local_m: FloatArray  # (3,) one end of the axis segment
    b_local_m: FloatArray  # (3,) the other end
    radius_m: float
    name: str


#: The hand every chain's mount is checked against (its digit names and default finger mount).
_HAND = load_hand()


@dataclass(frozen=True, kw_only=True)
class FingerMount(Validated):
    """Which digit of the described hand a chain models, and where the hand is fixed in the world.

    effector "finger": the simulator's single-finger effector, one of the long fingers; the base is
    the proximal end of its metacarpal. effector "hand": the simulator's hand; the base is the palm,
    and ``finger`` may also be the thumb. ``scale`` multiplies every length and radius, as in the
    simulator's scene. The defaults are the hand description's finger mount (hand.yaml
    ``finger_mount``): where the simulator places its finger in front of its default object.
    """

    #: The simulator's effector the chain belongs to: "finger" (base: the metacarpal's proximal end) or
    #: "hand" (base: the palm).
    effector: Literal["finger", "hand"] = "finger"
    #: The digit the chain models, the one that taps: a long finger (with effector hand also the thumb).
    finger: Annotated[str, OneOf(tuple(d.name for d in _HAND.digits))] = _HAND.finger_mount.finger
    #: Multiplies every length and radius of the hand description, as the simulator's scene ``scale``.
    scale: PositiveFloat = 1.0
    #: The base (metacarpal base or palm) in the world, metres.
    base_position_m: tuple[float, float, float] = _HAND.finger_mount.base_position_m
    #: The base's orientation in the world (w, x, y, z), as the simulator's ``base_quaternion_wxyz``.
    base_quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.effector == "finger" and self.finger not in _HAND.long_fingers:
            raise ConfigError(
                f"finger = {self.finger!r}: the single-finger effector is a long finger "
                f"({', '.join(_HAND.long_fingers)}); set effector: hand to model the {self.finger}",
                ("finger",),
            )
        if not math.hypot(*self.base_quaternion_wxyz) > 0:
            raise ConfigError(
                f"base_quaternion_wxyz = {self.base_quaternion_wxyz!r}: a zero quaternion is no rotation",
                ("base_quaternion_wxyz",),
            )

    def fact(self) -> dict[str, Any]:
        """Where this mount fixes the hand, as the simulator's scene must state it too (``mount_fact``)."""
        return mount_fact(self.effector, self.finger, self.scale, self.base_position_m, self.base_quaternion_wxyz)


@dataclass(frozen=True)
class _Joint:
    kind: int  # _HINGE or _SLIDE
    axis: FloatArray  # (3,) unit, body frame
    pos: FloatArray  # (3,) anchor, body frame
    qpos0: float
    column: int  # column of q


@dataclass(frozen=True)
class _Link:
    parent: int  # link index, -1 for the base
    pos: FloatArray  # (3,) body_pos
    rot: FloatArray  # (3, 3) R(body_quat)
    joints: tuple[_Joint, ...]


class KinematicChain:
    """A serial chain of links moved by J joints; ``forward`` maps q (K, J) to link poses."""

    def __init__(
        self,
        *,
        base_rot: FloatArray,
        base_pos_m: FloatArray,
        links: list[_Link],
        capsules: list[Capsule],
        joint_names: list[str],
        link_names: list[str],
        link_body_ids: list[int] | None = None,
    ) -> None:
        self.base_rot = np.asarray(base_rot, dtype=np.float64)
        self.base_pos_m = np.asarray(base_pos_m, dtype=np.float64)
        self._links = links
        self.capsule_list = capsules
        self.joint_names = list(joint_names)
        self.link_names = list(link_names)
        #: MuJoCo body id of each link (a chain read from a model only).
        self.link_body_ids = list(link_body_ids or [])
        self.capsule_radii_m = np.array([c.radius_m for c in capsules], dtype=np.float64)
        self._cap_links = np.array([c.link for c in capsules], dtype=np.intp)
        self._cap_local = np.array([[c.a_local_m, c.b_local_m] for c in capsules], dtype=np.float64).reshape(
            len(capsules), 2, 3
        )

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_links(self) -> int:
        return len(self._links)

    def link_of_body(self, body_id: int) -> int:
        """Link index of a MuJoCo body id; ConfigError if the body is not part of the chain."""
        try:
            return self.link_body_ids.index(int(body_id))
        except ValueError:
            raise ConfigError(
                f"body {body_id} is not a link of this chain (links are bodies {self.link_body_ids})"
            ) from None

    @classmethod
    def from_description(cls, hand: HandDescription, mount: FingerMount) -> KinematicChain:
        """The chain of ``mount.finger`` of the described hand, fixed where ``mount`` says.

        Its links are the digit's moving segments, their capsules run from joint to joint, and every
        number is rounded as the simulator's MJCF writes it (``as_written``), so the chain equals the
        one ``from_model`` reads from the simulator's model of the same effector.
        """
        digit = hand.digit(mount.finger)
        first = digit.fixed_segments
        if mount.effector == "finger" and first == 0:
            raise ConfigError(f"finger = {mount.finger!r}: the single-finger effector is a long finger; mount the hand")
        lengths = [as_written(v) for v in digit.lengths_m(mount.scale)]
        if mount.effector == "hand":  # the digit's rest frame in the palm (a quaternion in the MJCF)
            offset = np.array([as_written(v) for v in digit.base_m(mount.scale)])
            rest_q = ypr_deg_to_quat(*digit.rest_ypr_deg)
            rest = quat_to_matrix(np.array([as_written(v) for v in rest_q]))
        else:  # the metacarpal's base is the mount itself
            offset, rest = np.zeros(3), np.eye(3)
        column = {name: i for i, name in enumerate(digit.joint_names())}
        links, capsules, names = [], [], []
        for k in range(first, len(digit.segments)):
            segment = digit.segments[k]
            i = k - first
            joints = tuple(
                _Joint(
                    kind=_HINGE,
                    axis=np.array(j.axis, dtype=np.float64),
                    pos=np.zeros(3),
                    qpos0=0.0,
                    column=column[f"{digit.name}_{j.name}"],
                )
                for j in digit.segment_joints(segment)
            )
            if i == 0:  # the first moving segment starts at the end of the fixed ones
                pos, rot = offset + rest @ np.array([sum(lengths[:first]), 0.0, 0.0]), rest
            else:
                pos, rot = np.array([lengths[k - 1], 0.0, 0.0]), np.eye(3)
            links.append(_Link(parent=i - 1, pos=pos, rot=rot, joints=joints))
            names.append(f"{digit.name}_{segment}")
            a, b = _bone_capsule_ends(lengths[k])
            capsules.append(
                Capsule(
                    link=i,
                    a_local_m=a,
                    b_local_m=b,
                    radius_m=as_written(hand.radius_m(mount.scale)),
                    name=names[-1],
                )
            )
        quaternion = np.array([as_written(v) for v in mount.base_quaternion_wxyz])
        return cls(
            base_rot=quat_to_matrix(quaternion),
            base_pos_m=np.array([as_written(v) for v in mount.base_position_m]),
            links=links,
            capsules=capsules,
            joint_names=digit.joint_names(),
            link_names=names,
        )

    @classmethod
    def from_model(cls, model: Any, joint_names: list[str]) -> KinematicChain:
        """Read the chain moved by ``joint_names`` (hinge or slide) from a ``mujoco.MjModel``.

        Reads body_pos, body_quat, jnt_axis, jnt_pos, qpos0 and the capsule and sphere geoms of the
        links. Raises ConfigError naming the problem if a joint is missing, is not hinge or slide,
        the joints are not one serial chain, a link carries a joint not listed, or the base moves.
        """
        import mujoco  # local import: the pure maths above does not need MuJoCo

        if not joint_names:
            raise ConfigError("joint_names is empty: list the finger's joints from the root outwards")
        jids = []
        for name in joint_names:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise ConfigError(f"joint {name!r} is not in the model; check the finger's joint names")
            if int(model.jnt_type[jid]) not in (_HINGE, _SLIDE):
                raise ConfigError(f"joint {name!r} is not a hinge or slide joint; the chain supports only those")
            jids.append(jid)
        column = {jid: i for i, jid in enumerate(jids)}
        parent = np.asarray(model.body_parentid)
        joint_bodies = sorted({int(model.jnt_bodyid[j]) for j in jids})
        first, last = joint_bodies[0], joint_bodies[-1]

        def ancestors(b: int) -> list[int]:
            out = []
            while b != 0:
                out.append(b)
                b = int(parent[b])
            return out

        path = ancestors(last)
        if first not in path or any(b not in path for b in joint_bodies):
            raise ConfigError(f"joints {joint_names} do not form one serial chain of bodies")
        path_bodies = sorted(b for b in path if b >= first)
        base_bodies = [b for b in path if b < first]
        for b in base_bodies:
            if model.body_jntnum[b] > 0:
                raise ConfigError(f"body {b} above the chain has joints; list them in joint_names or fix the base")
        # joint-less bodies fixed to the chain (fingertip, nail): descendants reached without joints
        bodies = set(path_bodies)
        changed = True
        while changed:
            changed = False
            for b in range(model.nbody):
                if b not in bodies and int(parent[b]) in bodies and model.body_jntnum[b] == 0:
                    bodies.add(b)
                    changed = True
        body_ids = sorted(bodies)  # MuJoCo numbers bodies parents first
        link_of = {b: i for i, b in enumerate(body_ids)}

        base_rot = np.eye(3)
        base_pos = np.zeros(3)
        for b in sorted(base_bodies):  # world -> ... -> parent of the first link
            base_pos = base_pos + base_rot @ model.body_pos[b]
            base_rot = base_rot @ quat_to_matrix(model.body_quat[b])

        links = []
        for b in body_ids:
            joints = []
            for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b] + model.body_jntnum[b])):
                if j not in column:
                    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
                    raise ConfigError(f"link body {b} has joint {name!r} (id {j}) not listed in joint_names")
                joints.append(
                    _Joint(
                        kind=int(model.jnt_type[j]),
                        axis=np.array(model.jnt_axis[j], dtype=np.float64),
                        pos=np.array(model.jnt_pos[j], dtype=np.float64),
                        qpos0=float(model.qpos0[model.jnt_qposadr[j]]),
                        column=column[j],
                    )
                )
            links.append(
                _Link(
                    parent=link_of.get(int(parent[b]), -1),
                    pos=np.array(model.body_pos[b], dtype=np.float64),
                    rot=quat_to_matrix(model.body_quat[b]),
                    joints=tuple(joints),
                )
            )

        capsules = []
        for g in range(model.ngeom):
            b = int(model.geom_bodyid[g])
            kind = int(model.geom_type[g])
            if b not in link_of or kind not in (_CAPSULE, _SPHERE):
                continue
            rot = quat_to_matrix(model.geom_quat[g])
            centre = np.array(model.geom_pos[g], dtype=np.float64)
            half = float(model.geom_size[g][1]) if kind == _CAPSULE else 0.0
            capsules.append(
                Capsule(
                    link=link_of[b],
                    a_local_m=centre - rot[:, 2] * half,
                    b_local_m=centre + rot[:, 2] * half,
                    radius_m=float(model.geom_size[g][0]),
                    name=mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}",
                )
            )
        if not capsules:
            raise ConfigError(f"the chain of joints {joint_names} has no capsule or sphere geoms")
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in body_ids]
        return cls(
            base_rot=base_rot,
            base_pos_m=base_pos,
            links=links,
            capsules=capsules,
            joint_names=list(joint_names),
            link_names=names,
            link_body_ids=body_ids,
        )

    def forward(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Link poses for joint angles q (K, J) (radians, metres for slides).

        Returns rotations (K, L, 3, 3) (link frame -> world) and origins (K, L, 3) in metres.
        """
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != self.n_joints:
            raise ConfigError(f"q must have shape (K, {self.n_joints}), got {q.shape}")
        K = q.shape[0]
        rots = np.empty((K, self.n_links, 3, 3))
        pos = np.empty((K, self.n_links, 3))
        for i, link in enumerate(self._links):
            if link.parent < 0:  # the fixed base: constant, computed once
                x = np.broadcast_to(self.base_pos_m + self.base_rot @ link.pos, (K, 3))
                r = np.broadcast_to(self.base_rot @ link.rot, (K, 3, 3))
            else:
                pr = rots[:, link.parent]
                x = pos[:, link.parent] + pr @ link.pos
                r = pr @ link.rot
            for jt in link.joints:
                angle = q[:, jt.column] - jt.qpos0
                if jt.kind == _HINGE:
                    off = bool(np.any(jt.pos))
                    anchor = x + r @ jt.pos if off else x
                    r = r @ axis_angle_to_matrices(jt.axis, angle)
                    x = anchor - r @ jt.pos if off else x
                else:
                    x = x + (r @ jt.axis) * angle[:, None]
            rots[:, i] = r
            pos[:, i] = x
        return rots, pos

    def to_world(self, q: FloatArray, link_index: NDArray[np.integer], local_points: FloatArray) -> FloatArray:
        """World positions (K, n, 3) of points (n, 3) fixed in links link_index (n,), for q (K, J)."""
        rots, pos = self.forward(q)
        return transform_points(rots, pos, np.asarray(link_index, dtype=np.intp), local_points)

    def capsules(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Capsule axis end points (K, C, 2, 3) in metres for q (K, J), and radii (C,) in metres."""
        rots, pos = self.forward(q)
        r = rots[:, self._cap_links]  # (K, C, 3, 3)
        ends = _matvec(r[:, :, None], np.broadcast_to(self._cap_local, (*r.shape[:2], 2, 3)))
        return ends + pos[:, self._cap_links, None, :], self.capsule_radii_m.copy()


def transform_points(
    rots: FloatArray, pos: FloatArray, link_index: NDArray[np.intp], local_points: FloatArray
) -> FloatArray:
    """World positions (K, n, 3) = R[:, link] @ p + x[:, link] for points (n, 3) in links (n,)."""
    r = rots[:, link_index]  # (K, n, 3, 3)
    return _matvec(r, np.broadcast_to(local_points, (*r.shape[:2], 3))) + pos[:, link_index]
