"""Generated MJCF for the three effectors: a 21-DoF human hand, one finger of it, a fingertip probe.

The hand's geometry, joints and default ranges and gains come from the hand description
(palpate/description/hand.yaml, read by :func:`palpate.description.load_hand`), the one file the
mapper reads too; docs/hand_model.md gives the sources. A scene's config chooses the finger, the
scale and the base pose, and may change the ranges and gains.

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

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from palpate.config import NonNegativeFloat, OneOf, PositiveFloat, Validated
from palpate.description import Digit, load_hand
from palpate.errors import ConfigError
from palpate.geometry.rotations import ypr_deg_to_quat
from palpate.inputs import MAX_COORDINATE_M

#: The hand every effector is built from.
HAND = load_hand()
#: The hand's fingertip radius, the probe's default.
TIP_RADIUS_M = HAND.radius_m()
#: The four long fingers, radial to ulnar.
LONG_FINGERS: tuple[str, ...] = HAND.long_fingers

#: contype / conaffinity bits: the object uses bit 0; effector geoms use bit 1 as their type and,
#: when they may touch the object, bit 0 as affinity (so effector geoms never collide with each other).
EFFECTOR_CONTYPE = 2
OBJECT_CONTYPE = 1
#: Bone lengths of a long finger (metacarpal, proximal, middle, distal), mm.


def _range(digit: str, joint: str) -> tuple[float, float]:
    """The description's range of one joint, degrees (the long fingers share theirs: ask the index)."""
    (j,) = (j for j in HAND.digit(digit).joints if j.name == joint)
    return j.range_deg


@dataclass(frozen=True, kw_only=True)
class DigitConfig(Validated):
    """Scale, joint ranges and actuation shared by the hand and the single-finger effector.

    Lengths and the segment radius are the hand description's (mean bone lengths of 66 adults,
    Buryanov and Kotiuk 2010, Table I); ``scale`` multiplies every length and radius. The ranges
    and gains default to the description's.
    """

    #: Multiplies every bone length and the segment radius of the hand description (1: the mean adult hand).
    scale: PositiveFloat = 1.0
    # Human active ranges (AAOS 1965; DIP limited to 80 deg as in issue 3, AAOS gives 90).
    #: [lower, upper] MCP flexion of each long finger, degrees: the joint's limits and its actuator's target range.
    mcp_flex_range_deg: tuple[float, float] = _range("index", "mcp_flex")
    #: [lower, upper] MCP abduction of each long finger, degrees (positive towards the thumb).
    mcp_abd_range_deg: tuple[float, float] = _range("index", "mcp_abd")
    #: [lower, upper] PIP flexion of each long finger, degrees.
    pip_range_deg: tuple[float, float] = _range("index", "pip")
    #: [lower, upper] DIP flexion of each long finger, degrees.
    dip_range_deg: tuple[float, float] = _range("index", "dip")
    #: Position actuator stiffness (torque per rad of target error).
    kp_nm_per_rad: NonNegativeFloat = HAND.actuation.kp_nm_per_rad
    #: Joint damping, integrated implicitly (close to critical for kp and the armature below).
    damping_nm_s_per_rad: NonNegativeFloat = HAND.actuation.damping_nm_s_per_rad
    #: Joint armature: a numerical inertia that keeps the light phalanges stable at a 2 ms step.
    armature_kg_m2: NonNegativeFloat = HAND.actuation.armature_kg_m2
    #: Density of the capsules (soft tissue and bone).
    density_kg_m3: PositiveFloat = HAND.actuation.density_kg_m3

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (f.name for f in dataclasses.fields(self) if f.name.endswith("_range_deg")):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ConfigError(
                    f"{name} = {[lo, hi]}: empty joint range; give [lower, upper], lower < upper",
                    (name,),
                )

    def lengths_m(self, finger: str) -> tuple[float, ...]:
        """Scaled bone lengths of one long finger in metres (metacarpal, proximal, middle, distal)."""
        if finger not in LONG_FINGERS:
            raise ConfigError(f"unknown finger {finger!r}: use one of {', '.join(LONG_FINGERS)}")
        return HAND.digit(finger).lengths_m(self.scale)

    @property
    def radius_m(self) -> float:
        """Scaled capsule radius in metres."""
        return HAND.radius_m(self.scale)

    def joint_range_deg(self, joint: str) -> tuple[float, float]:
        """This config's range of a joint named as in the model (``index_pip``, ``thumb_mcp``), degrees."""
        digit, _, name = joint.partition("_")
        field = f"thumb_{name}_range_deg" if digit == "thumb" else f"{name}_range_deg"
        value: tuple[float, float] = getattr(self, field)
        return value


@dataclass(frozen=True, kw_only=True)
class HandConfig(DigitConfig):
    """The 21-DoF hand of paper 000: four long fingers (4 DoF each) and a 5-DoF thumb.

    The palm layout (metacarpal bases and directions) and the thumb's rest frame are the hand
    description's model choices approximating an adult right hand; see docs/hand_model.md.
    """

    # AAOS: CMC flexion 15 / extension 20, palmar abduction 70, MCP flexion 50, IP flexion 80.
    #: [lower, upper] thumb CMC flexion, degrees (negative: extension).
    thumb_cmc_flex_range_deg: tuple[float, float] = _range("thumb", "cmc_flex")
    #: [lower, upper] thumb CMC palmar abduction, degrees.
    thumb_cmc_abd_range_deg: tuple[float, float] = _range("thumb", "cmc_abd")
    #: Axial rotation (pronation positive) of the first metacarpal: a model choice covering opposition.
    thumb_cmc_rot_range_deg: tuple[float, float] = _range("thumb", "cmc_rot")
    #: [lower, upper] thumb MCP flexion, degrees.
    thumb_mcp_range_deg: tuple[float, float] = _range("thumb", "mcp")
    #: [lower, upper] thumb IP flexion, degrees.
    thumb_ip_range_deg: tuple[float, float] = _range("thumb", "ip")
    #: Which fingertip ``effector_pose`` reports.
    pose_finger: Annotated[str, OneOf((*LONG_FINGERS, "thumb"))] = "index"
    #: Palm pose in the world; None lets the scene place the hand so the object is in reach.
    base_position_m: tuple[float, float, float] | None = None
    #: Palm orientation in the world (w, x, y, z); identity: fingers along world +x, palm facing -z.
    base_quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def thumb_lengths_m(self) -> tuple[float, float, float]:
        """Scaled thumb bone lengths in metres (metacarpal, proximal, distal)."""
        a, b, c = HAND.digit("thumb").lengths_m(self.scale)
        return (a, b, c)

    def mcp_position_m(self, finger: str) -> np.ndarray:
        """MCP joint of a long finger in the palm frame, metres, shape (3,)."""
        self.lengths_m(finger)  # ConfigError for anything but a long finger
        return HAND.digit(finger).first_joint_m(self.scale)


@dataclass(frozen=True, kw_only=True)
class FingerConfig(DigitConfig):
    """One long finger of the hand on a fixed metacarpal; the rest of the hand is not simulated.

    The base frame is the metacarpal's proximal end, with the metacarpal along local +x and the
    back of the finger facing local +z.
    """

    #: Default: the description's finger mount (the mapper's default too).
    finger: Annotated[str, OneOf(LONG_FINGERS)] = HAND.finger_mount.finger
    #: Metacarpal base in the world; None lets the scene place it so the object is in reach (on the
    #: default object, that is the description's finger mount).
    base_position_m: tuple[float, float, float] | None = None
    #: Metacarpal base orientation in the world (w, x, y, z); identity: finger along world +x, its back facing +z.
    base_quaternion_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class ProbeConfig(Validated):
    """A spherical fingertip with ideal 6-DoF Cartesian velocity control (paper 002, Algorithm 1).

    The probe is a free body whose velocity is imposed every step (an ideal Cartesian velocity
    controller: ``setVelocity`` / ``setAngularVelocity`` of Algorithm 1). Its local z axis is the
    direction the fingertip faces.
    """

    #: The hand's fingertip radius by default.
    radius_m: PositiveFloat = TIP_RADIUS_M
    #: Start of the probe centre; None starts it above the object's bounding-box centre in x and y (or,
    #: where nothing lies under that, as under a torus's hole, the nearest point with the object under
    #: the probe: ``scene.descent_xy``), with a gap of ``start_clearance_m`` between the probe and the top.
    start_position_m: tuple[float, float, float] | None = None
    #: Start orientation; the default (180 deg about x) makes the fingertip face world -z.
    start_quaternion_wxyz: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 0.0)
    #: Gap between the probe and the top of the object's bounding box at the start when start_position_m
    #: is null, metres.
    start_clearance_m: NonNegativeFloat = 0.03
    #: Gain of the velocity controller against a rigid surface: reported normal force is this
    #: gain times the commanded speed into the surface (what a velocity-controlled arm would push).
    force_gain_n_s_per_m: NonNegativeFloat = 50.0
    #: Density of the probe sphere, which sets its mass in the model (its velocity is imposed every step).
    density_kg_m3: PositiveFloat = 1100.0

    def __post_init__(self) -> None:
        super().__post_init__()
        start = self.start_position_m
        if start is not None and not max(abs(v) for v in start) <= MAX_COORDINATE_M:
            raise ConfigError(
                f"start_position_m = {list(start)!r} lies beyond {MAX_COORDINATE_M:g} m of the origin; "
                "start the probe near the object",
                ("start_position_m",),
            )
        if not math.hypot(*self.start_quaternion_wxyz) > 1e-6:
            raise ConfigError(
                f"start_quaternion_wxyz = {list(self.start_quaternion_wxyz)!r} has no direction (norm 0); give a "
                "unit quaternion (w, x, y, z), e.g. [0, 1, 0, 0] to face -z",
                ("start_quaternion_wxyz",),
            )


# --- helpers ---------------------------------------------------------------------------------------


def _fmt(values: np.ndarray | tuple[float, ...] | list[float]) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _collision_attrs(collide_with_object: bool) -> str:
    affinity = OBJECT_CONTYPE if collide_with_object else 0
    contype = EFFECTOR_CONTYPE if collide_with_object else 0
    return f'contype="{contype}" conaffinity="{affinity}"'


def _range_attr(range_deg: tuple[float, float]) -> str:
    lo, hi = range_deg
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


def _segments(digit: Digit, cfg: DigitConfig, collide: bool, first: int, first_attrs: str) -> str:
    """Nested bodies of the digit's segments from index ``first`` on, each with its joints and capsule,
    the tip site on the last; the first body's placement is ``first_attrs`` (``pos=... [quat=...]``)."""
    lengths = digit.lengths_m(cfg.scale)
    parts = []
    for k in range(first, len(digit.segments)):
        name = f"{digit.name}_{digit.segments[k]}"
        placement = first_attrs if k == first else f'pos="{lengths[k - 1]:.9g} 0 0"'  # on the parent bone's end
        parts.append(f'<body name="{name}" {placement}>')
        for j in digit.segment_joints(digit.segments[k]):
            joint = f"{digit.name}_{j.name}"
            parts.append(_joint(joint, _fmt(j.axis), cfg.joint_range_deg(joint), cfg))
        parts.append(_capsule(name, lengths[k], cfg, collide))
    parts.append(_tip_site(digit.name, lengths[-1], cfg))
    return "".join(parts) + "</body>" * (len(digit.segments) - first)


def _position_actuators(joint_names: list[str], cfg: DigitConfig) -> str:
    lines = []
    for name in joint_names:
        lo, hi = cfg.joint_range_deg(name)
        lines.append(
            f'<position name="{name}" joint="{name}" kp="{cfg.kp_nm_per_rad:.9g}" ctrllimited="true" '
            f'ctrlrange="{math.radians(lo):.9g} {math.radians(hi):.9g}"/>'
        )
    return "".join(lines)


def finger_joint_names(finger: str) -> list[str]:
    """Joint names of one long finger, proximal to distal."""
    return HAND.digit(finger).joint_names()


def hand_joint_names() -> list[str]:
    """All 21 hand joint names in model order (index, middle, ring, little, then thumb)."""
    return HAND.joint_names()


def joint_ranges_rad(cfg: HandConfig | FingerConfig) -> np.ndarray:
    """Joint limits in model order, radians, shape (J, 2)."""
    names = hand_joint_names() if isinstance(cfg, HandConfig) else finger_joint_names(cfg.finger)
    return np.radians(np.array([cfg.joint_range_deg(n) for n in names], dtype=np.float64))


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
    collide = collide_with_object
    parts = [f'<body name="palm" pos="{_fmt(np.asarray(base_position_m))}" quat="{_fmt(cfg.base_quaternion_wxyz)}">']
    for finger in LONG_FINGERS:
        digit = HAND.digit(finger)
        yaw = math.radians(digit.rest_ypr_deg[0])
        base = digit.base_m(cfg.scale)
        mcp = cfg.mcp_position_m(finger)
        parts.append(
            f'<geom name="{finger}_metacarpal" type="capsule" fromto="{_fmt(base)} {_fmt(mcp)}" '
            f'size="{cfg.radius_m:.9g}" density="{cfg.density_kg_m3:.9g}" {_collision_attrs(collide)} '
            f'rgba="0.85 0.7 0.6 1"/>'
        )
        # Phalanx chain in the palm frame turned by the metacarpal's yaw.
        parts.append(
            f'<frame pos="{_fmt(base)}" quat="{math.cos(yaw / 2):.9g} 0 0 {math.sin(yaw / 2):.9g}">'
            + _segments(digit, cfg, collide, 1, f'pos="{_fmt(np.array([cfg.lengths_m(finger)[0], 0.0, 0.0]))}"')
            + "</frame>"
        )
    thumb = HAND.digit("thumb")
    thumb_pos = thumb.base_m(cfg.scale)
    thumb_quat = ypr_deg_to_quat(*thumb.rest_ypr_deg)
    parts.append(_segments(thumb, cfg, collide, 0, f'pos="{_fmt(thumb_pos)}" quat="{_fmt(thumb_quat)}"'))
    parts.append("</body>")
    actuators = _position_actuators(hand_joint_names(), cfg)
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
        + _segments(HAND.digit(finger), cfg, collide_with_object, 1, f'pos="{_fmt(np.array([meta, 0.0, 0.0]))}"')
        + "</body>"
    )
    actuators = _position_actuators(finger_joint_names(finger), cfg)
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
