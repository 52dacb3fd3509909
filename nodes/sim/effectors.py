"""Generated MJCF for the three effectors: a 21-DoF human hand, one finger of it, a fingertip probe.

Every length, range and gain is a field of a frozen config dataclass, so a scene can rescale or
re-proportion the hand without editing XML. Segment lengths are the mean bone lengths of 66 adults
(Buryanov and Kotiuk 2010, Table I); joint ranges follow the AAOS active ranges of motion (see
docs/hand_model.md for the table and the sources).

Conventions (hand frame = the frame of body ``palm``; finger frame = the frame of each phalanx):
- Fingers point along +x, the back of the hand faces +z, the palm faces -z; the thumb is on the +y
  side (a right hand, palm down).
- Each phalanx body has its origin at its proximal joint and extends along its local +x.
- Flexion is a positive rotation about the local +y axis, which curls the finger towards -z (palmar).
- MCP abduction is a rotation about the local +z axis applied before flexion (closer to the palm);
  positive moves the finger towards +y (the thumb side, radial deviation).
- A fingertip site ``<finger>_tip`` sits at the distal end of the distal phalanx bone; its local z
  axis points out of the tip along the finger (the direction the fingertip faces).
- Effector geoms do not collide with each other; the scene decides whether they collide with the
  object (``collide_with_object``).
- Angles in the fragments are radians: the enclosing MJCF needs ``<compiler angle="radian"/>``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from palpate.errors import ConfigError
from palpate.geometry.rotations import ypr_deg_to_quat

#: The four long fingers, radial to ulnar.
LONG_FINGERS: tuple[str, ...] = ("index", "middle", "ring", "little")
#: Joints of a long finger, proximal to distal (MCP abduction before MCP flexion).
FINGER_JOINTS: tuple[str, ...] = ("mcp_abd", "mcp_flex", "pip", "dip")
#: Joints of the thumb, proximal to distal.
THUMB_JOINTS: tuple[str, ...] = ("cmc_flex", "cmc_abd", "cmc_rot", "mcp", "ip")

#: contype / conaffinity bits: the object uses bit 0; effector geoms use bit 1 as their type and,
#: when they may touch the object, bit 0 as affinity (so effector geoms never collide with each other).
EFFECTOR_CONTYPE = 2
OBJECT_CONTYPE = 1


@dataclass(frozen=True, kw_only=True)
class DigitConfig:
    """Geometry, ranges and actuation shared by the hand and the single-finger effector.

    Lengths are bone lengths in mm (metacarpal, proximal, middle, distal phalanx) from Buryanov and
    Kotiuk 2010, Table I (mean of 66 adults); ``scale`` multiplies every length and radius.
    """

    scale: float = 1.0
    index_lengths_mm: tuple[float, float, float, float] = (68.12, 39.78, 22.38, 15.82)
    middle_lengths_mm: tuple[float, float, float, float] = (64.60, 44.63, 26.33, 17.40)
    ring_lengths_mm: tuple[float, float, float, float] = (58.00, 41.37, 25.65, 17.30)
    little_lengths_mm: tuple[float, float, float, float] = (53.69, 32.74, 18.11, 15.96)
    #: Radius of every capsule segment (a 16 mm thick finger).
    segment_radius_mm: float = 8.0
    # Human active ranges (AAOS 1965; DIP limited to 80 deg as in issue 3, AAOS gives 90).
    mcp_flex_range_deg: tuple[float, float] = (0.0, 90.0)
    mcp_abd_range_deg: tuple[float, float] = (-20.0, 20.0)
    pip_range_deg: tuple[float, float] = (0.0, 100.0)
    dip_range_deg: tuple[float, float] = (0.0, 80.0)
    #: Position actuator stiffness (torque per rad of target error).
    kp_nm_per_rad: float = 0.5
    #: Joint damping, integrated implicitly (close to critical for kp and the armature below).
    damping_nm_s_per_rad: float = 0.03
    #: Joint armature: a numerical inertia that keeps the light phalanges stable at a 2 ms step.
    armature_kg_m2: float = 5e-4
    #: Density of the capsules (soft tissue and bone).
    density_kg_m3: float = 1100.0

    def lengths_m(self, finger: str) -> tuple[float, ...]:
        """Scaled bone lengths of one long finger in metres (metacarpal, proximal, middle, distal)."""
        table = {
            "index": self.index_lengths_mm,
            "middle": self.middle_lengths_mm,
            "ring": self.ring_lengths_mm,
            "little": self.little_lengths_mm,
        }
        if finger not in table:
            raise ConfigError(f"unknown finger {finger!r}: use one of {', '.join(LONG_FINGERS)}")
        return tuple(self.scale * v / 1000.0 for v in table[finger])

    @property
    def radius_m(self) -> float:
        """Scaled capsule radius in metres."""
        return self.scale * self.segment_radius_mm / 1000.0


@dataclass(frozen=True, kw_only=True)
class HandConfig(DigitConfig):
    """The 21-DoF hand of paper 000: four long fingers (4 DoF each) and a 5-DoF thumb.

    The palm layout (metacarpal bases and directions) and the thumb's rest frame are model choices
    approximating an adult right hand, not measurements; see docs/hand_model.md.
    """

    thumb_lengths_mm: tuple[float, float, float] = (46.22, 31.57, 21.67)
    # AAOS: CMC flexion 15 / extension 20, palmar abduction 70, MCP flexion 50, IP flexion 80.
    thumb_cmc_flex_range_deg: tuple[float, float] = (-20.0, 15.0)
    thumb_cmc_abd_range_deg: tuple[float, float] = (0.0, 70.0)
    #: Axial rotation (pronation positive) of the first metacarpal: a model choice covering opposition.
    thumb_cmc_rot_range_deg: tuple[float, float] = (-10.0, 30.0)
    thumb_mcp_range_deg: tuple[float, float] = (0.0, 50.0)
    thumb_ip_range_deg: tuple[float, float] = (0.0, 80.0)
    #: y of each long-finger metacarpal base in the palm frame (index, middle, ring, little), mm.
    metacarpal_base_y_mm: tuple[float, float, float, float] = (10.0, 0.0, -9.0, -17.0)
    #: x of each metacarpal base (the carpometacarpal row is slightly arched), mm.
    metacarpal_base_x_mm: tuple[float, float, float, float] = (0.0, 0.0, -2.0, -6.0)
    #: Direction of each metacarpal in the palm plane (towards +y positive), degrees.
    metacarpal_yaw_deg: tuple[float, float, float, float] = (12.0, 4.0, -7.0, -15.0)
    #: Thumb CMC joint in the palm frame, mm (radial and palmar of the index metacarpal base).
    thumb_cmc_position_mm: tuple[float, float, float] = (2.0, 20.0, -10.0)
    #: Thumb rest frame: yaw about palm z, then pitch about the new y (palmar tilt), then roll about
    #: the bone axis, degrees. Roll -90 turns the thumb's flexion plane across the palm.
    thumb_rest_ypr_deg: tuple[float, float, float] = (40.0, 20.0, -90.0)
    #: Which fingertip ``effector_pose`` reports.
    pose_finger: str = "index"
    #: Palm pose in the world; None lets the scene place the hand so the object is in reach.
    base_position_m: tuple[float, float, float] | None = None
    base_quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def thumb_lengths_m(self) -> tuple[float, float, float]:
        """Scaled thumb bone lengths in metres (metacarpal, proximal, distal)."""
        a, b, c = (self.scale * v / 1000.0 for v in self.thumb_lengths_mm)
        return (a, b, c)

    def mcp_position_m(self, finger: str) -> np.ndarray:
        """MCP joint of a long finger in the palm frame, metres, shape (3,)."""
        i = LONG_FINGERS.index(finger)
        yaw = math.radians(self.metacarpal_yaw_deg[i])
        meta = self.lengths_m(finger)[0]
        base = self.scale * np.array([self.metacarpal_base_x_mm[i], self.metacarpal_base_y_mm[i], 0.0]) / 1e3
        return base + meta * np.array([math.cos(yaw), math.sin(yaw), 0.0])


@dataclass(frozen=True, kw_only=True)
class FingerConfig(DigitConfig):
    """One long finger of the hand on a fixed metacarpal; the rest of the hand is not simulated.

    The base frame is the metacarpal's proximal end, with the metacarpal along local +x and the
    back of the finger facing local +z.
    """

    finger: str = "index"
    #: Metacarpal base in the world; None lets the scene place it so the object is in reach.
    base_position_m: tuple[float, float, float] | None = None
    base_quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class ProbeConfig:
    """A spherical fingertip with ideal 6-DoF Cartesian velocity control (paper 002, Algorithm 1).

    The probe is a free body whose velocity is imposed every step (an ideal Cartesian velocity
    controller: ``setVelocity`` / ``setAngularVelocity`` of Algorithm 1). Its local z axis is the
    direction the fingertip faces.
    """

    radius_m: float = 0.008
    #: Start of the probe centre; None starts it above the object with ``start_clearance_m``.
    start_position_m: tuple[float, float, float] | None = None
    #: Start orientation; the default (180 deg about x) makes the fingertip face world -z.
    start_quaternion_wxyz: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 0.0)
    start_clearance_m: float = 0.03
    #: Gain of the velocity controller against a rigid surface: reported normal force is this
    #: gain times the commanded speed into the surface (what a velocity-controlled arm would push).
    force_gain_n_s_per_m: float = 50.0
    density_kg_m3: float = 1100.0


# --- helpers ---------------------------------------------------------------------------------------


def _fmt(values: np.ndarray | tuple[float, ...] | list[float]) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _collision_attrs(collide_with_object: bool) -> str:
    affinity = OBJECT_CONTYPE if collide_with_object else 0
    contype = EFFECTOR_CONTYPE if collide_with_object else 0
    return f'contype="{contype}" conaffinity="{affinity}"'


def _range_attr(range_deg: tuple[float, float]) -> str:
    lo, hi = range_deg
    if not lo < hi:
        raise ConfigError(f"joint range {list(range_deg)!r} is empty: give (lower, upper) with lower < upper")
    return f'range="{math.radians(lo):.9g} {math.radians(hi):.9g}"'


def _joint(name: str, axis: str, range_deg: tuple[float, float], cfg: DigitConfig) -> str:
    return (
        f'<joint name="{name}" type="hinge" axis="{axis}" {_range_attr(range_deg)} limited="true" '
        f'damping="{cfg.damping_nm_s_per_rad:.9g}" armature="{cfg.armature_kg_m2:.9g}"/>'
    )


def _capsule(name: str, length_m: float, cfg: DigitConfig, collide: bool) -> str:
    return (
        f'<geom name="{name}" type="capsule" fromto="0 0 0 {length_m:.9g} 0 0" '
        f'size="{cfg.radius_m:.9g}" density="{cfg.density_kg_m3:.9g}" {_collision_attrs(collide)} '
        f'rgba="0.92 0.76 0.65 1"/>'
    )


def _tip_site(finger: str, length_m: float, cfg: DigitConfig) -> str:
    # Local z of the site along the finger axis (+x of the phalanx): rotate +90 deg about y.
    return (
        f'<site name="{finger}_tip" pos="{length_m:.9g} 0 0" quat="0.707106781 0 0.707106781 0" '
        f'size="{0.25 * cfg.radius_m:.9g}" rgba="1 0 0 1"/>'
    )


def _long_finger_chain(finger: str, cfg: DigitConfig, collide: bool, mcp_pos: np.ndarray) -> str:
    """Proximal, middle and distal phalanx bodies with their four joints, starting at the MCP."""
    _, prox, mid, dist = cfg.lengths_m(finger)
    return (
        f'<body name="{finger}_proximal" pos="{_fmt(mcp_pos)}">'
        + _joint(f"{finger}_mcp_abd", "0 0 1", cfg.mcp_abd_range_deg, cfg)
        + _joint(f"{finger}_mcp_flex", "0 1 0", cfg.mcp_flex_range_deg, cfg)
        + _capsule(f"{finger}_proximal", prox, cfg, collide)
        + f'<body name="{finger}_middle" pos="{prox:.9g} 0 0">'
        + _joint(f"{finger}_pip", "0 1 0", cfg.pip_range_deg, cfg)
        + _capsule(f"{finger}_middle", mid, cfg, collide)
        + f'<body name="{finger}_distal" pos="{mid:.9g} 0 0">'
        + _joint(f"{finger}_dip", "0 1 0", cfg.dip_range_deg, cfg)
        + _capsule(f"{finger}_distal", dist, cfg, collide)
        + _tip_site(finger, dist, cfg)
        + "</body></body></body>"
    )


def _position_actuators(joint_names: list[str], ranges_deg: list[tuple[float, float]], cfg: DigitConfig) -> str:
    lines = []
    for name, (lo, hi) in zip(joint_names, ranges_deg, strict=True):
        lines.append(
            f'<position name="{name}" joint="{name}" kp="{cfg.kp_nm_per_rad:.9g}" ctrllimited="true" '
            f'ctrlrange="{math.radians(lo):.9g} {math.radians(hi):.9g}"/>'
        )
    return "".join(lines)


def finger_joint_names(finger: str) -> list[str]:
    """Joint names of one long finger, proximal to distal."""
    return [f"{finger}_{j}" for j in FINGER_JOINTS]


def hand_joint_names() -> list[str]:
    """All 21 hand joint names in model order (index, middle, ring, little, then thumb)."""
    names = [n for f in LONG_FINGERS for n in finger_joint_names(f)]
    return names + [f"thumb_{j}" for j in THUMB_JOINTS]


def _finger_ranges(cfg: DigitConfig) -> list[tuple[float, float]]:
    return [cfg.mcp_abd_range_deg, cfg.mcp_flex_range_deg, cfg.pip_range_deg, cfg.dip_range_deg]


def _hand_ranges(cfg: HandConfig) -> list[tuple[float, float]]:
    thumb = [
        cfg.thumb_cmc_flex_range_deg,
        cfg.thumb_cmc_abd_range_deg,
        cfg.thumb_cmc_rot_range_deg,
        cfg.thumb_mcp_range_deg,
        cfg.thumb_ip_range_deg,
    ]
    return _finger_ranges(cfg) * len(LONG_FINGERS) + thumb


def joint_ranges_rad(cfg: HandConfig | FingerConfig) -> np.ndarray:
    """Joint limits in model order, radians, shape (J, 2)."""
    ranges = _hand_ranges(cfg) if isinstance(cfg, HandConfig) else _finger_ranges(cfg)
    return np.radians(np.array(ranges, dtype=np.float64))


# --- public builders -------------------------------------------------------------------------------


@dataclass(frozen=True)
class EffectorMjcf:
    """MJCF fragments of one effector: bodies for <worldbody> and actuators for <actuator>."""

    worldbody: str
    actuators: str


def build_hand_mjcf(
    cfg: HandConfig,
    base_position_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    collide_with_object: bool = True,
) -> EffectorMjcf:
    """The 21-DoF hand rooted at body ``palm`` (fixed in the world at ``base_position_m``).

    The long-finger metacarpals are capsules of the palm body (no CMC motion for fingers II-V);
    the thumb metacarpal moves on three CMC hinges.
    """
    if cfg.pose_finger not in (*LONG_FINGERS, "thumb"):
        raise ConfigError(f"pose_finger {cfg.pose_finger!r} is not a finger: use index, middle, ring, little or thumb")
    collide = collide_with_object
    parts = [f'<body name="palm" pos="{_fmt(np.asarray(base_position_m))}" quat="{_fmt(cfg.base_quaternion_wxyz)}">']
    for i, finger in enumerate(LONG_FINGERS):
        yaw = math.radians(cfg.metacarpal_yaw_deg[i])
        base = cfg.scale * np.array([cfg.metacarpal_base_x_mm[i], cfg.metacarpal_base_y_mm[i], 0.0]) / 1e3
        mcp = cfg.mcp_position_m(finger)
        parts.append(
            f'<geom name="{finger}_metacarpal" type="capsule" fromto="{_fmt(base)} {_fmt(mcp)}" '
            f'size="{cfg.radius_m:.9g}" density="{cfg.density_kg_m3:.9g}" {_collision_attrs(collide)} '
            f'rgba="0.85 0.7 0.6 1"/>'
        )
        # Phalanx chain in the palm frame turned by the metacarpal's yaw.
        parts.append(
            f'<frame pos="{_fmt(base)}" quat="{math.cos(yaw / 2):.9g} 0 0 {math.sin(yaw / 2):.9g}">'
            + _long_finger_chain(finger, cfg, collide, np.array([cfg.lengths_m(finger)[0], 0.0, 0.0]))
            + "</frame>"
        )
    meta, prox, dist = cfg.thumb_lengths_m()
    thumb_pos = cfg.scale * np.array(cfg.thumb_cmc_position_mm) / 1e3
    thumb_quat = ypr_deg_to_quat(*cfg.thumb_rest_ypr_deg)
    parts.append(
        f'<body name="thumb_metacarpal" pos="{_fmt(thumb_pos)}" quat="{_fmt(thumb_quat)}">'
        + _joint("thumb_cmc_flex", "0 1 0", cfg.thumb_cmc_flex_range_deg, cfg)
        + _joint("thumb_cmc_abd", "0 0 1", cfg.thumb_cmc_abd_range_deg, cfg)
        + _joint("thumb_cmc_rot", "1 0 0", cfg.thumb_cmc_rot_range_deg, cfg)
        + _capsule("thumb_metacarpal", meta, cfg, collide)
        + f'<body name="thumb_proximal" pos="{meta:.9g} 0 0">'
        + _joint("thumb_mcp", "0 1 0", cfg.thumb_mcp_range_deg, cfg)
        + _capsule("thumb_proximal", prox, cfg, collide)
        + f'<body name="thumb_distal" pos="{prox:.9g} 0 0">'
        + _joint("thumb_ip", "0 1 0", cfg.thumb_ip_range_deg, cfg)
        + _capsule("thumb_distal", dist, cfg, collide)
        + _tip_site("thumb", dist, cfg)
        + "</body></body></body>"
    )
    parts.append("</body>")
    actuators = _position_actuators(hand_joint_names(), _hand_ranges(cfg), cfg)
    return EffectorMjcf(worldbody="".join(parts), actuators=actuators)


def build_finger_mjcf(
    cfg: FingerConfig,
    base_position_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    collide_with_object: bool = True,
) -> EffectorMjcf:
    """One long finger: body ``<finger>_metacarpal`` fixed at the base pose, then 4 hinge joints."""
    finger = cfg.finger
    meta = cfg.lengths_m(finger)[0]
    body = (
        f'<body name="{finger}_metacarpal" pos="{_fmt(np.asarray(base_position_m))}" '
        f'quat="{_fmt(cfg.base_quaternion_wxyz)}">'
        + _capsule(f"{finger}_metacarpal", meta, cfg, collide_with_object)
        + _long_finger_chain(finger, cfg, collide_with_object, np.array([meta, 0.0, 0.0]))
        + "</body>"
    )
    actuators = _position_actuators(finger_joint_names(finger), _finger_ranges(cfg), cfg)
    return EffectorMjcf(worldbody=body, actuators=actuators)


def build_probe_mjcf(
    cfg: ProbeConfig,
    start_position_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> EffectorMjcf:
    """Body ``probe``: a free joint and a sphere that MuJoCo never collides (contacts are exact-mesh).

    A free joint rather than 3 slides + a ball: its qvel is (linear velocity in the world frame,
    angular velocity in the body frame), which the simulation sets each step from the command.
    A short visual capsule behind the sphere (along local -z) shows which way the fingertip faces.
    Gravity is compensated (``gravcomp``): a velocity-controlled arm holds the probe up.
    """
    if cfg.radius_m <= 0:
        raise ConfigError(f"probe radius_m must be positive, got {cfg.radius_m!r}")
    r = cfg.radius_m
    body = (
        f'<body name="probe" pos="{_fmt(np.asarray(start_position_m))}" quat="{_fmt(cfg.start_quaternion_wxyz)}" '
        'gravcomp="1">'
        '<freejoint name="probe"/>'
        f'<geom name="probe" type="sphere" size="{r:.9g}" density="{cfg.density_kg_m3:.9g}" '
        'contype="0" conaffinity="0" rgba="0.92 0.76 0.65 1"/>'
        f'<geom name="probe_shaft" type="capsule" fromto="0 0 {-1.5 * r:.9g} 0 0 {-5 * r:.9g}" '
        f'size="{0.6 * r:.9g}" contype="0" conaffinity="0" mass="0" group="1" rgba="0.6 0.6 0.6 0.5"/>'
        f'<site name="probe_tip" pos="0 0 0" size="{0.25 * r:.9g}"/>'
        "</body>"
    )
    return EffectorMjcf(worldbody=body, actuators="")


def segment_lengths(cfg: HandConfig | FingerConfig) -> dict[str, tuple[float, ...]]:
    """Scaled bone lengths in metres per digit: long fingers (metacarpal, proximal, middle, distal),
    thumb (metacarpal, proximal, distal). A FingerConfig gives only its one finger."""
    if isinstance(cfg, HandConfig):
        out: dict[str, tuple[float, ...]] = {f: cfg.lengths_m(f) for f in LONG_FINGERS}
        out["thumb"] = cfg.thumb_lengths_m()
        return out
    return {cfg.finger: cfg.lengths_m(cfg.finger)}
