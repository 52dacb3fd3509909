"""Proprioceptive and contact-sensor noise (pure core of the noise node).

Joint angles: q_noisy = q + b + sigma * z, z ~ N(0, 1) per joint and reading (paper 000: Gaussian
proprioceptive noise with sigma = 1.5 deg). Contacts (paper 002's fingertip sensor): isotropic
Gaussian position noise, and normals rotated by a random tangent vector whose per-axis standard
deviation is ``normal_sigma_deg`` (so the angle to the true normal is Rayleigh distributed with
that scale). Zero sigma and zero bias pass values through unchanged, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np

from palpate.config import NonNegativeFloat, Range, Validated
from palpate.errors import InputError
from palpate.inputs import MAX_COORDINATE_M, UNIT_TOLERANCE, coordinates, unique_names, unit_vectors

#: Largest joint-noise standard deviation, degrees: a quarter turn. Beyond it the noise means nothing of a
#: sensor, and the mappers refuse readings past a full turn (1000 deg refused nearly every reading, and
#: `eval slam` then blamed its snapshot times).
MAX_JOINT_SIGMA_DEG = 90.0
#: Largest contact-position noise standard deviation, metres: the controller refuses contacts 0.1 m beyond
#: the fingertip's surface (2 sigma), so a larger one ends runs at "a unit other than metres?".
MAX_POSITION_SIGMA_M = 0.05
JointSigmaDeg = Annotated[float, Range(ge=0.0, le=MAX_JOINT_SIGMA_DEG)]


@dataclass(frozen=True, kw_only=True)
class JointNoiseConfig(Validated):
    """Joint-angle noise. ``per_joint_sigma_deg`` overrides ``sigma_deg`` for the joints it names;
    ``bias_deg`` is one constant for every joint or a mapping joint name -> bias (others 0)."""

    #: Standard deviation of the Gaussian noise added to every joint angle of every reading, independently
    #: (q + bias + sigma z, z ~ N(0, 1)); 0 passes the angles through bit for bit.
    sigma_deg: JointSigmaDeg = 1.5
    #: Joint name -> its own standard deviation (the others keep sigma_deg); a name the readings lack is
    #: refused at the first reading.
    per_joint_sigma_deg: Mapping[str, JointSigmaDeg] = field(default_factory=dict)
    #: A constant offset of every joint angle, or joint name -> its offset (others 0).
    bias_deg: float | Mapping[str, float] = 0.0


class JointNoise:
    """Adds joint-angle noise to readings of the joints ``joint_names``, drawing from ``rng``.

    The names come from a reading (a JointState's ``names``): InputError when one is empty or
    repeated, or when the reading lacks a joint that ``per_joint_sigma_deg`` or ``bias_deg`` names.
    """

    def __init__(self, config: JointNoiseConfig, joint_names: Sequence[str], rng: np.random.Generator) -> None:
        names = unique_names(joint_names, "names")
        known = set(names)
        bias_map = config.bias_deg if isinstance(config.bias_deg, Mapping) else {}
        for label, mapping in (("per_joint_sigma_deg", config.per_joint_sigma_deg), ("bias_deg", bias_map)):
            unknown = sorted(set(mapping) - known)
            if unknown:
                raise InputError("names", f"lacks joint(s) {unknown} that the noise node's {label} names")
        sigma_deg = np.array([config.per_joint_sigma_deg.get(n, config.sigma_deg) for n in names], float)
        if isinstance(config.bias_deg, Mapping):
            bias_deg = np.array([config.bias_deg.get(n, 0.0) for n in names], float)
        else:
            bias_deg = np.full(len(names), float(config.bias_deg))
        self.joint_names = tuple(names)
        self.sigma_rad = np.radians(sigma_deg)
        self.bias_rad = np.radians(bias_deg)
        self._noisy = (self.sigma_rad > 0) | (self.bias_rad != 0)
        self._some_noisy, self._all_noisy = bool(self._noisy.any()), bool(self._noisy.all())
        self._rng = rng

    def apply(self, q_rad: np.ndarray) -> np.ndarray:
        """Noisy copy of joint angles q_rad (..., J) in radians. Joints with sigma 0 and bias 0 keep
        their values bit for bit; the generator is only drawn from when some joint is noisy."""
        q = np.asarray(q_rad, dtype=np.float64)
        if q.shape[-1:] != (len(self.joint_names),):
            raise ValueError(f"expected joint angles of shape (..., {len(self.joint_names)}), got {q.shape}")
        if not self._some_noisy:
            return np.array(q)
        z = self._rng.standard_normal(q.shape)
        noisy = q + self.bias_rad + self.sigma_rad * z  # q + b + sigma z
        return noisy if self._all_noisy else np.where(self._noisy, noisy, q)


class JointStreamNoise:
    """Joint noise on a stream of readings whose joint names come with the first reading: the
    JointNoise model is built for those names (and the config checked against them) then, and every
    reading goes through it."""

    def __init__(self, config: JointNoiseConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.model: JointNoise | None = None
        self._rng = rng

    def apply(self, joint_names: Sequence[str], q_rad: np.ndarray) -> np.ndarray:
        """Noisy copy of one reading q_rad (J,) of the joints joint_names (see JointNoise.apply)."""
        if self.model is None or self.model.joint_names != tuple(joint_names):
            # joint names come with the readings; a bad reading (InputError) leaves the last model in place
            self.model = JointNoise(self.config, joint_names, self._rng)
        return self.model.apply(q_rad)


@dataclass(frozen=True, kw_only=True)
class ContactNoiseConfig(Validated):
    """Contact-sensor noise: position sigma per axis (m), normal direction sigma per tangent axis (deg)."""

    #: Standard deviation of the Gaussian noise added to each coordinate of each contact position.
    position_sigma_m: Annotated[float, Range(ge=0.0, le=MAX_POSITION_SIGMA_M)] = 0.0
    #: Each contact normal is turned by a Gaussian step of this standard deviation per tangent axis (the
    #: step z ~ N(0, sigma^2 I) projected onto the normal's tangent plane; the normal turns by its length,
    #: towards it) and stays a unit vector.
    normal_sigma_deg: NonNegativeFloat = 0.0


class ContactNoise:
    """Adds noise to contact positions and outward normals, drawing from ``rng``."""

    def __init__(self, config: ContactNoiseConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._sigma_position_m = float(config.position_sigma_m)
        self._sigma_normal_rad = math.radians(config.normal_sigma_deg)
        #: How many (n, 3) blocks of standard normal values a reading of n contacts draws.
        self._blocks = int(self._sigma_position_m > 0) + int(self._sigma_normal_rad > 0)
        self._rng = rng

    def apply(self, positions_m: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Noisy copies of positions (n, 3) m and unit normals (n, 3); the normals stay unit length.
        Without noise (or contacts) the values pass unchanged: read-only inputs as they are, others
        copied.

        One draw of standard normal values per reading: the positions' block (n, 3) first, then the
        normals' (the values of two draws in that order). InputError (naming the ContactSet field)
        for positions beyond palpate.inputs' bounds or normals that are not unit vectors."""
        p = np.asarray(positions_m, dtype=np.float64)
        n = np.asarray(normals, dtype=np.float64)
        if 0 < len(p) <= FEW_DIRECTIONS and self._blocks and p.shape == n.shape == (len(p), 3):
            few = self._apply_few(p.ravel().tolist(), n.ravel().tolist())
            if few is not None:
                return few
        p = coordinates(p, "positions_m")
        n = unit_vectors(n, "normals")
        if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
            raise ValueError(f"positions and normals must both have shape (n, 3), got {p.shape} and {n.shape}")
        if not len(p) or not self._blocks:  # nothing to draw (drawing no values leaves the generator as it is)
            return _unchanged(p), _unchanged(n)
        z = self._rng.standard_normal((self._blocks, *p.shape))
        if self._sigma_position_m > 0:
            p, z = p + self._sigma_position_m * z[0], z[1:]
        else:
            p = np.array(p)
        n = _perturb(n, self._sigma_normal_rad * z[0]) if self._sigma_normal_rad > 0 else np.array(n)
        return p, n

    def _apply_few(self, p: list[float], n: list[float]) -> tuple[np.ndarray, np.ndarray] | None:
        """`apply` of a few rows (flattened) in Python scalars, with the same draw and the same bits; None
        when a value is not surely valid (the general path then checks it and names the fault)."""
        if not (math.isfinite(sum(p) + sum(n)) and max(map(abs, p)) <= MAX_COORDINATE_M):
            return None
        lengths = []
        for i in range(0, len(n), 3):
            squared = n[i] * n[i] + n[i + 1] * n[i + 1] + n[i + 2] * n[i + 2]
            if not _SURELY_UNIT[0] < squared < _SURELY_UNIT[1]:
                return None
            lengths.append(math.sqrt(squared))  # numpy's norm of a row of three, for these values
        rows = len(lengths)
        z = self._rng.standard_normal(self._blocks * 3 * rows).tolist()
        if self._sigma_position_m > 0:
            s = self._sigma_position_m
            p = [v + s * dz for v, dz in zip(p, z[: 3 * rows], strict=True)]
            z = z[3 * rows :]
        if self._sigma_normal_rad > 0:
            s = self._sigma_normal_rad
            n = _turned_few(n, lengths, [s * dz for dz in z])
        return np.array(p).reshape(rows, 3), np.array(n).reshape(rows, 3)


def _unchanged(a: np.ndarray) -> np.ndarray:
    """`a` itself when it is read-only (a received array: nothing can change it, and the codec passes
    it on without a copy), else a copy."""
    return a if not a.flags.writeable else np.array(a)


#: Squared norms surely within `unit_vectors`' tolerance (a hair inside it; the rest is checked there).
_SURELY_UNIT = ((1.0 - UNIT_TOLERANCE + 1e-9) ** 2, (1.0 + UNIT_TOLERANCE - 1e-9) ** 2)

#: Up to this many directions, `_perturb` computes in Python (numpy's call overhead is most of the cost
#: of a few rows), with the same operations in the same order, so the same bits.
FEW_DIRECTIONS = 4


def perturb_directions(normals: np.ndarray, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Rotate unit vectors (n, 3) by a tangent Gaussian step t (sigma per tangent axis, radians).

    Exponential map on the sphere: n' = cos|t| n + sin|t| t/|t|, so angle(n, n') = |t| exactly and the
    result is unit length. ValueError for rows that are not finite and nonzero (they have no direction).
    """
    normals = np.asarray(normals, dtype=np.float64)
    if normals.ndim != 2 or normals.shape[1] != 3:
        raise ValueError(f"normals must have shape (n, 3), got {normals.shape}")
    if not (np.isfinite(normals).all() and (np.abs(normals).max(axis=1, initial=0.0) > 0.0).all()):
        raise ValueError("normals must be finite and nonzero (a zero row has no direction)")
    return _perturb(normals, sigma_rad * rng.standard_normal(np.shape(normals)))


def _perturb(normals: np.ndarray, z: np.ndarray) -> np.ndarray:
    """`perturb_directions` with the step z (n, 3) drawn."""
    few = 0 < len(normals) <= FEW_DIRECTIONS and normals.shape[1:] == (3,)
    if few and math.isfinite(sum(normals.ravel().tolist())):
        return _perturb_few(normals, z)
    return _perturb_many(normals, z)


def _perturb_many(normals: np.ndarray, z: np.ndarray) -> np.ndarray:
    """`_perturb` in vectorised maths. The dot products sum their three products left to right
    (``(z * n).sum(axis=1)``; einsum sums them as (p0 + p2) + p1), as `_perturb_few` does."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    t = z - (z * n).sum(axis=1)[:, None] * n  # project onto the tangent plane
    angle = np.linalg.norm(t, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        direction = np.where(angle > 0, t / angle, 0.0)
    out = np.cos(angle) * n + np.sin(angle) * direction
    return np.asarray(out / np.linalg.norm(out, axis=1, keepdims=True))


def _perturb_few(normals: np.ndarray, z: np.ndarray) -> np.ndarray:
    """`_perturb_many` of a few finite rows in Python scalars (`_turned_few`), with its bits."""
    n = normals.ravel().tolist()
    lengths = [math.sqrt(n[i] * n[i] + n[i + 1] * n[i + 1] + n[i + 2] * n[i + 2]) for i in range(0, len(n), 3)]
    return np.array(_turned_few(n, lengths, z.ravel().tolist()), dtype=np.float64).reshape(-1, 3)


def _turned_few(n: list[float], lengths: list[float], z: list[float]) -> list[float]:
    """Rows of three (flattened) n turned by the steps z: numpy's norm of a row of three and the sum of
    three products both add left to right, so these lines give `_perturb_many`'s bits; cos and sin are
    numpy's (its float64 kernels may differ from libm's)."""
    units, tangents, angles = [], [], []
    for i, length in zip(range(0, len(n), 3), lengths, strict=True):
        a, b, c = n[i] / length, n[i + 1] / length, n[i + 2] / length
        za, zb, zc = z[i], z[i + 1], z[i + 2]
        dot = za * a + zb * b + zc * c
        ta, tb, tc = za - dot * a, zb - dot * b, zc - dot * c  # project onto the tangent plane
        angle = math.sqrt(ta * ta + tb * tb + tc * tc)
        units.append((a, b, c))
        tangents.append((ta / angle, tb / angle, tc / angle) if angle > 0 else (0.0, 0.0, 0.0))
        angles.append(angle)
    out: list[float] = []
    cos, sin = np.cos(angles).tolist(), np.sin(angles).tolist()
    for (a, b, c), (ta, tb, tc), ca, sa in zip(units, tangents, cos, sin, strict=True):
        x, y, w = ca * a + sa * ta, ca * b + sa * tb, ca * c + sa * tc
        length = math.sqrt(x * x + y * y + w * w)
        out += (x / length, y / length, w / length)
    return out
