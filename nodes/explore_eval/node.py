"""Exploration evaluator node: reads ground truth (an evaluator), scores the run, stops it at the goal.

It asks the GPIS node for the whole-object surface when coverage first reaches each milestone (50 %
and 80 %) to measure the surface RMSE there (with the GP variance, for the confident part), every
``EvalConfig.shape_interval`` contacts for the shape scores (without it), and ends the run at the coverage
goal or a budget.
At the end it prints a line for a reader (contacts, coverage, travel, how it ended), then one line
`explore_result: {json}` (without the per-touch rows and the shape scores every 10 contacts), and
optionally writes all of it as JSON, and a PNG.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from palpate.config import KeyPath, Validated
from palpate.errors import InputError
from palpate.geometry.mesh_query import edge_uses
from palpate.geometry.rotations import quat_to_matrix
from palpate.inputs import (
    MAX_COORDINATE_M,
    MAX_PATH_M,
    MAX_RATE,
    MAX_TURN_DEG,
    Accumulated,
    bounded,
    coordinates,
    per_vertex,
    triangle_mesh,
    unit_quaternion,
)
from palpate.jsonio import dumps as json_dumps
from palpate.jsonio import write as write_json
from palpate.messages.schemas import ObjectTruth, Pose, SurfaceMesh, SurfaceRequest, TouchEvent
from palpate.nodes.explore_eval.core import (
    FINISHED_PREFIX,
    EvalConfig,
    ExplorationEvaluator,
    RunControl,
    size_note,
)
from palpate.nodes.explore_eval.plot import plot_formats
from palpate.paths import output_path_problem
from palpate.runtime.spec import Context, NodeSpec, Port


@dataclass(frozen=True, kw_only=True)
class ExploreEvalNodeConfig(Validated):
    """Evaluation settings and where to write the results."""

    eval: EvalConfig = field(default_factory=EvalConfig)
    #: Write the whole result (every touch, milestone and shape score) to this JSON file; "": none.
    results_path: str = ""
    #: Draw the true mesh, the last estimate and the contacts to this image file, its format from the suffix
    #: (none: PNG); "": no plot.
    plot_path: str = ""
    #: Print the one-line JSON result when the run ends, and say at its start when the object is so small
    #: or so large that its run behaves unlike others (an evaluation's runs do not: it says both itself).
    report: bool = True


#: A run whose object truth has not come this long after its first tick (seconds of its time) fails.
NO_TRUTH_S = 5.0
#: How a launch caps a large object's runs and gives its mesh's unit (``size_note``).
LAUNCH_CAPS = (
    "cap them with the eval node's max_contacts and max_travel_m, with contacts_per_bound and travel_per_bound_m "
    "0 (--set eval.eval.contacts_per_bound=0 ...; a run ended by the launch's duration_s has no end-of-run "
    "scores); give scale:="
)


class ExploreEvalNode:
    """Thin wrapper around ExplorationEvaluator and its RunControl."""

    def __init__(self, config: ExploreEvalNodeConfig, ctx: Context):
        self.config, self.ctx = config, ctx
        self.name = ""  # the object's name, from its truth message
        self.evaluator: ExplorationEvaluator | None = None
        self.run: RunControl | None = None
        self.fingertip_quaternion: np.ndarray | None = None  # the fingertip's orientation (w, x, y, z), checked
        self.first_stamp_ns: int | None = None  # the first tick's stamp, while no truth has come
        self.truthless_stop = False  # the run was ended for want of a truth
        #: the touches' path length and rotation since the start, each checked against the last
        self.travelled = Accumulated("travelled_m", "m", MAX_PATH_M, MAX_RATE)
        self.turned = Accumulated("rotation_deg", "deg", MAX_TURN_DEG, math.degrees(MAX_RATE))
        self.last_estimate: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32))
        self.last_variance = np.zeros(0)
        self.result: dict[str, Any] = {}

    def on_truth_object(self, message: ObjectTruth) -> None:
        vertices, faces = triangle_mesh(message.vertices_m, message.faces, solid=True)
        if self.evaluator is not None:  # one object per run: a repeat must not wipe the records so far
            same = message.name == self.name and np.array_equal(vertices, self.evaluator.vertices_m)
            if same:
                return
            raise InputError("name", f"a second object {message.name!r} during the run on {self.name!r}")
        self.name = message.name
        self.evaluator = ExplorationEvaluator(np.array(vertices), np.array(faces), self.config.eval)
        self.run = RunControl(self.evaluator)
        bound = self.evaluator.covering_bound
        note = size_note(message.name, self.evaluator.area_m2, bound, self.config.eval, LAUNCH_CAPS)
        if note and self.config.report:
            self.ctx.log.warning("explore_eval: %s", note)
        if open_edges := int((edge_uses(np.asarray(faces)) == 1).sum()):
            self.ctx.log.warning(
                "explore_eval: the true mesh of %r is not closed (%d edges on one triangle only): its area, coverage "
                "and shape scores count the faces it has",
                message.name,
                open_edges,
            )

    def on_pose(self, message: Pose) -> None:
        coordinates(message.position_m, "position_m")  # checked as every pose; only the axis is used, at touches
        self.fingertip_quaternion = unit_quaternion(message.quaternion_wxyz, "quaternion_wxyz")

    def on_touches(self, message: TouchEvent) -> None:
        if self.run is None:
            raise InputError(
                "index", f"touch {message.index} came while no object truth (truth/object) was taken; it is not scored"
            )
        position = coordinates(message.position_m, "position_m")
        predicted = coordinates(message.predicted_contact_m, "predicted_contact_m", allow_nan=True)
        normal = np.array(coordinates(message.normal, "normal"))
        travelled = self.travelled.judge(message.travelled_m, message.stamp_ns)
        turned = self.turned.judge(message.rotation_deg, message.stamp_ns)
        asks = self.run.touch(
            self.ctx.stamp_ns,
            np.array(position),
            np.array(predicted),
            travelled.total,
            turned.total,
            None if self.fingertip_quaternion is None else quat_to_matrix(self.fingertip_quaternion)[:, 2],
            message.missed,
            normal,
        )
        self.travelled.take(travelled)  # a touch refused for any field leaves both as they were
        self.turned.take(turned)
        self.ctx.metrics["coverage"] = self.run.evaluator.tracker.coverage
        if asks:
            self._request_surface(self.ctx.stamp_ns)

    def on_surface(self, message: SurfaceMesh) -> None:
        if message.region != "global" or self.run is None:
            return
        vertices, faces = triangle_mesh(message.vertices_m, message.faces, solid=False)
        self.last_estimate = (np.array(vertices), np.array(faces))
        # a vertex without a variance counts as unsure (infinite variance)
        count = len(message.vertices_m)
        variance = bounded(message.vertex_variance, "vertex_variance", MAX_COORDINATE_M**2, "m^2", lower=0.0)
        self.last_variance = per_vertex(variance, message.variance_vertices, count, "variance_vertices", np.inf)
        if self.run.surface(*self.last_estimate, self.last_variance, message.num_contacts):
            self.ctx.request_stop(f"{FINISHED_PREFIX}: {self.run.evaluator.finished}")

    def on_tick(self, stamp_ns: int) -> None:
        """Watchdogs: end a run that has made no touch for EvalConfig.max_idle_s of simulated time, or whose
        last whole-object surface has not come within EvalConfig.surface_wait_s; and, as a failure, one
        without an object truth NO_TRUTH_S after its first tick (nothing could be scored)."""
        if self.run is None:
            self.first_stamp_ns = stamp_ns if self.first_stamp_ns is None else self.first_stamp_ns
            if stamp_ns - self.first_stamp_ns >= NO_TRUTH_S * 1e9 and not self.truthless_stop:
                self.truthless_stop = True
                self.ctx.request_stop(
                    f"explore_eval: no usable object truth on truth/object {NO_TRUTH_S:g} s into the run, so nothing "
                    "can be scored (the simulator, or a driver that plays it, publishes it at the start; a refused "
                    "one is logged above)",
                    failed=True,
                )
            return
        if self.run.tick(stamp_ns):
            self._request_surface(stamp_ns)
        elif self.run.overdue(stamp_ns):
            wait = self.config.eval.surface_wait_s
            finished = self.run.evaluator.finished
            self.ctx.request_stop(f"{FINISHED_PREFIX}: {finished} (no whole-object surface came within {wait:g} s)")

    def _request_surface(self, stamp_ns: int) -> None:
        """Ask for the whole-object surface, with the GP variance only when a milestone waits for it."""
        assert self.run is not None
        request = SurfaceRequest(stamp_ns=stamp_ns, region="global", variance=self.run.needs_variance)
        self.ctx.publish("request", request)

    def close(self) -> None:
        if self.evaluator is None:
            return
        self.evaluator.close_incomplete()
        self.result = self.evaluator.summary()
        self.result["object"] = self.name
        stopped_by = self.ctx.run_stopped_by
        if self.result["finished"] == "clock" and stopped_by and not stopped_by.startswith(FINISHED_PREFIX):
            self.result.update(finished="stopped", stop_reason=stopped_by)  # another node ended the run
        if self.result["finished"] == "clock" and self.config.report:
            shape = self.result.get("shape") or []
            last = f"those after contact {shape[-1]['contacts']}" if shape else "none"
            self.ctx.log.warning(
                "explore_eval: the run ended on the simulated clock (the launch's duration_s) after %d contacts, "
                "before any end-of-run score: its last shape scores are %s, and milestones not reached have no "
                "figures (the budgets, max_contacts and max_travel_m, end a run with them)",
                self.result.get("contacts", 0),
                last,
            )
        if self.config.report:  # first: a file that cannot be written must not take the result with it
            print(_headline(self.result), flush=True)
            brief = {k: v for k, v in self.result.items() if k not in ("touches", "shape")}  # results_path has all
            print("explore_result: " + json_dumps(brief), flush=True)
        try:
            self._write_files()
        except OSError as exc:  # a full disk, a folder removed during the run
            self.ctx.log.error("explore_eval: could not write the run's files: %s", exc)

    def _write_files(self) -> None:
        """The whole result as JSON (results_path) and the plot (plot_path), where set."""
        if self.config.results_path:
            write_json(self.config.results_path, self.result, indent=1)
        if self.config.plot_path:
            from palpate.nodes.explore_eval.plot import plot_run

            assert self.evaluator is not None
            contacts = np.array([t["position_m"] for t in self.result["touches"]]).reshape(-1, 3)
            title = f"{self.name}: {len(contacts)} contacts, coverage {100 * self.result['coverage']:.0f} %"
            plot_run(
                Path(self.config.plot_path),
                (self.evaluator.vertices_m, self.evaluator.faces),
                self.last_estimate,
                contacts,
                title,
            )


def _headline(result: dict[str, Any]) -> str:
    """The run in one line for a reader: contacts, coverage, travel and how it ended (the JSON line follows)."""
    touches = result.get("touches") or [{}]
    travel_cm = float(touches[-1].get("travel_cm", 0.0))
    why = f" ({result['stop_reason']})" if result.get("stop_reason") else ""
    return (
        f"{result.get('object')}: {result['contacts']} contacts, coverage {100 * result['coverage']:.1f} %, "
        f"travel {travel_cm:.1f} cm, finished: {result['finished']}{why}"
    )


def _checks(config: ExploreEvalNodeConfig) -> dict[KeyPath, str]:
    """Output paths the node could not write at the end of the run (it writes them only then)."""
    problems: dict[KeyPath, str] = {}
    for key, name in (("results_path", config.results_path), ("plot_path", config.plot_path)):
        example = "run.json" if key == "results_path" else "run.png"
        if name and (problem := output_path_problem(Path(name), example)):
            problems[(key,)] = problem
    if config.plot_path and not problems.get(("plot_path",)):
        suffix = Path(config.plot_path).suffix.lower().lstrip(".")
        formats = plot_formats()
        if suffix and suffix not in formats:  # (none: a PNG)
            problems[("plot_path",)] = (
                f"{config.plot_path}: the plot's format comes from its suffix, one of {', '.join(sorted(formats))}"
            )
    return problems


SPEC = NodeSpec(
    name="explore_eval",
    config=ExploreEvalNodeConfig,
    factory=ExploreEvalNode,
    inputs={
        "touches": Port(TouchEvent),
        "truth_object": Port(ObjectTruth),
        "pose": Port(Pose),
        "surface": Port(SurfaceMesh),
    },
    outputs={"request": Port(SurfaceRequest)},
    doc="Scores an exploration run against the true mesh (evaluator: reads truth/ topics).",
    checks=_checks,
)
