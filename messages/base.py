"""Message base class and field descriptors.

A message is a frozen, keyword-only dataclass. Its class variables name the wire type, the schema
version and the default topic; each field's metadata says how it travels and what it means, so that
the codec can validate it and `docs/messages.md` can be generated from the schemas alone.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, dataclass_transform

import numpy as np

#: Every message type known to this build, by wire name.
REGISTRY: dict[str, type[Message]] = {}

# A shape entry is an int (fixed length) or a name shared between fields of one message (same length).
Shape = tuple[int | str, ...]


@dataclass(frozen=True)
class FieldSpec:
    """How one field travels: kind, unit, meaning and, for arrays, dtype, shape and finiteness."""

    kind: str  # "int", "float", "str", "bool", "str_list", "array"
    unit: str
    doc: str
    dtype: str | None = None
    shape: Shape | None = None
    finite: bool = False


def scalar(kind: str, doc: str, unit: str = "", *, finite: bool = True, default: Any = dataclasses.MISSING) -> Any:
    """A scalar field (int, float, str or bool)."""
    spec = FieldSpec(kind=kind, unit=unit, doc=doc, finite=finite and kind == "float")
    return field(default=default, metadata={"spec": spec})


def strings(doc: str, length: int | str | None = None) -> Any:
    """A list of strings; `length` ties its length to an array dimension name."""
    shape: Shape | None = None if length is None else (length,)
    return field(metadata={"spec": FieldSpec(kind="str_list", unit="", doc=doc, shape=shape)})


def array(shape: Shape, dtype: str, doc: str, unit: str = "", *, finite: bool = True) -> Any:
    """A numpy array field with a fixed dtype and a shape pattern, finite unless told otherwise."""
    spec = FieldSpec(kind="array", unit=unit, doc=doc, dtype=np.dtype(dtype).str, shape=shape, finite=finite)
    return field(metadata={"spec": spec})


@dataclass_transform(kw_only_default=True, frozen_default=True, field_specifiers=(field, scalar, strings, array))
@dataclass(frozen=True, kw_only=True, eq=False)
class Message:
    """Base of every message. `stamp_ns` is simulated time (or hardware time in real-time mode)."""

    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 0
    TOPIC: ClassVar[str] = ""
    #: True for state (the latest value supersedes older ones): real-time subscribers keep only the latest.
    STATE: ClassVar[bool] = False

    stamp_ns: int = scalar("int", "simulated time of the data, nanoseconds since the start of the run", "ns")

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        dataclass(frozen=True, kw_only=True, eq=False)(cls)
        if cls.TYPE:
            if cls.TYPE in REGISTRY:
                raise TypeError(f"message type {cls.TYPE!r} is defined twice")
            REGISTRY[cls.TYPE] = cls

    @classmethod
    def field_specs(cls) -> dict[str, FieldSpec]:
        """The wire description of every field, in declaration order (computed once per class)."""
        specs = cls.__dict__.get("_field_specs")
        if specs is None:
            specs = {f.name: f.metadata["spec"] for f in dataclasses.fields(cls)}
            cls._field_specs = specs  # type: ignore[attr-defined]
        return specs

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for name, spec in self.field_specs().items():
            a, b = getattr(self, name), getattr(other, name)
            if spec.kind == "array":
                if not np.array_equal(a, b, equal_nan=True):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]
