"""palpate.config: one path from YAML mappings to validated config dataclasses, with errors that name
the key path, the bad value, what is allowed and (from a launch file) the line of the key."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from palpate.config import (
    BlankIsDefault,
    Fraction,
    NonEmpty,
    NonNegative,
    NonNegativeFloat,
    OneOf,
    PositiveFloat,
    PositiveInt,
    Range,
    ScalarIsTuple,
    Validated,
    _fields,
    _split,
    check,
    load,
    load_yaml,
)
from palpate.errors import ConfigError, LaunchError
from palpate.launch.graph import resolve
from palpate.launch.loader import load_launch
from palpate.launch.node_types import NODE_TYPES, load_node_type
from palpate.nodes.controller.node import ControllerNodeConfig
from palpate.nodes.controller.trajectory import ControllerConfig
from palpate.nodes.explore_eval.core import EvalConfig
from palpate.nodes.planner.config import PlannerConfig


@dataclass(frozen=True, kw_only=True)
class Inner(Validated):
    radius_m: PositiveFloat = 0.01
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # a position: any sign


@dataclass(frozen=True, kw_only=True)
class Config(Validated):
    rate_hz: PositiveFloat
    count: Annotated[int, Range(ge=0)] = 3
    name: str = "x"
    enabled: bool = True
    sigma: Annotated[float | None, NonNegative] = None
    mode: Literal["igef", "gpv"] = "igef"
    kind: Annotated[str, OneOf(("cube", "sphere"))] = "cube"
    size_m: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = (0.1, 0.1, 0.1)
    gains: list[float] = field(default_factory=list)
    limits: dict[str, NonNegativeFloat] = field(default_factory=dict)
    share: Annotated[float, Fraction] = 0.5
    delay_s: NonNegativeFloat = 0.0
    seeds: Annotated[tuple[int, ...], NonEmpty] = (0,)
    inner: Inner = field(default_factory=Inner)
    parts: tuple[Inner, ...] = ()


@dataclass(frozen=True, kw_only=True)
class Interval(Validated):
    low_s: NonNegativeFloat = 0.0
    high_s: NonNegativeFloat = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.low_s < self.high_s:  # across fields: stays in __post_init__
            raise ConfigError(f"high_s = {self.high_s!r} must exceed low_s = {self.low_s!r}", ("high_s",))


def test_load_fills_defaults_and_converts() -> None:
    config = load(
        Config,
        {
            "rate_hz": 100,  # an int is a valid float
            "size_m": [1, 2, 3],
            "gains": [1, 2.5],
            "limits": {"a": 1},
            "inner": {"radius_m": 2, "offset_m": [-1, 0, 0]},
            "parts": [{}, {"radius_m": 0.5}],
            "mode": "gpv",
            "sigma": 0.5,
        },
    )
    assert config.rate_hz == 100.0 and isinstance(config.rate_hz, float)
    assert config.size_m == (1.0, 2.0, 3.0)
    assert config.gains == [1.0, 2.5]
    assert config.limits == {"a": 1.0}
    assert config.inner == Inner(radius_m=2.0, offset_m=(-1.0, 0.0, 0.0))
    assert config.parts == (Inner(), Inner(radius_m=0.5))
    assert (config.mode, config.sigma, config.count) == ("gpv", 0.5, 3)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({}, "where: missing required key 'rate_hz' (float)"),
        ({"rate_hz": 1, "rate": 2}, "where.rate: unknown key 'rate'; known keys: count, delay_s, enabled, gains, "),
        ({"rate_hz": math.nan}, "where.rate_hz: expected a finite number > 0, got nan"),
        ({"rate_hz": math.inf}, "where.rate_hz: expected a finite number > 0, got inf"),
        ({"rate_hz": 1, "gains": [1, -math.inf]}, "where.gains[1]: expected a finite number, got -inf"),
        ({"rate_hz": -1}, "where.rate_hz: expected a finite number > 0, got -1"),
        ({"rate_hz": 0}, "where.rate_hz: expected a finite number > 0, got 0"),
        ({"rate_hz": 1, "delay_s": -0.5}, "where.delay_s: expected a finite number >= 0, got -0.5"),
        ({"rate_hz": 1, "size_m": [0.1, -0.1, 0.1]}, "where.size_m[1]: expected a finite number > 0, got -0.1"),
        ({"rate_hz": 1, "share": 1.5}, "where.share: expected a finite number >= 0 and <= 1, got 1.5"),
        ({"rate_hz": "fast"}, "where.rate_hz: expected a finite number > 0, got 'fast'"),
        ({"rate_hz": True}, "where.rate_hz: expected a finite number > 0, got True"),
        ({"rate_hz": 1, "count": 2.5}, "where.count: expected an integer >= 0, got 2.5"),
        ({"rate_hz": 1, "count": -1}, "where.count: expected an integer >= 0, got -1"),
        ({"rate_hz": 1, "count": False}, "where.count: expected an integer >= 0, got False"),
        ({"rate_hz": 1, "name": 3}, "where.name: expected a string, got 3"),
        ({"rate_hz": 1, "enabled": "yes"}, "where.enabled: expected true or false, got 'yes'"),
        ({"rate_hz": 1, "mode": "random"}, "where.mode: expected one of ['igef', 'gpv'], got 'random'"),
        ({"rate_hz": 1, "kind": "cone"}, "where.kind: expected one of ['cube', 'sphere'], got 'cone'"),
        ({"rate_hz": 1, "size_m": [1, 2]}, "where.size_m: expected 3 items, got [1, 2]"),
        ({"rate_hz": 1, "gains": [1, "a"]}, "where.gains[1]: expected a finite number, got 'a'"),
        ({"rate_hz": 1, "gains": 3}, "where.gains: expected a list, got 3"),
        ({"rate_hz": 1, "gains": "abc"}, "where.gains: expected a list, got 'abc'"),
        ({"rate_hz": 1, "seeds": []}, "where.seeds: expected a non-empty list, got []"),
        ({"rate_hz": 1, "limits": [1]}, "where.limits: expected a mapping, got [1]"),
        ({"rate_hz": 1, "limits": {"a": -1}}, "where.limits.a: expected a finite number >= 0, got -1"),
        ({"rate_hz": 1, "sigma": "big"}, "where.sigma: expected a finite number >= 0, got 'big'"),
        ({"rate_hz": 1, "sigma": -1.0}, "where.sigma: expected a finite number >= 0, got -1.0"),
        ({"rate_hz": 1, "inner": {"radius": 1}}, "where.inner.radius: unknown key 'radius'; known keys: offset_m, "),
        ({"rate_hz": 1, "inner": {"radius_m": -1}}, "where.inner.radius_m: expected a finite number > 0, got -1"),
        ({"rate_hz": 1, "inner": 3}, "where.inner: expected a mapping of Inner keys, got 3"),
        (
            {"rate_hz": 1, "parts": [{}, {"radius_m": math.nan}]},
            "where.parts[1].radius_m: expected a finite number > 0",
        ),
        ({"rate_hz": 1, "inner": {"offset_m": [0, math.nan, 0]}}, "where.inner.offset_m[1]: expected a finite number"),
    ],
)
def test_errors_name_the_key_path_the_value_and_what_is_allowed(params: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load(Config, params, "where")
    assert str(info.value).startswith(message), str(info.value)


def test_an_unknown_key_names_the_closest_known_one() -> None:
    with pytest.raises(
        ConfigError, match=r"^where\.delay: unknown key 'delay'; known keys: count, .*; did you mean 'delay_s'\?$"
    ):
        load(Config, {"rate_hz": 1, "delay": 1}, "where")
    with pytest.raises(ConfigError, match=r"^where\.qqq: unknown key 'qqq'; known keys: count, .*, size_m$"):
        load(Config, {"rate_hz": 1, "qqq": 1}, "where")


def test_error_paths_lead_to_the_key() -> None:
    with pytest.raises(ConfigError) as info:
        load(Config, {"rate_hz": 1, "parts": [{}, {"offset_m": [0, 0, math.inf]}]})
    assert info.value.path == ("parts", 1, "offset_m", 2)
    with pytest.raises(ConfigError) as info:
        load(Config, {"rate_hz": 1, "inner": {"radius": 1}})
    assert info.value.path == ("inner", "radius")
    with pytest.raises(ConfigError) as info:
        load(Config, {"inner": {}})
    assert info.value.path == ()  # a missing key points at the mapping that lacks it


def test_the_class_name_is_the_default_root() -> None:
    with pytest.raises(ConfigError, match=r"^Config\.rate_hz: expected a finite number > 0, got -2$"):
        load(Config, {"rate_hz": -2})


def test_a_non_mapping_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"^where: expected a mapping of keys, got \[1, 2\]"):
        load(Config, [1, 2], "where")


def test_checks_across_fields_stay_in_post_init_and_name_their_key() -> None:
    assert load(Interval, {"low_s": 1, "high_s": 2}) == Interval(low_s=1.0, high_s=2.0)
    with pytest.raises(ConfigError) as info:
        load(Interval, {"low_s": 3, "high_s": 2}, "params.window")
    assert str(info.value) == "params.window: high_s = 2.0 must exceed low_s = 3.0"
    assert info.value.path == ("high_s",)


def test_a_check_across_fields_that_overflows_is_a_config_error() -> None:
    """A fuzzer's find: the simulator's tick_period_s = 1e308 made its check's round() raise OverflowError."""

    @dataclass(frozen=True, kw_only=True)
    class Ticks(Validated):
        tick_s: PositiveFloat = 0.01
        step_s: PositiveFloat = 0.002

        def __post_init__(self) -> None:
            super().__post_init__()
            if round(self.tick_s / self.step_s) < 1:
                raise ConfigError("tick_s must be at least step_s", ("tick_s",))

    with pytest.raises(ConfigError, match=r"^params: cannot convert float infinity to integer$"):
        load(Ticks, {"tick_s": 1e308, "step_s": 1e-300}, "params")


def test_building_in_python_runs_the_same_checks() -> None:
    with pytest.raises(ConfigError, match=r"^Config\.rate_hz: expected a finite number > 0, got nan$"):
        Config(rate_hz=math.nan)
    with pytest.raises(ConfigError, match=r"^Inner\.radius_m: expected a finite number > 0, got -0\.01$"):
        Inner(radius_m=-0.01)
    with pytest.raises(ConfigError, match=r"^Config\.inner: expected a mapping of Inner keys, got \{\}"):
        Config(rate_hz=1.0, inner={})  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"Interval\.low_s: expected a finite number >= 0"):
        Interval(low_s=-1.0)
    # numpy scalars and arrays are numbers and lists; nothing is converted when built in Python
    config = Config(rate_hz=np.float64(2.0), count=np.int64(1), size_m=np.ones(3))  # type: ignore[arg-type]
    assert isinstance(config.size_m, np.ndarray)
    check(config)


def test_blank_values_keep_the_default_and_a_scalar_can_be_a_tuple() -> None:
    @dataclass(frozen=True, kw_only=True)
    class Spec:
        size_m: Annotated[tuple[PositiveFloat, ...], BlankIsDefault, ScalarIsTuple] = (1.0,)
        path: Annotated[str | None, BlankIsDefault] = None
        name: str = "x"

    for blank in (None, "", []):
        assert load(Spec, {"size_m": blank, "path": blank}) == Spec()
    assert load(Spec, {"size_m": 0.5}).size_m == (0.5,)
    with pytest.raises(ConfigError, match=r"Spec\.size_m\[0\]: expected a finite number > 0, got -0.5"):
        load(Spec, {"size_m": -0.5})
    with pytest.raises(ConfigError, match=r"Spec\.name: expected a string, got None"):
        load(Spec, {"name": None})  # only declared fields treat blank as "not given"


def test_unsupported_annotations_are_a_programming_error() -> None:
    @dataclass(frozen=True)
    class Odd:
        tags: set[int] = field(default_factory=set)

    with pytest.raises(TypeError, match="cannot be read from YAML"):
        load(Odd, {"tags": [1]})
    with pytest.raises(TypeError, match="is not a dataclass"):
        load(dict, {})


# --- every node config -----------------------------------------------------------------------------------


def _node_config_classes() -> list[type]:
    """Every config dataclass a launch file can fill: node configs and the dataclasses inside them."""
    found: list[type] = []

    def visit(cls: type) -> None:
        if cls in found:
            return
        found.append(cls)
        for info in _fields(cls).values():
            for leaf in _leaves(info.hint):
                if dataclasses.is_dataclass(leaf):
                    visit(leaf)

    for node_type in sorted(NODE_TYPES):
        visit(load_node_type(node_type).config)
    return found


def _leaves(hint: Any) -> list[Any]:
    base = _split(hint)[0]
    origin, args = typing.get_origin(base), typing.get_args(base)
    if origin in (typing.Union, types.UnionType, tuple, list, dict) or (origin and args):
        return [leaf for a in args if a not in (Ellipsis, type(None)) for leaf in _leaves(a)]
    return [base]


NODE_CONFIGS = _node_config_classes()
#: Lengths and times that may be negative: positions and offsets. Every other *_m, *_mm and *_s field
#: of a node config declares a lower bound.
POSITIONS = {
    "ControllerNodeConfig.initial_target_m",
    "GPISNodeConfig.prior_centre_m",
    "MapperConfig.region_min_m",
    "MapperConfig.region_max_m",
    "SceneConfig.finger_mcp_offset_m",
    "ObjectSpec.position_m",
    "HandConfig.base_position_m",
    "FingerMount.base_position_m",
    "FingerConfig.base_position_m",
    "ProbeConfig.start_position_m",
}


def test_the_node_configs_are_found() -> None:
    names = {c.__name__ for c in NODE_CONFIGS}
    assert {"SimNodeConfig", "SceneConfig", "ObjectSpec", "HandConfig", "PlannerConfig", "GPISConfig"} <= names
    assert [c for c in NODE_CONFIGS if not issubclass(c, Validated)] == []


def test_every_length_and_time_declares_a_lower_bound_unless_it_is_a_position() -> None:
    unbounded = set()
    for cls in NODE_CONFIGS:
        for name, info in _fields(cls).items():
            if not name.endswith(("_m", "_mm", "_s")):
                continue
            for leaf_hint in _number_hints(info.hint):
                bounds = [m for m in _split(leaf_hint)[1] if isinstance(m, Range)]
                if not any(b.ge is not None or b.gt is not None for b in bounds):
                    unbounded.add(f"{cls.__name__}.{name}")
    assert unbounded == POSITIONS


def _number_hints(hint: Any, meta: tuple[Any, ...] = ()) -> list[Any]:
    """The number types inside a hint, each Annotated with every constraint that applies to it."""
    base, own = _split(hint)
    meta = (*meta, *own)
    if base in (int, float):
        return [Annotated[base, *meta]] if meta else [base]  # type: ignore[valid-type]
    args = [a for a in typing.get_args(base) if a not in (Ellipsis, type(None))]
    if typing.get_origin(base) in (typing.Union, types.UnionType):
        return [h for a in args for h in _number_hints(a, meta)]
    if typing.get_origin(base) in (tuple, list):
        return [h for a in args for h in _number_hints(a)]
    return []


def _float_fields(cls: type) -> list[str]:
    """Fields that hold one float (or None)."""
    out = []
    for name, info in _fields(cls).items():
        base = _split(info.hint)[0]
        options = typing.get_args(base) if typing.get_origin(base) in (typing.Union, types.UnionType) else (base,)
        if float in [_split(o)[0] for o in options]:
            out.append(name)
    return out


REGION = {"region_min_m": [0, 0, 0], "region_max_m": [0.1, 0.1, 0.1]}
REQUIRED = {
    "MapperConfig": REGION,
    "MapperNodeConfig": {"mapper": REGION},
    "ObjectSpec": {"kind": "cube"},
}
FLOAT_FIELDS = [(cls, name) for cls in NODE_CONFIGS for name in _float_fields(cls)]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize(("cls", "name"), FLOAT_FIELDS, ids=[f"{c.__name__}.{n}" for c, n in FLOAT_FIELDS])
def test_no_float_field_of_a_node_config_takes_nan_or_infinity(cls: type, name: str, bad: float) -> None:
    with pytest.raises(ConfigError) as info:
        load(cls, {**REQUIRED.get(cls.__name__, {}), name: bad}, "params")
    assert info.value.path == (name,)
    assert f"params.{name}: expected a finite number" in str(info.value)


# --- launch files: the line of the offending key ---------------------------------------------------------

SIM_LAUNCH = """\
nodes:
  - name: sim
    type: sim
    params:
      duration_s: 1.0
      tick_period_s: {tick}
      scene:
        effector: probe
        probe: {{radius_m: {radius}}}
        object:
          kind: box
          size_m:
            - 0.05
            - {size}
            - 0.05
"""


@pytest.mark.parametrize(
    ("values", "line", "message"),
    [
        ({"size": ".nan"}, 14, "params.scene.object.size_m[1]: expected a finite number > 0, got nan"),
        ({"size": "-0.04"}, 14, "params.scene.object.size_m[1]: expected a finite number > 0, got -0.04"),
        ({"radius": "-.inf"}, 9, "params.scene.probe.radius_m: expected a finite number > 0, got -inf"),
        ({"tick": "-0.01"}, 6, "params.tick_period_s: expected a finite number > 0, got -0.01"),
        ({"tick": "0.003"}, 6, "params: tick_period_s = 0.003 must be a positive multiple of the scene's time step"),
        ({"size": "wide"}, 14, "params.scene.object.size_m[1]: expected a finite number > 0, got 'wide'"),
    ],
)
def test_a_launch_file_error_names_the_line_of_the_key(
    values: dict[str, str], line: int, message: str, tmp_path: Path
) -> None:
    path = tmp_path / "sim.yaml"
    path.write_text(SIM_LAUNCH.format(**{"tick": "0.01", "radius": "0.008", "size": "0.04", **values}))
    with pytest.raises(LaunchError) as info:
        resolve(load_launch(path), bus_dir=tmp_path)
    assert str(info.value).startswith(f"{path}:{line}: node 'sim': {message}"), str(info.value)


def test_a_launch_file_names_unknown_and_missing_nested_keys_at_their_lines(tmp_path: Path) -> None:
    path = tmp_path / "sim.yaml"
    text = SIM_LAUNCH.format(tick="0.01", radius="0.008", size="0.04")
    path.write_text(text.replace("          kind: box\n", "          knd: box\n"))
    with pytest.raises(LaunchError, match=rf"^{path}:11: node 'sim': params.scene.object.knd: unknown key 'knd'"):
        resolve(load_launch(path), bus_dir=tmp_path)
    path.write_text(text.replace("          kind: box\n", ""))
    with pytest.raises(LaunchError, match=rf"^{path}:10: node 'sim': params.scene.object: missing required key 'kind'"):
        resolve(load_launch(path), bus_dir=tmp_path)


# --- property: valid values round-trip through YAML -----------------------------------------------------


def _strategy(hint: Any) -> st.SearchStrategy[Any]:
    """Valid YAML values (plain lists and dicts) for a declared config type."""
    base, meta = _split(hint)
    origin, args = typing.get_origin(base), typing.get_args(base)
    if origin in (typing.Union, types.UnionType):
        return st.one_of(
            *(st.none() if a is type(None) else _strategy(Annotated[a, *meta] if meta else a) for a in args)
        )  # type: ignore[valid-type]
    if origin is Literal:
        return st.sampled_from(args)
    if base is bool:
        return st.booleans()
    if base in (int, float):
        bounds = [m for m in meta if isinstance(m, Range)]
        low = max([b for r in bounds for b in (r.ge, r.gt) if b is not None], default=-1e6)
        high = min([b for r in bounds for b in (r.le, r.lt) if b is not None], default=1e6)
        if base is int:
            return st.integers(math.ceil(low) + any(r.gt is not None for r in bounds), int(high))
        strict_low = any(r.gt is not None for r in bounds)
        strict_high = any(r.lt is not None for r in bounds)
        return st.floats(low, high, exclude_min=strict_low, exclude_max=strict_high, allow_nan=False)
    if base is str:
        choices = [m.choices for m in meta if isinstance(m, OneOf)]
        return st.sampled_from(choices[0]) if choices else st.text(max_size=8)
    if origin in (tuple, list):
        if origin is tuple and args and args[-1] is not Ellipsis:
            return st.tuples(*(_strategy(a) for a in args)).map(list)
        return st.lists(_strategy(args[0]), min_size=1 if NonEmpty in meta else 0, max_size=4)
    if origin is dict:
        return st.dictionaries(st.text(min_size=1, max_size=6), _strategy(args[1]), max_size=3)
    if dataclasses.is_dataclass(base):
        fields = _fields(base)  # type: ignore[arg-type]
        return st.fixed_dictionaries(
            {n: _strategy(f.hint) for n, f in fields.items() if f.required},
            optional={n: _strategy(f.hint) for n, f in fields.items() if not f.required},
        )
    raise TypeError(hint)


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _assert_kept(given: Any, written: Any) -> None:
    """Every given value is in the loaded config (nested mappings also hold defaults)."""
    if isinstance(given, dict):
        for key, value in given.items():
            _assert_kept(value, written[key])
    elif isinstance(given, list):
        assert len(given) == len(written)
        for a, b in zip(given, written, strict=True):
            _assert_kept(a, b)
    else:
        assert given == written, (given, written)
        assert type(written) is (float if type(given) is int and type(written) is float else type(given))


@settings(max_examples=150, deadline=None)
@given(data=st.data())
@pytest.mark.parametrize("cls", [Config, PlannerConfig, ControllerConfig, ControllerNodeConfig, EvalConfig])
def test_valid_values_round_trip_through_yaml(cls: type, data: st.DataObject) -> None:
    params = data.draw(_strategy(cls))
    config = load(cls, params)
    written = _plain(config)
    _assert_kept(params, written)
    again = load(cls, yaml.safe_load(yaml.safe_dump(written)))
    assert again == config


def test_an_integer_too_large_for_a_float_is_a_config_error() -> None:
    from palpate.nodes.planner.config import PlannerConfig

    with pytest.raises(ConfigError, match=r"sigma1_m: expected a finite number > 0, got 1000"):
        load(PlannerConfig, {"sigma1_m": 10**400}, "planner")


@dataclass(frozen=True, kw_only=True)
class Edges(Validated):
    workers: PositiveInt = 1
    point_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    level: Literal[1, 2] = 1
    either: int | str = 0


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"workers": 0}, "where.workers: expected an integer >= 1, got 0"),
        ({"point_m": [1, 2, 3, 4]}, "where.point_m: expected 3 items, got [1, 2, 3, 4]"),
        ({"level": 1.0}, "where.level: expected one of [1, 2], got 1.0"),
        ({"level": True}, "where.level: expected one of [1, 2], got True"),
        ({"either": None}, "where.either: expected an integer or a string, got None"),
        ({"either": 1.5}, "where.either: expected an integer or a string, got 1.5"),  # (said "an integer")
    ],
)
def test_edges_of_the_declared_types_are_refused(params: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load(Edges, params, "where")
    assert str(info.value) == message


def test_edges_of_the_declared_types_pass() -> None:
    assert load(Edges, {"workers": 1, "point_m": [1, 2, 3], "level": 2, "either": "x"}) == Edges(
        workers=1, point_m=(1.0, 2.0, 3.0), level=2, either="x"
    )


def test_a_yaml_document_error_names_the_line_of_the_key() -> None:
    text = "rate_hz: 1\ninner:\n  offset_m: [0, 0, 0]\n  radius_m: -1\n"
    with pytest.raises(ConfigError) as info:
        load_yaml(Config, text, "config.yaml", "config")
    assert str(info.value) == "config.yaml:4: config.inner.radius_m: expected a finite number > 0, got -1"
    assert info.value.path == ("inner", "radius_m")


@dataclass(frozen=True, kw_only=True)
class Part(Validated):
    """A part.

    size_m, depth_m: how large
        it is.
    """

    size_m: PositiveFloat
    depth_m: NonNegativeFloat = 0.0
    #: Its name.
    name: str = "x"


@dataclass(frozen=True, kw_only=True)
class Whole(Validated):
    part: Part = field(default_factory=lambda: Part(size_m=2.0))
    spare: Part | None = None
    gains: Mapping[str, float] = field(default_factory=dict)


def test_describe_lists_every_key_with_type_default_and_description() -> None:
    """For the node reference (docs/nodes.md): nested keys dotted, defaults of a nested section from the
    section's default, descriptions from `#:` comments and from `name: text` entries of the docstring."""
    from palpate.config import describe

    rows = {d.key: (d.type, d.default, d.doc) for d in describe(Whole)}
    assert rows["part.size_m"] == ("float (> 0)", 2.0, "how large it is.")
    assert rows["part.name"] == ("str", "x", "Its name.")
    assert rows["spare"] == ("mapping or null", None, "")
    assert rows["spare.size_m"][1] is dataclasses.MISSING  # required where a spare is given
    assert rows["gains"] == ("mapping of str to float", {}, "")
