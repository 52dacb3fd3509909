"""`palpate bench fuzz [--frames N] [--json]`: feed every node's input handlers schema-valid extremes and garbage.

The contract (docs/runtime.md, "Bad input"): no message a node can receive kills it. A payload that
does not decode is a `decode_error`; a schema-valid message the node cannot use (a zero quaternion,
a joint state without the joints it needs, a target a kilometre away) is an `input_error`, logged
with node, topic, field and reason; either way the node keeps its state and goes on.

Targets: every node of every launch file shipped in `launch/` (each distinct node type, parameters
and ports once; parameters ending in `_path` are blanked so that nothing is written), plus the
simulator's finger driven by joint commands, which no shipped launch file uses. Each node object is
built from its NodeSpec exactly as a node process builds it, and each frame goes the way the runtime
takes it: `codec.decode` of the payload (a MessageError is a decode error), then the runtime's
`deliver` (palpate/runtime/node.py), which counts and logs a rejection. After every round of frames
(one per input topic) the node's `on_tick` runs, or, for a clock source, `step()`.

Frames (per input topic, `FrameGenerator`, seeded): 70 % schema-valid messages built from the
message's schema alone: named dimensions from 0 to 50,000 entries, every float field drawn from a
profile (plausible for its unit, zeros, constant, tiny 1e-300, huge 1e300, the largest double,
mixtures; a plausible stamp is the graph's time, as a sender stamps what it sends), quaternions and
normals unit or not, integer fields up to the int64 limits, strings from
the hand's joint and link names and the topics' words, shuffled, cut, duplicated, unknown or empty.
A third of these are plausible in every field, two fifths plausible but for one extreme field. The
other 30 % are malformed payloads: random bytes, truncated or bit-flipped payloads, another message
type, another schema version, missing, extra or mistyped fields, field names sent as msgpack bin
(bytes) beside str ones, NaN in a finite field, a claimed array larger than the payload.

A crash is an exception that would end a node process: anything but a PalpateError from a handler,
or any exception from `on_tick`, `step()` or `close()`. The report counts frames, decode errors,
input errors and crashes per node and topic; with --json the last line is one JSON object whose
`crashes` must be 0 (exit code 1 otherwise).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import logging
import re
import sys
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from palpate import jsonio
from palpate.argtypes import non_negative_int, positive_int
from palpate.config import load
from palpate.errors import ConfigError, MessageError, OutputError
from palpate.messages import codec
from palpate.messages.base import REGISTRY, FieldSpec, Message
from palpate.text_table import Column, fixed_width_table

#: Frames per input topic (--quick: QUICK_FRAMES).
FRAMES = 1000
QUICK_FRAMES = 200
#: Share of frames that are malformed payloads (the rest are schema-valid messages).
MALFORMED_SHARE = 0.3
#: The largest named dimension a frame gets (the issue's 50,000-joint JointState).
BIG_DIMENSION = 50_000

_FLOAT_MAX = float(np.finfo(np.float64).max)
_INT64 = (-(2**63), 2**63 - 1)
#: Plausible magnitude of a value by unit (the message schemas' units).
_UNIT_SCALE = {"m": 0.05, "m/s": 0.05, "rad": 1.0, "rad/s": 1.0, "N": 2.0, "deg": 90.0, "m^2": 1e-4, "ns": 1e9}
_TINY_AND_HUGE = (5e-324, -5e-324, 1e-300, -1e-200, 1e-30, 1e30, -1e30, 1e200, -1e300, _FLOAT_MAX, -_FLOAT_MAX)
_EXTREME_FLOATS = (0.0, -0.0, *_TINY_AND_HUGE)
_QUOTED = re.compile(r"'([^']+)'")
_FLOAT_PROFILES = ("zeros", "constant", "tiny", "huge", "large", "mixed")
_INT_PROFILES = ("zeros", "negative", "huge", "mixed")
#: Words the nodes compare strings with (regions, strategies, commands, curve kinds, map kinds).
_WORDS = (
    "local",
    "global",
    "igef",
    "gpv",
    "random",
    "stop",
    "initial",
    "approach",
    "recovery",
    "fingertip",
    "probe",
    "known",
    "best",
    "weighted",
    "dead_reckoning",
    "primitive",
    "torus",
)


def default_vocabulary() -> list[str]:
    """Strings a node may look for: the hand description's joint, digit and link names, and `_WORDS`."""
    from palpate.description import load_hand

    hand = load_hand()
    names = [*hand.joint_names(), *(d.name for d in hand.digits)]
    names += [f"{d.name}_{segment}" for d in hand.digits for segment in d.segments]
    return [*names, *_WORDS]


def name_groups() -> list[list[str]]:
    """Whole joint-name lists a node may expect (the hand's, each digit's), for JointState-like frames."""
    from palpate.description import load_hand

    hand = load_hand()
    return [hand.joint_names(), *(d.joint_names() for d in hand.digits)]


class FrameGenerator:
    """Schema-valid extremes and malformed payloads of one message type, from its schema alone."""

    def __init__(
        self,
        cls: type[Message],
        rng: np.random.Generator,
        vocabulary: Sequence[str] | None = None,
        groups: Sequence[Sequence[str]] | None = None,
    ) -> None:
        self.cls = cls
        self.rng = rng
        self.vocabulary = list(vocabulary) if vocabulary is not None else default_vocabulary()
        self.groups = [list(g) for g in groups] if groups is not None else name_groups()
        self.specs = cls.field_specs()
        self.others = [c for c in REGISTRY.values() if c is not cls]
        self.int_hints: list[int] = []
        #: The graph's time (ns): a plausible stamp is it, as a sender stamps what it sends (the harness sets it).
        self.now_ns = 0

    # --- schema-valid messages -------------------------------------------------------------------
    def message(self, int_hints: Sequence[int] = ()) -> Message:
        """One schema-valid message: plausible (1/3), plausible but for one extreme field (2/5), or any.

        int_hints: counts a plausible integer field takes half the time (the harness passes how many
        messages the node accepted per topic, so that a field such as `num_contacts` can match).
        """
        self.int_hints = list(int_hints)
        u = self.rng.random()
        names = list(self.specs)
        if u < 1 / 3:
            profiles = dict.fromkeys(names, "plausible")
        elif u < 1 / 3 + 2 / 5:
            profiles = dict.fromkeys(names, "plausible")
            profiles[names[int(self.rng.integers(len(names)))]] = "extreme"
        else:
            profiles = {name: "extreme" if self.rng.random() < 0.5 else "plausible" for name in names}
        dims: dict[str, int] = {}
        values: dict[str, Any] = {}
        # string lists first: a list of names tied to a dimension fixes its length
        for name, spec in self.specs.items():
            if spec.kind == "str_list":
                values[name] = self._strings(spec, dims, profiles[name])
        for name, spec in self.specs.items():
            if spec.kind != "str_list":
                values[name] = self._value(name, spec, dims, profiles[name])
        return self.cls(**values)

    def _dimension(self, dims: dict[str, int], dim: str) -> int:
        if dim not in dims:
            u = self.rng.random()
            if u < 0.1:
                dims[dim] = 0
            elif u < 0.3:
                dims[dim] = 1
            elif u < 0.7:
                dims[dim] = int(self.rng.integers(2, 11))
            elif u < 0.98:
                dims[dim] = int(self.rng.integers(11, 301))
            else:
                dims[dim] = BIG_DIMENSION
        return dims[dim]

    def _length(self, spec: FieldSpec, dims: dict[str, int]) -> int | None:
        if spec.shape and isinstance(spec.shape[0], str) and spec.shape[0] in dims:
            return dims[spec.shape[0]]
        return None

    def _strings(self, spec: FieldSpec, dims: dict[str, int], profile: str) -> list[str]:
        rng = self.rng
        fixed = self._length(spec, dims)
        u = rng.random() if profile == "extreme" or fixed is not None else rng.random() * 0.4
        if fixed is None and u < 0.25 and self.groups:  # a whole name list, shuffled
            words = list(self.groups[int(rng.integers(len(self.groups)))])
            rng.shuffle(words)
        elif fixed is None and u < 0.4 and self.groups:  # a subset of one
            group = self.groups[int(rng.integers(len(self.groups)))]
            words = [group[i] for i in sorted(rng.choice(len(group), int(rng.integers(0, len(group) + 1)), False))]
        else:
            n = fixed if fixed is not None else self._dimension({}, "n")
            words = [self._word() for _ in range(min(n, 1000))]
            words += words[-1:] * (n - len(words)) if words else []  # 50,000 names: duplicates
        if spec.shape and isinstance(spec.shape[0], str):
            dims[spec.shape[0]] = len(words)
        return words

    def _word(self) -> str:
        u = self.rng.random()
        if u < 0.75:
            return self.vocabulary[int(self.rng.integers(len(self.vocabulary)))]
        if u < 0.85:
            return ""
        if u < 0.97:
            return "".join(chr(int(c)) for c in self.rng.integers(32, 0x2FF, int(self.rng.integers(1, 20))))
        return "x" * 10_000

    def _value(self, name: str, spec: FieldSpec, dims: dict[str, int], profile: str) -> Any:
        rng = self.rng
        if spec.kind == "bool":
            return bool(rng.random() < 0.5)
        if spec.kind == "str":
            if profile == "extreme":
                return self._word()
            quoted = _QUOTED.findall(spec.doc)  # the values a field's doc names: 'local', 'global'
            if quoted and rng.random() < 0.8:
                return str(quoted[int(rng.integers(len(quoted)))])
            return self.vocabulary[int(rng.integers(len(self.vocabulary)))]
        if spec.kind == "int":
            if profile == "plausible":
                if spec.unit == "ns":
                    return self.now_ns
                if self.int_hints and rng.random() < 0.5:
                    return int(self.int_hints[int(rng.integers(len(self.int_hints)))])
                return int(rng.integers(0, 16 if rng.random() < 0.5 else 1000))
            return int(rng.choice([0, -1, 1, 2**31, -(2**31), *_INT64]))
        if spec.kind == "float":
            return float(self._floats(name, spec, (), profile)[()])
        assert spec.shape is not None and spec.dtype is not None
        shape = tuple(d if isinstance(d, int) else self._dimension(dims, d) for d in spec.shape)
        if np.dtype(spec.dtype).kind in "iu":
            info = np.iinfo(spec.dtype)
            return np.clip(self._ints(name, shape, dims, profile), info.min, info.max).astype(spec.dtype)
        values = self._floats(name, spec, shape, profile)
        if np.dtype(spec.dtype) != np.float64:  # float32: the largest finite value of that type at most
            top = float(np.finfo(spec.dtype).max)
            with np.errstate(invalid="ignore"):
                values = np.where(np.isfinite(values), np.clip(values, -top, top), values)
        return values.astype(spec.dtype)

    def _floats(self, name: str, spec: FieldSpec, shape: tuple[int, ...], profile: str) -> np.ndarray:
        rng = self.rng
        scale = _UNIT_SCALE.get(spec.unit, 1.0)
        if profile == "plausible":
            out = rng.normal(0.0, scale, shape)
            directional = "quaternion" in name or "normal" in name or "direction" in name
            if out.ndim and out.shape[-1] in (3, 4) and directional:
                out /= np.linalg.norm(out, axis=-1, keepdims=True)
            if "variance" in name:
                out = np.abs(out)
            return out
        profile = str(rng.choice(_FLOAT_PROFILES + (("nonfinite",) if not spec.finite else ())))
        if profile == "zeros":
            return np.zeros(shape)
        if profile == "constant":
            return np.full(shape, rng.choice(_EXTREME_FLOATS) if rng.random() < 0.5 else rng.normal(0.0, scale))
        signs = rng.choice([-1.0, 1.0], shape)
        if profile == "tiny":
            return signs * rng.choice([5e-324, 1e-300, 1e-200, 1e-30], shape)
        if profile == "huge":
            return signs * rng.choice([1e30, 1e200, 1e300, _FLOAT_MAX], shape)
        if profile == "large":
            return rng.normal(0.0, 10.0 ** float(rng.integers(3, 13)), shape)
        if profile == "nonfinite":
            return rng.choice([np.nan, np.inf, -np.inf, 0.0], shape)
        pool = np.array([*_EXTREME_FLOATS, scale, -scale, 1.0])
        return np.where(rng.random(shape) < 0.5, rng.choice(pool, shape), rng.normal(0.0, scale, shape))

    def _ints(self, name: str, shape: tuple[int, ...], dims: dict[str, int], profile: str) -> np.ndarray:
        rng = self.rng
        if profile == "plausible":
            high = dims.get("v", 64) if name in ("faces", "variance_vertices") else 64
            if name == "variance_vertices" and shape[0] <= high:  # a subset of the vertices, ascending
                return np.sort(rng.choice(high, shape[0], replace=False))
            return rng.integers(0, max(high, 1), shape)
        profile = str(rng.choice(_INT_PROFILES))
        if profile == "zeros":
            return np.zeros(shape, dtype=np.int64)
        if profile == "negative":
            return -rng.integers(1, 1000, shape)
        if profile == "huge":
            return rng.choice(np.array([2**31 - 1, -(2**31), *_INT64], dtype=np.int64), shape)
        return rng.integers(-(2**40), 2**40, shape)

    # --- malformed payloads ----------------------------------------------------------------------
    def payload(self, int_hints: Sequence[int] = ()) -> tuple[bytes, str]:
        """One frame: (payload, kind), kind 'valid' or 'malformed:<what>'."""
        if self.rng.random() >= MALFORMED_SHARE:
            return codec.encode(self.message(int_hints)), "valid"
        what = str(
            self.rng.choice(
                [
                    "random-bytes",
                    "truncated",
                    "bit-flips",
                    "other-type",
                    "other-version",
                    "missing-field",
                    "extra-field",
                    "mistyped-field",
                    "binary-keys",
                    "non-finite",
                    "huge-claimed-array",
                ]
            )
        )
        return self._malformed(what), f"malformed:{what}"

    def _malformed(self, what: str) -> bytes:
        rng = self.rng
        if what == "random-bytes":
            return rng.bytes(int(rng.integers(0, 300)))
        if what == "other-type":
            other = self.others[int(rng.integers(len(self.others)))]
            return codec.encode(FrameGenerator(other, rng, self.vocabulary, self.groups).message())
        good = codec.encode(self.message())
        if what == "truncated":
            return good[: int(rng.integers(0, max(len(good), 1)))]
        if what == "bit-flips":
            data = bytearray(good)
            for i in rng.integers(0, len(data), int(rng.integers(1, 8))):
                data[i] ^= 1 << int(rng.integers(8))
            return bytes(data)
        header, blob = msgpack.unpackb(good, raw=False)
        fields = header["fields"]
        names = list(fields)
        pick = names[int(rng.integers(len(names)))]
        if what == "other-version":
            header["version"] = int(rng.choice([0, header["version"] + 1, -1, 2**40]))
        elif what == "missing-field":
            del fields[pick]
        elif what == "extra-field":
            fields["unexpected_" + pick] = 1
        elif what == "mistyped-field":
            fields[pick] = [None, "text", 1.5, [1, 2], {"a": 1}, True][int(rng.integers(6))]
        elif what == "binary-keys":  # another encoder's bin keys beside str ones: a field renamed, one added
            fields[pick.encode()] = fields.pop(pick)
            fields["unexpected_" + pick] = 1
        elif what == "non-finite":
            floats = [n for n, s in self.specs.items() if s.finite and (s.kind == "float" or s.dtype == "<f8")]
            if not floats:
                return self._malformed("random-bytes")
            target = floats[int(rng.integers(len(floats)))]
            if self.specs[target].kind == "float":
                fields[target] = float(rng.choice([np.nan, np.inf, -np.inf]))
            else:
                arr = np.full(max(1, fields[target]["nbytes"] // 8), np.nan)
                fields[target] = {**fields[target], "offset": len(blob), "nbytes": arr.nbytes}
                fields[target]["shape"] = [1] * (len(fields[target]["shape"]) - 1) + [len(arr)]
                blob = blob + arr.tobytes()
        elif what == "huge-claimed-array":
            arrays = [n for n, s in self.specs.items() if s.kind == "array"]
            if not arrays:
                return self._malformed("truncated")
            target = arrays[int(rng.integers(len(arrays)))]
            fields[target] = {**fields[target], "shape": [2**40] * len(fields[target]["shape"]), "nbytes": 2**43}
        return bytes(msgpack.packb([header, blob], use_bin_type=True))


# --- targets -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FuzzTarget:
    """One node to fuzz: where it comes from, its NodeSpec and the process spec the launcher made."""

    label: str
    spec: Any  # NodeSpec
    process: Any  # NodeProcessSpec


def targets(launch_dir: Path | None = None, *, one_per_type: bool = False) -> list[FuzzTarget]:
    """Each distinct node (type, parameters, ports) of the shipped launch files, plus extra variants;
    with `one_per_type`, only the first of each node type and set of input topics."""
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch
    from palpate.paths import LAUNCH_DIR

    found: dict[str, FuzzTarget] = {}
    for path in sorted((launch_dir or LAUNCH_DIR).glob("*.yaml")):
        graph = resolve(load_launch(path))
        for spec, process in graph.in_process_members():
            process = dataclasses.replace(process, params=_blank_paths(process.params))
            key = jsonio.dumps([process.type, process.params, process.subscribes], sort_keys=True)
            found.setdefault(key, FuzzTarget(f"{path.name}:{process.name}", spec, process))
    out = [t for t in found.values() if t.spec.inputs]
    out.extend(_commanded_fingers(list(found.values())))
    if one_per_type:
        first: dict[str, FuzzTarget] = {}
        for t in out:
            first.setdefault(jsonio.dumps([t.process.type, sorted(t.process.subscribes.values())]), t)
        out = list(first.values())
    return out


def _blank_paths(params: Mapping[str, Any]) -> dict[str, Any]:
    return {k: ("" if k.endswith("_path") and isinstance(v, str) else v) for k, v in params.items()}


def _commanded_fingers(found: list[FuzzTarget]) -> list[FuzzTarget]:
    """The simulator's finger (or hand) taking joint commands, which no shipped launch file has."""
    from palpate.launch.node_types import load_node_type
    from palpate.messages import topics

    out = []
    for target in found:
        params = target.process.params
        scene = params.get("scene")
        if target.process.type != "sim" or not isinstance(scene, Mapping) or scene.get("effector") == "probe":
            continue
        params = {**params, "scripted_motion": False}
        subscribes = {"joint_commands": topics.JOINT_COMMANDS}
        process = dataclasses.replace(target.process, params=params, subscribes=subscribes)
        spec = load_node_type("sim").with_params(params)
        out.append(FuzzTarget(f"{target.label} (scripted_motion false)", spec, process))
        break
    return out


# --- running ---------------------------------------------------------------------------------------
#: A node that is not a clock source is rebuilt every this many rounds, so that state (a GP of every
#: touch so far) stays small enough for the counts in the frames to match it now and then.
RESET_ROUNDS = 50


@dataclass
class TopicReport:
    """Outcome of the frames sent to one input topic."""

    frames: int = 0
    decode_errors: int = 0
    input_errors: int = 0
    accepted: int = 0
    crashes: int = 0


@dataclass
class TargetReport:
    """Outcome for one node: per topic, plus crashes outside the handlers and refused outputs."""

    label: str
    node_type: str
    topics: dict[str, TopicReport] = field(default_factory=dict)
    #: Exceptions from on_tick, step() or close().
    tick_crashes: int = 0
    #: Messages the node tried to publish that failed validation (NaN computed from an accepted input).
    bad_outputs: int = 0
    #: Messages the node published (it got past its checks into its real work).
    published: int = 0
    crash_examples: list[str] = field(default_factory=list)
    slowest_frame_ms: float = 0.0
    seconds: float = 0.0

    @property
    def crashes(self) -> int:
        return self.tick_crashes + sum(t.crashes for t in self.topics.values())


class _Harness:
    """One node object, built as a node process builds it, fed frames through the runtime's delivery."""

    def __init__(self, target: FuzzTarget, report: TargetReport) -> None:
        from palpate.runtime.node import NodeContext

        self.target = target
        self.report = report
        process = target.process
        self.ctx = NodeContext(process.name, process.seed, self._send, dict(process.publishes))
        # one warning per rejected input is the point, not the output: a logger of the fuzzer's own, so the
        # node's (palpate.<name>) keeps its level for whatever runs next in this process
        self.ctx.log = logging.getLogger(f"palpate.fuzz.{process.name}")
        self.ctx.log.setLevel(logging.ERROR)
        validate = self.ctx.publish

        def publish(port: str, message: Message) -> None:
            try:
                validate(port, message)
            except OutputError:
                report.bad_outputs += 1
                raise

        self.ctx.publish = publish  # type: ignore[method-assign]
        config: Any = load(target.spec.config, process.params, f"node {process.name!r} params")
        self.node: Any = target.spec.factory(config, self.ctx)
        self.tick = 0
        self.period_ns = int(getattr(self.node, "period_ns", 0) or 10_000_000)
        self.accepted: dict[str, int] = {}

    def _send(self, topic: str, message: Message) -> None:
        codec.encode(message)  # what the bus does with it (ctx.publish validated it)
        self.report.published += 1

    def deliver(self, port: str, topic: str, payload: bytes) -> str:
        """'decode_errors', 'input_errors' or 'accepted'; raises when the node would crash."""
        from palpate.runtime.node import deliver

        cls = self.target.spec.inputs[port].message
        try:
            message = codec.decode(payload, cls)
        except MessageError:
            return "decode_errors"
        if not deliver(self.ctx, self.node, port, topic, message):
            return "input_errors"
        self.accepted[topic] = self.accepted.get(topic, 0) + 1
        return "accepted"

    def advance(self) -> bool:
        """One tick: `step()` of a clock source (False when its run is over), else `on_tick`."""
        stamp = self.tick * self.period_ns
        self.ctx.stamp_ns, self.ctx.tick = stamp, self.tick
        self.tick += 1
        if self.target.process.clock_source:
            return self.node.step() is not None
        self.node.on_tick(stamp)
        return self.tick % RESET_ROUNDS != 0

    def close(self) -> None:
        close = getattr(self.node, "close", None)
        if close is not None:
            close()


def fuzz_target(target: FuzzTarget, frames: int, seed: int = 0) -> TargetReport:
    """Feed `frames` frames to each input topic of `target`: in each round one frame per topic, then a tick."""
    rng = np.random.default_rng(seed)
    ports = dict(target.process.subscribes)
    generators = {port: FrameGenerator(target.spec.inputs[port].message, rng) for port in ports}
    report = TargetReport(target.label, target.process.type, {topic: TopicReport() for topic in ports.values()})
    start = time.perf_counter()
    harness = _Harness(target, report)
    for _ in range(frames):
        for port, topic in ports.items():
            generators[port].now_ns = harness.ctx.stamp_ns
            payload, kind = generators[port].payload(list(harness.accepted.values()))
            counts = report.topics[topic]
            counts.frames += 1
            t0 = time.perf_counter()
            try:
                outcome = harness.deliver(port, topic, payload)
            except Exception:  # the fuzzer's purpose: this exception would end the node process
                counts.crashes += 1
                _remember(report, f"{topic} handler, {kind} frame")
                harness = _Harness(target, report)
                continue
            finally:
                report.slowest_frame_ms = max(report.slowest_frame_ms, 1e3 * (time.perf_counter() - t0))
            setattr(counts, outcome, getattr(counts, outcome) + 1)
        try:
            alive = harness.advance()
        except Exception:  # as above: on_tick or step() raising ends the node process
            report.tick_crashes += 1
            _remember(report, "on_tick/step")
            alive = False
        if not alive:
            _close(harness, report)
            harness = _Harness(target, report)
    _close(harness, report)
    report.seconds = time.perf_counter() - start
    return report


def _close(harness: _Harness, report: TargetReport) -> None:
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # evaluators print their results at exit
            harness.close()
    except Exception:  # as above: close() raising ends the node process badly
        report.tick_crashes += 1
        _remember(report, "close")


def _remember(report: TargetReport, where: str) -> None:
    if len(report.crash_examples) < 5:
        last = traceback.format_exc().strip().splitlines()
        report.crash_examples.append(f"{where}: " + " | ".join(line.strip() for line in last[-3:]))


def run(
    frames: int, seed: int = 0, select: Callable[[FuzzTarget], bool] | None = None, *, one_per_type: bool = False
) -> list[TargetReport]:
    """Fuzz every target (or those `select` keeps) with `frames` frames per input topic."""
    reports = []
    for i, target in enumerate(targets(one_per_type=one_per_type)):
        if select is not None and not select(target):
            continue
        reports.append(fuzz_target(target, frames, seed + i))
        r = reports[-1]
        print(
            f"  {r.label}: {sum(t.frames for t in r.topics.values())} frames, {r.crashes} crashes, "
            f"{r.bad_outputs} bad outputs, {r.published} published, "
            f"{r.seconds:.1f} s",
            file=sys.stderr,
            flush=True,
        )
    return reports


def format_table(reports: Sequence[TargetReport]) -> str:
    """One line per node and input topic: frames, decode errors, input errors, accepted, crashes."""
    rows: list[dict[str, Any]] = [
        {
            "node": r.label,
            "topic": topic,
            "frames": t.frames,
            "decode_errors": t.decode_errors,
            "input_errors": t.input_errors,
            "accepted": t.accepted,
            "crashes": t.crashes,
        }
        for r in reports
        for topic, t in r.topics.items()
    ]
    width = max((len(r.label) for r in reports), default=4) + 2
    topic_width = max((len(topic) for r in reports for topic in r.topics), default=5) + 2
    columns = [
        Column("node", width, "node", align="<"),
        Column("topic", topic_width, "topic", align="<"),
        Column("frames", 8, "frames"),
        Column("decode errors", 15, "decode_errors"),
        Column("input errors", 14, "input_errors"),
        Column("accepted", 10, "accepted"),
        Column("crashes", 9, "crashes"),
    ]
    return fixed_width_table(columns, rows)


def summary(reports: Sequence[TargetReport], frames: int, seed: int, seconds: float) -> dict[str, Any]:
    return {
        "crashes": sum(r.crashes for r in reports),
        "frames_per_topic": frames,
        "seed": seed,
        "nodes": len(reports),
        "topics": sum(len(r.topics) for r in reports),
        "frames": sum(t.frames for r in reports for t in r.topics.values()),
        "decode_errors": sum(t.decode_errors for r in reports for t in r.topics.values()),
        "input_errors": sum(t.input_errors for r in reports for t in r.topics.values()),
        "accepted": sum(t.accepted for r in reports for t in r.topics.values()),
        "bad_outputs": sum(r.bad_outputs for r in reports),
        "slowest_frame_ms": max((r.slowest_frame_ms for r in reports), default=0.0),
        "seconds": seconds,
        "rows": [
            {
                "node": r.label,
                "type": r.node_type,
                "tick_crashes": r.tick_crashes,
                "bad_outputs": r.bad_outputs,
                "published": r.published,
                "seconds": r.seconds,
                "slowest_frame_ms": r.slowest_frame_ms,
                "crash_examples": r.crash_examples,
                "topics": {topic: dataclasses.asdict(t) for topic, t in r.topics.items()},
            }
            for r in reports
        ],
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--frames", type=positive_int, help=f"frames per input topic (default {FRAMES}, --quick {QUICK_FRAMES})"
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the frame generators")
    parser.add_argument("--node", action="append", default=[], help="only nodes whose label contains this text")


def main(args: argparse.Namespace) -> int:
    frames = args.frames or (QUICK_FRAMES if args.quick else FRAMES)
    wanted: list[str] = list(getattr(args, "node", []) or [])
    labels = [t.label for t in targets()]
    if unmatched := [w for w in wanted if not any(w in label for label in labels)]:  # a typo fuzzed nothing, green
        raise ConfigError(f"--node {', '.join(map(repr, unmatched))}: no node's label contains it; labels: {labels}")
    print(f"palpate bench fuzz: {frames} frames per input topic of every node, seed {args.seed}", flush=True)
    start = time.perf_counter()
    reports = run(frames, args.seed, (lambda t: any(w in t.label for w in wanted)) if wanted else None)
    print(format_table(reports))
    for r in reports:
        for example in r.crash_examples:
            print(f"crash in {r.label}: {example}")
    out = summary(reports, frames, args.seed, time.perf_counter() - start)
    print(f"crashes: {out['crashes']} in {out['frames']} frames ({out['seconds']:.0f} s)")
    if args.json:
        print(jsonio.dumps(out, sort_keys=True))
    return 0 if out["crashes"] == 0 and out["bad_outputs"] == 0 else 1
