"""Checks of values that arrive in messages: the one place where nodes decide what input they refuse.

The codec guarantees a message's schema (types, shapes, dtypes, finite floats). It cannot know that a
quaternion of norm 0 is no rotation, that a joint state lacks the joints a mapper needs, or that a
position of 1e300 m is garbage. These functions do, for every node alike: each returns the value
ready to use (normalised, reordered, cleaned) or raises InputError naming the message field and the
reason. The runtime counts an InputError in the node's ``input_errors`` and logs it once with node,
topic, field and reason; a handler calls these before it changes any state, so the node goes on with
the state it had (docs/runtime.md, "Bad input").

Checks do not change values: an accepted array comes back as float64 with the same numbers (a unit
vector within the tolerance is not renormalised here; consumers that need exact unit length
normalise, as ``quat_to_matrix`` does), so adding a check never moves a result.

The bounds are sanity bounds against garbage (uninitialised memory, a unit mistake), far outside any
tabletop robot, not workspaces: a node with a real workspace (the mapper's grid) checks that as well.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.description.names import match_names
from palpate.errors import InputError
from palpate.geometry.rotations import quat_to_matrix

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Largest coordinate accepted, metres: a kilometre from the world origin. Squares and products of
#: such coordinates stay exact to far below a micrometre in float64; garbage (1e300) would overflow.
MAX_COORDINATE_M = 1e3
#: Largest speed (m/s), angular speed (rad/s) or joint rate accepted in a message: a thousand units.
MAX_RATE = 1e3
#: A unit vector or unit quaternion may deviate from norm 1 by this fraction (float32 senders, drift);
#: the consumer normalises it. A larger deviation (norm 0, 1e-200, 2) means the sender has no valid value.
UNIT_TOLERANCE = 1e-2
#: Largest contact force accepted, newtons.
MAX_FORCE_N = 1e6
#: Largest path length (m) and accumulated rotation (deg) accepted since a run's start: far beyond any run
#: (a thousand kilometres), far below garbage (1e308, which summed to an infinite travel).
MAX_PATH_M = 1e6
MAX_TURN_DEG = 1e9


class Reading(NamedTuple):
    """An accepted reading of an :class:`Accumulated` quantity: the total, and the state it leaves."""

    total: float
    last: float
    offset: float
    stamp_ns: int


class Accumulated:
    """Readings of a quantity its sender accumulates since its start (a path length, a turned angle), in
    turn, each with its own stamp. A reading is refused (InputError naming ``field``) when it lies outside
    [0, ``limit``] or has grown faster than ``max_rate`` units per second of the stamps since the last one
    taken (since stamp 0 for the first: a simulated run starts there): a path of 1000 m 10 ms into a run
    is no odometer's. One that falls below the last starts a new segment (a restarted sender counts from
    0 again), so the total never falls. :meth:`judge` leaves the state as it is (a message may still be
    refused for another field), :meth:`take` keeps a judged reading."""

    def __init__(self, field: str, unit: str, limit: float, max_rate: float) -> None:
        self.field, self.unit, self.limit, self.max_rate = field, unit, limit, max_rate
        self.last, self.offset, self.stamp_ns = 0.0, 0.0, 0

    def judge(self, value: float, stamp_ns: int) -> Reading:
        """``value`` (float) read at ``stamp_ns`` as the next reading, when it is a plausible one."""
        x = float(bounded(value, self.field, self.limit, self.unit, lower=0.0))
        restarted = x < self.last - 1e-9 * max(1.0, self.last)
        grown = x if restarted else x - self.last
        elapsed_s = max(0, stamp_ns - self.stamp_ns) * 1e-9
        if grown > self.max_rate * elapsed_s + 1e-9 * max(1.0, x):
            went_back = (
                f" (its stamp is {(self.stamp_ns - stamp_ns) * 1e-9:.6g} s before the last reading's: a clock source "
                "that started again from 0? it continues its stamps)"
                if stamp_ns < self.stamp_ns
                else ""
            )
            raise InputError(
                self.field,
                f"grew by {grown:.6g} {self.unit} in {elapsed_s:.6g} s of its stamps, faster than {self.max_rate:g} "
                f"{self.unit}/s{went_back}",
            )
        offset = self.offset + self.last if restarted else self.offset
        return Reading(offset + x, x, offset, stamp_ns)

    def take(self, reading: Reading) -> None:
        """Keep ``reading`` (from :meth:`judge`) as the last one."""
        self.last, self.offset, self.stamp_ns = reading.last, reading.offset, reading.stamp_ns


def coordinates(
    values: ArrayLike, field: str, limit_m: float = MAX_COORDINATE_M, *, allow_nan: bool = False
) -> FloatArray:
    """`values` (any shape) as float64 when every coordinate is within +-limit_m, else InputError.

    allow_nan: NaN entries pass (a field where NaN means "none", such as a TouchEvent's predicted
    contact before the first target); infinity never does.
    """
    a = np.asarray(values, dtype=np.float64)
    if 0 < a.size <= _FEW_VALUES:
        few = a.ravel().tolist()
        if math.isfinite(sum(few)) and max(map(abs, few)) <= limit_m:  # no NaN, none beyond the limit
            return a
    check = a[~np.isnan(a)] if allow_nan else a
    if check.size and not float(np.max(np.abs(check))) <= limit_m:
        largest = _largest(check)
        if not math.isfinite(largest):
            raise InputError(field, f"coordinate {largest} is not finite")
        raise InputError(field, f"coordinate {largest:.6g} m lies beyond {limit_m:g} m of the origin")
    return a


def within_reach(points_m: FloatArray, centre_m: FloatArray, reach_m: float, field: str, what: str) -> FloatArray:
    """`points_m` (n, 3) when each lies within reach_m of `centre_m` (3,), else InputError: a point no part of
    `what` can touch (millimetres sent as metres lie a thousand times too far)."""
    if len(points_m):
        distances = np.linalg.norm(points_m - centre_m, axis=1)
        if not float(distances.max()) <= reach_m:
            at = int(np.argmax(distances))
            raise InputError(
                field,
                f"entry {at} lies {distances[at]:.6g} m from the {what} at {np.round(centre_m, 6).tolist()}, beyond "
                f"the {reach_m:g} m any contact of it can lie (a unit other than metres?)",
            )
    return points_m


def bounded(values: ArrayLike, field: str, limit: float, unit: str = "", *, lower: float | None = None) -> FloatArray:
    """`values` (any shape) as float64 when every element lies in [-limit, limit] (or [lower, limit]),
    else InputError."""
    a = np.asarray(values, dtype=np.float64)
    low = -limit if lower is None else lower
    if 0 < a.size <= _FEW_VALUES:
        few = a.ravel().tolist()
        if math.isfinite(sum(few)) and min(few) >= low and max(few) <= limit:  # no NaN, none out of range
            return a
    if a.size and not (float(np.min(a)) >= low and float(np.max(a)) <= limit):
        bad = float(np.min(a)) if not float(np.min(a)) >= low else float(np.max(a))
        units = f" {unit}" if unit else ""
        raise InputError(field, f"value {bad:.6g}{units} is outside [{low:g}, {limit:g}]{units}")
    return a


def unit_vectors(values: ArrayLike, field: str, tolerance: float = UNIT_TOLERANCE) -> FloatArray:
    """`values` (..., k) as float64 when every row's norm is within 1 +- tolerance, else InputError."""
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return a
    if a.size <= _FEW_VALUES and a.ndim in (1, 2):
        few = a.ravel().tolist()
        if math.isfinite(sum(few)):  # the norms of `_few_norms`, checked in Python
            k = a.shape[-1]
            if all(abs(_few_norm(few[i : i + k]) - 1.0) <= tolerance for i in range(0, len(few), k)):
                return a
    norms = _norms(a)
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= tolerance).ravel())
    if bad.size:
        row = int(bad[0])
        raise InputError(
            field,
            f"row {row} has norm {norms.ravel()[row]:.6g}, not 1 (+-{tolerance:g}); send unit vectors"
            if a.ndim > 1
            else f"norm {norms.ravel()[row]:.6g}, not 1 (+-{tolerance:g}); send a unit vector",
        )
    return a


def unit_or_zero_rows(values: ArrayLike, field: str, tolerance: float = UNIT_TOLERANCE) -> FloatArray:
    """Directions (n, 3) as float64 whose every row has norm 1 +- tolerance or is exactly zero ("no
    direction", as a surface normal where the gradient vanishes), else InputError."""
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(field, f"shape {a.shape}, not (n, 3)")
    norms = _norms(a).ravel()
    bad = np.flatnonzero(~((np.abs(norms - 1.0) <= tolerance) | (norms == 0.0)))
    if bad.size:
        row = int(bad[0])
        raise InputError(field, f"row {row} has norm {norms[row]:.6g}, neither 0 nor 1 (+-{tolerance:g})")
    return a


def unit_or_zero(values: ArrayLike, field: str, tolerance: float = UNIT_TOLERANCE) -> FloatArray:
    """A direction (3,) as float64 whose norm is 1 +- tolerance, or exactly zero ("no direction"), else
    InputError."""
    a = np.asarray(values, dtype=np.float64)
    if a.shape != (3,):
        raise InputError(field, f"shape {a.shape}, not (3,)")
    norm = float(_norms(a).ravel()[0])
    if not (norm == 0.0 or abs(norm - 1.0) <= tolerance):
        raise InputError(field, f"norm {norm:.6g}, neither 0 nor 1 (+-{tolerance:g}); send a unit vector or zeros")
    return a


def unit_quaternion(q_wxyz: ArrayLike, field: str, tolerance: float = UNIT_TOLERANCE) -> FloatArray:
    """A quaternion (w, x, y, z) (4,) as float64 when its norm is within 1 +- tolerance, else InputError.

    An uninitialised IMU sends (0, 0, 0, 0); that is no rotation, and normalising a norm of 1e-200
    would invent one.
    """
    q = np.asarray(q_wxyz, dtype=np.float64)
    if q.shape != (4,):
        raise InputError(field, f"a quaternion has 4 components (w, x, y, z), got shape {q.shape}")
    values = q.tolist()
    norm = _few_norm(values) if math.isfinite(sum(values)) else float(_norms(q))  # `_norms`, without an array
    if not abs(norm - 1.0) <= tolerance:
        raise InputError(field, f"norm {norm:.6g} is not that of a unit quaternion (w, x, y, z), 1 +- {tolerance:g}")
    return q


def fingertip_pose(position_m: ArrayLike, quaternion_wxyz: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """A Pose's position (3,) m (a copy) and orientation as a rotation matrix (3, 3), checked."""
    r = coordinates(position_m, "position_m")
    q = unit_quaternion(quaternion_wxyz, "quaternion_wxyz")
    return np.array(r), quat_to_matrix(q)


def contact_arrays(
    positions_m: ArrayLike, normals: ArrayLike, forces_n: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A ContactSet's positions (n, 3) m, unit normals (n, 3) and forces (n,) N in [0, MAX_FORCE_N], checked."""
    forces = bounded(forces_n, "forces_n", MAX_FORCE_N, "N", lower=0.0)
    return coordinates(positions_m, "positions_m"), unit_vectors(normals, "normals"), forces


def vertex_subset(indices: ArrayLike, count: int, field: str) -> IntArray:
    """Indices (k,) of some of `count` vertices as int64: ascending, distinct and in range, else InputError."""
    idx = np.asarray(indices).astype(np.int64, copy=False)
    if idx.ndim != 1:
        raise InputError(field, f"must be a flat index array, got shape {idx.shape}")
    bad = (idx < 0) | (idx >= count)
    bad[1:] |= idx[1:] <= idx[:-1]
    if bad.any():
        at = int(np.argmax(bad))
        reason = f"must be ascending distinct vertex indices in [0, {count}); entry {at} is {int(idx[at])}"
        raise InputError(field, reason)
    return idx


def per_vertex(values: ArrayLike, indices: ArrayLike, count: int, field: str, missing: float = math.nan) -> FloatArray:
    """Values (count,) from values (k,) given at the vertices `indices` (k,) (``vertex_subset``), `missing` elsewhere.

    For a SurfaceMesh: ``per_vertex(m.vertex_variance, m.variance_vertices, len(m.vertices_m), "variance_vertices")``.
    """
    idx = vertex_subset(indices, count, field)
    v = np.asarray(values, dtype=np.float64)
    if v.shape != idx.shape:
        raise InputError(field, f"has {idx.size} indices for {v.size} values")
    out = np.full(count, missing)
    out[idx] = v
    return out


def unique_names(names: Sequence[str], field: str) -> list[str]:
    """`names` as a list when none is empty or repeated, else InputError."""
    out = list(names)
    if len(set(out)) != len(out):
        repeated = sorted(name for name, count in Counter(out).items() if count > 1)
        raise InputError(field, f"repeated name(s) {_few(repeated)}: each name must appear once")
    if "" in out:
        raise InputError(field, f"entry {out.index('')} is an empty name")
    return out


def select_named(names: Sequence[str], values: ArrayLike, wanted: Sequence[str], field: str) -> FloatArray:
    """The entries of `values` (n, ...) named `wanted`, in that order, from a message's `names` (n,).

    Names the node does not need are ignored; a wanted name that is missing or repeated is an
    InputError (a reading of a subset of the joints, or an ambiguous one).
    """
    match = match_names(wanted, names)
    if match.missing:
        missing = list(match.missing)
        raise InputError(field, f"lacks {len(missing)} of the {len(wanted)} names needed: {_few(missing)}")
    ambiguous = sorted(set(match.repeated) & set(wanted))
    if ambiguous:
        raise InputError(field, f"repeats needed name(s) {_few(ambiguous)}: each name must appear once")
    return np.asarray(np.asarray(values, dtype=np.float64)[match.index], dtype=np.float64)


def triangle_mesh(
    vertices: ArrayLike,
    faces: ArrayLike,
    *,
    solid: bool,
    vertices_field: str = "vertices_m",
    faces_field: str = "faces",
) -> tuple[FloatArray, NDArray[np.integer]]:
    """A mesh (vertices (v, 3) m, faces (f, 3)) whose faces index its vertices, else InputError.

    Refused: coordinates beyond MAX_COORDINATE_M, faces indexing outside the vertices. With `solid`
    (a mesh the node measures against, such as the true object) its triangles without area are dropped
    (they bound nothing, and closest-point formulas divide by their edge lengths) and a mesh without a
    triangle left is refused; otherwise (an estimate, which may be empty) the faces are kept as sent.
    """
    V = coordinates(vertices, vertices_field)
    F = np.asarray(faces)
    if F.size and (int(F.min()) < 0 or int(F.max()) >= len(V)):
        bad = int(F.min()) if int(F.min()) < 0 else int(F.max())
        raise InputError(faces_field, f"vertex index {bad} is outside 0..{len(V) - 1}")
    if not solid:
        return V, F
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cross = np.cross(B - A, C - A)
    # squared lengths, as the formulas use them: a sliver whose square underflows counts as no area
    keep = (_squares(cross) > 0.0) & (_squares(B - A) > 0.0) & (_squares(C - B) > 0.0) & (_squares(A - C) > 0.0)
    if not keep.any():
        raise InputError(faces_field, f"none of the {len(F)} triangles has an area")
    return V, F if keep.all() else F[keep]


def _squares(rows: FloatArray) -> FloatArray:
    return np.asarray(np.einsum("ij,ij->i", rows, rows), dtype=np.float64)


#: Float arrays up to this many elements are checked for finiteness in Python (`all_finite`).
FEW_FINITE = 64


def all_finite(array: np.ndarray) -> bool:
    """True when no element of `array` is NaN or infinite."""
    # A sum of Python floats is NaN or infinite when any term is (NaN and infinity propagate, and
    # inf - inf is NaN), and cheaper than numpy for a few elements; an overflowing sum of finite terms
    # is settled by the exact test below.
    if array.dtype.kind == "f" and array.size <= FEW_FINITE and math.isfinite(sum(array.ravel().tolist())):
        return True
    return bool(np.isfinite(array).all())


def _norms(a: FloatArray) -> FloatArray:
    """Euclidean norms along the last axis, scaled so that 1e200 or 1e-200 components do not over/underflow."""
    if 0 < a.size <= _FEW_VALUES and a.ndim in (1, 2):
        values = a.ravel().tolist()
        if math.isfinite(sum(values)):  # finite: the scalar twin below gives numpy's bits
            return _few_norms(values, a.shape)
    scale = np.max(np.abs(a), axis=-1)
    safe = np.where(scale > 0, scale, 1.0)
    with np.errstate(over="ignore"):  # a norm beyond the largest double is infinite, and refused
        return np.asarray(scale * np.linalg.norm(a / safe[..., None], axis=-1), dtype=np.float64)


#: Arrays of at most this many finite values take the scalar path of `_norms` and `coordinates`
#: (one pose, quaternion or contact: numpy's call overhead is most of their cost).
_FEW_VALUES = 16


def _few_norms(values: list[float], shape: tuple[int, ...]) -> FloatArray:
    """`_norms` of finite values (the flattened array of `shape`) in Python: the same maths in the same
    order (numpy sums a row of a few squares left to right), so the same bits."""
    k = shape[-1]
    out = [_few_norm(values[start : start + k]) for start in range(0, len(values), k)]
    return np.array(out, dtype=np.float64).reshape(shape[:-1])


def _few_norm(row: list[float]) -> float:
    """The norm of one row of finite values, as `_norms` computes it (scaled by the largest magnitude)."""
    scale = max(map(abs, row))
    safe = scale if scale > 0 else 1.0
    total = 0.0
    for v in row:
        x = v / safe
        total += x * x
    return scale * math.sqrt(total)


def _largest(a: FloatArray) -> float:
    return float(a.ravel()[int(np.argmax(np.abs(a).ravel()))])


def _few(names: Sequence[str], limit: int = 5) -> str:
    shown = ", ".join(repr(n) for n in names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")
