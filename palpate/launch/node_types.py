"""Built-in node types by name; a launch file may also name any `module:ATTRIBUTE` holding a NodeSpec.

The launcher resolves a type name to a NodeSpec reference here and hands the reference to the node
process (`NodeProcessSpec.node_spec`), so the runtime never needs to know which nodes exist.
"""

from __future__ import annotations

from typing import Any

from palpate.errors import LaunchError
from palpate.runtime.registry import load_node_spec
from palpate.runtime.spec import NodeSpec

#: Built-in node types and the `module:ATTRIBUTE` of each one's NodeSpec.
NODE_TYPES: dict[str, str] = {
    "sim": "palpate.nodes.sim.node:SPEC",
    "noise": "palpate.nodes.noise.node:SPEC",
    "mapper": "palpate.nodes.mapper.node:SPEC",
    "gpis": "palpate.nodes.gpis.node:SPEC",
    "planner": "palpate.nodes.planner.node:SPEC",
    "controller": "palpate.nodes.controller.node:SPEC",
    "explore_eval": "palpate.nodes.explore_eval.node:SPEC",
    "cube_contacts": "palpate.nodes.demo.node:CUBE_CONTACTS",
    "contact_stats": "palpate.nodes.demo.node:CONTACT_STATS",
    "bbox_estimator": "palpate.nodes.demo.node:BBOX_ESTIMATOR",
    "replay": "palpate.record.replay_node:SPEC",
}


def node_spec_reference(node_type: str) -> str:
    """The `module:ATTRIBUTE` of a built-in type name, or `node_type` itself when it is one."""
    if node_type in NODE_TYPES:
        return NODE_TYPES[node_type]
    if ":" not in node_type:
        raise LaunchError(f"unknown node type {node_type!r}; built-in types: {', '.join(sorted(NODE_TYPES))}")
    return node_type


def load_node_type(node_type: str) -> NodeSpec[Any]:
    """The NodeSpec of a built-in type name or of a `module:ATTRIBUTE` reference."""
    return load_node_spec(node_spec_reference(node_type), label=node_type)
