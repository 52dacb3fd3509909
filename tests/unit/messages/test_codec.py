"""The codec: round trips for every message type, zero-copy decoding, and every named decode error."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from palpate.errors import (
    MalformedMessageError,
    MessageError,
    NonFiniteError,
    SchemaVersionError,
    UnknownMessageTypeError,
)
from palpate.messages import REGISTRY, codec
from palpate.messages.base import FieldSpec, Message, array
from palpate.messages.schemas import Clock, ContactSet, NodeStatus, Pose, SurfaceMesh, TouchEvent, Trajectory

ALL_TYPES = sorted(REGISTRY)


# --- building valid examples generically from the FieldSpecs -----------------------------------------


def _scalar(spec: FieldSpec, rng: np.random.Generator) -> Any:
    if spec.kind == "int":
        return int(rng.integers(-(2**62), 2**62))
    if spec.kind == "float":
        return float(rng.normal() * 10.0 ** rng.integers(-5, 6))
    if spec.kind == "bool":
        return bool(rng.integers(2))
    return "".join(rng.choice(list("abcxyz_/é0123"), size=int(rng.integers(0, 12))))


def _array(spec: FieldSpec, dims: dict[str, int], rng: np.random.Generator) -> np.ndarray:
    assert spec.shape is not None and spec.dtype is not None
    shape = tuple(d if isinstance(d, int) else dims[d] for d in spec.shape)
    dtype = np.dtype(spec.dtype)
    if dtype.kind == "f":
        return rng.normal(size=shape).astype(dtype)
    return rng.integers(-1000, 1000, size=shape).astype(dtype)


def example(cls: type[Message], rng: np.random.Generator, dims: dict[str, int] | None = None) -> Message:
    """A valid instance of `cls` with random content; named dimensions get lengths from `dims` or 0..5."""
    sizes: dict[str, int] = dict(dims or {})
    values: dict[str, Any] = {}
    for name, spec in cls.field_specs().items():
        for d in spec.shape or ():
            if isinstance(d, str) and d not in sizes:
                sizes[d] = int(rng.integers(0, 6))
        if spec.kind == "array":
            values[name] = _array(spec, sizes, rng)
        elif spec.kind == "str_list":
            length = sizes[spec.shape[0]] if spec.shape and isinstance(spec.shape[0], str) else 2  # type: ignore[index]
            values[name] = [f"s{i}" for i in range(length)]
        else:
            values[name] = _scalar(spec, rng)
    return cls(**values)


def contact_set(n: int = 3) -> ContactSet:
    rng = np.random.default_rng(7)
    return ContactSet(
        stamp_ns=5,
        positions_m=rng.normal(size=(n, 3)),
        local_positions_m=rng.normal(size=(n, 3)),
        normals=rng.normal(size=(n, 3)),
        forces_n=rng.uniform(size=n),
        links=[f"link{i}" for i in range(n)],
    )


def repack(payload: bytes, edit: Any) -> bytes:
    """Decode the envelope with plain msgpack, let `edit(header, blob)` change the header, pack it again."""
    header, blob = msgpack.unpackb(payload, raw=False)
    edit(header, blob)
    return msgpack.packb([header, blob], use_bin_type=True)


def same_bytes(a: Message, b: Message) -> None:
    """Field by field equality, arrays compared bit for bit (so -0.0 and NaN payloads count)."""
    assert type(a) is type(b)
    for name, spec in type(a).field_specs().items():
        x, y = getattr(a, name), getattr(b, name)
        if spec.kind == "array":
            assert x.dtype == y.dtype and x.shape == y.shape, name
            assert x.tobytes() == y.tobytes(), name
        elif spec.kind == "float":
            assert math.copysign(1.0, x) == math.copysign(1.0, y) and (x == y or (x != x and y != y)), name
        else:
            assert x == y, name


# --- round trips ---------------------------------------------------------------------------------------


def test_registry_covers_the_issue_list() -> None:
    wanted = {
        "Clock",
        "JointState",
        "JointCommand",
        "Pose",
        "CartesianVelocityCommand",
        "ContactSet",
        "Trajectory",
        "TouchTarget",
        "SurfaceMesh",
        "OccupancyGrid",
        "ParticleSetSummary",
        "NodeStatus",
    }
    assert wanted <= set(REGISTRY)


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_round_trip_every_message_type(type_name: str) -> None:
    cls = REGISTRY[type_name]
    assert cls.VERSION >= 1 and cls.TOPIC, f"{type_name} needs a version and a default topic"
    rng = np.random.default_rng(sum(type_name.encode()))
    for _ in range(5):
        message = example(cls, rng)
        codec.validate(message)
        payload = codec.encode(message)
        decoded = codec.decode(payload, cls)
        same_bytes(decoded, message)
        assert decoded == message
        assert codec.encode(decoded) == payload  # the encoding is canonical


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_round_trip_with_empty_dimensions(type_name: str) -> None:
    cls = REGISTRY[type_name]
    names = {d for s in cls.field_specs().values() for d in (s.shape or ()) if isinstance(d, str)}
    message = example(cls, np.random.default_rng(0), dict.fromkeys(names, 0))
    same_bytes(codec.decode(codec.encode(message), cls), message)


@st.composite
def messages(draw: st.DrawFn) -> Message:
    """Any message type, random named-dimension lengths and random values (NaN/inf only where allowed)."""
    cls = REGISTRY[draw(st.sampled_from(ALL_TYPES))]
    dims: dict[str, int] = {}
    values: dict[str, Any] = {}
    for name, spec in cls.field_specs().items():
        for d in spec.shape or ():
            if isinstance(d, str) and d not in dims:
                dims[d] = draw(st.integers(0, 7))
        if spec.kind == "array":
            assert spec.shape is not None and spec.dtype is not None
            shape = tuple(d if isinstance(d, int) else dims[d] for d in spec.shape)
            dtype = np.dtype(spec.dtype)
            count = math.prod(shape)
            if dtype.kind == "f":
                elements = st.floats(
                    width=dtype.itemsize * 8, allow_nan=not spec.finite, allow_infinity=not spec.finite
                )
            else:
                info = np.iinfo(dtype)
                elements = st.integers(int(info.min), int(info.max))
            values[name] = np.array(draw(st.lists(elements, min_size=count, max_size=count)), dtype=dtype).reshape(
                shape
            )
        elif spec.kind == "str_list":
            assert spec.shape is not None and isinstance(spec.shape[0], str)
            n = dims[spec.shape[0]]
            values[name] = draw(st.lists(st.text(max_size=8), min_size=n, max_size=n))
        elif spec.kind == "int":
            values[name] = draw(st.integers(-(2**63), 2**63 - 1))
        elif spec.kind == "float":
            values[name] = draw(st.floats(allow_nan=not spec.finite, allow_infinity=not spec.finite))
        elif spec.kind == "bool":
            values[name] = draw(st.booleans())
        else:
            values[name] = draw(st.text(max_size=20))
    return cls(**values)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages())
def test_property_random_messages_round_trip_exactly(message: Message) -> None:
    payload = codec.encode(message)
    decoded = codec.decode(payload, type(message))
    same_bytes(decoded, message)
    assert codec.encode(decoded) == payload


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_property_mutated_payloads_only_raise_message_errors(data: st.DataObject) -> None:
    """Flipping, cutting or extending a valid payload never raises anything but a MessageError."""
    cls = REGISTRY[data.draw(st.sampled_from(ALL_TYPES))]
    payload = bytearray(codec.encode(example(cls, np.random.default_rng(data.draw(st.integers(0, 99))))))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(payload)))
    payload = payload[:cut] + data.draw(st.binary(max_size=4))
    try:
        decoded = codec.decode(bytes(payload))
    except MessageError:
        return
    assert isinstance(decoded, Message)


# --- zero copy -----------------------------------------------------------------------------------------


def test_decoded_arrays_are_read_only_views_on_the_payload() -> None:
    payload = codec.encode(contact_set(4))
    decoded = codec.decode(payload, ContactSet)
    raw = np.frombuffer(payload, dtype=np.uint8)
    for name in ("positions_m", "local_positions_m", "normals", "forces_n"):
        arr = getattr(decoded, name)
        assert np.shares_memory(arr, raw), f"{name} was copied"
        assert not arr.flags.writeable
    header, _ = msgpack.unpackb(payload, raw=False)
    offsets = [f["offset"] for f in header["fields"].values() if isinstance(f, dict)]
    assert len(offsets) == 4 and all(o % 8 == 0 for o in offsets)  # each array starts 8-byte aligned in the blob


def test_decoding_a_writable_buffer_is_zero_copy_too() -> None:
    payload = bytearray(codec.encode(contact_set(2)))
    decoded = codec.decode(payload, ContactSet)
    before = float(decoded.forces_n[0])
    start = payload.index(np.float64(before).tobytes())
    payload[start : start + 8] = np.float64(123.5).tobytes()
    assert decoded.forces_n[0] == 123.5  # the array sees the buffer change: no copy was made


# --- named errors --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "payload",
    [b"", b"\x00", b"\x92", b"\xc1", b"hello world", b"\x91\x80", b"\x93\x80\xc4\x00\x00", b"\x92\x80\xc4\x00"],
)
def test_malformed_bytes_raise_malformed_message_error(payload: bytes) -> None:
    with pytest.raises(MalformedMessageError):
        codec.decode(payload)


def test_every_truncation_of_a_payload_is_rejected() -> None:
    payload = codec.encode(contact_set(3))
    for end in range(len(payload)):
        with pytest.raises(MalformedMessageError):
            codec.decode(payload[:end])
    with pytest.raises(MalformedMessageError, match="blob length"):
        codec.decode(payload + b"\0")


def test_a_header_msgpack_cannot_read_is_named_in_words() -> None:
    """An outside fuzzer: a deep nesting said "payload is not msgpack: " (nothing more), a map key that is
    no string called valid msgpack "not msgpack", and text that is not UTF-8 did not name its field."""
    from palpate.record.mcap_io import peek

    deep = b"\x92" + b"\x91" * 3000 + b"\x01\xc4\x00"
    int_key = msgpack.packb([{1: 2}, b""], use_bin_type=True)
    valid = msgpack.packb([{"type": "Clock", "fields": {"frame_id": "\u00ff"}}, b""], use_bin_type=True)
    bad_text = valid.replace("\u00ff".encode(), b"\xff\xfe")
    miscounted = codec.encode(Clock(stamp_ns=0, tick=0, period_ns=1, lockstep=True))
    miscounted = miscounted[:1] + b"\x82" + miscounted[2:]  # the header declares 2 of its 3 entries
    appended = codec.encode(Clock(stamp_ns=0, tick=0, period_ns=1, lockstep=True)) + b"\n"
    for payload, extra in ((miscounted, 40), (appended, 1)):  # an outside driver's NodeStatus: "not msgpack"
        with pytest.raises(MalformedMessageError) as info:
            peek(payload)
        assert str(info.value) == (
            f"payload goes on for {extra} bytes after its [header, blob] array ends: bytes appended to it, or a "
            "map or array in it that declares fewer items than it holds"
        )
    cases = [
        (deep, "payload's header nests deeper than msgpack reads (no message nests that deep)"),
        (int_key, "a map in the header has a key that is not a string (int): a message's keys are strings"),
        (bad_text, "a string in the header at fields.frame_id is not UTF-8 (invalid start byte)"),
    ]
    for payload, message in cases:
        for read in (codec.decode, peek):  # the recorder's look at a payload says the same
            with pytest.raises(MalformedMessageError) as info:
                read(payload)
            assert str(info.value) == message


def test_header_that_is_not_an_envelope() -> None:
    with pytest.raises(MalformedMessageError, match="header must be a map"):
        codec.decode(msgpack.packb([{"type": "Clock"}, b""], use_bin_type=True))
    with pytest.raises(MalformedMessageError, match="header must be a map"):
        codec.decode(msgpack.packb([[1, 2], b""], use_bin_type=True))


def test_unknown_type() -> None:
    payload = repack(codec.encode(contact_set()), lambda h, b: h.update(type="Banana"))
    with pytest.raises(UnknownMessageTypeError, match="Banana"):
        codec.decode(payload)


def test_wrong_version_raises_schema_version_error() -> None:
    payload = repack(codec.encode(contact_set()), lambda h, b: h.update(version=ContactSet.VERSION + 1))
    with pytest.raises(SchemaVersionError, match=r"ContactSet has schema version 2; this build speaks version 1"):
        codec.decode(payload, ContactSet)


def test_a_version_or_an_array_size_that_is_not_an_int_is_rejected() -> None:
    """msgpack's true and 1.0 equal 1 in Python; the wire says int (an outside fuzzer sent them)."""
    for version in (True, 1.0):
        payload = repack(codec.encode(contact_set()), lambda h, b, v=version: h.update(version=v))
        with pytest.raises(MalformedMessageError, match=f"'version' must be a msgpack int, got .* {version!r}"):
            codec.decode(payload, ContactSet)

    def bool_shape(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["forces_n"]["shape"] = [True]
        header["fields"]["forces_n"]["nbytes"] = 8
        header["fields"]["positions_m"]["shape"] = [1, 3]  # the named dimension n agrees
        header["fields"]["local_positions_m"]["shape"] = [1, 3]
        header["fields"]["normals"]["shape"] = [1, 3]
        for name in ("positions_m", "local_positions_m", "normals"):
            header["fields"][name]["nbytes"] = 24
        header["fields"]["links"] = ["tip"]

    with pytest.raises(MalformedMessageError, match=r"ContactSet.forces_n: shape must be a list of non-negative ints"):
        codec.decode(repack(codec.encode(contact_set(3)), bool_shape))

    def float_nbytes(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["forces_n"]["nbytes"] = float(header["fields"]["forces_n"]["nbytes"])

    with pytest.raises(MalformedMessageError, match=r"ContactSet.forces_n: data range"):
        codec.decode(repack(codec.encode(contact_set(3)), float_nbytes))


def test_an_int_beyond_the_signed_64_bit_range_is_rejected() -> None:
    for stamp in (1 << 63, (1 << 64) - 1):
        payload = repack(codec.encode(contact_set()), lambda h, b, v=stamp: h["fields"].update(stamp_ns=v))
        with pytest.raises(MalformedMessageError, match=r"ContactSet.stamp_ns must be in the signed 64-bit range"):
            codec.decode(payload)
    payload = repack(codec.encode(contact_set()), lambda h, b: h["fields"].update(stamp_ns=(1 << 63) - 1))
    assert codec.decode(payload).stamp_ns == (1 << 63) - 1


def test_other_type_than_expected() -> None:
    with pytest.raises(MalformedMessageError, match="expected a Pose message, got ContactSet"):
        codec.decode(codec.encode(contact_set()), Pose)


def test_missing_and_extra_fields() -> None:
    payload = repack(codec.encode(contact_set()), lambda h, b: h["fields"].pop("links"))
    with pytest.raises(MalformedMessageError, match=r"missing fields \['links'\]"):
        codec.decode(payload)
    payload = repack(codec.encode(contact_set()), lambda h, b: h["fields"].update(extra=1))
    with pytest.raises(MalformedMessageError, match=r"unknown fields \['extra'\]"):
        codec.decode(payload)


def test_wrong_scalar_type() -> None:
    payload = repack(codec.encode(contact_set()), lambda h, b: h["fields"].update(stamp_ns="now"))
    with pytest.raises(MalformedMessageError, match=r"ContactSet.stamp_ns must be int, got str"):
        codec.decode(payload)
    payload = repack(codec.encode(contact_set()), lambda h, b: h["fields"].update(stamp_ns=True))
    with pytest.raises(MalformedMessageError, match=r"ContactSet.stamp_ns must be int, got bool"):
        codec.decode(payload)
    payload = repack(codec.encode(contact_set()), lambda h, b: h["fields"].update(links=["a", 3, "c"]))
    with pytest.raises(MalformedMessageError, match=r"ContactSet.links must be a list of strings"):
        codec.decode(payload)


def test_wrong_dtype() -> None:
    def to_float32(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["forces_n"]["dtype"] = "<f4"
        header["fields"]["forces_n"]["nbytes"] //= 2

    with pytest.raises(MalformedMessageError, match=r"ContactSet.forces_n must have dtype <f8, got '<f4'"):
        codec.decode(repack(codec.encode(contact_set()), to_float32))


def test_wrong_fixed_shape() -> None:
    def flat(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["positions_m"]["shape"] = [9]

    with pytest.raises(MalformedMessageError, match=r"ContactSet.positions_m must have shape \(n, 3\), got \(9,\)"):
        codec.decode(repack(codec.encode(contact_set(3)), flat))

    def three_by_two(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["positions_m"]["shape"] = [3, 2]
        header["fields"]["positions_m"]["nbytes"] = 48

    with pytest.raises(MalformedMessageError, match=r"must have shape \(n, 3\), got \(3, 2\)"):
        codec.decode(repack(codec.encode(contact_set(3)), three_by_two))


def test_array_range_outside_the_blob() -> None:
    def past_end(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["forces_n"]["offset"] = len(blob) - 8

    with pytest.raises(MalformedMessageError, match=r"ContactSet.forces_n: data range .* is not in the blob"):
        codec.decode(repack(codec.encode(contact_set(3)), past_end))

    def lying_nbytes(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["forces_n"]["nbytes"] = 16

    # an outside audit: this was called "not in the blob", although the blob holds it
    with pytest.raises(MalformedMessageError, match=r"ContactSet.forces_n: nbytes=16 does not match shape \(3,\) of"):
        codec.decode(repack(codec.encode(contact_set(3)), lying_nbytes))


def test_mismatched_named_dimensions() -> None:
    # forces_n claims 2 contacts while positions_m has 3 (its bytes stay inside the blob)
    def shorter(header: dict[str, Any], blob: bytes) -> None:
        header["fields"]["forces_n"]["shape"] = [2]
        header["fields"]["forces_n"]["nbytes"] = 16

    with pytest.raises(
        MalformedMessageError, match=r"ContactSet: forces_n has 2 entries along 'n' but positions_m has 3"
    ):
        codec.decode(repack(codec.encode(contact_set(3)), shorter))
    # a string list tied to the same dimension
    with pytest.raises(MalformedMessageError, match=r"links has 2 entries along 'n' but positions_m has 3"):
        codec.decode(repack(codec.encode(contact_set(3)), lambda h, b: h["fields"].update(links=["a", "b"])))
    # and before sending
    bad = ContactSet(
        stamp_ns=0,
        positions_m=np.zeros((3, 3)),
        local_positions_m=np.zeros((3, 3)),
        normals=np.zeros((3, 3)),
        forces_n=np.zeros(4),
        links=["a", "b", "c"],
    )
    with pytest.raises(MalformedMessageError, match=r"forces_n has 4 entries along 'n' but positions_m has 3"):
        codec.validate(bad)


def test_validate_rejects_wrong_fixed_shape() -> None:
    bad = Pose(
        stamp_ns=0,
        frame="tip",
        position_m=np.zeros(2),
        quaternion_wxyz=np.array([1.0, 0, 0, 0]),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )
    with pytest.raises(MalformedMessageError, match=r"Pose.position_m must have shape \(3\), got \(2,\)"):
        codec.validate(bad)


def _with_nan(message: ContactSet) -> ContactSet:
    positions = np.array(message.positions_m)
    positions[1, 2] = np.nan
    return ContactSet(
        stamp_ns=message.stamp_ns,
        positions_m=positions,
        local_positions_m=message.local_positions_m,
        normals=message.normals,
        forces_n=message.forces_n,
        links=message.links,
    )


def test_nan_in_a_finite_field_is_rejected_with_the_field_name() -> None:
    bad = _with_nan(contact_set(3))
    with pytest.raises(NonFiniteError, match=r"ContactSet\.positions_m must be finite"):
        codec.validate(bad)
    payload = codec.encode(bad)  # encode does not validate: a faulty driver can send this
    with pytest.raises(NonFiniteError, match=r"ContactSet\.positions_m must be finite"):
        codec.decode(payload, ContactSet)


def test_infinity_in_a_finite_scalar_is_rejected_with_the_field_name() -> None:
    trajectory = example(Trajectory, np.random.default_rng(1))
    payload = repack(codec.encode(trajectory), lambda h, b: h["fields"].update(length_m=float("inf")))
    with pytest.raises(NonFiniteError, match=r"Trajectory\.length_m must be finite, got inf"):
        codec.decode(payload, Trajectory)


def test_nan_is_allowed_where_the_schema_says_finite_false() -> None:
    assert not TouchEvent.field_specs()["predicted_contact_m"].finite
    first_touch = example(TouchEvent, np.random.default_rng(2))
    first_touch = TouchEvent(
        **{name: getattr(first_touch, name) for name in TouchEvent.field_specs()}
        | {"predicted_contact_m": np.full(3, np.nan)}
    )
    codec.validate(first_touch)
    decoded = codec.decode(codec.encode(first_touch), TouchEvent)
    assert np.isnan(decoded.predicted_contact_m).all()
    status = NodeStatus(
        stamp_ns=0,
        node="n",
        state="running",
        message="",
        counter_names=[],
        counter_values=np.zeros(0, np.int64),
        metric_names=["ratio"],
        metric_values=np.array([np.inf]),
    )
    assert codec.decode(codec.encode(status), NodeStatus).metric_values[0] == np.inf


def test_message_type_lookup() -> None:
    assert codec.message_type("ContactSet") is ContactSet
    with pytest.raises(UnknownMessageTypeError, match="unknown message type 'Nope'"):
        codec.message_type("Nope")


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages())
def test_property_fast_and_checked_decoding_paths_agree(message: Message) -> None:
    """The codec's fast path and its checked path (which names faults) build identical messages."""
    payload = codec.encode(message)
    header, blob = msgpack.unpackb(payload, raw=False)
    checked = codec._build_checked(type(message), header["fields"], memoryview(blob))
    same_bytes(checked, codec.decode(payload))
    same_bytes(checked, message)


# --- transfer: what the in-process executor delivers -------------------------------------------------


def _same_as_received(sent: Message, got: Message) -> None:
    """`got` is what a subscriber decodes from `sent`: equal bits, the same Python types, arrays read-only."""
    expected = codec.decode(codec.encode(sent), type(sent))
    same_bytes(got, expected)
    for name, spec in type(sent).field_specs().items():
        x, y = getattr(got, name), getattr(expected, name)
        assert type(x) is type(y), name
        if spec.kind == "array":
            assert not x.flags.writeable and x.flags.c_contiguous, name
            with pytest.raises(ValueError):
                x.flags.writeable = True  # a view of immutable bytes: nobody can change what was sent
        elif spec.kind == "str_list":
            assert x is not getattr(sent, name), name


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages())
def test_property_transfer_delivers_what_decoding_the_payload_does(message: Message) -> None:
    _same_as_received(message, codec.transfer(message))


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_transfer_of_received_arrays_shares_them_and_of_sent_arrays_copies_them(type_name: str) -> None:
    cls = REGISTRY[type_name]
    message = example(cls, np.random.default_rng(3), {d: 2 for d in "nmkjv"})
    first = codec.transfer(message)
    _same_as_received(message, first)
    again = codec.transfer(first)  # republished unchanged: no copy
    received = codec.decode(codec.encode(message), cls)
    for name, spec in cls.field_specs().items():
        if spec.kind == "array":
            assert getattr(first, name) is not getattr(message, name)
            assert getattr(again, name) is getattr(first, name)
            # a received array is a view of the socket's buffer, not of bytes: copied (its buffer is reused)
            if getattr(received, name).size:
                assert not np.shares_memory(codec.transfer(received).__dict__[name], getattr(received, name))


def test_transfer_raises_the_codecs_errors() -> None:
    with pytest.raises(NonFiniteError):
        codec.transfer(
            Pose(
                stamp_ns=1,
                frame="f",
                position_m=np.array([np.nan, 0.0, 0.0]),
                quaternion_wxyz=np.array([1.0, 0, 0, 0]),
                linear_velocity_m_s=np.zeros(3),
                angular_velocity_rad_s=np.zeros(3),
            )
        )
    bad = contact_set(3)
    object.__setattr__(bad, "forces_n", np.ones(2))  # disagrees with n = 3
    with pytest.raises(MalformedMessageError):
        codec.transfer(bad)
    odd = contact_set(2)
    object.__setattr__(odd, "stamp_ns", 5.0)  # a float in an int field
    with pytest.raises(MessageError):
        codec.transfer(odd)


# --- faults a foreign encoder can send, each named ----------------------------


def test_an_older_schema_version_is_refused_too() -> None:
    payload = repack(codec.encode(contact_set()), lambda h, b: h.update(version=ContactSet.VERSION - 1))
    with pytest.raises(SchemaVersionError, match=r"ContactSet has schema version 0; versions count from 1$"):
        codec.decode(payload, ContactSet)  # no side to upgrade (an outside audit: "upgrade the older side")
    payload = repack(codec.encode(contact_set()), lambda h, b: h.update(version=-1))
    with pytest.raises(SchemaVersionError, match=r"ContactSet has schema version -1; versions count from 1$"):
        codec.decode(payload, ContactSet)


def test_fields_that_are_not_a_map_are_named() -> None:
    payload = repack(codec.encode(contact_set()), lambda h, b: h.update(fields=[1, 2]))
    with pytest.raises(MalformedMessageError, match=r"^ContactSet: 'fields' must be a map$"):
        codec.decode(payload)


def test_an_array_map_without_one_of_its_keys_is_named() -> None:
    for key in ("dtype", "shape", "offset", "nbytes"):
        payload = repack(codec.encode(contact_set()), lambda h, b, k=key: h["fields"]["forces_n"].pop(k))
        with pytest.raises(
            MalformedMessageError, match=r"ContactSet.forces_n must be an array map with dtype, shape, offset, nbytes"
        ):
            codec.decode(payload)


def test_a_negative_array_offset_is_outside_the_blob() -> None:
    payload = repack(codec.encode(contact_set(3)), lambda h, b: h["fields"]["positions_m"].update(offset=-8))
    with pytest.raises(MalformedMessageError, match=r"ContactSet.positions_m: data range offset=-8 nbytes=72 is not"):
        codec.decode(payload)


def test_a_payload_of_three_items_is_not_an_envelope() -> None:
    header, blob = msgpack.unpackb(codec.encode(contact_set()), raw=False)
    with pytest.raises(MalformedMessageError, match=r"payload is not a 2-item msgpack array \[header, blob\]"):
        codec.decode(msgpack.packb([header, blob, b""], use_bin_type=True))


def test_every_array_starts_at_a_multiple_of_8_bytes_of_the_blob() -> None:
    """The wire contract (docs/messages.md): a decoder in another language may read each array in place.
    An int32 array of an odd length is followed by padding."""
    mesh = SurfaceMesh(
        stamp_ns=0,
        region="global",
        num_contacts=1,
        vertices_m=np.zeros((3, 3)),
        faces=np.array([[0, 1, 2]], np.int32),  # 12 bytes
        vertex_normals=np.ones((3, 3)),
        variance_vertices=np.arange(3, dtype=np.int32),  # 12 bytes
        vertex_variance=np.full(3, 0.5),
    )
    header, blob = msgpack.unpackb(codec.encode(mesh), raw=False)
    offsets = {name: value["offset"] for name, value in header["fields"].items() if isinstance(value, dict)}
    assert offsets == {
        "vertices_m": 0,
        "faces": 72,
        "vertex_normals": 88,
        "variance_vertices": 160,
        "vertex_variance": 176,
    }
    assert len(blob) == 176 + 24 and blob[84:88] == b"\0" * 4  # zero padding after the faces
    assert codec.decode(codec.encode(mesh)) == mesh


def test_a_big_message_whose_type_name_has_32_characters_round_trips() -> None:
    """32 bytes is one past msgpack's fixstr: the header that aligns a big blob is not widened then."""

    class LongNamedMessage(Message):
        TYPE: ClassVar[str] = "X" * 32
        VERSION: ClassVar[int] = 1
        values: np.ndarray = array(("n",), "float64", "values")

    try:
        message = LongNamedMessage(stamp_ns=1, values=np.arange(2000.0))  # a 16 KB blob
        decoded = codec.decode(codec.encode(message), LongNamedMessage)
        assert type(decoded) is LongNamedMessage and decoded == message
    finally:
        del REGISTRY[LongNamedMessage.TYPE]


# --- transfer refuses what decoding the payload refuses ------------------------


def test_transfer_refuses_an_infinite_float_field_naming_it() -> None:
    trajectory = example(Trajectory, np.random.default_rng(1))
    object.__setattr__(trajectory, "length_m", math.inf)
    with pytest.raises(NonFiniteError, match=r"Trajectory\.length_m must be finite, got inf"):
        codec.transfer(trajectory)


def test_field_names_sent_as_bytes_beside_strings_are_named_unknown() -> None:
    """An encoder that sends some keys as msgpack bin (bytes) and others as str: the keys do not sort
    together, and the error still names them (it raised TypeError)."""
    fields = {"stamp_ns": 1, b"tick": 0, "period_ns": 1, "lockstep": True, b"x": 1, "y": 2}
    payload = b"\x92" + msgpack.packb({"type": "Clock", "version": 1, "fields": fields}) + msgpack.packb(b"")
    with pytest.raises(
        MalformedMessageError, match=r"Clock: missing fields \['tick'\], unknown fields \['y', b'tick', b'x'\]"
    ):
        codec.decode(payload)


@pytest.mark.parametrize("stamp", [1 << 63, -(1 << 63) - 1, 1 << 64])
def test_an_int_beyond_64_bits_is_refused_before_it_is_sent(stamp: int) -> None:
    """The wire's ints are signed 64-bit: a node's check before sending (validate) and the in-process
    executor (transfer) refuse by name what decoding the payload refuses (msgpack cannot even pack 2**64)."""
    clock = Clock(stamp_ns=stamp, tick=0, period_ns=1, lockstep=True)
    for check in (codec.validate, codec.transfer):
        with pytest.raises(
            MalformedMessageError, match=rf"Clock\.stamp_ns must be in the signed 64-bit range, got {stamp}"
        ):
            check(clock)
    edges = Clock(stamp_ns=(1 << 63) - 1, tick=-(1 << 63), period_ns=1, lockstep=True)
    codec.validate(edges)
    assert codec.transfer(edges) == codec.decode(codec.encode(edges)) == edges


def test_transfer_refuses_a_string_list_holding_another_type() -> None:
    bad = contact_set(3)
    object.__setattr__(bad, "links", ["a", 3, "c"])
    with pytest.raises(MalformedMessageError, match=r"ContactSet\.links must be a list of strings"):
        codec.transfer(bad)


def test_transfer_delivers_a_transposed_received_array_c_ordered() -> None:
    """A received array transposed (a read-only view of the same bytes, not C-ordered) is copied into
    C order, as decoding its payload would deliver it."""
    received = codec.transfer(contact_set(3))
    transposed = received.positions_m.T
    assert not transposed.flags.c_contiguous and not transposed.flags.writeable
    message = ContactSet(
        stamp_ns=1,
        positions_m=transposed,
        local_positions_m=received.local_positions_m,
        normals=received.normals,
        forces_n=received.forces_n,
        links=received.links,
    )
    got = codec.transfer(message)
    _same_as_received(message, got)
    np.testing.assert_array_equal(got.positions_m, transposed)


def test_arrays_that_are_not_c_ordered_are_sent_in_c_order() -> None:
    grid = np.arange(12.0).reshape(3, 4)
    message = contact_set(3)
    object.__setattr__(message, "positions_m", grid[:, :3])  # a slice: rows 32 bytes apart
    object.__setattr__(message, "normals", np.asfortranarray(grid[:, 1:]))
    decoded = codec.decode(codec.encode(message), ContactSet)
    np.testing.assert_array_equal(decoded.positions_m, grid[:, :3])
    np.testing.assert_array_equal(decoded.normals, grid[:, 1:])
