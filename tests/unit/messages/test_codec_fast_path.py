"""The codec's fast decode path against its checked path: same messages, same errors, and it is taken."""

from __future__ import annotations

import copy
import dataclasses
import re
from typing import Any

import msgpack
import numpy as np
import pytest

from palpate.errors import MalformedMessageError, NonFiniteError
from palpate.messages import codec
from palpate.messages.base import REGISTRY, Message
from palpate.messages.schemas import ContactSet, ParticleSetSummary

ALL_TYPES = sorted(REGISTRY)
_ODD_VALUES: list[Any] = [
    None,
    True,
    0,
    -1,
    2.5,
    float("nan"),
    float("inf"),
    "x",
    "<f8",
    [],
    [1],
    [True],
    [-1],
    {},
    b"x",
]


def random_message(cls: type[Message], rng: np.random.Generator) -> Message:
    """A valid message of `cls` with random sizes (0 to 4 along each named dimension)."""
    dims: dict[str, int] = {}
    values: dict[str, Any] = {}
    for name, spec in cls.field_specs().items():
        shape = [dims.setdefault(d, int(rng.integers(0, 5))) if isinstance(d, str) else d for d in spec.shape or ()]
        if spec.kind == "array":
            dtype = np.dtype(spec.dtype)
            data = rng.normal(size=shape) if dtype.kind == "f" else rng.integers(-9, 9, size=shape)
            values[name] = data.astype(dtype)
        elif spec.kind == "str_list":
            values[name] = [f"s{i}" for i in range(shape[0] if shape else 2)]
        elif spec.kind == "int":
            values[name] = int(rng.integers(0, 1 << 40))
        elif spec.kind == "float":
            values[name] = float(rng.normal())
        elif spec.kind == "str":
            values[name] = "abc"
        else:
            values[name] = bool(rng.integers(2))
    return cls(**values)


def outcome(payload: bytes, expected: type[Message] | None) -> tuple[str, Any]:
    try:
        return "ok", codec.decode(payload, expected)
    except Exception as exc:  # compare whatever the two paths raise
        return type(exc).__name__, str(exc)


def checked_outcome(payload: bytes, expected: type[Message] | None, monkeypatch: pytest.MonkeyPatch) -> tuple[str, Any]:
    with monkeypatch.context() as m:
        m.setattr(codec, "_fast_values", lambda plan, fields, blob: None)
        return outcome(payload, expected)


def two_contacts(stamp_ns: int = 0) -> ContactSet:
    """A ContactSet of two contacts, its arrays of ones (the local positions zeros)."""
    return ContactSet(
        stamp_ns=stamp_ns,
        positions_m=np.ones((2, 3)),
        local_positions_m=np.zeros((2, 3)),
        normals=np.ones((2, 3)),
        forces_n=np.ones(2),
        links=["a", "b"],
    )


def split(payload: bytes) -> tuple[dict[str, Any], bytes]:
    header, blob = msgpack.unpackb(payload, raw=False)
    return header, blob


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_fast_path_is_taken_and_matches_the_checked_path(type_name: str) -> None:
    cls = REGISTRY[type_name]
    rng = np.random.default_rng(len(type_name))
    for _ in range(5):
        message = random_message(cls, rng)
        payload = codec.encode(message)
        header, blob = split(payload)
        fast = codec._fast_values(codec._plan_of(cls), header["fields"], memoryview(blob))
        assert fast is not None, "a well-formed message must not need the checked path"
        decoded = codec.decode(payload, cls)
        checked = codec._build_checked(cls, header["fields"], memoryview(blob))
        assert decoded == checked == message
        for name, spec in cls.field_specs().items():
            if spec.kind == "array":
                a, b = getattr(decoded, name), getattr(checked, name)
                assert a.dtype == b.dtype and a.shape == b.shape and not a.flags.writeable


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_malformed_fields_raise_the_same_error_on_both_paths(type_name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    cls = REGISTRY[type_name]
    rng = np.random.default_rng(100 + len(type_name))
    accepted = 0
    for _ in range(40):
        header, blob = split(codec.encode(random_message(cls, rng)))
        fields = copy.deepcopy(header["fields"])
        name = str(rng.choice(sorted(fields)))
        change = int(rng.integers(5))
        if change == 0:
            del fields[name]
        elif change == 1:
            fields["unexpected"] = 1
        elif change == 2 or not isinstance(fields[name], dict):
            fields[name] = _ODD_VALUES[int(rng.integers(len(_ODD_VALUES)))]
        else:
            key = str(rng.choice(["dtype", "shape", "offset", "nbytes"]))
            fields[name][key] = _ODD_VALUES[int(rng.integers(len(_ODD_VALUES)))]
        data = bytearray(blob)
        if len(data) >= 8 and rng.integers(2):
            at = int(rng.integers(len(data) // 8)) * 8
            data[at : at + 8] = np.array([np.nan]).tobytes()
        payload = msgpack.packb([{**header, "fields": fields}, bytes(data)], use_bin_type=True)
        fast, checked = outcome(payload, cls), checked_outcome(payload, cls, monkeypatch)
        assert fast[0] == checked[0] and fast[1] == checked[1], (fields, fast, checked)
        accepted += fast[0] == "ok"
    assert accepted < 40  # the mutations do hit errors


def test_nan_in_any_array_is_named_despite_the_whole_blob_check() -> None:
    n = 3
    for field in ("positions_m", "local_positions_m", "normals", "forces_n"):
        values = {
            "positions_m": np.ones((n, 3)),
            "local_positions_m": np.ones((n, 3)),
            "normals": np.ones((n, 3)),
            "forces_n": np.ones(n),
        }
        values[field].flat[-1] = np.inf
        message = ContactSet(stamp_ns=0, links=["a"] * n, **values)
        with pytest.raises(NonFiniteError, match=re.escape(f"ContactSet.{field} must be finite")):
            codec.validate(message)
        object.__setattr__(message, field, values[field])
        payload = codec.encode(message)
        with pytest.raises(NonFiniteError, match=re.escape(f"ContactSet.{field} must be finite")):
            codec.decode(payload, ContactSet)


def test_non_finite_bytes_outside_the_arrays_are_not_an_error() -> None:
    """A foreign sender may leave other bytes between arrays: only the arrays must be finite."""
    message = two_contacts()
    header, blob = split(codec.encode(message))
    gap = np.array([np.nan]).tobytes()
    fields = header["fields"]
    for name in ("local_positions_m", "normals", "forces_n"):
        fields[name]["offset"] += 8  # each later array moves past one NaN gap
    first_end = fields["positions_m"]["nbytes"]
    data = blob[:first_end] + gap + blob[first_end:] + gap
    assert len(data) % 8 == 0  # so that the whole-blob test runs, fails, and per-array tests decide
    decoded = codec.decode(msgpack.packb([header, data], use_bin_type=True), ContactSet)
    assert decoded == message


def test_validate_names_shape_and_dimension_faults() -> None:
    good = ParticleSetSummary(
        stamp_ns=0,
        num_particles=2,
        effective_sample_size=1.0,
        best_index=0,
        resampled=False,
        joint_names=["a"],
        pose_mean_rad=np.zeros(1),
        pose_best_rad=np.zeros(1),
        weights=np.full(2, 0.5),
    )
    codec.validate(good)
    wrong_ndim = copy.copy(good)
    object.__setattr__(wrong_ndim, "weights", np.zeros((2, 1)))
    with pytest.raises(MalformedMessageError, match=r"ParticleSetSummary.weights must have shape \(k\), got \(2, 1\)"):
        codec.validate(wrong_ndim)
    disagree = copy.copy(good)
    object.__setattr__(disagree, "pose_best_rad", np.zeros(2))
    with pytest.raises(MalformedMessageError, match="pose_best_rad has 2 entries along 'j' but joint_names has 1"):
        codec.validate(disagree)
    nan_float = copy.copy(good)
    object.__setattr__(nan_float, "effective_sample_size", float("nan"))
    with pytest.raises(NonFiniteError, match=re.escape("ParticleSetSummary.effective_sample_size must be finite")):
        codec.validate(nan_float)


def test_small_payloads_split_in_one_call_and_wide_blob_headers_take_the_general_path() -> None:
    message = two_contacts(stamp_ns=5)
    payload = codec.encode(message)
    header, blob = split(payload)
    fast = codec._split_small(memoryview(payload))
    assert fast is not None and fast[0] == header and bytes(fast[1]) == blob
    wide = b"\x92" + msgpack.packb(header, use_bin_type=True) + b"\xc6" + len(blob).to_bytes(4, "big") + blob
    assert codec._split_small(memoryview(wide)) is None  # bin 32 for a small blob: general path
    assert codec.decode(wide, ContactSet) == message
    with pytest.raises(MalformedMessageError, match="does not match the payload"):
        codec.decode(payload + b"\0", ContactSet)


@pytest.mark.parametrize("n", [1024, 1025, 1031, 4096, 20000])
def test_big_blobs_start_8_aligned_and_small_payloads_stay_canonical(n: int) -> None:
    rng = np.random.default_rng(n)
    for names in range(8):  # the joint names shift the header length through every remainder
        message = ParticleSetSummary(
            stamp_ns=int(rng.integers(1 << 40)),
            num_particles=n,
            effective_sample_size=2.0,
            best_index=1,
            resampled=True,
            joint_names=["j"] * names,
            pose_mean_rad=np.zeros(names),
            pose_best_rad=np.ones(names),
            weights=rng.random(n),
        )
        payload = codec.encode(message)
        header, blob = split(payload)
        assert (len(payload) - len(blob)) % 8 == 0  # the blob (8 KiB or more) starts 8-aligned
        assert (header["type"], header["version"]) == ("ParticleSetSummary", ParticleSetSummary.VERSION)
        assert codec.decode(payload, ParticleSetSummary) == message
        small = replace_weights(message, rng.random(3))
        small_payload = codec.encode(small)
        assert small_payload == msgpack.packb(list(split(small_payload)), use_bin_type=True)  # canonical


def replace_weights(message: ParticleSetSummary, weights: np.ndarray) -> ParticleSetSummary:
    return dataclasses.replace(message, num_particles=len(weights), weights=weights)


@pytest.mark.parametrize("n", [1, 5, 40])  # small arrays (summed in Python) and big ones (numpy)
def test_huge_finite_values_are_finite_and_nan_or_inf_anywhere_are_not(n: int) -> None:
    huge = np.full(n, 1e308)  # the sum overflows: the exact test must clear it
    message = ParticleSetSummary(
        stamp_ns=0,
        num_particles=n,
        effective_sample_size=1.0,
        best_index=0,
        resampled=False,
        joint_names=[],
        pose_mean_rad=np.zeros(0),
        pose_best_rad=np.zeros(0),
        weights=huge,
    )
    codec.validate(message)
    assert codec.decode(codec.encode(message), ParticleSetSummary) == message
    assert codec.transfer(message) == message
    for bad in (np.nan, np.inf, -np.inf):
        for at in {0, n // 2, n - 1}:
            weights = huge.copy()
            weights[at] = bad
            broken = dataclasses.replace(message, weights=weights)
            with pytest.raises(NonFiniteError, match=re.escape("ParticleSetSummary.weights must be finite")):
                codec.validate(broken)
            with pytest.raises(NonFiniteError, match=re.escape("ParticleSetSummary.weights must be finite")):
                codec.decode(codec.encode(broken), ParticleSetSummary)
            with pytest.raises(NonFiniteError, match=re.escape("ParticleSetSummary.weights must be finite")):
                codec.transfer(broken)


def test_validate_raises_the_first_fault_in_field_order() -> None:
    """Its fast path checks all fields at once; a fault still raises the error of the first faulty field."""
    nan_first = ContactSet(
        stamp_ns=0,
        positions_m=np.full((1, 3), np.nan),
        local_positions_m=np.zeros((1, 3)),
        normals=np.zeros((1, 2)),  # also wrong, but a later field
        forces_n=np.zeros(1),
        links=["a"],
    )
    with pytest.raises(NonFiniteError, match=re.escape("ContactSet.positions_m must be finite")):
        codec.validate(nan_first)
    shape_first = dataclasses.replace(nan_first, positions_m=np.zeros((1, 2)), normals=np.full((1, 3), np.inf))
    with pytest.raises(MalformedMessageError, match=re.escape("ContactSet.positions_m must have shape (n, 3)")):
        codec.validate(shape_first)


def test_frozen_arrays_are_read_only_copies_that_transfer_passes_on() -> None:
    source = np.arange(6.0).reshape(2, 3)
    frozen = codec.frozen(source)
    assert np.array_equal(frozen, source) and frozen.dtype == source.dtype and not frozen.flags.writeable
    assert not np.shares_memory(frozen, source)
    message = ContactSet(
        stamp_ns=0,
        positions_m=frozen,
        local_positions_m=frozen,
        normals=np.eye(3)[:2],
        forces_n=np.ones(2),
        links=["a", "b"],
    )
    assert codec.transfer(message).positions_m is frozen


def test_a_blob_with_bytes_past_its_arrays_decodes_when_its_length_is_no_multiple_of_8() -> None:
    """Bytes past the last array are outside every array; a blob of 8k + 1 bytes cannot be read as one
    float64 array, so the whole-blob test must not run (it raised numpy's ValueError)."""
    message = two_contacts()
    header, blob = split(codec.encode(message))
    assert codec.decode(msgpack.packb([header, blob + b"\0"], use_bin_type=True), ContactSet) == message


def test_a_negative_dimension_is_refused_even_when_nbytes_agrees(monkeypatch: pytest.MonkeyPatch) -> None:
    """shape [-1] with nbytes -8 (= -1 x 8): numpy's frombuffer reads count -1 as 'the rest of the blob'."""
    message = ContactSet(
        stamp_ns=0,
        positions_m=np.ones((1, 3)),
        local_positions_m=np.zeros((1, 3)),
        normals=np.ones((1, 3)),
        forces_n=np.full(1, 2.0),  # the last array: the rest of the blob is exactly it
        links=["a"],
    )
    header, blob = split(codec.encode(message))
    header["fields"]["forces_n"].update(shape=[-1], nbytes=-8)
    payload = msgpack.packb([header, blob], use_bin_type=True)
    expected = ("MalformedMessageError", "ContactSet.forces_n: shape must be a list of non-negative ints")
    assert outcome(payload, ContactSet) == expected
    assert checked_outcome(payload, ContactSet, monkeypatch) == expected
