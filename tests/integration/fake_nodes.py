"""Tiny node types for runtime tests, referenced from launch files as `tests.integration.fake_nodes:NAME`.

Node processes import this module by name, so tests start `palpate launch` with the repository root
as working directory and on PYTHONPATH.
"""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass

from palpate.messages.schemas import ContactSet, JointState, RunControl
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class CrasherConfig:
    after_ticks: int = 3
    exit_code: int = 3


class Crasher:
    """Logs a line per tick and dies with `exit_code` (no clean-up) after `after_ticks` ticks."""

    def __init__(self, config: CrasherConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.ticks = 0
        print(f"crasher: started as pid {os.getpid()}", flush=True)

    def on_tick(self, stamp_ns: int) -> None:
        self.ticks += 1
        print(f"crasher: tick {self.ticks} at {stamp_ns} ns", flush=True)
        if self.ticks >= self.config.after_ticks:
            print(f"crasher: giving up with exit code {self.config.exit_code}", flush=True)
            os._exit(self.config.exit_code)


@dataclass(frozen=True, kw_only=True)
class QuitterConfig:
    after_ticks: int = 5
    #: Stop as a failure (``request_stop(..., failed=True)``).
    failed: bool = False


class Quitter:
    """Asks the graph to stop, with a reason, after `after_ticks` ticks (as an exploration at its goal)."""

    def __init__(self, config: QuitterConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.ticks = 0

    def on_tick(self, stamp_ns: int) -> None:
        self.ticks += 1
        if self.ticks == self.config.after_ticks:
            self.ctx.request_stop(f"quitter: done after {self.ticks} ticks", failed=self.config.failed)


@dataclass(frozen=True, kw_only=True)
class StubbornConfig:
    hang_s: float = 60.0


class Stubborn:
    """Ignores SIGTERM and SIGINT and hangs in close(): only SIGKILL ends it."""

    def __init__(self, config: StubbornConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.armed = False

    def on_tick(self, stamp_ns: int) -> None:
        if not self.armed:  # the runner installs its own handlers before the first tick: replace them
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            self.armed = True
            print("stubborn: ignoring SIGTERM and SIGINT", flush=True)

    def close(self) -> None:
        print("stubborn: hanging in close()", flush=True)
        time.sleep(self.config.hang_s)


@dataclass(frozen=True, kw_only=True)
class JointSinkConfig:
    gain: float  # required: no default
    label: str = "sink"


class JointSink:
    """Consumes joint states (a subscriber of another type than the demo's contacts)."""

    def __init__(self, config: JointSinkConfig, ctx: Context):
        self.config, self.ctx = config, ctx

    def on_joints(self, message: JointState) -> None:
        self.ctx.metrics["joints"] = float(len(message.names))

    def on_tick(self, stamp_ns: int) -> None:
        """Nothing to do per tick."""


@dataclass(frozen=True, kw_only=True)
class TrailingEchoConfig:
    sleep_s: float = 0.002


class TrailingEcho:
    """Republishes each contact set it reads on ``trailing/echo`` and sleeps ``sleep_s`` per tick, so that
    the clock source runs ahead of it (its spec says ``may_trail``)."""

    def __init__(self, config: TrailingEchoConfig, ctx: Context):
        self.config, self.ctx = config, ctx

    def on_contacts(self, message: ContactSet) -> None:
        self.ctx.publish("echo", message)

    def on_tick(self, stamp_ns: int) -> None:
        time.sleep(self.config.sleep_s)


@dataclass(frozen=True, kw_only=True)
class TickCheckConfig:
    label: str = "check"


class TickCheck:
    """Counts inputs whose stamp is not the stamp of the tick they are handled in, and prints the count."""

    def __init__(self, config: TickCheckConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.ticks = self.inputs = self.misfiled = 0

    def _check(self, message: ContactSet) -> None:
        self.inputs += 1
        self.misfiled += message.stamp_ns != self.ctx.stamp_ns

    on_contacts = _check
    on_echo = _check

    def on_tick(self, stamp_ns: int) -> None:
        self.ticks += 1

    def close(self) -> None:
        print(f"{self.config.label}: {self.ticks} ticks, {self.inputs} inputs, {self.misfiled} misfiled", flush=True)


@dataclass(frozen=True, kw_only=True)
class FailingClockConfig:
    after_ticks: int = 5
    back_at_tick: int = 0


class FailingClock:
    """A clock source (10 ms ticks) that ends the run as a failure after `after_ticks` ticks."""

    def __init__(self, config: FailingClockConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.period_ns = 10_000_000
        self.tick = 0

    def step(self) -> int | None:
        self.tick += 1
        if self.tick == self.config.after_ticks:
            self.ctx.request_stop(f"failing clock: gave up after {self.tick} ticks", failed=True)
        if self.tick == self.config.back_at_tick:  # a clock that goes back (a log recorded so, replayed)
            return 0
        return self.tick * self.period_ns

    def on_tick(self, stamp_ns: int) -> None:
        """A clock source works in step()."""


@dataclass(frozen=True, kw_only=True)
class RunFailerConfig:
    after_ticks: int = 5


class RunFailer:
    """Does what a driver does to make the run fail: publishes ``RunControl(command="fail")`` on
    ``graph/control`` after `after_ticks` ticks (not ``ctx.request_stop``, which a driver does not have)."""

    def __init__(self, config: RunFailerConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.ticks = 0

    def on_tick(self, stamp_ns: int) -> None:
        self.ticks += 1
        if self.ticks == self.config.after_ticks:
            reason = f"run_failer: sensor lost after {self.ticks} ticks"
            self.ctx.publish("control", RunControl(stamp_ns=stamp_ns, command="fail", reason=reason))


CRASHER = NodeSpec(name="crasher", config=CrasherConfig, factory=Crasher, doc="dies after a few ticks")
FAILING_CLOCK = NodeSpec(
    name="failing_clock",
    config=FailingClockConfig,
    factory=FailingClock,
    clock_source=True,
    doc="a clock source that ends the run as a failure",
)
QUITTER = NodeSpec(name="quitter", config=QuitterConfig, factory=Quitter, doc="requests a stop after a few ticks")
STUBBORN = NodeSpec(name="stubborn", config=StubbornConfig, factory=Stubborn, doc="ignores SIGTERM")
JOINT_SINK = NodeSpec(
    name="joint_sink",
    config=JointSinkConfig,
    factory=JointSink,
    inputs={"joints": Port(JointState)},
    doc="reads joint states; has a required parameter",
)
TRAILING_ECHO = NodeSpec(
    name="trailing_echo",
    config=TrailingEchoConfig,
    factory=TrailingEcho,
    inputs={"contacts": Port(ContactSet)},
    outputs={"echo": Port(ContactSet, topic="trailing/echo")},
    may_trail=True,
    doc="republishes contact sets, slowly",
)
TICK_CHECK = NodeSpec(
    name="tick_check",
    config=TickCheckConfig,
    factory=TickCheck,
    inputs={"contacts": Port(ContactSet), "echo": Port(ContactSet, topic="trailing/echo")},
    may_trail=True,
    doc="counts inputs handled in another tick than their stamp's",
)
RUN_FAILER = NodeSpec(
    name="run_failer",
    config=RunFailerConfig,
    factory=RunFailer,
    outputs={"control": Port(RunControl)},
    doc="publishes RunControl 'fail' after a few ticks, as a driver would",
)
