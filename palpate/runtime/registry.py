"""Node types by name. A launch file may also name any `module:ATTRIBUTE` holding a NodeSpec."""

from __future__ import annotations

import importlib
from typing import Any

from palpate.errors import LaunchError
from palpate.runtime.spec import NodeSpec

#: Built-in node types and the module whose `SPEC` describes each.
NODE_TYPES: dict[str, str] = {
    "sim": "palpate.nodes.sim.node",
    "noise": "palpate.nodes.noise.node",
    "mapper": "palpate.nodes.mapper.node",
    "gpis": "palpate.nodes.gpis.node",
    "planner": "palpate.nodes.planner.node",
    "controller": "palpate.nodes.controller.node",
    "explore_eval": "palpate.nodes.explore_eval.node",
    "cube_contacts": "palpate.nodes.demo.node:CUBE_CONTACTS",
    "contact_stats": "palpate.nodes.demo.node:CONTACT_STATS",
    "bbox_estimator": "palpate.nodes.demo.node:BBOX_ESTIMATOR",
    "replay": "palpate.record.replay_node:SPEC",
}


def load_node_spec(node_type: str) -> NodeSpec[Any]:
    """The NodeSpec of a built-in type name or of a `module:ATTRIBUTE` reference."""
    target = NODE_TYPES.get(node_type, node_type)
    module_name, _, attribute = target.partition(":")
    if not module_name or (node_type not in NODE_TYPES and not attribute):
        raise LaunchError(f"unknown node type {node_type!r}; built-in types: {', '.join(sorted(NODE_TYPES))}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise LaunchError(f"node type {node_type!r}: cannot import {module_name}: {exc}") from exc
    spec = getattr(module, attribute or "SPEC", None)
    if not isinstance(spec, NodeSpec):
        raise LaunchError(f"node type {node_type!r}: {module_name} has no NodeSpec named {attribute or 'SPEC'}")
    return spec
