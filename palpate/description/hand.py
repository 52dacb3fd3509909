"""The hand description: the one data file (hand.yaml) the simulator and the mapper both read.

As ROS nodes read a robot's URDF, the simulator generates its hand and finger MJCF from this
description (nodes/sim/effectors.py) and the mapper builds its finger's kinematic chain from it
(nodes/mapper/kinematics.py), so the two cannot disagree on a length or an axis. ``load_hand()``
reads the file once through palpate.config (``HandFile`` declares its structure; an error names
the file, line and key) and builds the frozen ``HandDescription``.

A digit is a serial chain of segments (bones). Segment k's frame has its origin at its proximal
joint and its bone along local +x; segment k + 1 starts at (length_k, 0, 0) in it. Segment 0 starts
at ``base_mm`` in the palm frame, turned by ``rest_ypr_deg``. Leading segments without joints (the
metacarpal of a long finger) are rigid parts of the palm.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray

from palpate.config import KeyPath, NonEmpty, PositiveFloat, Validated, dotted, load, load_yaml
from palpate.errors import ConfigError

#: Significant digits of every number the simulator writes into its MJCF, so of every number its
#: MuJoCo model holds (nodes/sim/effectors.py formats with ``.9g``).
MJCF_SIGNIFICANT_DIGITS = 9


def as_written(x: float) -> float:
    """``x`` rounded as the simulator's MJCF writes it, i.e. the value its MuJoCo model holds.

    A kinematic chain built from the description with these numbers equals the one read from the
    simulator's model bit for bit (tests/unit/mapper/test_kinematics.py checks it).
    """
    return float(f"{x:.{MJCF_SIGNIFICANT_DIGITS}g}")


@dataclass(frozen=True, kw_only=True)
class Joint(Validated):
    """A hinge of a digit; its model name is ``<digit>_<name>``."""

    name: str
    #: The segment the joint moves (the joint sits at that segment's proximal end).
    segment: str
    #: Rotation axis in the segment's frame (unit vector); positive angles follow the right-hand rule.
    axis: tuple[float, float, float]
    #: (lower, upper) limit in degrees.
    range_deg: tuple[float, float]
    #: Where the range comes from.
    source: str

    def __post_init__(self) -> None:
        super().__post_init__()
        if abs(math.hypot(*self.axis) - 1.0) > 1e-9:
            raise ConfigError(f"axis = {list(self.axis)}: expected a unit vector", ("axis",))
        lo, hi = self.range_deg
        if not lo < hi:
            raise ConfigError(
                f"range_deg = {[lo, hi]}: empty range; give [lower, upper] with lower < upper", ("range_deg",)
            )


@dataclass(frozen=True, kw_only=True)
class Digit:
    """One finger or the thumb: segments proximal to distal, their bone lengths and joints."""

    name: str
    segments: tuple[str, ...]
    #: Bone length of each segment, mm (distance between joint centres).
    lengths_mm: tuple[float, ...]
    #: Joints proximal to distal; the joints of one segment apply in this order.
    joints: tuple[Joint, ...]
    #: Proximal end of segment 0 in the palm frame, mm.
    base_mm: tuple[float, float, float]
    #: Rest frame of segment 0 in the palm frame: yaw about z, pitch about the new y, roll about the
    #: new x, degrees (a long finger only yaws in the palm plane).
    rest_ypr_deg: tuple[float, float, float]

    @property
    def fixed_segments(self) -> int:
        """Number of leading segments without joints (1 for a long finger: its metacarpal)."""
        return _fixed_segments(self.segments, self.joints)

    def joint_names(self) -> list[str]:
        """Model names of the digit's joints, proximal to distal (``index_mcp_abd``, ...)."""
        return [f"{self.name}_{j.name}" for j in self.joints]

    def segment_joints(self, segment: str) -> tuple[Joint, ...]:
        """The joints that move ``segment``, in order."""
        return tuple(j for j in self.joints if j.segment == segment)

    def lengths_m(self, scale: float = 1.0) -> tuple[float, ...]:
        """Scaled bone lengths in metres, one per segment."""
        return tuple(scale * v / 1000.0 for v in self.lengths_mm)

    def base_m(self, scale: float = 1.0) -> NDArray[np.float64]:
        """Scaled proximal end of segment 0 in the palm frame, metres, shape (3,)."""
        return np.asarray(scale * np.array(self.base_mm) / 1e3, dtype=np.float64)

    def first_joint_m(self, scale: float = 1.0) -> NDArray[np.float64]:
        """Scaled proximal joint of the first moving segment in the palm frame, metres, shape (3,).

        The thumb's CMC (its base); a long finger's MCP, at the end of its metacarpal (which only
        yaws in the palm plane).
        """
        base = self.base_m(scale)
        if self.fixed_segments == 0:
            return base
        yaw = math.radians(self.rest_ypr_deg[0])
        fixed = sum(self.lengths_m(scale)[: self.fixed_segments])
        return np.asarray(base + fixed * np.array([math.cos(yaw), math.sin(yaw), 0.0]), dtype=np.float64)


@dataclass(frozen=True, kw_only=True)
class Actuation(Validated):
    """The simulator's default joint actuation and mass (see docs/hand_model.md)."""

    kp_nm_per_rad: PositiveFloat
    damping_nm_s_per_rad: PositiveFloat
    armature_kg_m2: PositiveFloat
    density_kg_m3: PositiveFloat


@dataclass(frozen=True, kw_only=True)
class DefaultMount(Validated):
    """Where the single-finger effector is fixed unless a scene or a mapper says otherwise (hand.yaml)."""

    #: A long finger.
    finger: str
    #: The finger's metacarpal base in the world, metres (fingers along +x, palm down).
    base_position_m: tuple[float, float, float]


@dataclass(frozen=True, kw_only=True)
class HandDescription:
    """The whole hand: long fingers radial to ulnar, then the thumb (the model's joint order)."""

    segment_radius_mm: float
    digits: tuple[Digit, ...]
    actuation: Actuation
    finger_mount: DefaultMount

    @property
    def long_fingers(self) -> tuple[str, ...]:
        """Names of the long fingers (every digit but the thumb), radial to ulnar."""
        return tuple(d.name for d in self.digits if d.name != "thumb")

    def digit(self, name: str) -> Digit:
        """The digit called ``name``; ConfigError listing the digits if there is none."""
        for d in self.digits:
            if d.name == name:
                return d
        raise ConfigError(f"unknown finger {name!r}: use one of {', '.join(d.name for d in self.digits)}")

    def joint_names(self) -> list[str]:
        """All joint names in model order (long fingers, then the thumb)."""
        return [n for d in self.digits for n in d.joint_names()]

    def radius_m(self, scale: float = 1.0) -> float:
        """Scaled capsule (and fingertip) radius in metres."""
        return scale * self.segment_radius_mm / 1000.0


# --- hand.yaml: its structure, checked by palpate.config ---------------------------------------------


@dataclass(frozen=True, kw_only=True)
class LongFingerEntry(Validated):
    """One long finger in hand.yaml (``long_fingers.<name>``)."""

    #: Bone lengths, one per ``long_finger_segments`` entry.
    lengths_mm: tuple[PositiveFloat, ...]
    #: (x, y) of the metacarpal base in the palm frame.
    metacarpal_base_mm: tuple[float, float]
    #: The metacarpal's direction in the palm plane (+y positive).
    metacarpal_yaw_deg: float


@dataclass(frozen=True, kw_only=True)
class ThumbEntry(Validated):
    """The thumb in hand.yaml: its own segments and joints; its first segment moves."""

    segments: Annotated[tuple[str, ...], NonEmpty]
    lengths_mm: tuple[PositiveFloat, ...]
    cmc_position_mm: tuple[float, float, float]
    rest_ypr_deg: tuple[float, float, float]
    joints: Annotated[tuple[Joint, ...], NonEmpty]

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_chain(self.segments, self.lengths_mm, self.joints, ())
        if _fixed_segments(self.segments, self.joints) != 0:
            raise ConfigError("joints: the thumb's first segment (its metacarpal) must have a joint", ("joints",))


@dataclass(frozen=True, kw_only=True)
class HandFile(Validated):
    """The structure of hand.yaml (the long fingers share their segments and joints)."""

    segment_radius_mm: PositiveFloat
    long_finger_segments: Annotated[tuple[str, ...], NonEmpty]
    long_finger_joints: Annotated[tuple[Joint, ...], NonEmpty]
    #: Radial to ulnar.
    long_fingers: Mapping[str, LongFingerEntry]
    thumb: ThumbEntry
    actuation: Actuation
    finger_mount: DefaultMount

    def __post_init__(self) -> None:
        super().__post_init__()
        names = list(self.long_fingers)
        if not names or "thumb" in names:
            raise ConfigError(f"long_fingers: {names}: name at least one finger (and not 'thumb')", ("long_fingers",))
        if self.finger_mount.finger not in names:
            raise ConfigError(
                f"finger_mount.finger: {self.finger_mount.finger!r} is not a long finger; use one of {names}",
                ("finger_mount", "finger"),
            )
        for name, finger in self.long_fingers.items():
            _check_chain(self.long_finger_segments, finger.lengths_mm, self.long_finger_joints, ("long_fingers", name))
        if _fixed_segments(self.long_finger_segments, self.long_finger_joints) != 1:
            raise ConfigError(
                "long_finger_joints: the first segment (the metacarpal) must have no joint, the second one must",
                ("long_finger_joints",),
            )

    def description(self) -> HandDescription:
        """The hand these entries describe."""
        digits = [
            Digit(
                name=name,
                segments=self.long_finger_segments,
                lengths_mm=finger.lengths_mm,
                joints=self.long_finger_joints,
                base_mm=(*finger.metacarpal_base_mm, 0.0),
                rest_ypr_deg=(finger.metacarpal_yaw_deg, 0.0, 0.0),
            )
            for name, finger in self.long_fingers.items()
        ]
        t = self.thumb
        thumb = Digit(
            name="thumb",
            segments=t.segments,
            lengths_mm=t.lengths_mm,
            joints=t.joints,
            base_mm=t.cmc_position_mm,
            rest_ypr_deg=t.rest_ypr_deg,
        )
        return HandDescription(
            segment_radius_mm=self.segment_radius_mm,
            digits=(*digits, thumb),
            actuation=self.actuation,
            finger_mount=self.finger_mount,
        )


def mount_fact(
    effector: str,
    finger: str | None,
    scale: float,
    base_position_m: Sequence[float],
    base_quaternion_wxyz: Sequence[float],
) -> dict[str, Any]:
    """Where a hand (effector "hand") or its single finger (effector "finger") is fixed in the world, as a
    model built from the description holds it (rounded as the simulator's MJCF writes it), and
    ``finger``, the finger that taps (the single one, or the hand's tapping finger): what a simulator's
    scene and the mappers that model its finger must agree on (a mapper of another finger of a hand
    would see none of the taps)."""
    return {
        "effector": effector,
        **({"finger": finger} if finger is not None else {}),
        "scale": as_written(scale),
        "base_position_m": [as_written(v) for v in base_position_m],
        "base_quaternion_wxyz": [as_written(v) for v in base_quaternion_wxyz],
    }


def _fixed_segments(segments: tuple[str, ...], joints: tuple[Joint, ...]) -> int:
    """Number of leading segments that no joint moves."""
    moving = {j.segment for j in joints}
    return next((i for i, s in enumerate(segments) if s in moving), len(segments))


def _check_chain(
    segments: tuple[str, ...], lengths_mm: tuple[float, ...], joints: tuple[Joint, ...], path: KeyPath
) -> None:
    """A digit's segments, lengths and joints agree; ConfigError naming the key path. ``path`` holds
    ``lengths_mm``; ``segments`` and ``joints`` are its siblings, or the long fingers' shared keys."""
    shared = path[:1] == ("long_fingers",)
    segments_path: KeyPath = ("long_finger_segments",) if shared else (*path, "segments")
    joints_path: KeyPath = ("long_finger_joints",) if shared else (*path, "joints")

    def fail(where: KeyPath, problem: str) -> ConfigError:
        return ConfigError(f"{dotted(where)}: {problem}", where)

    if not all(segments) or len(set(segments)) != len(segments):
        raise fail(segments_path, f"{list(segments)}: give each segment a name, once")
    if len(lengths_mm) != len(segments):
        raise fail((*path, "lengths_mm"), f"{len(lengths_mm)} lengths; give one per segment {list(segments)}")
    for i, joint in enumerate(joints):
        if joint.segment not in segments:
            raise fail((*joints_path, i, "segment"), f"{joint.segment!r} is not one of the segments {list(segments)}")
    order = [segments.index(j.segment) for j in joints]
    if order != sorted(order) or len({j.name for j in joints}) != len(joints):
        raise fail(joints_path, "list the joints proximal to distal, each name once")


def parse_hand(data: Any, where: str = "hand") -> HandDescription:
    """Check the mapping read from a hand file and build the description; ConfigError naming the key."""
    return load(HandFile, data, where).description()


def load_hand(path: str | Path | None = None) -> HandDescription:
    """Read and check a hand file; without ``path``, the packaged hand.yaml (read once, cached)."""
    if path is None:
        return _packaged_hand()
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the hand description: {error.strerror}") from error
    return load_yaml(HandFile, text, str(path), "hand").description()


@functools.cache
def _packaged_hand() -> HandDescription:
    text = resources.files("palpate.description").joinpath("hand.yaml").read_text()
    return load_yaml(HandFile, text, "palpate/description/hand.yaml", "hand").description()
