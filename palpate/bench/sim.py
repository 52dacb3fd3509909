"""`palpate bench sim`: steps per second and real-time factor of the simulation, bare and in the graph.

For each scene (probe, finger, hand) touching a YCB object (011_banana; a box when the YCB folder is
absent, and the output says so), three tiers on the same MuJoCo model:

- bare: a bare ``mj_step`` loop (``nodes/sim/model_stats.py`` ``bare_step_rate``), zero controls, no
  contact sensing: the physics alone.
- in-process: the same launch graph run by ``palpate.runtime.inprocess.InProcessGraph`` (node
  objects, codec encode and decode, lockstep order; one process, no sockets), in a fresh process with
  the node processes' allocator settings: the simulation core with its exact-mesh contacts, the
  scripted motion, the node wrappers and the messages.
- graph: ``palpate launch`` of that graph, one process per node in lockstep over the bus.

The graphs are: probe - ``launch/probe.yaml`` (sim + :data:`PROBE_DRIVER`, which presses the probe
onto the object and slides it around, so the exact contact sensor runs every physics step, + noise
on the contacts); finger and hand - sim with its scripted exploration + noise on the joint angles +
:data:`SIM_SINK`, which reads pose, contacts and joint states. Both timing nodes record the wall
time of every tick; the rates use the ticks after a warm-up (start-up, including the scripted
motion's search for touch poses, is excluded). Real-time factor = simulated time / wall time;
steps per second = real-time factor / time step. overhead = in-process rate / graph rate is the
runtime's own cost (processes, sockets, lockstep acknowledgements); bare / graph is everything on
top of MuJoCo.

The ratio in-process / bare compares runs made side by side: each round measures the bare loop (the
best of three short trials: on a shared machine a single loop's rate varies by more than the goal's
margin) right before its in-process run, and the best of the rounds counts for each.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from palpate import jsonio
from palpate.argtypes import positive_float, positive_int
from palpate.config import NonNegativeFloat, Validated, load
from palpate.errors import BenchmarkError, InputError
from palpate.inputs import unit_vectors
from palpate.launch.loader import LaunchFile, load_launch, parse_cli_args
from palpate.launch.placement import PLACEMENTS
from palpate.messages import codec
from palpate.messages.schemas import CartesianVelocityCommand, ContactSet, JointState, Pose
from palpate.paths import LAUNCH_DIR, ycb_dir
from palpate.runtime.spec import Context, NodeSpec, Port
from palpate.runtime.timing import TIMING_ENV, breakdown
from palpate.text_table import Column, fixed_width_table

PROBE_LAUNCH = LAUNCH_DIR / "probe.yaml"
SCENES = ("probe", "finger", "hand")
YCB_OBJECT = "011_banana"
#: Used when the YCB folder is absent.
FALLBACK_OBJECT: dict[str, Any] = {"kind": "box"}


# --- timing nodes (used by the benchmark's graphs and by launch/probe.yaml) ---------------------------


#: The driver's angular velocity (3,): zero, frozen once (the codec passes it on without a copy).
_NO_TURN = codec.frozen(np.zeros(3))


class _TickTimes:
    """Wall time of every tick, written as JSON to ``path`` at close (nothing when path is empty)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.stamps_ns: list[int] = []
        self.wall_s: list[float] = []

    def tick(self, stamp_ns: int) -> None:
        self.stamps_ns.append(int(stamp_ns))
        self.wall_s.append(time.perf_counter())

    def close(self, extra: Mapping[str, Any]) -> None:
        if self.path:
            jsonio.write(self.path, {"stamps_ns": self.stamps_ns, "wall_s": self.wall_s, **extra})


@dataclass(frozen=True, kw_only=True)
class ProbeDriverConfig(Validated):
    """A scripted press-and-slide twist for the probe (a stand-in for the exploration controller)."""

    #: Speed towards the object before the first contact and after losing it, m/s.
    approach_speed_m_s: NonNegativeFloat = 0.05
    #: Speed into the surface while touching (the sim keeps the probe on the surface), m/s.
    press_speed_m_s: NonNegativeFloat = 0.01
    #: Speed along the surface while touching, m/s; the sliding direction turns at turn_rate_rad_s.
    slide_speed_m_s: NonNegativeFloat = 0.03
    turn_rate_rad_s: float = 2.0
    #: Write the wall time of every tick here as JSON (palpate bench sim); empty: do not.
    timing_path: str = ""


class ProbeDriver:
    """Presses the probe onto the object and slides it around; counts the contacts it gets.

    Before the first contact it moves along -z; while touching, it commands
    ``slide * t - press * n`` (n the mean contact normal, t a horizontal direction turning at
    turn_rate, projected onto the tangent plane); after losing contact it moves back along the last
    normal. The command goes out every tick (the sim applies it at the next tick).
    """

    def __init__(self, config: ProbeDriverConfig, ctx: Context) -> None:
        self.config, self.ctx = config, ctx
        self.times = _TickTimes(config.timing_path)
        self.normal: tuple[float, float, float] | None = None  # last contact normal
        self.touching = False
        self.contacts = 0
        self.ticks_in_contact = 0

    def on_contacts(self, message: ContactSet) -> None:
        rows = unit_vectors(message.normals, "normals").tolist()  # the one field the driver reads
        self.touching = len(rows) > 0
        if not self.touching:
            return
        x, y, z = rows[0] if len(rows) == 1 else np.mean(rows, axis=0).tolist()
        length = math.sqrt(x * x + y * y + z * z)
        if not length > 1e-6:  # opposite normals cancel: no direction to press along
            raise InputError("normals", "the contact normals cancel out; no direction to press along")
        self.normal = (x / length, y / length, z / length)
        self.contacts += len(rows)
        self.ticks_in_contact += 1

    def on_tick(self, stamp_ns: int) -> None:
        self.times.tick(stamp_ns)
        cfg = self.config
        if self.normal is None:
            linear = (0.0, 0.0, -cfg.approach_speed_m_s)
        elif not self.touching:
            nx, ny, nz = self.normal
            speed = cfg.approach_speed_m_s
            linear = (-speed * nx, -speed * ny, -speed * nz)
        else:
            nx, ny, nz = self.normal
            angle = cfg.turn_rate_rad_s * stamp_ns * 1e-9
            dx, dy = math.cos(angle), math.sin(angle)
            along = dx * nx + dy * ny
            tx, ty, tz = dx - along * nx, dy - along * ny, -along * nz  # d projected onto the tangent plane
            length = math.sqrt(tx * tx + ty * ty + tz * tz)
            scale = cfg.slide_speed_m_s / length if length > 1e-6 else 0.0
            press = cfg.press_speed_m_s
            linear = (scale * tx - press * nx, scale * ty - press * ny, scale * tz - press * nz)
        self.ctx.publish(
            "velocity",
            CartesianVelocityCommand(stamp_ns=stamp_ns, linear_m_s=np.array(linear), angular_rad_s=_NO_TURN),
        )

    def close(self) -> None:
        self.ctx.log.info(
            "probe driver: %d contacts in %d of %d ticks",
            self.contacts,
            self.ticks_in_contact,
            len(self.times.stamps_ns),
        )
        self.times.close({"contacts": self.contacts, "ticks_in_contact": self.ticks_in_contact})


PROBE_DRIVER = NodeSpec(
    name="probe_driver",
    config=ProbeDriverConfig,
    factory=ProbeDriver,
    inputs={"contacts": Port(ContactSet)},
    outputs={"velocity": Port(CartesianVelocityCommand)},
    doc="Scripted press-and-slide velocity commands for the sim probe (benchmark and tests).",
)


@dataclass(frozen=True, kw_only=True)
class SimSinkConfig(Validated):
    """Where to write the wall time of every tick (empty: nowhere)."""

    timing_path: str = ""


class SimSink:
    """Reads what a hand or finger sim publishes (pose, contacts, joint states) and times the ticks."""

    def __init__(self, config: SimSinkConfig, ctx: Context) -> None:
        self.ctx = ctx
        self.times = _TickTimes(config.timing_path)
        self.contacts = 0
        self.joint_states = 0
        self.poses = 0

    def on_pose(self, message: Pose) -> None:
        self.poses += 1

    def on_contacts(self, message: ContactSet) -> None:
        self.contacts += len(message.normals)

    def on_joint_states(self, message: JointState) -> None:
        self.joint_states += 1

    def on_tick(self, stamp_ns: int) -> None:
        self.times.tick(stamp_ns)

    def close(self) -> None:
        self.times.close({"contacts": self.contacts, "joint_states": self.joint_states, "poses": self.poses})


SIM_SINK = NodeSpec(
    name="sim_sink",
    config=SimSinkConfig,
    factory=SimSink,
    inputs={"pose": Port(Pose), "contacts": Port(ContactSet), "joint_states": Port(JointState)},
    doc="Consumes a hand or finger sim's outputs and records the wall time of every tick (benchmark).",
    may_trail=True,  # never stops a run: the clock need not wait for it when nothing in the loop reads it
)


# --- the benchmark ------------------------------------------------------------------------------------

_ARM_LAUNCH = """\
# generated by palpate bench sim
mode: lockstep
placement: ${{placement}}
seed: 0
nodes:
  - name: sim
    type: sim
    params:
      scene: {scene}
      tick_period_s: {tick_period_s}
      duration_s: {duration_s}
      scripted_motion: true
  - name: noise
    type: noise
    params: {{joints: true, sigma_deg: 1.5}}
  - name: sink
    type: palpate.bench.sim:SIM_SINK
    params: {{timing_path: "${{timing}}"}}
    remaps: {{joint_states: sensors/joint_states_noisy}}
args:
  timing: ""
  placement: os
"""


@dataclass(frozen=True, kw_only=True)
class SimBenchConfig:
    """How long to run each scene."""

    duration_s: float = 4.0
    warmup_s: float = 0.5
    bare_seconds: float = 2.0
    tick_period_s: float = 0.01
    #: In-process and graph runs alternate over this many rounds; the best of each counts.
    rounds: int = 2
    #: CPU placement of the launched graphs (palpate.launch.placement); "": each launch file's own.
    placement: str = ""


QUICK = SimBenchConfig(duration_s=1.0, warmup_s=0.2, bare_seconds=0.5, rounds=2)


def object_section() -> tuple[dict[str, Any], str]:
    """The scene's object: the YCB banana, or a box when the YCB folder is absent; and a note saying which."""
    root = ycb_dir()
    if root is not None and (root / f"{YCB_OBJECT}.stl").is_file():
        return {"kind": "mesh", "path": f"ycb:{YCB_OBJECT}"}, f"YCB {YCB_OBJECT}"
    return dict(FALLBACK_OBJECT), "a box primitive (YCB meshes not found: set PALPATE_YCB_DIR for 011_banana)"


def probe_start(obj: Mapping[str, Any], clearance_m: float = 0.012) -> list[float]:
    """A probe start above the object's highest vertex, so the driver's first descent meets it."""
    from palpate.nodes.sim.objects import ObjectSpec, load_object

    mesh = load_object(load(ObjectSpec, obj, "object")).mesh
    vertices = np.asarray(mesh.vertices)
    top = vertices[int(np.argmax(vertices[:, 2]))]
    return [float(top[0]), float(top[1]), float(top[2] + 0.008 + clearance_m)]


def scene_launch(scene: str, obj: Mapping[str, Any], config: SimBenchConfig, workdir: Path) -> tuple[Path, list[str]]:
    """The launch file of ``scene`` and its arguments (without ``timing``)."""
    if scene == "probe":
        args = [
            f"object:={obj['kind']}",
            f"mesh:={obj.get('path', '')}",
            f"start:={json.dumps(probe_start(obj))}",
            f"duration_s:={config.duration_s}",
            *_placement_args(config),
        ]
        return PROBE_LAUNCH, args
    text = _ARM_LAUNCH.format(
        scene=json.dumps({"effector": scene, "object": dict(obj)}),
        tick_period_s=config.tick_period_s,
        duration_s=config.duration_s,
    )
    path = workdir / f"{scene}.yaml"
    path.write_text(text)
    return path, _placement_args(config)


def _placement_args(config: SimBenchConfig) -> list[str]:
    return [f"placement:={config.placement}"] if config.placement else []


def rate_from_timing(path: Path, warmup_s: float) -> dict[str, float]:
    """Real-time factor over the ticks after ``warmup_s`` of simulated time, from a timing file."""
    data = json.loads(path.read_text())
    stamps = np.asarray(data["stamps_ns"], dtype=np.float64) * 1e-9
    wall = np.asarray(data["wall_s"], dtype=np.float64)
    start = int(np.searchsorted(stamps, warmup_s))
    if len(stamps) - start < 2:
        raise BenchmarkError(f"{path}: only {len(stamps)} ticks recorded; run longer than the warm-up {warmup_s} s")
    sim_s = float(stamps[-1] - stamps[start])
    wall_s = float(wall[-1] - wall[start])
    return {"sim_s": sim_s, "wall_s": wall_s, "rtf": sim_s / wall_s, "contacts": float(data.get("contacts", 0))}


def run_in_process(launch: Path, args: Sequence[str], timing: Path, warmup_s: float = 0.0) -> None:
    """Run the launch graph with the in-process executor, in this process; where the ticks after
    ``warmup_s`` spent their wall time (``InProcessGraph(profile=True)``) goes to ``<timing>.parts.json``."""
    from palpate.launch.graph import resolve
    from palpate.runtime.inprocess import InProcessGraph

    graph = resolve(load_launch(launch, parse_cli_args([*args, f"timing:={timing}"])), bus_dir=timing.parent / "bus")
    period_s = float(graph.by_name["sim"].params.get("tick_period_s", 0.01))
    runner = InProcessGraph(graph.in_process_members(), profile=True)
    runner.profile_from_tick = math.ceil(warmup_s / period_s)
    ticks = runner.run()
    measured = max(1, ticks - runner.profile_from_tick)
    parts = {name: 1000.0 * seconds / measured for name, seconds in sorted((runner.timing or {}).items())}
    _parts_path(timing).write_text(json.dumps({"ticks": measured, "ms_per_tick": parts}))


def _parts_path(timing: Path) -> Path:
    return timing.with_suffix(".parts.json")


def run_in_process_fresh(
    launch: Path, args: Sequence[str], timing: Path, timeout_s: float, warmup_s: float = 0.0
) -> dict[str, Any]:
    """:func:`run_in_process` in a fresh Python process with the node processes' allocator settings,
    so that both tiers start alike; returns the ms per tick of each part after the warm-up.
    BenchmarkError with its output on failure."""
    command = [sys.executable, "-m", "palpate.bench.sim", "inprocess", str(launch), str(timing), str(warmup_s), *args]
    _run_checked(command, timing, timeout_s)
    parts: dict[str, Any] = json.loads(_parts_path(timing).read_text())
    return parts


def run_launched(
    launch: Path, args: Sequence[str], timing: Path, timeout_s: float, warmup_s: float = 0.0
) -> dict[str, Any]:
    """``palpate launch`` the graph (one process per node) with per-tick timing on
    (``palpate.runtime.timing``); returns its breakdown after the warm-up. BenchmarkError with its
    output on failure."""
    command = [sys.executable, "-m", "palpate.cli", "launch", str(launch), *args, f"timing:={timing}"]
    command += ["--bus", str(timing.parent / f"bus-{timing.stem}")]
    folder = timing.parent / f"ticks-{timing.stem}"
    _run_checked(command, timing, timeout_s, {TIMING_ENV: str(folder)})
    return breakdown(folder, first_tick=math.ceil(warmup_s / 0.01))


def _run_checked(command: Sequence[str], timing: Path, timeout_s: float, env: Mapping[str, str] | None = None) -> None:
    try:
        done = subprocess.run(
            command,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
            env={**os.environ, **(env or {})},
        )
    except subprocess.TimeoutExpired as exc:
        raise BenchmarkError(f"{' '.join(command)} did not finish in {timeout_s:.0f} s") from exc
    if done.returncode != 0 or not timing.is_file():
        tail = "\n".join((done.stdout + done.stderr).splitlines()[-20:])
        raise BenchmarkError(f"{' '.join(command)} exited with code {done.returncode}:\n{tail}")


def scene_model(launch: LaunchFile) -> Any:
    """The scene's ``Simulation`` (its model, time step and sizes), built from the launch file."""
    from palpate.launch.graph import resolve
    from palpate.nodes.sim.core import Simulation
    from palpate.nodes.sim.scene import SceneConfig

    with tempfile.TemporaryDirectory() as bus_dir:
        graph = resolve(launch, bus_dir=Path(bus_dir))
    return Simulation(load(SceneConfig, graph.by_name["sim"].params["scene"], "scene"))


def bare_rate(model: Any, seconds: float, trials: int = 3) -> float:
    """Bare mj_step steps per second on ``model``: the best of ``trials`` loops of ``seconds / trials``."""
    from palpate.nodes.sim.model_stats import bare_step_rate

    return max(bare_step_rate(model, seconds / trials) for _ in range(trials))


#: Goals of issue 14: every scene in-process at 1/10 of bare mj_step or faster; the probe graph at
#: 10 times real time or faster.
GOAL_INPROCESS_OVER_BARE = 0.1
GOAL_PROBE_GRAPH_RTF = 10.0


def bench_scene(scene: str, obj: Mapping[str, Any], config: SimBenchConfig, workdir: Path) -> dict[str, Any]:
    """One row: bare, in-process and graph rates for ``scene``, the model's sizes and where a tick's
    time goes in each tier; the tiers alternate (ABBA...) over ``config.rounds`` rounds and the best
    round of each counts (a shared machine only slows runs down), with that round's breakdown."""
    from palpate.nodes.sim.model_stats import model_sizes

    launch, args = scene_launch(scene, obj, config, workdir)
    loaded = load_launch(launch, parse_cli_args(args))
    sim = scene_model(loaded)
    dt = sim.timestep_s
    sizes = {**model_sizes(sim.model), "exact_contact_spheres": sim.exact_contact_spheres}
    bare: list[float] = []
    rtf: dict[str, list[float]] = {"inprocess": [], "graph": []}
    totals: dict[str, list[float]] = {"inprocess": [], "graph": []}
    parts: dict[str, list[dict[str, Any]]] = {"inprocess": [], "graph": []}
    contacts = 0.0
    timeout_s = 180.0 + 20.0 * config.duration_s
    for round_index in range(config.rounds):
        tiers = ("inprocess", "graph") if round_index % 2 == 0 else ("graph", "inprocess")
        for tier in tiers:
            timing = workdir / f"{scene}-{tier}-{round_index}.json"
            if tier == "inprocess":  # the bare loop right before its in-process run
                bare.append(bare_rate(sim.model, config.bare_seconds))
            start = time.perf_counter()
            runner = run_in_process_fresh if tier == "inprocess" else run_launched
            parts[tier].append(runner(launch, args, timing, timeout_s, config.warmup_s))
            totals[tier].append(time.perf_counter() - start)
            rate = rate_from_timing(timing, config.warmup_s)
            rtf[tier].append(rate["rtf"])
            contacts = rate["contacts"]
    best = {tier: int(np.argmax(values)) for tier, values in rtf.items()}
    inproc, graph = rtf["inprocess"][best["inprocess"]], rtf["graph"][best["graph"]]
    bare_steps = max(bare)
    row: dict[str, Any] = {
        "scene": scene,
        "placement": loaded.placement,
        "timestep_s": dt,
        **sizes,
        "bare_steps_s": bare_steps,
        "bare_rtf": bare_steps * dt,
        "inprocess_steps_s": inproc / dt,
        "inprocess_rtf": inproc,
        "graph_steps_s": graph / dt,
        "graph_rtf": graph,
        "inprocess_over_bare": inproc / dt / bare_steps,
        "runtime_overhead": inproc / graph,
        "bare_over_graph": bare_steps * dt / graph,
        "measured_sim_s": config.duration_s - config.warmup_s,
        "contacts": contacts,
        "bare_steps_s_rounds": bare,
        "inprocess_rtf_rounds": rtf["inprocess"],
        "graph_rtf_rounds": rtf["graph"],
        "inprocess_total_s": min(totals["inprocess"]),
        "graph_total_s": min(totals["graph"]),
        "inprocess_breakdown_ms": parts["inprocess"][best["inprocess"]]["ms_per_tick"],
        "graph_breakdown_ms": parts["graph"][best["graph"]],
    }
    goals = {"inprocess_over_bare": row["inprocess_over_bare"] >= GOAL_INPROCESS_OVER_BARE}
    if scene == "probe":
        goals["graph_rtf"] = graph >= GOAL_PROBE_GRAPH_RTF
    row["goals_met"] = goals
    row["pass"] = all(goals.values())
    return row


def table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Plain-text table of the rows."""
    columns = [
        Column("scene", 8, "scene", align="<"),
        Column("dt ms", 6, lambda r: 1000 * r["timestep_s"], ".1f"),
        Column("bare steps/s", 14, "bare_steps_s", ".0f"),
        Column("in-proc steps/s", 17, "inprocess_steps_s", ".0f"),
        Column("graph steps/s", 15, "graph_steps_s", ".0f"),
        Column("graph RTF", 11, "graph_rtf", ".2f"),
        Column("in-proc/bare", 14, lambda r: r["bare_steps_s"] and r["inprocess_steps_s"] / r["bare_steps_s"], ".3f"),
        Column("overhead", 10, "runtime_overhead", ".2f"),
        Column("contacts", 10, "contacts", ".0f"),
    ]
    return fixed_width_table(columns, rows)


def sizes_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The MuJoCo model of each scene: bodies (world excluded), geoms, degrees of freedom, the geom pairs
    MuJoCo's collision detection considers, and the spheres of the exact-mesh contact sensing."""
    columns = [
        Column("scene", 8, "scene", align="<"),
        Column("bodies", 8, "bodies", "d"),
        Column("geoms", 7, "geoms", "d"),
        Column("DoF", 5, "dof", "d"),
        Column("actuators", 11, "actuators", "d"),
        Column("contact pairs", 15, "contact_pairs", "d"),
        Column("exact spheres", 15, "exact_contact_spheres", "d"),
    ]
    return fixed_width_table(columns, rows)


def breakdown_text(row: Mapping[str, Any]) -> str:
    """Where one tick's wall time goes (ms per tick), in-process and as a launched graph."""
    inproc = row["inprocess_breakdown_ms"]
    graph = row["graph_breakdown_ms"]
    lines = [f"  {row['scene']}: one {1000 * 0.01:g} ms tick, ms of wall time"]
    lines.append(
        "    in-process: "
        + ", ".join(f"{name} {value:.3f}" for name, value in inproc.items())
        + " (transfer is inside step and the handlers)"
    )
    per_node = ", ".join(
        f"{name} hop {graph['clock_hop_ms'][name]:.3f} wait {graph['wait_ms'][name]:.3f} "
        f"handle {graph['handle_ms'][name]:.3f}"
        for name in graph["handle_ms"]
    )
    lines.append(
        f"    graph: tick {graph['tick_ms']:.3f} = step {graph['step_ms']:.3f} (sim, building messages) + Clock "
        f"round trip {graph['round_trip_ms']:.3f} + commands {graph['source_dispatch_ms']:.3f} + rest; "
        f"encode {graph['encode_ms']:.3f} (all nodes); ack hop {graph['ack_hop_ms']:.3f}; {per_node}"
    )
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `palpate bench sim` beyond the shared --quick and --json."""
    parser.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES), help="scenes to run")
    parser.add_argument(
        "--duration", type=_duration, help=f"simulated seconds per scene and tier (at most {MAX_DURATION_S:g})"
    )
    parser.add_argument("--rounds", type=positive_int, help="alternating in-process/graph rounds; the best counts")
    parser.add_argument(
        "--placement",
        choices=PLACEMENTS,
        help="CPU placement of the launched graphs (default: each launch file's own: loop for the probe, os for "
        "finger and hand)",
    )


#: Longest --duration (simulated seconds): a day; 1e12 overflowed the subprocess's timeout.
MAX_DURATION_S = 86_400.0


def _duration(text: str) -> float:
    value = positive_float(text)
    if value > MAX_DURATION_S:
        raise argparse.ArgumentTypeError(f"{text!r} is more than {MAX_DURATION_S:g} s")
    return value


def main(args: argparse.Namespace) -> int:
    """`palpate bench sim [--quick] [--json] [--scenes ...] [--duration S]`; exit code 1 when a goal is missed."""
    config = QUICK if args.quick else SimBenchConfig()
    if getattr(args, "duration", None):
        config = replace(config, duration_s=args.duration, warmup_s=min(config.warmup_s, args.duration / 4))
    if getattr(args, "rounds", None):
        config = replace(config, rounds=args.rounds)
    if getattr(args, "placement", None):
        config = replace(config, placement=args.placement)
    obj, note = object_section()
    scenes = list(getattr(args, "scenes", None) or SCENES)
    print(
        f"palpate bench sim: {', '.join(scenes)} on {note}; {config.duration_s:g} s simulated per run "
        f"(first {config.warmup_s:g} s not timed), tick {1000 * config.tick_period_s:g} ms, best of "
        f"{config.rounds} alternating round(s); "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )
    rows = []
    with tempfile.TemporaryDirectory(prefix="palpate-bench-sim-") as tmp:
        for scene in scenes:
            print(f"  {scene} ...", file=sys.stderr, flush=True)
            rows.append(bench_scene(scene, obj, config, Path(tmp)))
    print(sizes_table(rows))
    print()
    print(table(rows))
    print(
        "overhead = in-process / graph rate (processes, sockets, lockstep); in-proc/bare = in-process rate over "
        "the bare mj_step rate of the same model"
    )
    print("where a tick goes (best round of each tier):")
    for row in rows:
        print(breakdown_text(row))
    passed = all(row["pass"] for row in rows)
    print(
        f"goals (issue 14): in-process >= {GOAL_INPROCESS_OVER_BARE:g} x bare in every scene, probe graph RTF >= "
        f"{GOAL_PROBE_GRAPH_RTF:g}: "
        + "; ".join(f"{row['scene']} {'met' if row['pass'] else 'MISSED'}" for row in rows)
    )
    if args.json:
        out = {
            "object": note,
            "duration_s": config.duration_s,
            "warmup_s": config.warmup_s,
            "rounds": config.rounds,
            "quick": bool(args.quick),
            "load_average_1min": os.getloadavg()[0],
            "goals": {"inprocess_over_bare_min": GOAL_INPROCESS_OVER_BARE, "probe_graph_rtf_min": GOAL_PROBE_GRAPH_RTF},
            "scenes": {row["scene"]: {k: v for k, v in row.items() if k != "scene"} for row in rows},
            "runtime_overhead_max": max(row["runtime_overhead"] for row in rows),
            "pass": passed,
        }
        print(jsonio.dumps(out, sort_keys=True))
    return 0 if passed else 1


def _inprocess_main(argv: Sequence[str]) -> int:
    """``python -m palpate.bench.sim inprocess LAUNCH TIMING WARMUP_S [name:=value ...]`` (used by the benchmark)."""
    if len(argv) < 4 or argv[0] != "inprocess":
        print("usage: python -m palpate.bench.sim inprocess LAUNCH TIMING WARMUP_S [name:=value ...]", file=sys.stderr)
        return 64
    from palpate.runtime import memory

    memory.keep_freed_buffers()  # as node processes do
    run_in_process(Path(argv[1]), argv[4:], Path(argv[2]), float(argv[3]))
    return 0


if __name__ == "__main__":
    sys.exit(_inprocess_main(sys.argv[1:]))
