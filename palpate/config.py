"""One configuration path: YAML mappings in, typed and validated frozen dataclasses out.

Every node config, scene and object description is a dataclass whose fields carry their unit in
their name (``timestep_s``, ``radius_m``) and their constraint in their type::

    @dataclass(frozen=True, kw_only=True)
    class ProbeConfig(Validated):
        radius_m: PositiveFloat = 0.008
        start_position_m: tuple[float, float, float] | None = None  # a position: any sign
        mode: Annotated[str, OneOf(("fast", "exact"))] = "fast"

:func:`load` fills one from a mapping (a launch file's ``params``, a scene section): it rejects
unknown keys (naming the known ones), missing keys, values of the wrong type, NaN and infinity in
every float, and values outside a field's declared :class:`Range`; lists become tuples and ints
become floats where the type says so. :class:`Validated` runs the same checks (without conversion)
when a config is built in Python, so ``PlannerConfig(sigma1_m=-1.0)`` fails too. Checks that involve
several fields (``a < b``) stay in the class's ``__post_init__``. No field allows infinity today;
a length or time is non-negative only because its field says so (positions may be negative).

Every error is a :class:`~palpate.errors.ConfigError` whose message names the key path, the bad
value and what is allowed (``params.scene.object.size_m[0]: expected a finite number > 0, got -0.05``) and
whose ``path`` attribute holds that key path, so that the launcher can prefix the ``file:line`` of
the offending key itself. :func:`load_yaml` does the same for a whole YAML file (the hand
description): its errors start with ``file:line:`` of the offending key (:func:`key_lines`).

Why our own walker (~200 lines) and not pydantic or msgspec (both looked at): the configs are plain frozen
dataclasses used everywhere (tests build them directly, ``dataclasses.replace`` them, compare them);
msgspec validates dataclasses only in ``msgspec.convert`` (so ``PlannerConfig(sigma1_m=-1.0)``
would pass) and pydantic would turn them into its own dataclasses with its own coercion rules (lax
mode reads ``"1"`` as ``1``); neither rejects NaN and infinity in every float by default; their
errors locate values as ``$.scene.object`` or ``("scene", "object")`` with no source line, so the
launcher would map key paths to ``file:line:`` itself all the same. msgspec is not a dependency, and
pydantic is here only as a dependency of a dependency (open3d -> dash). No new dependency, and one
error style with the rest of palpate.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import re
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

import yaml

from palpate.errors import ConfigError

T = TypeVar("T")
V = TypeVar("V")
#: Where a value sits below the root of what was loaded: mapping keys and list indices.
KeyPath = tuple[str | int, ...]


# --- declared constraints ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Range:
    """Bounds of a number field: ``Annotated[float, Range(ge=0.0, le=1.0)]`` (gt/lt: strict)."""

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None

    def admits(self, x: float) -> bool:
        return not (
            (self.ge is not None and not x >= self.ge)
            or (self.gt is not None and not x > self.gt)
            or (self.le is not None and not x <= self.le)
            or (self.lt is not None and not x < self.lt)
        )

    def __str__(self) -> str:
        low = f">= {self.ge:g}" if self.ge is not None else f"> {self.gt:g}" if self.gt is not None else ""
        high = f"<= {self.le:g}" if self.le is not None else f"< {self.lt:g}" if self.lt is not None else ""
        return " and ".join(b for b in (low, high) if b)


@dataclass(frozen=True)
class OneOf:
    """The allowed values of a string field: ``Annotated[str, OneOf(("hand", "finger"))]``."""

    choices: tuple[str, ...]


class _Marker:
    def __init__(self, doc: str) -> None:
        self.__doc__ = doc


#: A list or tuple field that must hold at least one item.
NonEmpty = _Marker("A list or tuple field that must hold at least one item.")
#: YAML null, "" and [] mean "not given": the field keeps its default (launch files pass every argument).
BlankIsDefault = _Marker("YAML null, '' and [] mean 'not given': the field keeps its default.")
#: A single number is read as a one-item tuple (``size_m: 0.03`` means ``size_m: [0.03]``).
ScalarIsTuple = _Marker("A single number is read as a one-item tuple.")

Positive = Range(gt=0.0)
NonNegative = Range(ge=0.0)
Fraction = Range(ge=0.0, le=1.0)
PositiveFloat = Annotated[float, Positive]
NonNegativeFloat = Annotated[float, NonNegative]
PositiveInt = Annotated[int, Range(ge=1)]
NonNegativeInt = Annotated[int, NonNegative]


# --- entry points ------------------------------------------------------------------------------------


def load(cls: type[T], data: Any, where: str = "", path: KeyPath = ()) -> T:
    """Build the dataclass ``cls`` from the mapping ``data``; ConfigError on anything wrong.

    ``where`` names the root in messages (default: the class name), e.g. ``params``, or
    ``node 'sim' params``; ``path`` is the key path of ``data`` below that root.
    """
    if not (dataclasses.is_dataclass(cls) and isinstance(cls, type)):
        raise TypeError(f"{cls!r} is not a dataclass")
    where = where or cls.__name__
    if not isinstance(data, Mapping):
        raise ConfigError(f"{_loc(where, path)}: expected a mapping of keys, got {data!r}", path)
    fields = _fields(cls)
    for key in data:
        if key not in fields:
            known = ", ".join(sorted(fields))
            close = difflib.get_close_matches(str(key), fields, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(
                f"{_loc(where, (*path, key))}: unknown key {key!r}; known keys: {known}{hint}", (*path, key)
            )
    values: dict[str, Any] = {}
    for name, info in fields.items():
        if name in data and not (BlankIsDefault in info.meta and _blank(data[name])):
            values[name] = _value(info.hint, data[name], where, (*path, name), convert=True)
        elif info.required:
            raise ConfigError(f"{_loc(where, path)}: missing required key {name!r} ({_type_name(info.hint)})", path)
    try:
        return cls(**values)
    except ConfigError as exc:  # a check across fields in __post_init__
        full = (*path, *exc.path)
        raise ConfigError(f"{_loc(where, path)}: {exc}", full) from None
    except (TypeError, ValueError, ArithmeticError) as exc:  # ArithmeticError: a check's sum of huge values
        raise ConfigError(f"{_loc(where, path)}: {exc}", path) from exc


class YamlLoader(yaml.SafeLoader):
    """The YAML of palpate's files (launch files, `name:=value`, hand.yaml): YAML 1.1 as PyYAML reads it,
    plus the floats of YAML 1.2 without a dot or an exponent sign (`1e3`, `1.0e400`), which 1.1 reads as
    strings, and without 1.1's octal and base-60 numbers (`010` is 8 and `1:30` is 90 there): those are
    text, which a numeric parameter refuses by name."""


_INT_TAG, _FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
YamlLoader.add_implicit_resolver(
    _FLOAT_TAG, re.compile(r"^[-+]?[0-9][0-9_]*(\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789")
)
for _first, _resolvers in YamlLoader.yaml_implicit_resolvers.items():  # (a copy of SafeLoader's, made above)
    _resolvers[:] = [(tag, rx) for tag, rx in _resolvers if tag not in (_INT_TAG, _FLOAT_TAG) or ":" not in rx.pattern]
YamlLoader.add_implicit_resolver(  # 1.1's ints without the octal (0 then digits) and base-60 forms
    _INT_TAG, re.compile(r"^(?:[-+]?0b[0-1_]+|[-+]?(?:0|[1-9][0-9_]*)|[-+]?0x[0-9a-fA-F_]+)$"), list("-+0123456789")
)
YamlLoader.add_implicit_resolver(  # 1.1's floats without the base-60 form
    _FLOAT_TAG,
    re.compile(
        r"^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+][0-9]+)?|\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
    ),
    list("-+0123456789."),
)


def load_yaml(cls: type[T], text: str, source: str, where: str = "") -> T:
    """Build ``cls`` from the YAML document ``text`` read from ``source`` (a file name, for messages).

    A ConfigError reads ``source:line: where.key.path: ...``, with the line of the offending key.
    """
    loader = YamlLoader(text)
    try:
        node = loader.get_single_node()
        data = None if node is None else loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: invalid YAML: {exc}") from exc
    finally:
        loader.dispose()
    try:
        return load(cls, data, where)
    except ConfigError as exc:
        lines = {} if node is None else key_lines(node)
        line = line_at(lines, exc.path) or (1 if node is None else node.start_mark.line + 1)
        raise ConfigError(f"{source}:{line}: {exc}", exc.path) from None


def key_lines(node: yaml.Node, path: KeyPath = ()) -> dict[KeyPath, int]:
    """The line (from 1) of every mapping key and list item below a composed YAML ``node``, by key path."""
    out: dict[KeyPath, int] = {}
    if isinstance(node, yaml.MappingNode):
        for knode, vnode in node.value:
            key = (*path, str(knode.value))
            out[key] = knode.start_mark.line + 1
            out.update(key_lines(vnode, key))
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            out[(*path, index)] = item.start_mark.line + 1
            out.update(key_lines(item, (*path, index)))
    return out


def line_at(lines: Mapping[KeyPath, V], path: KeyPath) -> V | None:
    """The entry of ``lines`` for the deepest prefix of ``path`` it holds (None if it holds none)."""
    for end in range(len(path), 0, -1):
        if path[:end] in lines:
            return lines[path[:end]]
    return None


def check(obj: Any) -> None:
    """Check every field of the dataclass instance ``obj`` against its declared type and constraints."""
    cls: type = type(obj)
    for name, info in _fields(cls).items():
        _value(info.hint, getattr(obj, name), cls.__name__, (name,), convert=False)


class Validated:
    """Base of config dataclasses: ``__post_init__`` runs :func:`check`. A subclass with checks
    across fields defines its own ``__post_init__`` and calls ``super().__post_init__()`` first."""

    def __post_init__(self) -> None:
        check(self)


# --- the walker --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Field:
    hint: Any
    meta: tuple[Any, ...]
    required: bool


@functools.cache
def _fields(cls: type) -> dict[str, _Field]:
    hints = typing.get_type_hints(cls, include_extras=True)
    out = {}
    for f in dataclasses.fields(cls):
        if f.init:
            required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
            out[f.name] = _Field(hints[f.name], _split(hints[f.name])[1], required)
    return out


def _split(hint: Any) -> tuple[Any, tuple[Any, ...]]:
    """(type, constraints) of a possibly Annotated hint."""
    if typing.get_origin(hint) is Annotated:
        return hint.__origin__, tuple(hint.__metadata__)
    return hint, ()


def _value(hint: Any, value: Any, where: str, path: KeyPath, *, convert: bool, meta: tuple[Any, ...] = ()) -> Any:
    """Check ``value`` against ``hint`` (and constraints); with ``convert``: lists -> tuples, ints -> floats."""
    base, own = _split(hint)
    meta = (*meta, *own)
    origin, args = typing.get_origin(base), typing.get_args(base)

    def fail(expected: str) -> ConfigError:
        return ConfigError(f"{_loc(where, path)}: expected {expected}, got {value!r}", path)

    if base is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        options = [a for a in args if a is not type(None)]
        if value is None and len(options) < len(args):
            return None
        fitting = [o for o in options if _shape(o) == _shape(type(value))]
        if len(options) == 1 or len(fitting) == 1:  # one candidate: its own error says most
            return _value((fitting or options)[0], value, where, path, convert=convert, meta=meta)
        errors = []
        for option in options:
            try:
                return _value(option, value, where, path, convert=convert, meta=meta)
            except ConfigError as exc:
                errors.append((option, exc))
        for option, error in errors:  # a number out of range: the number's own error says most
            kind = {int: numbers.Integral, float: numbers.Real}.get(_split(option)[0])
            if kind is not None and isinstance(value, kind) and not isinstance(value, bool):
                raise error
        raise fail(_type_name(base, values=True))
    if origin is typing.Literal:
        if any(type(value) is type(arg) and value == arg for arg in args):  # True is not the literal 1
            return value
        raise fail(f"one of {list(args)}")
    if base is bool:
        if isinstance(value, bool):
            return value
        raise fail("true or false")
    if base in (int, float):
        kind = numbers.Integral if base is int else numbers.Real
        bounds = [b for b in meta if isinstance(b, Range)]
        what = " ".join(["an integer" if base is int else "a finite number", *map(str, bounds)])
        if isinstance(value, bool) or not isinstance(value, kind):
            raise fail(what)
        try:
            x = base(value)
        except OverflowError:  # an integer too large for a float
            raise fail(what) from None
        if not (math.isfinite(x) and all(b.admits(x) for b in bounds)):
            raise fail(what)
        return x if convert else value
    if base is str:
        if not isinstance(value, str):
            raise fail("a string")
        for choice in meta:
            if isinstance(choice, OneOf) and value not in choice.choices:
                raise fail(f"one of {list(choice.choices)}")
        return value
    if origin in (tuple, list, Sequence):
        if ScalarIsTuple in meta and isinstance(value, numbers.Real) and not isinstance(value, bool):
            value = (value,)
        if isinstance(value, str) or not (isinstance(value, list | tuple) or hasattr(value, "__array__")):
            raise fail("a list")
        items = list(value)
        if NonEmpty in meta and not items:
            raise fail("a non-empty list")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(items) != len(args):
                raise fail(f"{len(args)} items")
            pairs = enumerate(zip(args, items, strict=True))
            out = [_value(a, v, where, (*path, i), convert=convert) for i, (a, v) in pairs]
        else:
            item = args[0] if args else Any
            out = [_value(item, v, where, (*path, i), convert=convert) for i, v in enumerate(items)]
        if not convert:
            return value
        return out if origin is list else tuple(out)
    if origin in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise fail("a mapping")
        key_type, item_type = args if args else (Any, Any)
        out_map = {
            _value(key_type, k, where, path, convert=convert): _value(item_type, v, where, (*path, k), convert=convert)
            for k, v in value.items()
        }
        return out_map if convert else value
    if dataclasses.is_dataclass(base) and isinstance(base, type):
        if isinstance(value, base):
            return value
        if convert and isinstance(value, Mapping):
            return load(base, value, where, path)
        raise fail(f"a mapping of {base.__name__} keys")
    raise TypeError(f"{_loc(where, path)}: a config field of type {hint!r} cannot be read from YAML")


def _shape(hint: Any) -> str:
    """'mapping', 'list' or 'scalar': what YAML node a type reads from."""
    base = _split(hint)[0]
    origin = typing.get_origin(base) or base
    if isinstance(origin, type) and (issubclass(origin, Mapping) or dataclasses.is_dataclass(origin)):
        return "mapping"
    if isinstance(origin, type) and issubclass(origin, list | tuple | Sequence) and not issubclass(origin, str):
        return "list"
    return "scalar"


def _blank(value: Any) -> bool:
    return value is None or (isinstance(value, str | list | tuple) and len(value) == 0)


def dotted(path: KeyPath) -> str:
    """A key path as messages write it: ``long_fingers.ring.lengths_mm[1]``."""
    return _loc("", path).removeprefix(".")


def _loc(where: str, path: KeyPath) -> str:
    return where + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path)


_VALUE_NAMES = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}


def _type_name(hint: Any, *, values: bool = False) -> str:
    """The type's name ("float, 'auto' or null"), or with ``values`` what its values look like, for an
    error about a value ("a number, 'auto' or null")."""
    base, _ = _split(hint)
    origin, args = typing.get_origin(base), typing.get_args(base)
    if origin in (typing.Union, types.UnionType):  # "a number, 'auto' or null", not "Union"
        names = [_type_name(a, values=values) for a in args if a is not type(None)]
        names += ["null"] if type(None) in args else []
        return ", ".join(names[:-1]) + f" or {names[-1]}" if len(names) > 1 else names[0]
    if values and base in _VALUE_NAMES:
        return _VALUE_NAMES[base]
    if origin is typing.Literal:
        return " or ".join(repr(a) for a in args)
    return getattr(base, "__name__", None) or str(base).replace("typing.", "")


# --- reference ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FieldDoc:
    """One key of a config for a reference page: its dotted path, type and constraint, default and the
    ``#:`` comment above it in the source ("" when it has none)."""

    key: str
    type: str
    default: Any
    doc: str


def describe(cls: type, prefix: str = "", defaults: Any = None) -> list[FieldDoc]:
    """Every key of the config dataclass ``cls`` (nested configs' keys dotted, ``gp.R_m``), in field order;
    ``defaults``: an instance whose values are the defaults (a nested section's default)."""
    out = []
    docs = _field_docs(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        hint = _fields(cls)[f.name].hint
        base, meta = _split(hint)
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if defaults is not None:
            default, required = getattr(defaults, f.name), False
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = None if required else f.default
        if dataclasses.is_dataclass(base) and isinstance(base, type):
            out += describe(base, f"{prefix}{f.name}.", default)
            continue
        options = [a for a in typing.get_args(base) if a is not type(None)]
        if len(options) == 1 and dataclasses.is_dataclass(options[0]):  # an optional section: itself, then its keys
            out.append(FieldDoc(prefix + f.name, "mapping or null", default, docs.get(f.name, "")))
            out += describe(options[0], f"{prefix}{f.name}.", default)  # type: ignore[arg-type]
            continue
        constraint = " ".join(str(m) for m in meta if isinstance(m, Range))
        choices = next((list(m.choices) for m in meta if isinstance(m, OneOf)), None)
        text = (
            _type_text(base) + (f" ({constraint})" if constraint else "") + (f", one of {choices}" if choices else "")
        )
        out.append(FieldDoc(prefix + f.name, text, dataclasses.MISSING if required else default, docs.get(f.name, "")))
    return out


def _type_text(hint: Any) -> str:
    """A field's type as a reference page writes it: "list of float", "mapping of str to float"."""
    base, _ = _split(hint)
    origin, args = typing.get_origin(base), typing.get_args(base)
    if origin in (typing.Union, types.UnionType):
        names = [_type_text(a) for a in args if a is not type(None)] + (["null"] if type(None) in args else [])
        return " or ".join(names)
    if origin is tuple and args and args[-1] is not Ellipsis:
        return "[" + ", ".join(_type_text(a) for a in args) + "]"
    if origin in (tuple, list, Sequence) and args:
        return f"list of {_type_text(args[0])}"
    if origin in (dict, Mapping) and args:
        return f"mapping of {_type_text(args[0])} to {_type_text(args[1])}"
    return _type_name(base)


def _field_docs(cls: type) -> dict[str, str]:
    """field name -> its description, over the dataclasses ``cls`` is made of: the ``#:`` comment lines
    right above the field, or an entry ``name: text`` (``a, b: text``) of the class's docstring."""
    import inspect

    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        docs.update(_docstring_entries(inspect.getdoc(klass) or ""))
        try:
            lines = inspect.getsource(klass).splitlines()
        except (OSError, TypeError):  # no source (a class made at run time)
            continue
        comment: list[str] = []
        for line in lines:
            text = line.strip()
            if text.startswith("#:"):
                comment.append(text[2:].strip())
                continue
            if comment and (match := re.match(r"(\w+)\s*:", text)):
                docs[match.group(1)] = " ".join(comment)
            comment = []
    return docs


def _docstring_entries(doc: str) -> dict[str, str]:
    """The ``name: text`` entries of a docstring (continued on more indented lines)."""
    entries: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in doc.splitlines():
        if match := re.match(r"(\w+(?:, \w+)*): (\S.*)", line):
            current = [match.group(2)]
            for name in match.group(1).split(", "):
                entries[name] = current
        elif current is not None and line.startswith(" ") and line.strip():
            current.append(line.strip())
        else:
            current = None
    return {name: " ".join(text) for name, text in entries.items()}
