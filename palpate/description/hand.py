"""The hand description: the one data file (hand.yaml) the simulator and the mapper both read.

As ROS nodes read a robot's URDF, the simulator generates its hand and finger MJCF from this
description (nodes/sim/effectors.py) and the mapper builds its finger's kinematic chain from it
(nodes/mapper/kinematics.py), so the two cannot disagree on a length or an axis. ``load_hand()``
reads and validates the file once; the result is frozen.

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
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

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
class Joint:
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
        moving = {j.segment for j in self.joints}
        return next(i for i, s in enumerate(self.segments) if s in moving)

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
class Actuation:
    """The simulator's default joint actuation and mass (see docs/hand_model.md)."""

    kp_nm_per_rad: float
    damping_nm_s_per_rad: float
    armature_kg_m2: float
    density_kg_m3: float


@dataclass(frozen=True, kw_only=True)
class HandDescription:
    """The whole hand: long fingers radial to ulnar, then the thumb (the model's joint order)."""

    segment_radius_mm: float
    digits: tuple[Digit, ...]
    actuation: Actuation

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


# --- reading and checking hand.yaml ----------------------------------------------------------------


def _keys(d: Any, required: Sequence[str], where: str, optional: Sequence[str] = ()) -> Mapping[str, Any]:
    if not isinstance(d, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {d!r}")
    for key in d:
        if key not in (*required, *optional):
            raise ConfigError(f"{where}: unknown key {key!r}; allowed keys are {sorted((*required, *optional))}")
    for key in required:
        if key not in d:
            raise ConfigError(f"{where}: missing key {key!r}")
    return d


def _number(value: Any, where: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where} = {value!r}: expected a finite number")
    if positive and not value > 0:
        raise ConfigError(f"{where} = {value!r}: expected a positive number")
    return float(value)


def _numbers(value: Any, n: int | None, where: str, positive: bool = False) -> tuple[float, ...]:
    if isinstance(value, str) or not isinstance(value, Sequence) or (n is not None and len(value) != n):
        raise ConfigError(f"{where} = {value!r}: expected a list of {n if n is not None else 'some'} numbers")
    return tuple(_number(v, f"{where}[{i}]", positive) for i, v in enumerate(value))


def _names(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
        raise ConfigError(f"{where} = {value!r}: expected a non-empty list of names")
    if len(set(value)) != len(value):
        raise ConfigError(f"{where} = {value!r}: names repeat")
    return tuple(value)


def _joint(d: Any, segments: tuple[str, ...], where: str) -> Joint:
    d = _keys(d, ("name", "segment", "axis", "range_deg", "source"), where)
    if d["segment"] not in segments:
        raise ConfigError(f"{where}.segment = {d['segment']!r}: not one of the segments {list(segments)}")
    axis = _numbers(d["axis"], 3, f"{where}.axis")
    if abs(math.hypot(*axis) - 1.0) > 1e-9:
        raise ConfigError(f"{where}.axis = {list(axis)}: expected a unit vector")
    lo, hi = _numbers(d["range_deg"], 2, f"{where}.range_deg")
    if not lo < hi:
        raise ConfigError(f"{where}.range_deg = {[lo, hi]}: empty range; give [lower, upper] with lower < upper")
    return Joint(
        name=str(d["name"]),
        segment=d["segment"],
        axis=(axis[0], axis[1], axis[2]),
        range_deg=(lo, hi),
        source=str(d["source"]),
    )


def _digit(
    name: str,
    segments: tuple[str, ...],
    lengths: Any,
    joints: Any,
    base_mm: tuple[float, float, float],
    rest_ypr_deg: tuple[float, float, float],
    where: str,
) -> Digit:
    if not isinstance(joints, list) or not joints:
        raise ConfigError(f"{where}: expected a non-empty list of joints, got {joints!r}")
    parsed = tuple(_joint(j, segments, f"{where} joints[{i}]") for i, j in enumerate(joints))
    order = [segments.index(j.segment) for j in parsed]
    if order != sorted(order) or len({j.name for j in parsed}) != len(parsed):
        raise ConfigError(f"{where}: list the joints proximal to distal, each name once")
    return Digit(
        name=name,
        segments=segments,
        lengths_mm=_numbers(lengths, len(segments), f"{where} lengths_mm", positive=True),
        joints=parsed,
        base_mm=base_mm,
        rest_ypr_deg=rest_ypr_deg,
    )


_TOP_KEYS = ("segment_radius_mm", "long_finger_segments", "long_finger_joints", "long_fingers", "thumb", "actuation")
_ACTUATION_KEYS = ("kp_nm_per_rad", "damping_nm_s_per_rad", "armature_kg_m2", "density_kg_m3")


def parse_hand(data: Any, source: str = "hand.yaml") -> HandDescription:
    """Check the mapping read from a hand file and build the description; ConfigError naming the key."""
    top = _keys(data, _TOP_KEYS, source)
    segments = _names(top["long_finger_segments"], f"{source}: long_finger_segments")
    fingers = top["long_fingers"]
    if not isinstance(fingers, Mapping) or not fingers or "thumb" in fingers:
        raise ConfigError(f"{source}: long_fingers = {fingers!r}: name at least one finger (and not 'thumb')")
    digits = []
    for name, f in fingers.items():
        where = f"{source}: long_fingers.{name}"
        f = _keys(f, ("lengths_mm", "metacarpal_base_mm", "metacarpal_yaw_deg"), where)
        x, y = _numbers(f["metacarpal_base_mm"], 2, f"{where}.metacarpal_base_mm")
        yaw = _number(f["metacarpal_yaw_deg"], f"{where}.metacarpal_yaw_deg")
        digit = _digit(
            str(name), segments, f["lengths_mm"], top["long_finger_joints"], (x, y, 0.0), (yaw, 0.0, 0.0), where
        )
        if digit.fixed_segments != 1:
            raise ConfigError(f"{source}: long_finger_joints: the first segment (the metacarpal) must have no joint")
        digits.append(digit)
    where = f"{source}: thumb"
    t = _keys(top["thumb"], ("segments", "lengths_mm", "cmc_position_mm", "rest_ypr_deg", "joints"), where)
    px, py, pz = _numbers(t["cmc_position_mm"], 3, f"{where}.cmc_position_mm")
    yaw, pitch, roll = _numbers(t["rest_ypr_deg"], 3, f"{where}.rest_ypr_deg")
    thumb_segments = _names(t["segments"], f"{where}.segments")
    thumb = _digit("thumb", thumb_segments, t["lengths_mm"], t["joints"], (px, py, pz), (yaw, pitch, roll), where)
    if thumb.fixed_segments != 0:
        raise ConfigError(f"{where}.joints: the thumb's first segment (its metacarpal) must have a joint")
    a = _keys(top["actuation"], _ACTUATION_KEYS, f"{source}: actuation")
    return HandDescription(
        segment_radius_mm=_number(top["segment_radius_mm"], f"{source}: segment_radius_mm", positive=True),
        digits=(*digits, thumb),
        actuation=Actuation(**{k: _number(v, f"{source}: actuation.{k}", positive=True) for k, v in a.items()}),
    )


def load_hand(path: str | Path | None = None) -> HandDescription:
    """Read and check a hand file; without ``path``, the packaged hand.yaml (read once, cached)."""
    if path is None:
        return _packaged_hand()
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the hand description: {error.strerror}") from error
    return _parse_text(text, str(path))


@functools.cache
def _packaged_hand() -> HandDescription:
    text = resources.files("palpate.description").joinpath("hand.yaml").read_text()
    return _parse_text(text, "palpate/description/hand.yaml")


def _parse_text(text: str, source: str) -> HandDescription:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ConfigError(f"{source}: invalid YAML: {error}") from error
    return parse_hand(data, source)
