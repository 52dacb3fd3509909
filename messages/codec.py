"""The one codec: messages to msgpack payloads and back, validated against the schemas.

Wire format of a payload (one ZeroMQ frame, after the topic frame) -- a msgpack array of two items:

    [ {"type": str, "version": int, "fields": {name: value, ...}},  blob: bin ]

Scalars and string lists are plain msgpack values. An array field is the map
``{"dtype": "<f8", "shape": [n, 3], "offset": int, "nbytes": int}`` pointing into ``blob``, which
holds the raw C-order bytes of every array, each starting at a multiple of 8 bytes. A decoder in any
language reads the header, then slices the blob; this Python decoder maps the arrays onto the
received buffer without copying (they are read-only).

The encoder writes canonical (smallest) msgpack, except that a header in front of a blob of 8 KiB
or more is widened by up to 7 bytes (map 16, str 8/16, uint 8/16/32 where a shorter form would do)
so that the blob starts at a multiple of 8 bytes of the payload: such payloads arrive in 8-aligned
buffers, so their arrays are aligned in memory, which numpy reads faster. Decoders see the same values.

Speed: each message class is compiled once into a `_Plan` (dtype objects, fixed axes, named
dimensions). Decoding first tries a fast path that only accepts well-formed fields; anything it does
not accept goes through the checked path (`_build_checked`), which raises the named error. So the
fast path changes timings, never results or error messages (tests/unit/messages checks both paths).
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
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
_PADDING = [b"\0" * n for n in range(_ALIGN)]
_SCALAR_TYPES: dict[str, tuple[type, ...]] = {
    "int": (int,),
    "float": (float, int),
    "str": (str,),
    "bool": (bool,),
}
_EXACT_TYPE: dict[str, type] = {"int": int, "str": str, "bool": bool}
_FLOAT64 = np.dtype("<f8")
_INT64_MIN, _INT64_MAX = -(1 << 63), (1 << 63) - 1  # the wire's int fields (docs/messages.md)
_SMALL_ARRAY = 32  # float arrays up to this many elements are checked for finiteness in Python
_HEADER_KEYS = frozenset({"type", "version", "fields"})
_SMALL_PAYLOAD = 16384  # decode parses payloads up to this size in one msgpack call (copying the blob)
_BIN_MARKERS = {1: 0xC4, 2: 0xC5, 4: 0xC6}  # msgpack bin 8, 16, 32 by width of the length
_ALIGN_BLOB_BYTES = 8192  # blobs from this size on start 8-aligned in the payload (see _aligned_header)
# Extra header bytes -> (widen the map by 2, widen the type name by 0/1/2, widen the version by 0/1/2/4).
_WIDENINGS = {
    0: (0, 0, 0),
    1: (0, 0, 1),
    2: (0, 0, 2),
    3: (0, 1, 2),
    4: (0, 0, 4),
    5: (0, 1, 4),
    6: (0, 2, 4),
    7: (2, 1, 4),
}
_STR_HEADERS: dict[int, Callable[[int], bytes]] = {
    0: lambda n: bytes([0xA0 | n]),  # fixstr
    1: lambda n: struct.pack(">BB", 0xD9, n),  # str 8
    2: lambda n: struct.pack(">BH", 0xDA, n),  # str 16
}
_UINT_CODES: dict[int, Callable[[int], bytes]] = {
    0: lambda v: bytes([v]),  # positive fixint
    1: lambda v: struct.pack(">BB", 0xCC, v),  # uint 8
    2: lambda v: struct.pack(">BH", 0xCD, v),  # uint 16
    4: lambda v: struct.pack(">BI", 0xCE, v),  # uint 32
}


@dataclass(frozen=True, slots=True)
class _FieldPlan:
    """One field, precompiled: its spec and, for arrays, the numpy dtype and the fixed axes."""

    name: str
    kind: str
    spec: FieldSpec
    where: str  # "Type.field", for error messages
    dtype: np.dtype[Any] | None = None
    ndim: int = 0
    fixed: tuple[tuple[int, int], ...] = ()  # (axis, length) of every fixed-length axis
    check_finite: bool = False  # floats: spec.finite; arrays: spec.finite and a floating dtype
    finite: bool = False  # spec.finite
    wire_dtype: str = ""  # arrays: spec.dtype, the dtype string on the wire
    itemsize: int = 0  # arrays: bytes per element


@dataclass(frozen=True, slots=True)
class _Plan:
    """What the codec needs to know about a message class, computed once per class."""

    fields: tuple[_FieldPlan, ...]
    names: frozenset[str]
    # For every named dimension: the (field, axis) pairs that share it; axis -1 means len(string list).
    dims: tuple[tuple[tuple[str, int], ...], ...]
    plain_init: bool  # the dataclass __init__ only stores the fields (no __post_init__)
    float64_blob: bool  # every array field is float64 and must be finite


_PLANS: dict[type[Message], _Plan] = {}


def _plan_of(cls: type[Message]) -> _Plan:
    plan = _PLANS.get(cls)
    if plan is None:
        plan = _PLANS[cls] = _compile(cls)
    return plan


def _compile(cls: type[Message]) -> _Plan:
    fields = []
    members: dict[str, list[tuple[str, int]]] = {}
    for name, spec in cls.field_specs().items():
        where = f"{cls.TYPE}.{name}"
        if spec.kind == "array":
            assert spec.dtype is not None and spec.shape is not None
            dtype = np.dtype(spec.dtype)
            fixed = tuple((axis, want) for axis, want in enumerate(spec.shape) if isinstance(want, int))
            check = spec.finite and dtype.kind == "f"
            fields.append(
                _FieldPlan(
                    name,
                    spec.kind,
                    spec,
                    where,
                    dtype,
                    len(spec.shape),
                    fixed,
                    check,
                    spec.finite,
                    spec.dtype,
                    dtype.itemsize,
                )
            )
        else:
            check = spec.kind == "float" and spec.finite
            fields.append(_FieldPlan(name, spec.kind, spec, where, check_finite=check, finite=spec.finite))
        for axis, want in enumerate(spec.shape or ()):
            if isinstance(want, str):
                members.setdefault(want, []).append((name, -1 if spec.kind == "str_list" else axis))
    arrays = sum(f.kind == "array" for f in fields)
    init_fields = {f.name for f in dataclasses.fields(cls) if f.init}
    plain_init = not hasattr(cls, "__post_init__") and init_fields == set(cls.field_specs())
    return _Plan(
        fields=tuple(fields),
        names=frozenset(cls.field_specs()),
        dims=tuple(tuple(m) for m in members.values()),
        plain_init=plain_init,
        float64_blob=arrays > 0 and all(f.dtype == _FLOAT64 and f.check_finite for f in fields if f.kind == "array"),
    )


def encode(message: Message) -> bytes:
    """Serialise a message into one payload frame."""
    cls = type(message)
    fields: dict[str, Any] = {}
    chunks: list[Any] = [b"\x92", b"", b""]  # header and blob header go in slots 1 and 2
    offset = 0
    for f in _plan_of(cls).fields:
        value = getattr(message, f.name)
        kind = f.kind
        if kind == "array":
            arr = np.ascontiguousarray(value, dtype=f.dtype)
            pad = -offset % _ALIGN
            if pad:
                chunks.append(_PADDING[pad])
                offset += pad
            nbytes = arr.nbytes
            fields[f.name] = {"dtype": arr.dtype.str, "shape": list(arr.shape), "offset": offset, "nbytes": nbytes}
            if nbytes:
                chunks.append(arr)  # C-contiguous: joined through the buffer protocol, one copy
            offset += nbytes
        elif kind == "str_list":
            fields[f.name] = list(value)
        elif kind == "float":
            fields[f.name] = float(value)
        else:
            fields[f.name] = value
    chunks[2] = _bin_header(offset)
    if offset < _ALIGN_BLOB_BYTES:
        chunks[1] = msgpack.packb({"type": cls.TYPE, "version": cls.VERSION, "fields": fields}, use_bin_type=True)
    else:
        chunks[1] = _aligned_header(cls, fields, 1 + len(chunks[2]))
    return b"".join(chunks)


def _aligned_header(cls: type[Message], fields: dict[str, Any], around: int) -> bytes:
    """The header map, its msgpack headers widened so that the blob starts at a multiple of 8 bytes.

    `around` counts the other bytes before the blob (the array marker and the blob's bin header).
    A big payload arrives in a buffer of its own, 8-aligned, so its arrays are then aligned in
    memory, which numpy processes faster. Any msgpack decoder reads a widened header (map 16 for
    fixmap, str 8/16 for fixstr, uint 8/16/32 for a positive fixint) as the same values.
    """
    name = cls.TYPE.encode()
    if len(name) >= 32 or not 0 <= cls.VERSION < 128:  # no fixstr / fixint to widen: leave it
        return msgpack.packb({"type": cls.TYPE, "version": cls.VERSION, "fields": fields}, use_bin_type=True)
    packed_fields = msgpack.packb(fields, use_bin_type=True)
    size = 1 + 5 + 1 + len(name) + 8 + 1 + 7 + len(packed_fields)  # map, "type", name, "version", V, "fields"
    widen_map, widen_name, widen_version = _WIDENINGS[-(size + around) % _ALIGN]
    return b"".join(
        [
            b"\xde\x00\x03" if widen_map else b"\x83",
            b"\xa4type",
            _STR_HEADERS[widen_name](len(name)),
            name,
            b"\xa7version",
            _UINT_CODES[widen_version](cls.VERSION),
            b"\xa6fields",
            packed_fields,
        ]
    )


def decode(payload: bytes | memoryview, expected: type[M] | None = None) -> M:
    """Parse and validate one payload frame; arrays are read-only views onto `payload`.

    Raises a subclass of MessageError (malformed bytes, unknown type, wrong version, wrong shape or
    dtype, a non-finite value in a field that must be finite, or a type other than `expected`).
    """
    view = memoryview(payload).cast("B")
    split = _split_small(view) if len(view) <= _SMALL_PAYLOAD else None
    if split is None:
        header, blob_start = _read_header(view)
        blob = _blob_view(view, blob_start)
    else:
        header, blob = split
    if not (type(header) is dict or isinstance(header, Mapping)) or not header.keys() >= _HEADER_KEYS:
        raise MalformedMessageError("header must be a map with keys 'type', 'version' and 'fields'")
    type_name, version, fields = header["type"], header["version"], header["fields"]
    cls = REGISTRY.get(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise UnknownMessageTypeError(f"unknown message type {type_name!r}; known: {sorted(REGISTRY)}")
    if expected is not None and cls is not expected:
        raise MalformedMessageError(f"expected a {expected.TYPE} message, got {type_name}")
    if type(version) is not int:
        raise MalformedMessageError(
            f"{type_name}: 'version' must be a msgpack int, got {type(version).__name__} {version!r} "
            "(an encoder that sends every number as a float?)"
        )
    if version < 1:
        raise SchemaVersionError(f"{type_name} has schema version {version!r}; versions count from 1")
    if version != cls.VERSION:
        raise SchemaVersionError(
            f"{type_name} has schema version {version!r}; this build speaks version {cls.VERSION}: "
            "upgrade the older side"
        )
    if not (type(fields) is dict or isinstance(fields, Mapping)):
        raise MalformedMessageError(f"{type_name}: 'fields' must be a map")
    return _build(cls, fields, blob)  # type: ignore[return-value]


def transfer(message: M) -> M:
    """What a subscriber of `message` receives, ``decode(encode(message))``, without the bytes.

    For the in-process executor. The same field values of the same types: floats as float, string
    lists as new lists, arrays of the schema's dtype, C-ordered and read-only. Each array is a view of
    an immutable bytes copy, so nobody can change what a subscriber sees; an array that already is
    such a view (received, or transferred before, and published again unchanged) is passed on without
    a copy. Anything the fast path does not accept (a wrong type, shape or dtype, a non-finite value)
    goes through `encode` and `decode`, which raise the named error, so errors are the codec's.
    """
    cls = type(message)
    plan = _plan_of(cls)
    values = _transfer_values(plan, message.__dict__)
    if values is None:
        validate(message)  # a fault encode cannot tell (an int beyond 64 bits) is named here
        return decode(encode(message), cls)
    if plan.plain_init:  # as _build
        out = object.__new__(cls)
        out.__dict__.update(values)
        return out
    return cls(**values)


def _transfer_values(plan: _Plan, fields: Mapping[str, Any]) -> dict[str, Any] | None:
    """Field values for `transfer` when every field is well-formed, else None."""
    values: dict[str, Any] = {}
    value: Any
    total = 0.0  # the elements of the small float arrays that must be finite: see _all_finite
    for f in plan.fields:
        value = fields[f.name]
        kind = f.kind
        if kind == "array":
            value = _immutable_array(f, value)
            if value is None:
                return None
            if f.check_finite and value.size:
                if value.size <= _SMALL_ARRAY:
                    total += sum(value.ravel().tolist())
                elif not _all_finite(value):
                    return None
        elif kind == "float":
            if type(value) is not float and type(value) is not int:
                return None
            value = float(value)
            if f.check_finite and not math.isfinite(value):
                return None
        elif kind == "str_list":
            if type(value) is not list and type(value) is not tuple:
                return None
            for item in value:
                if type(item) is not str:
                    return None
            value = list(value)
        elif type(value) is not _EXACT_TYPE[kind] or (kind == "int" and not _in_int64(value)):
            return None
        values[f.name] = value
    if not math.isfinite(total):  # a NaN or infinity (or finite values that overflow: decode passes them)
        return None
    if plan.dims and not _dims_agree(plan, values):
        return None
    return values


def _in_int64(value: object) -> bool:
    """Whether an int field's value is an int within the wire's signed 64 bits."""
    return isinstance(value, int) and _INT64_MIN <= value <= _INT64_MAX


def _immutable_array(f: _FieldPlan, value: Any) -> np.ndarray | None:
    """`value` as a read-only view of a bytes object (itself when it already is one), or None when it
    does not fit the field (dtype, rank, fixed axes). Finiteness is left to the caller."""
    if type(value) is np.ndarray and value.dtype == f.dtype:
        arr = value if _views_bytes(value) and value.flags.c_contiguous else frozen(value)
    else:
        try:
            arr = frozen(np.ascontiguousarray(value, dtype=f.dtype))  # as encode converts it
        except (TypeError, ValueError):
            return None
    return arr if _shape_fits(f, arr.shape) else None


def frozen(array: np.ndarray) -> np.ndarray:
    """A read-only copy of `array`, C-ordered, over a bytes object (the bytes `encode` writes): nothing
    can change it, so `transfer` passes it on without a copy. For an array a node publishes unchanged
    tick after tick, freeze it once."""
    arr = np.frombuffer(array.tobytes(), array.dtype)
    return arr if array.ndim == 1 else arr.reshape(array.shape)


def _views_bytes(arr: np.ndarray) -> bool:
    """True when `arr` is a read-only view of a bytes object (which nothing can change)."""
    base = arr.base
    while type(base) is np.ndarray:
        base = base.base
    return type(base) is bytes and not arr.flags.writeable


def _split_small(view: memoryview) -> tuple[Any, memoryview] | None:
    """Header and blob of a small payload in one msgpack call, or None to take the general path.

    The general path (`_read_header`, `_blob_view`) names the fault of a bad payload; this one only
    accepts a well-formed payload whose blob header has the smallest width (as `encode` writes it),
    which puts the bin marker at a known place before the blob's last byte.
    """
    try:
        top = msgpack.unpackb(view, raw=False)
    except Exception:  # garbage of any kind: the general path raises the named error
        return None
    if type(top) is not list or len(top) != 2 or type(top[1]) is not bytes:
        return None
    length = len(top[1])
    width = 1 if length < 1 << 8 else 2 if length < 1 << 16 else 4
    begin = len(view) - length
    if begin - 1 - width < 0 or view[begin - 1 - width] != _BIN_MARKERS[width]:
        return None
    return top[0], view[begin:]


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
            raise MalformedMessageError(header_error(exc, view)) from exc


def header_error(exc: Exception, view: memoryview) -> str:
    """Why msgpack (raising ``exc``) could not read the header of payload ``view``, in words: it says nothing
    of a nesting too deep, and its own words make valid msgpack that is no message's "not msgpack"."""
    if isinstance(exc, msgpack.StackError):
        return "payload's header nests deeper than msgpack reads (no message nests that deep)"
    if isinstance(exc, UnicodeDecodeError):
        where = _bad_text_path(view)
        return f"a string in the header{' at ' + where if where else ''} is not UTF-8 ({exc.reason})"
    if isinstance(exc, msgpack.ExtraData):
        return (
            f"payload goes on for {len(exc.extra)} bytes after its [header, blob] array ends: bytes appended to it, "
            "or a map or array in it that declares fewer items than it holds"
        )
    if isinstance(exc, ValueError) and "for map key" in str(exc):
        kind = str(exc).split(" is not")[0]
        return f"a map in the header has a key that is not a string ({kind}): a message's keys are strings"
    return f"payload is not msgpack: {exc or type(exc).__name__}"


def _bad_text_path(view: memoryview) -> str:
    """Where the first string that is not UTF-8 lies in the header ("fields.frame_id"), or ""."""
    try:  # bytes that are not UTF-8 come back as lone surrogates, which do not encode
        top = msgpack.unpackb(view, raw=False, strict_map_key=False, unicode_errors="surrogateescape")
    except Exception:
        return ""

    def bad(text: object) -> bool:
        return isinstance(text, str) and not text.isascii() and not _encodes(text)

    def find(value: Any, path: str) -> str:
        items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
        for key, item in items:
            where = f"{path}[{key}]" if isinstance(value, list) else f"{path}.{key!s}".lstrip(".")
            if bad(key):
                return f"{path or 'the top'} (a key)"
            if bad(item):
                return where
            if found := find(item, where):
                return found
        return ""

    return find(top[0], "") if isinstance(top, list) and top else ""


def _encodes(text: str) -> bool:
    try:
        text.encode()
    except UnicodeEncodeError:
        return False
    return True


def _build(cls: type[Message], fields: Mapping[str, Any], blob: memoryview) -> Message:
    plan = _plan_of(cls)
    values = _fast_values(plan, fields, blob) if type(fields) is dict else None
    if values is None:
        return _build_checked(cls, fields, blob)
    if plan.plain_init:  # what the generated frozen __init__ does, without its per-field calls
        message = object.__new__(cls)
        message.__dict__.update(values)
        return message
    return cls(**values)


def _fast_values(plan: _Plan, fields: dict[str, Any], blob: memoryview) -> dict[str, Any] | None:
    """Field values when every field is well-formed, else None (then `_build_checked` names the fault)."""
    if fields.keys() != plan.names:
        return None
    values: dict[str, Any] = {}
    unchecked: list[np.ndarray] = []  # non-empty arrays that must be finite, checked together below
    value: Any
    for f in plan.fields:
        raw = fields[f.name]
        kind = f.kind
        if kind == "array":
            value = _fast_array(f, raw, blob)
            if value is None:
                return None
            if f.check_finite and value.size:
                unchecked.append(value)
        elif kind == "float":
            if type(raw) is not float and type(raw) is not int:
                return None
            value = float(raw)
            if f.check_finite and not math.isfinite(value):
                return None
        elif kind == "str_list":
            if type(raw) is not list:
                return None
            for item in raw:
                if type(item) is not str:
                    return None
            value = raw
        elif kind == "int":
            if type(raw) is not int or not _INT64_MIN <= raw <= _INT64_MAX:
                return None
            value = raw
        elif type(raw) is _EXACT_TYPE[kind]:
            value = raw
        else:
            return None
        values[f.name] = value
    if plan.dims and not _dims_agree(plan, values):
        return None
    # Every array float64 and finite: one test over the whole blob (its padding is zeros) replaces
    # one per array; a blob that holds other bytes fails it and falls back to the arrays.
    if len(unchecked) > 1 and plan.float64_blob and len(blob) % 8 == 0 and _all_finite(np.frombuffer(blob, _FLOAT64)):
        return values
    for arr in unchecked:
        if not _all_finite(arr):
            return None
    return values


def _fast_array(f: _FieldPlan, raw: Any, blob: memoryview) -> np.ndarray | None:
    """The array a well-formed array map points to (a read-only view of `blob`), else None.

    Finiteness is left to the caller.
    """
    if type(raw) is not dict:
        return None
    try:
        dtype, shape, offset, nbytes = raw["dtype"], raw["shape"], raw["offset"], raw["nbytes"]
    except KeyError:
        return None
    if dtype != f.wire_dtype or type(shape) is not list or len(shape) != f.ndim:
        return None
    count = 1
    for d in shape:
        if type(d) is not int or d < 0:
            return None
        count *= d
    for axis, want in f.fixed:
        if shape[axis] != want:
            return None
    if (
        type(offset) is not int
        or type(nbytes) is not int
        or offset < 0
        or nbytes != count * f.itemsize
        or offset + nbytes > len(blob)
    ):
        return None
    arr = np.frombuffer(blob, f.dtype, count, offset)
    return arr if f.ndim == 1 else arr.reshape(shape)


def _all_finite(arr: np.ndarray) -> bool:
    """True when no element is NaN or infinite."""
    # A sum of Python floats is NaN or infinite when any term is (NaN and infinity propagate, and
    # inf - inf is NaN), and cheaper than numpy for a few elements; an overflowing sum of finite
    # terms is settled by the exact test below.
    if arr.dtype.kind == "f" and arr.size <= _SMALL_ARRAY and math.isfinite(sum(arr.ravel().tolist())):
        return True
    return bool(np.isfinite(arr).all())


def _dims_agree(plan: _Plan, values: Mapping[str, Any]) -> bool:
    """Whether fields sharing a named dimension agree on its length (`check_dimensions` names a fault)."""
    for members in plan.dims:
        size = -1
        for name, axis in members:
            value = values[name]
            n = len(value) if axis < 0 else value.shape[axis]
            if size < 0:
                size = n
            elif n != size:
                return False
    return True


def _build_checked(cls: type[Message], fields: Mapping[str, Any], blob: memoryview) -> Message:
    """The checked path: validates field by field and raises the named error of the first fault."""
    specs = cls.field_specs()
    missing = specs.keys() - fields.keys()
    extra = fields.keys() - specs.keys()
    if missing or extra:
        # another encoder's keys may be bytes beside strings (msgpack's bin keys), which do not sort together
        unknown = sorted(extra, key=repr)
        raise MalformedMessageError(f"{cls.TYPE}: missing fields {sorted(missing)}, unknown fields {unknown}")
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
    if type(raw) is int and spec.kind == "int" and not _INT64_MIN <= raw <= _INT64_MAX:
        raise MalformedMessageError(f"{where} must be in the signed 64-bit range, got {raw}")
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
    if not isinstance(shape, list) or not all(type(d) is int and d >= 0 for d in shape):
        raise MalformedMessageError(f"{where}: shape must be a list of non-negative ints")
    assert spec.dtype is not None and spec.shape is not None
    dtype = np.dtype(spec.dtype)
    if len(shape) != len(spec.shape) or any(
        isinstance(want, int) and got != want for want, got in zip(spec.shape, shape, strict=True)
    ):
        raise MalformedMessageError(f"{where} must have shape {_shape_text(spec.shape)}, got {tuple(shape)}")
    count = math.prod(shape)
    if type(nbytes) is int and nbytes != count * dtype.itemsize:
        raise MalformedMessageError(
            f"{where}: nbytes={nbytes!r} does not match shape {tuple(shape)} of {spec.dtype} "
            f"({count * dtype.itemsize} bytes)"
        )
    if type(offset) is not int or type(nbytes) is not int or offset < 0 or offset + nbytes > len(blob):
        raise MalformedMessageError(
            f"{where}: data range offset={offset!r} nbytes={nbytes!r} is not in the blob of {len(blob)} bytes"
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
        raise MalformedMessageError(f"blob length {length} does not match the payload ({len(view) - begin} bytes)")
    return view[begin : begin + length]


def message_type(type_name: str) -> type[Message]:
    """The message class of a wire type name."""
    try:
        return REGISTRY[type_name]
    except KeyError:
        raise UnknownMessageTypeError(f"unknown message type {type_name!r}; known: {sorted(REGISTRY)}") from None


def validate(message: Message) -> None:
    """Check a message built in Python against its schema (shapes and finiteness) before sending.

    The same checks run on receipt; running them before sending keeps NaN from leaving a node.
    """
    cls = type(message)
    plan = _plan_of(cls)
    fields = message.__dict__
    if _surely_valid(plan, fields):
        return
    converted: dict[str, Any] = {}  # array fields that are not ndarrays, as arrays
    for f in plan.fields:
        value = fields[f.name]
        if f.kind == "array":
            arr = value
            if type(arr) is not np.ndarray:
                arr = converted[f.name] = np.asarray(value)
            if not _shape_fits(f, arr.shape):
                raise MalformedMessageError(
                    f"{f.where} must have shape {_shape_text(f.spec.shape or ())}, got {arr.shape}"
                )
            if f.finite and arr.dtype.kind in "fc" and arr.size and not _all_finite(arr):
                raise NonFiniteError(f"{f.where} must be finite, but holds NaN or infinity")
        elif f.check_finite and not math.isfinite(value):
            raise NonFiniteError(f"{f.where} must be finite, got {value}")
        elif f.kind == "int" and type(value) is int and not _in_int64(value):
            raise MalformedMessageError(f"{f.where} must be in the signed 64-bit range, got {value}")
    if not plan.dims:
        return
    values = {**fields, **converted} if converted else fields
    try:
        agree = _dims_agree(plan, values)
    except TypeError:  # a string list that has no length: let check_dimensions report it
        agree = False
    if not agree:
        check_dimensions(cls, values)


def _surely_valid(plan: _Plan, fields: Mapping[str, Any]) -> bool:
    """`validate`'s fast path: True when every field passes (ndarrays of fitting shapes, the small
    float64 ones checked for finiteness by one sum, as in `_all_finite`), False when `validate`
    must check field by field (which raises the first fault, or passes finite values whose sum overflows)."""
    total = 0.0
    for f in plan.fields:
        value = fields[f.name]
        if f.kind == "array":
            if type(value) is not np.ndarray or not _shape_fits(f, value.shape):
                return False
            if f.finite and value.size:
                if value.dtype is _FLOAT64 and value.size <= _SMALL_ARRAY:
                    total += sum(value.ravel().tolist())
                elif value.dtype.kind in "fc" and not _all_finite(value):
                    return False
        elif f.check_finite:
            if type(value) is not float:
                return False
            total += value
        elif f.kind == "int" and type(value) is int and not _in_int64(value):
            return False
    try:
        return math.isfinite(total) and (not plan.dims or _dims_agree(plan, fields))
    except TypeError:  # a string list that has no length
        return False


def _shape_fits(f: _FieldPlan, shape: tuple[int, ...]) -> bool:
    if len(shape) != f.ndim:
        return False
    for axis, want in f.fixed:  # noqa: SIM110 (a loop, not all(generator): runs for every array of every message)
        if shape[axis] != want:
            return False
    return True
