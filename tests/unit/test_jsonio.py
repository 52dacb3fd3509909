"""Strict JSON: no bare NaN or Infinity in anything palpate writes as JSON, and every writer uses palpate.jsonio."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate import jsonio
from palpate.paths import REPO_ROOT

#: Calls of json.dump/json.dumps allowed outside palpate.jsonio: internal files that never hold a float.
INTERNAL_JSON = {
    "palpate/runtime/bus.py": "manifests: endpoint, pid, topic names",
    "palpate/runtime/spec.py": "the launcher's process spec (launch parameters are validated finite)",
    "palpate/record/mcap_io.py": "MCAP schema documents",
    "palpate/commands/docs.py": "the wire-format example in docs/messages.md",
    "palpate/commands/keys.py": "CurveZMQ key files",
    "palpate/commands/launch.py": "the recorder's --curve-servers argument (keys)",
    "palpate/bench/sim.py": "launch arguments passed on a command line",
}


def strict_loads(text: str) -> Any:
    """json.loads that refuses NaN and Infinity, as JSON parsers other than Python's do."""

    def refuse(name: str) -> None:
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_floats_become_null_everywhere() -> None:
    value = {
        "rmse_mm": math.nan,
        "inf": -math.inf,
        "ok": 1.5,
        "np": np.float64(np.nan),
        "np32": np.float32(2.5),
        "int": np.int64(3),
        "flag": np.bool_(True),
        "array": np.array([1.0, np.nan, np.inf]),
        "nested": [{"a": (math.nan, 2)}],
        "path": Path("out/x.json"),
    }
    text = jsonio.dumps(value, sort_keys=True)
    assert strict_loads(text) == {
        "array": [1.0, None, None],
        "flag": True,
        "inf": None,
        "int": 3,
        "nested": [{"a": [None, 2]}],
        "np": None,
        "np32": 2.5,
        "ok": 1.5,
        "path": "out/x.json",
        "rmse_mm": None,
    }
    with pytest.raises(ValueError, match="not JSON: NaN"):  # the check can fail: Python's own output
        strict_loads(json.dumps({"rmse_mm": math.nan}))
    with pytest.raises(TypeError, match="object is not JSON serialisable"):
        jsonio.dumps({"x": object()})


def test_write_creates_the_folder(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b.json"
    jsonio.write(path, {"x": math.nan}, indent=1)
    assert strict_loads(path.read_text()) == {"x": None}


def test_every_json_writer_goes_through_jsonio() -> None:
    """An ast scan: json.dump/json.dumps only in palpate.jsonio and the internal files listed above."""
    found = []
    for root in ("palpate", "nodes", "messages"):
        for path in sorted((REPO_ROOT / root).rglob("*.py")):
            rel = str(path.relative_to(REPO_ROOT))
            for node in ast.walk(ast.parse(path.read_text())):
                if (
                    isinstance(node, ast.Call)
                    and isinstance(node.func, ast.Attribute)
                    and node.func.attr in ("dump", "dumps")
                    and isinstance(node.func.value, ast.Name)
                    and node.func.value.id == "json"
                ):
                    found.append(rel)
    assert found, "the scan found no call at all: it is broken"
    stray = sorted({f for f in found if f not in INTERNAL_JSON and f != "palpate/jsonio.py"})
    assert not stray, f"write JSON with palpate.jsonio (null for NaN), not json.dumps: {stray}"
