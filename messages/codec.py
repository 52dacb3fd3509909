"""The one codec: messages to msgpack payloads and back, validated against the schemas.

Wire format of a payload (one ZeroMQ frame, after the topic frame) -- a msgpack array of two items:

    [ {"type": str, "version": int, "fields": {name: value, ...}},  blob: bin ]

Scalars and string lists are plain msgpack values. An array field is the map
``{"dtype": "<f8", "shape": [n, 3], "offset": int, "nbytes": int}`` pointing into ``blob``, which
holds the raw C-order bytes of every array, each starting at a multiple of 8 bytes. A decoder in any
language reads the header, then slices the blob; this Python decoder maps the arrays onto the
received buffer without copying (they are read-only).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from typing import Any, TypeVar

import msgpack
import numpy as np

from palpate.errors import (
    MalformedMessageError,
    MessageError,
    NonFiniteError,
    SchemaVersionError,
    UnknownMessageTypeError,
)
from palpate.messages import schemas as _schemas  # noqa: F401  (registers the message types)
from palpate.messages.base import REGISTRY, FieldSpec, Message

M = TypeVar("M", bound=Message)

_ALIGN = 8
_SCALAR_TYPES: dict[str, tuple[type, ...]] = {
    "int": (int,),
    "float": (float, int),
    "str": (str,),
    "bool": (bool,),
}


def encode(message: Message) -> bytes:
    """Serialise a message into one payload frame."""
    cls = type(message)
    fields: dict[str, Any] = {}
    chunks: list[bytes | memoryview] = []
    offset = 0
    for name, spec in cls.field_specs().items():
        value = getattr(message, name)
        if spec.kind == "array":
            arr = np.ascontiguousarray(value, dtype=np.dtype(spec.dtype))
            pad = -offset % _ALIGN
            if pad:
                chunks.append(b"\0" * pad)
                offset += pad
            fields[name] = {
                "dtype": arr.dtype.str,
                "shape": list(arr.shape),
                "offset": offset,
                "nbytes": arr.nbytes,
            }
            chunks.append(arr.reshape(-1).view(np.uint8).data)
            offset += arr.nbytes
        elif spec.kind == "str_list":
            fields[name] = list(value)
        elif spec.kind == "float":
            fields[name] = float(value)
        else:
            fields[name] = value
    header = msgpack.packb({"type": cls.TYPE, "version": cls.VERSION, "fields": fields}, use_bin_type=True)
    return b"".join([b"\x92", header, _bin_header(offset), *chunks])


def decode(payload: bytes | memoryview, expected: type[M] | None = None) -> M:
    """Parse and validate one payload frame; arrays are read-only views onto `payload`.

    Raises a subclass of MessageError (malformed bytes, unknown type, wrong version, wrong shape or
    dtype, a non-finite value in a field that must be finite, or a type other than `expected`).
    """
    view = memoryview(payload).cast("B")
    header, blob_start = _read_header(view)
    blob = _blob_view(view, blob_start)
    if not isinstance(header, Mapping) or not {"type", "version", "fields"} <= header.keys():
        raise MalformedMessageError("header must be a map with keys 'type', 'version' and 'fields'")
    type_name, version, fields = header["type"], header["version"], header["fields"]
    cls = REGISTRY.get(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise UnknownMessageTypeError(f"unknown message type {type_name!r}; known: {sorted(REGISTRY)}")
    if expected is not None and cls is not expected:
        raise MalformedMessageError(f"expected a {expected.TYPE} message, got {type_name}")
    if version != cls.VERSION:
        raise SchemaVersionError(
            f"{type_name} has schema version {version!r}; this build speaks version {cls.VERSION}: "
            "upgrade the older side"
        )
    if not isinstance(fields, Mapping):
        raise MalformedMessageError(f"{type_name}: 'fields' must be a map")
    return _build(cls, fields, blob)  # type: ignore[return-value]


def _read_header(view: memoryview) -> tuple[Any, int]:
    """Unpack the header map, feeding the unpacker only as much of the payload as it needs."""
    fed = 0
    chunk = 4096
    unpacker = msgpack.Unpacker(raw=False, max_buffer_size=len(view) + 16)
    while True:
        try:
            end = min(len(view), fed + chunk)
            unpacker.feed(view[fed:end])
            fed = end
            if unpacker.read_array_header() != 2:
                raise MalformedMessageError("payload is not a 2-item msgpack array [header, blob]")
            return unpacker.unpack(), unpacker.tell()
        except msgpack.OutOfData:
            if fed >= len(view):
                raise MalformedMessageError("payload ends inside the header") from None
            chunk *= 4
            unpacker = msgpack.Unpacker(raw=False, max_buffer_size=len(view) + 16)
            fed = 0
        except MessageError:
            raise
        except Exception as exc:  # msgpack raises several unrelated exception types on garbage
            raise MalformedMessageError(f"payload is not msgpack: {exc}") from exc


def _build(cls: type[Message], fields: Mapping[str, Any], blob: memoryview) -> Message:
    specs = cls.field_specs()
    missing = specs.keys() - fields.keys()
    extra = fields.keys() - specs.keys()
    if missing or extra:
        raise MalformedMessageError(
            f"{cls.TYPE}: missing fields {sorted(missing)}, unknown fields {sorted(extra)}"
        )
    values = {name: _field_value(cls.TYPE, name, spec, fields[name], blob) for name, spec in specs.items()}
    check_dimensions(cls, values)
    return cls(**values)


def _field_value(type_name: str, name: str, spec: FieldSpec, raw: Any, blob: memoryview) -> Any:
    where = f"{type_name}.{name}"
    if spec.kind == "array":
        return _array_value(where, spec, raw, blob)
    if spec.kind == "str_list":
        if not isinstance(raw, list) or not all(isinstance(s, str) for s in raw):
            raise MalformedMessageError(f"{where} must be a list of strings")
        return raw
    if not isinstance(raw, _SCALAR_TYPES[spec.kind]) or (spec.kind != "bool" and isinstance(raw, bool)):
        raise MalformedMessageError(f"{where} must be {spec.kind}, got {type(raw).__name__}")
    if spec.kind == "float":
        raw = float(raw)  # type: ignore[arg-type]
        if spec.finite and not math.isfinite(raw):
            raise NonFiniteError(f"{where} must be finite, got {raw}")
    return raw


def _array_value(where: str, spec: FieldSpec, raw: Any, blob: memoryview) -> np.ndarray:
    if not isinstance(raw, Mapping) or not {"dtype", "shape", "offset", "nbytes"} <= raw.keys():
        raise MalformedMessageError(f"{where} must be an array map with dtype, shape, offset, nbytes")
    if raw["dtype"] != spec.dtype:
        raise MalformedMessageError(f"{where} must have dtype {spec.dtype}, got {raw['dtype']!r}")
    shape, offset, nbytes = raw["shape"], raw["offset"], raw["nbytes"]
    if not isinstance(shape, list) or not all(isinstance(d, int) and d >= 0 for d in shape):
        raise MalformedMessageError(f"{where}: shape must be a list of non-negative ints")
    assert spec.dtype is not None and spec.shape is not None
    dtype = np.dtype(spec.dtype)
    if len(shape) != len(spec.shape) or any(
        isinstance(want, int) and got != want for want, got in zip(spec.shape, shape, strict=True)
    ):
        raise MalformedMessageError(f"{where} must have shape {_shape_text(spec.shape)}, got {tuple(shape)}")
    count = math.prod(shape)
    if (
        not isinstance(offset, int)
        or nbytes != count * dtype.itemsize
        or offset < 0
        or offset + nbytes > len(blob)
    ):
        raise MalformedMessageError(
            f"{where}: data range offset={offset!r} nbytes={nbytes!r} is not in the blob"
        )
    arr = np.frombuffer(blob, dtype=dtype, count=count, offset=offset).reshape(shape)
    if spec.finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise NonFiniteError(f"{where} must be finite, but holds NaN or infinity")
    return arr


def check_dimensions(cls: type[Message], values: Mapping[str, Any]) -> None:
    """Check that fields sharing a named dimension (such as 'n') agree on its length."""
    sizes: dict[str, tuple[str, int]] = {}
    for name, spec in cls.field_specs().items():
        if spec.shape is None:
            continue
        value = values[name]
        actual = (len(value),) if spec.kind == "str_list" else np.shape(value)
        for want, got in zip(spec.shape, actual, strict=False):
            if isinstance(want, str):
                first = sizes.setdefault(want, (name, got))
                if first[1] != got:
                    raise MalformedMessageError(
                        f"{cls.TYPE}: {name} has {got} entries along '{want}' but {first[0]} has {first[1]}"
                    )


def _shape_text(shape: tuple[int | str, ...]) -> str:
    return "(" + ", ".join(str(d) for d in shape) + ")"


def _bin_header(length: int) -> bytes:
    if length < 1 << 8:
        return struct.pack(">BB", 0xC4, length)
    if length < 1 << 16:
        return struct.pack(">BH", 0xC5, length)
    return struct.pack(">BI", 0xC6, length)


def _blob_view(view: memoryview, start: int) -> memoryview:
    """The bytes of the bin object that begins at `start`, without copying."""
    if start >= len(view):
        raise MalformedMessageError("payload ends before the blob")
    marker = view[start]
    sizes = {0xC4: (1, ">B"), 0xC5: (2, ">H"), 0xC6: (4, ">I")}
    if marker not in sizes:
        raise MalformedMessageError("second item of the payload must be a msgpack bin (the array blob)")
    width, fmt = sizes[marker]
    if start + 1 + width > len(view):
        raise MalformedMessageError("truncated blob header")
    (length,) = struct.unpack(fmt, view[start + 1 : start + 1 + width])
    begin = start + 1 + width
    if begin + length != len(view):
        raise MalformedMessageError(
            f"blob length {length} does not match the payload ({len(view) - begin} bytes)"
        )
    return view[begin : begin + length]


def message_type(type_name: str) -> type[Message]:
    """The message class of a wire type name."""
    try:
        return REGISTRY[type_name]
    except KeyError:
        raise UnknownMessageTypeError(
            f"unknown message type {type_name!r}; known: {sorted(REGISTRY)}"
        ) from None


def validate(message: Message) -> None:
    """Check a message built in Python against its schema (shapes and finiteness) before sending.

    The same checks run on receipt; running them before sending keeps NaN from leaving a node.
    """
    cls = type(message)
    values = {}
    for name, spec in cls.field_specs().items():
        value = getattr(message, name)
        where = f"{cls.TYPE}.{name}"
        if spec.kind == "array":
            assert spec.shape is not None
            arr = np.asarray(value)
            if arr.ndim != len(spec.shape) or any(
                isinstance(want, int) and got != want for want, got in zip(spec.shape, arr.shape, strict=True)
            ):
                raise MalformedMessageError(
                    f"{where} must have shape {_shape_text(spec.shape)}, got {arr.shape}"
                )
            if spec.finite and arr.dtype.kind in "fc" and not np.isfinite(arr).all():
                raise NonFiniteError(f"{where} must be finite, but holds NaN or infinity")
            value = arr
        elif spec.kind == "float" and spec.finite and not math.isfinite(value):
            raise NonFiniteError(f"{where} must be finite, got {value}")
        values[name] = value
    check_dimensions(cls, values)
