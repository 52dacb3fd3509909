"""`palpate bench fuzz`: every node survives schema-valid extremes and garbage, and the fuzzer can see a crash.

The in-process harness is faithful to a node process for this purpose: it builds the node from its
NodeSpec with the runtime's NodeContext, decodes each payload with the codec and hands it over with the
runtime's own `deliver` (tests/integration/test_bad_input.py feeds the same frames to a real process).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

from palpate.bench import fuzz
from palpate.config import Validated
from palpate.launch.node_types import NODE_TYPES
from palpate.messages import codec
from palpate.messages.base import REGISTRY
from palpate.messages.schemas import JointState, Pose
from palpate.runtime.spec import Context, NodeSpec, Port


@pytest.mark.slow
def test_every_node_survives_400_frames_per_input_topic() -> None:
    # 400: the planner plans only when a plausible pose, touch and surface meet (1-4 plans in 200 frames)
    reports = fuzz.run(400, seed=0, one_per_type=True)
    assert {r.node_type for r in reports} >= set(NODE_TYPES) - {"sim", "replay", "cube_contacts"}
    assert any(r.node_type == "sim" for r in reports)  # its velocity input and its joint commands
    for r in reports:
        assert (r.crashes, r.bad_outputs) == (0, 0), (r.label, r.crash_examples)
        for topic, t in r.topics.items():
            assert t.frames == 400 and t.decode_errors + t.input_errors + t.accepted == 400, (r.label, topic)
            assert t.decode_errors > 40 and t.accepted > 0, (r.label, topic)  # garbage and real input both arrived
        assert sum(t.input_errors for t in r.topics.values()) > 0, r.label  # schema-valid extremes were refused
        if r.node_type != "contact_stats":  # the one node without outputs
            assert r.published > 0, r.label  # accepted frames reached the node's real work


@dataclass(frozen=True, kw_only=True)
class _NoConfig(Validated):
    pass


class _Fragile:
    """What the issue found: a handler that indexes by joint name, a tick that divides by a quaternion norm."""

    def __init__(self, config: _NoConfig, ctx: Context) -> None:
        self.q = np.array([1.0, 0.0, 0.0, 0.0])

    def on_joints(self, message: JointState) -> None:
        {"index_mcp_abd": 0}[message.names[0]]

    def on_pose(self, message: Pose) -> None:
        self.q = np.array(message.quaternion_wxyz)

    def on_tick(self, stamp_ns: int) -> None:
        with np.errstate(over="ignore"):
            1.0 / float(self.q @ self.q)


def test_the_harness_counts_crashes_in_handlers_and_ticks() -> None:
    spec = NodeSpec(
        name="fragile",
        config=_NoConfig,
        factory=_Fragile,
        inputs={"joints": Port(JointState), "pose": Port(Pose)},
    )
    template = fuzz.targets(one_per_type=True)[0].process
    process = replace(template, name="fragile", type="fragile", params={}, subscribes={"joints": "j", "pose": "p"})
    report = fuzz.fuzz_target(fuzz.FuzzTarget("fragile", spec, replace(process, clock_source=False)), 100)
    assert report.topics["j"].crashes > 10 and report.tick_crashes > 0
    assert any("KeyError" in e for e in report.crash_examples)


def test_frames_are_schema_valid_and_reach_the_extremes() -> None:
    rng = np.random.default_rng(3)
    for cls in REGISTRY.values():
        generator = fuzz.FrameGenerator(cls, rng)
        for _ in range(60):
            message = generator.message()
            decoded = codec.decode(codec.encode(message), cls)  # schema-valid: it decodes
            assert decoded == message
    quaternions = fuzz.FrameGenerator(Pose, rng)
    with np.errstate(over="ignore"):  # the norm of a quaternion of 1e300s is infinite
        norms = [float(np.linalg.norm(quaternions.message().quaternion_wxyz)) for _ in range(400)]
    assert min(norms) == 0.0 and max(norms) > 1e100 and sum(abs(n - 1) < 1e-12 for n in norms) > 100
    joints = fuzz.FrameGenerator(JointState, rng)
    lengths = [len(joints.message().names) for _ in range(3000)]  # a big dimension comes in ~0.3 % of them
    assert 0 in lengths and fuzz.BIG_DIMENSION in lengths
    kinds = {fuzz.FrameGenerator(Pose, rng).payload()[1] for _ in range(300)}
    assert "valid" in kinds and len(kinds) >= 8  # and most kinds of malformed payload


def test_the_command_ends_with_a_json_line(capsys: Any) -> None:
    args = argparse.Namespace(quick=False, json=True, frames=20, seed=0, node=["demo_minimal.yaml:stats"])
    assert fuzz.main(args) == 0
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert last["crashes"] == 0 and last["frames"] == 20 and last["frames_per_topic"] == 20
    assert [row["node"] for row in last["rows"]] == ["demo_minimal.yaml:stats"]
