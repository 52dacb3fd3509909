"""Load a NodeSpec from its `module:ATTRIBUTE` reference (the launcher resolves type names)."""

from __future__ import annotations

import importlib
from typing import Any

from palpate.errors import LaunchError
from palpate.runtime.spec import NodeSpec


def load_node_spec(reference: str, *, label: str = "") -> NodeSpec[Any]:
    """The NodeSpec named by `reference`, ``package.module:ATTRIBUTE``; `label` names it in errors."""
    label = label or reference
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise LaunchError(f"node type {label!r}: expected a reference 'package.module:ATTRIBUTE', got {reference!r}")
    try:
        module = importlib.import_module(module_name)
    except (ImportError, TypeError, ValueError) as exc:  # TypeError, ValueError: a relative name such as "..x"
        raise LaunchError(f"node type {label!r}: cannot import {module_name}: {exc}") from exc
    spec = getattr(module, attribute, None)
    if not isinstance(spec, NodeSpec):
        raise LaunchError(f"node type {label!r}: {module_name} has no NodeSpec named {attribute}")
    return spec
