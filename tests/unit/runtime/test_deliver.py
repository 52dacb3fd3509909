"""The runtime's delivery of a message to a handler: a rejected input is counted, logged once with node,
topic, field and reason (rate-limited per topic and field), and the node keeps its state; a bug propagates."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from palpate.errors import EstimationError, InputError, OutputError
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import Pose
from palpate.runtime.node import NodeContext, deliver


def pose(q: list[float]) -> Pose:
    return Pose(
        stamp_ns=0,
        frame="fingertip",
        position_m=np.zeros(3),
        quaternion_wxyz=np.array(q),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )


class Keeper:
    """A node that keeps the last pose whose quaternion has norm 1."""

    def __init__(self) -> None:
        self.q = np.array([1.0, 0.0, 0.0, 0.0])

    def on_pose(self, message: Pose) -> None:
        if abs(float(np.linalg.norm(message.quaternion_wxyz)) - 1.0) > 0.01:
            raise InputError("quaternion_wxyz", "not a unit quaternion")
        self.q = np.array(message.quaternion_wxyz)

    def on_other(self, message: Message) -> None:
        raise EstimationError("the estimator cannot use it")

    def on_bug(self, message: Message) -> None:
        raise KeyError("index_mcp_abd")

    def on_tick(self, stamp_ns: int) -> None:
        """Nothing per tick."""


def context() -> NodeContext:
    return NodeContext("ctrl", 0, lambda topic, message: None, {})


def test_rejected_input_is_counted_and_logged_with_node_topic_field_and_reason(
    caplog: pytest.LogCaptureFixture,
) -> None:
    ctx, node = context(), Keeper()
    with caplog.at_level(logging.WARNING):
        assert deliver(ctx, node, "pose", "sensors/effector_pose", pose([0.0, 1.0, 0.0, 0.0]))
        assert not deliver(ctx, node, "pose", "sensors/effector_pose", pose([0.0, 0.0, 0.0, 0.0]))
    assert ctx.counters["input_errors"] == 1
    np.testing.assert_array_equal(node.q, [0.0, 1.0, 0.0, 0.0])  # the state before the bad message
    [record] = caplog.records
    assert record.getMessage() == (
        "node ctrl, topic sensors/effector_pose: input rejected, field Pose.quaternion_wxyz: "
        "not a unit quaternion (1 so far)"
    )


def test_other_palpate_errors_are_rejections_without_a_field(caplog: pytest.LogCaptureFixture) -> None:
    ctx = context()
    with caplog.at_level(logging.WARNING):
        assert not deliver(ctx, Keeper(), "other", "x", pose([1.0, 0.0, 0.0, 0.0]))
    assert ctx.counters["input_errors"] == 1
    assert "topic x: input rejected, Pose: the estimator cannot use it (1 so far)" in caplog.text


def test_a_bug_in_a_handler_propagates() -> None:
    with pytest.raises(KeyError):
        deliver(context(), Keeper(), "bug", "x", pose([1.0, 0.0, 0.0, 0.0]))


def test_the_log_is_rate_limited_per_topic_and_field(caplog: pytest.LogCaptureFixture) -> None:
    ctx, node = context(), Keeper()
    with caplog.at_level(logging.WARNING):
        for _ in range(250):
            deliver(ctx, node, "pose", "a", pose([0.0, 0.0, 0.0, 0.0]))
        deliver(ctx, node, "pose", "b", pose([0.0, 0.0, 0.0, 0.0]))  # another topic: logged at once
    assert ctx.counters["input_errors"] == 251
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 10 + 2 + 1  # first 10, then the 100th and 200th, then topic b's first
    assert lines[-2].endswith("(200 so far)") and lines[-1].startswith("node ctrl, topic b:")


class Echo:
    """A node that publishes what it receives: an invalid message is its own bug, not bad input."""

    def __init__(self, ctx: NodeContext) -> None:
        self.ctx = ctx

    def on_pose(self, message: Pose) -> None:
        self.ctx.publish("out", message)

    def on_tick(self, stamp_ns: int) -> None:
        """Nothing per tick."""


def test_an_invalid_output_is_counted_as_the_nodes_bug_and_propagates() -> None:
    sent: list[Message] = []
    ctx = NodeContext("echo", 0, lambda topic, message: sent.append(message), {"out": "echo/pose"})
    broken = Pose(
        stamp_ns=0,
        frame="fingertip",
        position_m=np.array([np.nan, 0.0, 0.0]),
        quaternion_wxyz=np.array([1.0, 0.0, 0.0, 0.0]),
        linear_velocity_m_s=np.zeros(3),
        angular_velocity_rad_s=np.zeros(3),
    )
    with pytest.raises(OutputError, match=r"node 'echo' published an invalid Pose on port 'out'"):
        deliver(ctx, Echo(ctx), "pose", "in/pose", broken)
    assert not sent and ctx.counters["output_errors"] == 1 and ctx.counters["input_errors"] == 0


@pytest.mark.parametrize(
    "position",
    [np.array([np.nan, 0.0, 0.0]), np.array([0.0, 0.0]), np.array([[0.0, 0.0, 0.0]])],
    ids=["nan", "short", "2-d"],
)
def test_a_checking_send_refuses_what_validate_refuses(position: np.ndarray) -> None:
    """In-process, `codec.transfer` checks the message instead of `codec.validate` (send_checks): the
    same OutputError, counted, and nothing delivered."""
    sent: list[Message] = []
    ctx = NodeContext(
        "echo", 0, lambda topic, message: sent.append(codec.transfer(message)), {"out": "echo/pose"}, send_checks=True
    )
    broken = dataclasses.replace(pose([1.0, 0.0, 0.0, 0.0]), position_m=position)
    with pytest.raises(OutputError, match=r"node 'echo' published an invalid Pose on port 'out'"):
        deliver(ctx, Echo(ctx), "pose", "in/pose", broken)
    assert not sent and ctx.counters["output_errors"] == 1


def test_integer_arrays_are_validated_before_a_checking_send() -> None:
    """transfer converts an array to the schema's dtype before checking it; for a message with an integer
    array field publish still validates, so a NaN there is refused rather than cast."""
    from palpate.messages.schemas import ObjectTruth

    sent: list[Message] = []
    ctx = NodeContext(
        "truth", 0, lambda topic, message: sent.append(message), {"out": "truth/object"}, send_checks=True
    )
    broken = ObjectTruth(
        stamp_ns=0,
        name="cube",
        source="primitive",
        position_m=np.zeros(3),
        quaternion_wxyz=np.array([1.0, 0.0, 0.0, 0.0]),
        vertices_m=np.zeros((3, 3)),
        faces=np.array([[0.0, 1.0, np.nan]]),
    )
    with pytest.raises(OutputError, match=r"invalid ObjectTruth"):
        ctx.publish("out", broken)
    assert not sent


class TwoFields:
    """A node that refuses a pose for its position or for its quaternion, whichever is bad."""

    def on_pose(self, message: Pose) -> None:
        if not np.all(np.abs(message.position_m) < 10.0):
            raise InputError("position_m", "too far")
        if abs(float(np.linalg.norm(message.quaternion_wxyz)) - 1.0) > 0.01:
            raise InputError("quaternion_wxyz", "not a unit quaternion")

    def on_tick(self, stamp_ns: int) -> None:
        """Nothing per tick."""


def test_the_log_is_rate_limited_per_field_of_one_topic(caplog: pytest.LogCaptureFixture) -> None:
    ctx, node = context(), TwoFields()
    far = dataclasses.replace(pose([1.0, 0.0, 0.0, 0.0]), position_m=np.array([99.0, 0.0, 0.0]))
    with caplog.at_level(logging.WARNING):
        for _ in range(10):
            assert not deliver(ctx, node, "pose", "a", pose([0.0, 0.0, 0.0, 0.0]))
        assert not deliver(ctx, node, "pose", "a", far)  # another field of the same topic: logged at once
    assert ctx.counters["input_errors"] == 11
    assert caplog.records[-1].getMessage() == (
        "node ctrl, topic a: input rejected, field Pose.position_m: too far (1 so far)"
    )


def test_publishing_on_a_port_the_node_lacks_names_its_ports() -> None:
    sent: list[Message] = []
    ctx = NodeContext("echo", 0, lambda topic, message: sent.append(message), {"out": "echo/pose", "aux": "echo/aux"})
    with pytest.raises(KeyError, match=r"node 'echo' has no output port 'outt'; ports: \['aux', 'out'\]"):
        ctx.publish("outt", pose([1.0, 0.0, 0.0, 0.0]))
    assert not sent


def test_an_int_beyond_64_bits_is_an_output_error_in_process() -> None:
    """The in-process executor's transfer stands in for the check before sending: the node's message is
    counted and named, and nothing is delivered."""
    from palpate.messages.schemas import Clock

    sent: list[Message] = []
    ctx = NodeContext("clock", 0, lambda topic, m: sent.append(codec.transfer(m)), {"out": "clock"}, send_checks=True)
    with pytest.raises(OutputError, match=r"published an invalid Clock on port 'out': .*signed 64-bit range"):
        ctx.publish("out", Clock(stamp_ns=1 << 64, tick=0, period_ns=1, lockstep=True))
    assert not sent and ctx.counters["output_errors"] == 1


def test_a_failed_stop_after_rejected_inputs_names_their_count_and_the_first(caplog: pytest.LogCaptureFixture) -> None:
    """An outside walkthrough: 5 m of contact noise failed as 'no surface within 0.5 m', the rejected
    contacts' warnings far above. The reason stays as given (evaluations group runs by it)."""
    ctx, node = context(), Keeper()
    deliver(ctx, node, "pose", "sensors/effector_pose", pose([0.0, 0.0, 0.0, 0.0]))
    deliver(ctx, node, "other", "x", pose([1.0, 0.0, 0.0, 0.0]))
    with caplog.at_level(logging.ERROR):
        ctx.request_stop("found no surface", failed=True)
        ctx.request_stop("found no surface again", failed=True)
    assert ctx.failure == "found no surface" and ctx.stop_requested == "found no surface again"
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR] == [
        "node ctrl: the failure below follows 2 rejected input message(s); the first: topic sensors/effector_pose, "
        "field Pose.quaternion_wxyz: not a unit quaternion"
    ]


def test_a_stop_without_rejected_inputs_or_not_failed_keeps_its_reason() -> None:
    ctx = context()
    ctx.request_stop("found no surface", failed=True)
    assert ctx.failure == "found no surface"
    ctx, node = context(), Keeper()
    deliver(ctx, node, "other", "x", pose([1.0, 0.0, 0.0, 0.0]))
    ctx.request_stop("budget reached")
    assert ctx.stop_requested == "budget reached"
