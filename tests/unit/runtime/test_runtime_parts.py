"""Socket-free parts of the runtime: config building, node-type registry, manifests, subscription counting."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pytest

from palpate.errors import ConfigError, LaunchError
from palpate.launch.node_types import NODE_TYPES, load_node_type
from palpate.messages import codec
from palpate.messages.schemas import ContactSet, TouchEvent
from palpate.runtime import bus
from palpate.runtime.node import _latest_state_messages
from palpate.runtime.spec import NodeProcessSpec, NodeSpec, build_config, coerce


@dataclass(frozen=True, kw_only=True)
class Inner:
    radius_m: float = 0.01


@dataclass(frozen=True, kw_only=True)
class Config:
    rate_hz: float
    count: int = 3
    name: str = "x"
    enabled: bool = True
    sigma: float | None = None
    mode: Literal["igef", "gpv"] = "igef"
    size_m: tuple[float, float, float] = (0.1, 0.1, 0.1)
    gains: list[float] = field(default_factory=list)
    limits: dict[str, float] = field(default_factory=dict)
    inner: Inner = field(default_factory=Inner)


def test_build_config_fills_and_converts() -> None:
    config = build_config(
        Config,
        {
            "rate_hz": 100,  # an int is a valid float
            "size_m": [1, 2, 3],
            "gains": [1, 2.5],
            "limits": {"a": 1},
            "inner": {"radius_m": 2},
            "mode": "gpv",
            "sigma": 0.5,
        },
    )
    assert config.rate_hz == 100.0 and isinstance(config.rate_hz, float)
    assert config.size_m == (1.0, 2.0, 3.0)
    assert config.gains == [1.0, 2.5]
    assert config.limits == {"a": 1.0}
    assert config.inner == Inner(radius_m=2.0)
    assert (config.mode, config.sigma, config.count) == ("gpv", 0.5, 3)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({}, "where: missing required parameter 'rate_hz' (float)"),
        ({"rate_hz": 1, "rate": 2}, "where: unknown parameter 'rate'; known parameters: "),
        ({"rate_hz": "fast"}, "where.rate_hz: expected a number, got 'fast'"),
        ({"rate_hz": True}, "where.rate_hz: expected a number, got True"),
        ({"rate_hz": 1, "count": 2.5}, "where.count: expected int, got 2.5"),
        ({"rate_hz": 1, "count": False}, "where.count: expected int, got False"),
        ({"rate_hz": 1, "name": 3}, "where.name: expected str, got 3"),
        ({"rate_hz": 1, "mode": "random"}, "where.mode: expected one of ['igef', 'gpv'], got 'random'"),
        ({"rate_hz": 1, "size_m": [1, 2]}, "where.size_m: expected 3 items, got 2"),
        ({"rate_hz": 1, "gains": [1, "a"]}, "where.gains[1]: expected a number, got 'a'"),
        ({"rate_hz": 1, "gains": 3}, "where.gains: expected a list, got 3"),
        ({"rate_hz": 1, "limits": [1]}, "where.limits: expected a mapping, got [1]"),
        ({"rate_hz": 1, "inner": {"radius": 1}}, "where.inner: unknown parameter 'radius'"),
        ({"rate_hz": 1, "sigma": "big"}, "where.sigma: expected float | None, got 'big'"),
    ],
)
def test_build_config_errors_quote_the_key_and_value(params: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        build_config(Config, params, "where")
    assert message in str(info.value)


def test_build_config_rejects_a_non_mapping() -> None:
    with pytest.raises(ConfigError, match="expected a mapping of parameters, got list"):
        build_config(Config, [1, 2], "where")  # type: ignore[arg-type]


def test_coerce_rejects_unsupported_annotations() -> None:
    with pytest.raises(ConfigError, match="unsupported parameter type"):
        coerce(set[int], [1], "p")


def test_registry_resolves_builtin_and_module_attribute_types() -> None:
    assert load_node_type("cube_contacts").clock_source
    spec = load_node_type("tests.integration.fake_nodes:CRASHER")
    assert isinstance(spec, NodeSpec) and spec.name == "crasher"
    assert "cube_contacts" in NODE_TYPES


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("no_such_type", "unknown node type 'no_such_type'"),
        ("no.such.module:SPEC", "cannot import no.such.module"),
        ("tests.integration.fake_nodes:NOTHING", "has no NodeSpec named NOTHING"),
        ("tests.integration.fake_nodes:CrasherConfig", "has no NodeSpec named CrasherConfig"),
    ],
)
def test_registry_errors(name: str, message: str) -> None:
    with pytest.raises(LaunchError, match=message):
        load_node_type(name)


def test_process_spec_json_round_trip() -> None:
    spec = NodeProcessSpec(
        name="stats",
        type="contact_stats",
        node_spec="palpate.nodes.demo.node:CONTACT_STATS",
        params={"report": False},
        bus_dir="/tmp/bus",
        endpoint="ipc:///tmp/bus/stats.pub",
        publishes={},
        subscribes={"contacts": "sensors/contacts"},
        connect=["ipc:///tmp/bus/cube.pub"],
        expected_subscribers={"lockstep/ack": 1},
        forward_upstream=["a"],
        curve={"public": "p", "secret": "s", "server_public": "q"},
    )
    assert NodeProcessSpec.from_json(spec.to_json()) == spec
    assert json.loads(spec.to_json())["mode"] == "lockstep"


def test_manifests_list_live_publishers_only(tmp_path: Path) -> None:
    live = bus.Manifest("cube", "ipc://x", os.getpid(), {"sensors/contacts": "ContactSet"}, {})
    live.write(tmp_path)
    dead = bus.Manifest("ghost", "ipc://y", 2**22 + 12345, {"sensors/contacts": "ContactSet"}, {})  # no such pid
    dead.write(tmp_path)
    (tmp_path / "garbage.json").write_text("{not json")
    assert bus.read_manifests(tmp_path) == [live]
    assert bus.publishers_of(tmp_path) == {"sensors/contacts": [live]}
    assert bus.publishers_of(tmp_path, ["status"]) == {}
    assert not list(tmp_path.glob("*.tmp"))  # written atomically


def test_default_bus_dir_follows_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(bus.BUS_ENV, str(tmp_path / "bus"))
    assert bus.default_bus_dir() == tmp_path / "bus"
    assert (tmp_path / "bus").is_dir()
    assert bus.ipc_endpoint(tmp_path, "cube") == f"ipc://{tmp_path}/cube.pub"


def test_subscription_counter() -> None:
    counter = bus.SubscriptionCounter()
    expected = {"sensors/contacts": 2, "lockstep/ack": 1}
    assert counter.missing(expected) == expected
    for frame in (b"\x01sensors/contacts", b"\x01sensors/contacts", b"\x01lockstep/ack", b"\x00lockstep/ack", b""):
        counter.feed(frame)
    assert not counter.satisfied(expected)
    assert counter.missing(expected) == {"lockstep/ack": 1}
    counter.feed(b"\x01lockstep/ack")
    assert counter.satisfied(expected)


def _contacts(stamp: int) -> bytes:
    return codec.encode(
        ContactSet(
            stamp_ns=stamp,
            positions_m=np.zeros((1, 3)),
            local_positions_m=np.zeros((1, 3)),
            normals=np.zeros((1, 3)),
            forces_n=np.zeros(1),
            links=["tip"],
        )
    )


def test_realtime_keeps_only_the_latest_state_message_but_every_event() -> None:
    types = {"sensors/contacts": ContactSet, "controller/events": TouchEvent}
    batch = [
        (0, 1, "sensors/contacts", _contacts(1)),
        (0, 2, "controller/events", b"e1"),
        (0, 3, "sensors/contacts", _contacts(2)),
        (0, 4, "controller/events", b"e2"),
        (0, 5, "sensors/contacts", _contacts(3)),
    ]
    kept = _latest_state_messages(batch, types)  # type: ignore[arg-type]
    assert [seq for _, seq, _, _ in kept] == [2, 4, 5]
